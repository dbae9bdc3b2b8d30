"""Replay check: map a file's moves back to the part and judge what they would build.

Reads only the file and the model: the ``;HOSTD_KINEMATICS`` header gives the inverse
kinematics, ``;HOSTD_PROCESS`` the bead sizes, ``;HOSTD_PLACEMENT`` the STL → platform
placement. The deposits are sampled every half line width along the paths; every sample's
bead is material (for support beneath later points and for coverage), and every second
sample, one line width apart along a path, is *judged*. Reported (all shares in [0, 1]):

* ``inside``: judged samples inside the model (or within 0.1 w of its surface);
* ``coverage`` / ``shell_coverage``: model volume reached by the beads (:mod:`.coverage`);
* ``supported``: judged samples with support beneath them or bridging sparse infill, and the
  wall figures of the strict rule (:mod:`.support`);
* ``collisions``: head samples that hit printed material or the platform
  (:mod:`.collide`).

Judging every sample gave the same figures to within 0.02 percentage points on the sample
pipes and the 50k-face pipe, five-axis and planar, and the same unsupported wall layers
(``bench/replay.py --planar``, 2026-12-02), for 0.9–1.8 s less CPU on the 50k-face pipe:
a point's verdict does not depend on which others are judged
(``tests/slicer/test_replay.py``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np
import trimesh

from kinematics.machine import MachineGeometry
from slicer.gcode import GcodeFormatError, ParsedGcode, read_gcode
from slicer.gcode.markers import KINEMATICS, PLACEMENT, PROCESS
from slicer.paths import SlicingError
from slicer.printhead import Printhead, Segment
from slicer.replay.collide import find_collisions
from slicer.replay.coverage import coverage
from slicer.replay.geometry import ModelIndex
from slicer.replay.kdtree import point_tree
from slicer.replay.samples import (
    Samples,
    extruding_moves,
    geometry_from_header,
    map_and_sample,
    move_lengths,
    positioned_moves,
    sample_count,
)
from slicer.replay.stages import Stages
from slicer.replay.support import (
    FOOTPRINT,
    OUTLINE_DEPTH,
    WALL_SLACK,
    LayerSupport,
    bad_wall_layers,
    bead_axes,
    bridged,
    layer_support,
    strict_support,
)
from slicer.settings import MAX_BEAD_SHARE

INSIDE_SLACK = 0.1  # × line width
JUDGE_STRIDE = 2  # inside, support and walls are judged on every second deposited sample
TIP_SPACING = 1.0  # mm between head samples along moves
FAR_TIP_SPACING = 3.0  # mm between samples of the carriage (radius ≥ 15 mm by default)
TIP_ANGLE = 1.0  # degrees between head samples while the table turns
H_MIN, H_MAX = 0.25, 2.0  # bead heights read from E are clipped to these × layer height
MEMORY_BUDGET = 1 << 30  # bytes the check may hold at its peak (memory_estimate)
BRIDGE_CHUNK = 1 << 16  # bridging candidates whose footprints are tested at once
BYTES_PER_SAMPLE = 160  # peak bytes per deposited sample, per head sample, per move
BYTES_PER_TIP = 80
BYTES_PER_MOVE = 64
MAX_MISSES = 4096  # unsupported wall samples a report keeps


class ReplayBudgetError(SlicingError):
    """The part is too large to check within the replay's memory budget (one line)."""


@dataclass
class ReplayReport:
    """Figures of one replay; plain data (picklable, JSON-friendly via :meth:`to_dict`)."""

    moves: int
    extruding_moves: int
    deposited_mm: float
    points: int  # deposited samples, every half line width along the paths
    inside: float
    coverage: float
    shell_coverage: float
    supported: float
    bridged: float
    wall_points: int  # judged samples within WALL_SLACK line widths of the surface
    wall_supported: float
    unsupported_wall_layers: list[str]
    collisions: int
    collision_messages: list[str]
    # per layer, the unsupported share of its extrusion by length and the longest unsupported
    # run (mm) of the layer nearest the refusal zone (:func:`layer_text`), and the layers in
    # it (over both OVERHANG_SHARE and OVERHANG_RUN: printed in the air), worst first
    worst_layer_unsupported: float = 0.0
    worst_layer_run_mm: float = 0.0
    worst_layer: dict[str, Any] | None = None
    overhang_layers: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    cpu_timings: dict[str, float] = field(default_factory=dict)
    # unsupported wall samples of the bad wall layers (platform frame, at most MAX_MISSES,
    # evenly drawn), for a retry that leans the layers there; not in to_dict
    wall_misses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False,
                                    compare=False)

    @property
    def ok(self) -> bool:
        """Whether the file may be emitted (no collisions, no layer printed in the air)."""
        return self.collisions == 0 and not self.overhang_layers

    def to_dict(self) -> dict[str, object]:
        """The report as a plain dict (without ``wall_misses``)."""
        d = asdict(self)
        d.pop("wall_misses")
        return d

    def summary(self) -> str:
        """One line of the main figures."""
        return (f"inside {100 * self.inside:.2f}%, coverage {100 * self.coverage:.2f}% "
                f"(shell {100 * self.shell_coverage:.2f}%), supported "
                f"{100 * self.supported:.2f}% (bridging {100 * self.bridged:.2f}%), walls "
                f"supported {100 * self.wall_supported:.2f}% with "
                f"{len(self.unsupported_wall_layers)} unsupported wall layers, worst layer "
                f"{worst_layer_text(self.worst_layer)}, {self.collisions} collisions")


def _process(parsed: ParsedGcode) -> dict[str, float]:
    proc = parsed.require(PROCESS)
    try:
        out = {k: float(proc[k]) for k in ("layer_height", "line_width", "filament_diameter")}
    except (KeyError, TypeError, ValueError) as exc:
        raise GcodeFormatError(f";HOSTD_PROCESS: bad or missing key {exc}") from None
    out["perimeters"] = float(proc.get("perimeters", 2))
    out["infill_density"] = float(proc.get("infill_density", 0.2))
    return out


def _placement(parsed: ParsedGcode) -> np.ndarray:
    try:
        m = np.asarray(parsed.require(PLACEMENT)["matrix"], dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise GcodeFormatError(f";HOSTD_PLACEMENT: bad matrix ({exc})") from None
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise GcodeFormatError(";HOSTD_PLACEMENT: the matrix must be 4 × 4 and finite")
    return m


def _head(parsed: ParsedGcode, head: Printhead | None) -> Printhead:
    if head is not None:
        return head
    segs = parsed.headers.get(KINEMATICS, {}).get("printhead")
    return Printhead(tuple(_segment(s) for s in segs)) if segs else Printhead()


def _segment(values: Iterable[Any]) -> Segment:
    """A header's ``[start, end, r_start, r_end]`` as floats (ValueError for another count)."""
    start, end, r_start, r_end = map(float, values)
    return start, end, r_start, r_end


def _placed_mesh(mesh: trimesh.Trimesh, placement: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The model's vertices moved into the platform frame (v, 3) and its faces (t, 3)."""
    v = np.asarray(mesh.vertices, dtype=float) @ placement[:3, :3].T + placement[:3, 3]
    return v, np.asarray(mesh.faces)


def part_frame_path(parsed: ParsedGcode) -> np.ndarray:
    """End points of the extruding moves mapped back to STL coordinates, (n, 3)."""
    from kinematics.transform import inverse

    g = geometry_from_header(parsed)
    m = extruding_moves(parsed)
    p = inverse(parsed.end[m, :3], parsed.end[m, 3], parsed.end[m, 4], g)
    place = _placement(parsed)
    return (p - place[:3, 3]) @ np.linalg.inv(place[:3, :3]).T


def model_index(mesh: trimesh.Trimesh, line_width: float,
                placement: np.ndarray | None = None) -> ModelIndex:
    """The model's distance and inside index for a replay at ``line_width``: ``mesh`` moved by
    ``placement`` (already in the platform frame when ``None``).

    It needs nothing of the G-code, so a caller that slices the part may build it while the
    part is planned and hand it to :func:`replay_check`.
    """
    return ModelIndex(*_placed_mesh(mesh, np.eye(4) if placement is None else placement),
                      inside_pitch=_inside_pitch(line_width))


def replay_check(parsed: ParsedGcode, mesh: trimesh.Trimesh, head: Printhead | None = None,
                 platform_radius: float | None = None, placed: bool = False, threads: int = 2,
                 index: ModelIndex | None = None, memory_budget: float | None = None
                 ) -> ReplayReport:
    """Replay ``parsed`` against ``mesh`` and report the figures.

    ``mesh`` is in STL coordinates (moved by the file's placement), or already in the
    platform frame with ``placed``. ``head`` and ``platform_radius`` default to the file's
    ``;HOSTD_KINEMATICS`` values. With ``threads`` ≥ 2 the stages run on that many threads
    as their inputs allow (:mod:`.stages`); the figures are the same. ``index`` is
    :func:`model_index` of the placed ``mesh`` at the file's line width, when already built.

    Raises :class:`ReplayBudgetError` before any sample is taken when the check would need
    more than ``memory_budget`` bytes (default ``MEMORY_BUDGET``; :func:`check_budget`).
    """
    t0 = time.perf_counter()
    geo = geometry_from_header(parsed)
    proc = _process(parsed)
    w, t = proc["line_width"], proc["layer_height"]
    head = _head(parsed, head)
    radius = platform_radius if platform_radius is not None else float(
        parsed.headers.get(KINEMATICS, {}).get("platform_radius", 150.0))
    bead_area = math.pi * proc["filament_diameter"] ** 2 / 4.0 / w
    placement = np.eye(4) if placed else _placement(parsed)
    lengths = move_lengths(parsed)
    budget = MEMORY_BUDGET if memory_budget is None else memory_budget
    check_budget(parsed, lengths, w, budget, index.nbytes if _fits(index, w) else 0)
    with Stages(threads) as st:  # in an order where every input is submitted first
        model_f = st.submit("index", lambda: index if _fits(index, w) else model_index(
            mesh, w, placement))
        dep_f = st.submit("sample", lambda: _deposits(parsed, geo, lengths, bead_area, w, t))
        # the head's samples need no deposits: taken while the deposits are sampled
        tips_f = st.submit("head samples", lambda: _head_samples(parsed, geo, lengths,
                                                                 bead_area))
        tree_f = st.submit("tree", lambda: point_tree(dep_f.result()[1].p), dep_f)
        wall_f = st.submit("wall", lambda: _wall(
            model_f.result(), dep_f.result()[1].p[::JUDGE_STRIDE], w), model_f, dep_f)
        ok_f = st.submit("support", lambda: strict_support(
            dep_f.result()[1], t, w, radius, tree_f.result(),
            judged_samples(len(dep_f.result()[1]))), tree_f)
        hit_f = st.submit("collisions", lambda: find_collisions(
            parsed, *tips_f.result(), dep_f.result()[1], head, radius), tips_f, dep_f)
        cov_f = st.submit("coverage", lambda: coverage(
            model_f.result(), dep_f.result()[1], w, t, int(proc["perimeters"]),
            proc["infill_density"], tree_f.result()), model_f, tree_f)
        inside_f = st.submit("inside", lambda: _inside_share(
            model_f.result(), dep_f.result()[1].p[::JUDGE_STRIDE], wall_f.result()[0],
            INSIDE_SLACK * w), wall_f)
        bridge_f = st.submit("bridging", lambda: _bridging(
            model_f.result(), dep_f.result()[1], ok_f.result(), t, w,
            proc["infill_density"]), ok_f, model_f)
        (n_beads, deposited), s = dep_f.result()
        ok, wall, bridge = ok_f.result(), wall_f.result()[1], bridge_f.result()
        (n_hit, reports), (cov, shell_cov) = hit_f.result(), cov_f.result()
        inside_share = inside_f.result()
    held = ok | bridge  # a wall bead bridging sparse infill is a skin, not one in the air
    bad_seq = bad_wall_layers(s.seq[::JUDGE_STRIDE], wall, held)
    bad_layers = [_layer_name(s, k) for k in bad_seq]
    n = max(len(ok), 1)
    per_layer = layer_support(s, judged_samples(len(s)), ok | bridge, w)
    to_part = np.linalg.inv(_placement(parsed)) if PLACEMENT in parsed.headers else None
    worst = per_layer.worst()
    worst_d = None if worst is None else _layer_dict(per_layer, worst, to_part)
    return ReplayReport(
        moves=len(parsed), extruding_moves=n_beads, deposited_mm=deposited,
        points=len(s), inside=inside_share, coverage=cov, shell_coverage=shell_cov,
        supported=float((ok | bridge).sum() / n), bridged=float((bridge & ~ok).sum() / n),
        wall_points=int(wall.sum()),
        wall_supported=float(held[wall].mean()) if wall.any() else 1.0,
        unsupported_wall_layers=bad_layers, collisions=n_hit,
        wall_misses=_misses(s.p[::JUDGE_STRIDE], s.seq[::JUDGE_STRIDE], wall & ~held, bad_seq),
        collision_messages=[r.message() for r in reports],
        worst_layer_unsupported=0.0 if worst_d is None else worst_d["share"],
        worst_layer_run_mm=0.0 if worst_d is None else worst_d["run_mm"],
        worst_layer=worst_d,
        overhang_layers=[_layer_dict(per_layer, int(i), to_part)
                         for i in per_layer.overhangs()],
        seconds=time.perf_counter() - t0, timings=st.wall, cpu_timings=st.cpu)


def _misses(points: np.ndarray, seq: np.ndarray, missed: np.ndarray, bad: list[int]
            ) -> np.ndarray:
    """The judged ``points`` (m, 3) that are ``missed`` (unsupported walls) in the layers
    ``bad``, at most ``MAX_MISSES`` of them evenly drawn, (k, 3)."""
    idx = np.flatnonzero(missed & np.isin(seq, bad))
    if len(idx) > MAX_MISSES:
        idx = idx[np.linspace(0, len(idx) - 1, MAX_MISSES).astype(np.int64)]
    return points[idx].copy()


def _fits(index: ModelIndex | None, line_width: float) -> TypeGuard[ModelIndex]:
    """Whether a prebuilt ``index`` serves a replay at ``line_width``."""
    return index is not None and math.isclose(index.inside_pitch, _inside_pitch(line_width))


def _inside_pitch(line_width: float) -> float:
    """Spacing of the inside test's lines: exact for every point farther than the inside
    slack from the surface (pitch / √2 below it), where closer ones count through the slack."""
    return INSIDE_SLACK * line_width * math.sqrt(2.0) * (1.0 - 1e-9)


def _deposits(parsed: ParsedGcode, geo: MachineGeometry,
              lengths: tuple[np.ndarray, np.ndarray], bead_area: float, line_width: float,
              layer_height: float) -> tuple[tuple[int, float], Samples]:
    """(number of extruding moves, their length in mm) and their samples every half line
    width (the mapped moves are dropped: they would live as long as the samples)."""
    moves = extruding_moves(parsed, lengths)
    return ((len(moves), float(lengths[0][moves].sum())),
            map_and_sample(parsed, geo, moves, lengths, bead_area, 0.5 * line_width,
                           TIP_ANGLE, (H_MIN * layer_height, H_MAX * layer_height)))


def memory_estimate(parsed: ParsedGcode, lengths: tuple[np.ndarray, np.ndarray],
                    line_width: float) -> tuple[int, int]:
    """(deposited samples, bytes) the replay of ``parsed`` needs at its peak, from the
    moves alone (nothing is sampled): ``BYTES_PER_SAMPLE`` per deposited sample,
    ``BYTES_PER_TIP`` per head sample, ``BYTES_PER_MOVE`` per move.

    The figures bound the traced peak of the check's arrays (the samples, their KD-tree,
    the stages' chunked temporaries; two stages at once) on ``bench/slice_memory.py``'s
    parts, rounded up; the model index is counted apart (:func:`check_budget`), the parsed
    file not at all (the caller holds it anyway).
    """
    dep, pos = extruding_moves(parsed, lengths), positioned_moves(parsed, lengths)
    n = sample_count(lengths[0][dep], lengths[1][dep], 0.5 * line_width, TIP_ANGLE)
    tips = (sample_count(lengths[0][pos], lengths[1][pos], TIP_SPACING, TIP_ANGLE)
            + sample_count(lengths[0][pos], lengths[1][pos], FAR_TIP_SPACING, TIP_ANGLE))
    return n, n * BYTES_PER_SAMPLE + tips * BYTES_PER_TIP + len(parsed) * BYTES_PER_MOVE


def check_budget(parsed: ParsedGcode, lengths: tuple[np.ndarray, np.ndarray],
                 line_width: float, budget: float, index_bytes: int = 0) -> None:
    """Raise :class:`ReplayBudgetError` when :func:`memory_estimate` plus ``index_bytes``
    (a prebuilt model index) exceeds ``budget`` bytes (the check holds every deposited
    sample at once). The message says what would fit (:func:`budget_advice`)."""
    n, need = memory_estimate(parsed, lengths, line_width)
    if need + index_bytes > budget:
        proc = parsed.headers.get(PROCESS, {})
        advice = budget_advice(need, budget - index_bytes, _number(proc, "layer_height"),
                               _number(proc, "nozzle_diameter"))
        raise ReplayBudgetError(
            f"too large to replay-check: {n / 1e6:.1f} M bead samples would need about "
            f"{(need + index_bytes) / 2**30:.1f} GiB, above the check's budget of "
            f"{budget / 2**30:.1f} GiB ({advice})")


def budget_advice(need: float, room: float, layer_height: float | None,
                  nozzle_diameter: float | None) -> str:
    """What fits the replay's memory budget when the samples need ``need`` bytes and have
    ``room``: the samples, the head's and the moves scale with the number of layers, so a
    layer height of ``layer_height · need / room`` would, if the nozzle allows it (at most
    :data:`~slicer.settings.MAX_BEAD_SHARE` × ``nozzle_diameter``); else only a smaller part.
    Unknown heights (a file without them) give the general advice."""
    if layer_height is None or nozzle_diameter is None:
        return "a smaller part, or a larger layer height, fits"
    largest = MAX_BEAD_SHARE * nozzle_diameter
    fits = layer_height * need / room if room > 0 else math.inf
    if layer_height >= largest - 1e-9:
        return (f"the layer height {layer_height:g} mm is already the largest the "
                f"{nozzle_diameter:g} mm nozzle takes: the part is too large for the "
                f"check's memory budget; only a smaller part fits")
    if fits > largest + 1e-9:
        return (f"even the largest layer height the {nozzle_diameter:g} mm nozzle takes, "
                f"{largest:g} mm, would not fit: the part is too large for the check's "
                f"memory budget; only a smaller part fits")
    return (f"a layer height of about {math.ceil(fits * 100 - 1e-6) / 100:g} mm or more "
            f"(process.layer_height, at most {largest:g} mm) fits, or a smaller part")


def _number(values: dict[str, Any], key: str) -> float | None:
    """``values[key]`` as a positive finite float, or ``None``."""
    try:
        v = float(values[key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def _wall(model: ModelIndex, points: np.ndarray, line_width: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """(:meth:`~ModelIndex.nearest_bound`, wall mask) of points (n, 3): walls lie within
    ``WALL_SLACK`` line widths of the surface."""
    bound = model.nearest_bound(points, WALL_SLACK * line_width)
    return bound, model.within(points, WALL_SLACK * line_width, bound)


def _head_samples(parsed: ParsedGcode, geo: MachineGeometry,
                  lengths: tuple[np.ndarray, np.ndarray], bead_area: float
                  ) -> tuple[Samples, Samples]:
    """The head sampled along every move for :func:`~slicer.replay.collide.find_collisions`:
    (near samples for the nozzle, far ones for the carriage)."""
    moves = positioned_moves(parsed, lengths)
    near, far = (map_and_sample(parsed, geo, moves, lengths, bead_area, spacing, TIP_ANGLE,
                                ends=True, beads=False)
                 for spacing in (TIP_SPACING, FAR_TIP_SPACING))
    return near, far


def judged_samples(n: int) -> np.ndarray:
    """Indices of the samples judged (inside, support, walls) of ``n`` deposited ones: those
    of the slice ``[::JUDGE_STRIDE]``, which the stages take of the sample arrays."""
    return np.arange(0, n, JUDGE_STRIDE)


def _bridging(model: ModelIndex, s: Samples, ok: np.ndarray, layer_height: float,
              line_width: float, infill_density: float) -> np.ndarray:
    """Which judged samples (``ok`` is theirs) are unsupported over the previous layer's
    outline and bridge sparse infill (:func:`~slicer.replay.support.bridged`), (m,) bool.

    Over the outline: the bead's footprint at the previous layer's mid-height beneath the
    sample (``OUTLINE_DEPTH`` bead heights down its axis), its centre and the points
    ``FOOTPRINT`` widths from it along and across the bead, lies inside the model, exactly
    (no slack: under a ledge printed in thin layers that point lies a fraction of a layer
    below the ledge's underside). The points are offset across the axis only, so the
    part's top, however near, takes no part.
    """
    judged = judged_samples(len(s))
    cand = ~ok
    idx = judged[cand]
    over = np.zeros(len(idx), dtype=bool)
    r = FOOTPRINT * line_width
    for lo in range(0, len(idx), BRIDGE_CHUNK):  # (5 · chunk, 3) footprints at a time
        j = idx[lo:lo + BRIDGE_CHUNK]
        below = s.p[j] - OUTLINE_DEPTH * s.h[j, None] * s.u[j]
        along, across = bead_axes(s.u[j], s.step[j])
        points = np.concatenate([below, below + r * along, below - r * along,
                                 below + r * across, below - r * across])
        over[lo:lo + len(j)] = model.inside(points).reshape(5, len(j)).all(axis=0)
    cand[cand] = over
    mask = np.zeros(len(s), dtype=bool)
    mask[judged[cand]] = True
    return bridged(s, mask, layer_height, line_width, infill_density)[judged]


def _inside_share(model: ModelIndex, points: np.ndarray, bound: np.ndarray, slack: float
                  ) -> float:
    """Share of points (n, 3) inside the model or within ``slack`` of its surface.

    ``bound`` is the points' :meth:`~ModelIndex.nearest_bound`. The column test is exact
    for points farther than ``model.inside_pitch / √2`` from the surface; with that below
    ``slack`` every closer point counts through the slack, so no ray is cast, and only the
    points the column test puts outside need their distance to the surface.
    """
    if len(points) == 0:
        return 1.0
    if model.inside_pitch / math.sqrt(2.0) > slack:
        near = np.isfinite(model.distance(points, slack, bound))
        return float(np.mean(model.inside(points) | near))
    ok = model.parity_inside(points)
    out = np.flatnonzero(~ok)
    ok[out] = np.isfinite(model.distance(points[out], slack, bound[out]))
    return float(np.mean(ok))


def _layer_dict(layers: LayerSupport, row: int, to_part: np.ndarray | None
                ) -> dict[str, Any]:
    """Row ``row`` of ``layers`` as plain data; its point moved into the part's (STL) frame
    by ``to_part`` (4, 4; the inverse placement, ``None``: left in the platform frame)."""
    where = layers.where[row]
    if to_part is not None:
        where = to_part[:3, :3] @ where + to_part[:3, 3]
    return {"subpart": int(layers.subpart[row]), "layer": int(layers.layer[row]),
            "z": round(float(layers.z[row]), 3),
            "extruded_mm": round(float(layers.length[row]), 2),
            "unsupported_mm": round(float(layers.unsupported[row]), 2),
            "share": round(float(layers.share[row]), 4),
            "run_mm": round(float(layers.run[row]), 2),
            "point": None if not np.isfinite(where).all() else [
                round(float(v), 2) for v in where]}


def worst_layer_text(layer: dict[str, Any] | None) -> str:
    """A layer of :class:`ReplayReport` (``worst_layer``, ``overhang_layers``) in a few
    words: where, the unsupported share of its extrusion and the longest unsupported run."""
    if layer is None:
        return "none"
    return (f"sub-part {layer['subpart']} layer {layer['layer']} (z {layer['z']:.2f} mm) "
            f"{100 * layer['share']:.1f}% of {layer['extruded_mm']:.0f} mm unsupported, "
            f"longest run {layer['run_mm']:.1f} mm")


def overhang_text(layer: dict[str, Any]) -> str:
    """One clause naming a layer printed in the air and a point of it in the part frame."""
    point = layer["point"]
    at = "" if point is None else (
        f" around [{point[0]:.1f}, {point[1]:.1f}, {point[2]:.1f}] mm (part frame)")
    return (f"sub-part {layer['subpart']} layer {layer['layer']} (z {layer['z']:.2f} mm) "
            f"prints {100 * layer['share']:.1f}% of its {layer['extruded_mm']:.0f} mm of "
            f"extrusion over nothing ({layer['unsupported_mm']:.0f} mm unsupported, a run "
            f"of {layer['run_mm']:.0f} mm{at})")


def _layer_name(s: Samples, seq: int) -> str:
    i = int(np.flatnonzero(s.seq == seq)[0])
    return f"sub-part {int(s.subpart[i])} layer {int(s.layer[i])}"


def replay_file(path: str | Path, mesh: trimesh.Trimesh, head: Printhead | None = None,
                platform_radius: float | None = None) -> ReplayReport:
    """Read ``path`` and replay it against ``mesh``."""
    return replay_check(read_gcode(path), mesh, head, platform_radius)
