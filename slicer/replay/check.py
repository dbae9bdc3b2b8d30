"""Replay check: map a file's moves back to the part and judge what they would build.

Reads only the file and the model: the ``;HOSTD_KINEMATICS`` header gives the inverse
kinematics, ``;HOSTD_PROCESS`` the bead sizes, ``;HOSTD_PLACEMENT`` the STL → platform
placement. The deposits are sampled every half line width along the paths; every sample's
bead is material (for support beneath later points and for coverage), and every second
sample, one line width apart along a path, is *judged*. Reported (all shares in [0, 1]):

* ``inside``: judged samples inside the model (or within 0.1 w of its surface);
* ``coverage`` / ``shell_coverage``: model volume reached by the beads (:mod:`.coverage`);
* ``supported``: judged samples with support beneath them or bridging sparse infill, and the
  wall figures (issue 8): wall samples held by the strict rule (:mod:`.support`) or bridging
  sparse infill inside the part, which is not an overhang, and the layers with more than 5 %
  of their wall samples held by neither (``unsupported_wall_layers``, the layers *over air*:
  ``wall_layers``);
* ``collisions``: head samples that hit printed material or the platform
  (:mod:`.collide`).

Judging every sample gave the same figures to within 0.02 percentage points on the sample
pipes and the 50k-face pipe, five-axis and planar, and the same unsupported wall layers
(``bench/replay.py --planar``, 2026-12-02), for 0.9–1.8 s less CPU on the 50k-face pipe:
a point's verdict does not depend on which others are judged
(``tests/slicer/test_replay.py``).

The samples are never all held at once (:mod:`.stream`, :mod:`.passes`): the check walks
them by slabs of platform z (support, coverage), by chunks of whole layers (walls, inside,
bridging, the figures per layer) and by chunks of moves (the head), each a bounded size;
what it keeps for the whole file is a verdict bit or two per judged sample and the first
bead of each occupied 0.5 mm voxel (:func:`memory_estimate`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np
import trimesh

from kinematics.machine import MachineGeometry
from slicer.gcode import GcodeFormatError, ParsedGcode, read_gcode
from slicer.gcode.markers import KINEMATICS, PLACEMENT, PROCESS
from slicer.paths import SlicingError
from slicer.printhead import Printhead, Segment
from slicer.replay import stream
from slicer.replay.coverage import shares
from slicer.replay.geometry import ModelIndex
from slicer.replay.passes import (
    LayerFigures,
    Rules,
    collision_pass,
    layer_pass,
    support_pass,
    wall_pass,
)
from slicer.replay.samples import (
    Samples,
    extruding_moves,
    geometry_from_header,
    move_lengths,
    sample_count,
)
from slicer.replay.stages import Stages
from slicer.replay.stream import Deposits, measure
from slicer.replay.support import LayerSupport
from slicer.replay.walls import WallLayer, WallSamples, worst_first
from slicer.settings import MAX_BEAD_SHARE

INSIDE_SLACK = 0.1  # × line width
JUDGE_STRIDE = 2  # inside, support and walls are judged on every second deposited sample
TIP_ANGLE = 1.0  # degrees between head samples while the table turns
H_MIN, H_MAX = 0.25, 2.0  # bead heights read from E are clipped to these × layer height
MEMORY_BUDGET = 1 << 30  # bytes the check may hold at its peak (memory_estimate)
WINDOW_BYTES = 352 << 20  # peak of a tile, a chunk of layers and a chunk of the head at once
BYTES_PER_SAMPLE = 1  # kept for the whole file per deposited sample (verdicts)
BYTES_PER_HELD = 96  # per sample of a file small enough to be held (stream.HOLD_SAMPLES)
BYTES_PER_BEAD = 80  # per bead of the collision check's material (one per 0.5 mm voxel)
BEADS_PER_MM3 = 16  # of deposited volume, at most (measured 9-14: the sample parts, boxes)
BYTES_PER_MOVE = 64
WALLS_HELD = 0.998
"""Share of wall samples a support-free file holds at least (:attr:`ReplayReport.support_free`,
with no unsupported wall layer: issue 8's wall rule)."""


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
    # the wall layers over air (those of unsupported_wall_layers: wall points that bridge
    # sparse infill held) described, worst first (at most MAX_WALL_LAYERS), and their
    # unsupported wall samples in the platform frame (not in to_dict)
    wall_layers: list[WallLayer] = field(default_factory=list)
    wall_layers_over_air: int = 0
    unsupported_walls: WallSamples = field(default_factory=WallSamples.empty, repr=False,
                                           compare=False)
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    cpu_timings: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether the file may be emitted (no collisions, no layer printed in the air)."""
        return self.collisions == 0 and not self.overhang_layers

    @property
    def support_free(self) -> bool:
        """Whether every wall is held by issue 8's wall rule: at least :data:`WALLS_HELD` of
        the wall samples held (strictly supported, or bridging sparse infill) and no wall
        layer with more than its unsupported share (what the closed loop aims at; a file
        with such layers is refused unless the caller allows them)."""
        return self.wall_supported >= WALLS_HELD and not self.unsupported_wall_layers

    def to_dict(self) -> dict[str, object]:
        """The report as a plain dict, without ``unsupported_walls`` (arrays)."""
        out = asdict(replace(self, unsupported_walls=WallSamples.empty()))
        out.pop("unsupported_walls")
        return out

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
    rules = Rules(w, t, proc["infill_density"], int(proc["perimeters"]), radius, JUDGE_STRIDE,
                  INSIDE_SLACK * w)
    to_part = np.linalg.inv(_placement(parsed)) if PLACEMENT in parsed.headers else None
    with Stages(threads) as st:  # in an order where every input is submitted first
        model_f = st.submit("index", lambda: index if _fits(index, w) else model_index(
            mesh, w, placement))
        dep_f = st.submit("sample", lambda: _measured(parsed, geo, lengths, bead_area, w, t))
        ok_f = st.submit("support", lambda: support_pass(dep_f.result(), model_f.result(),
                                                         rules), dep_f, model_f)
        # the walls and the head need no support verdicts: checked beside the support pass
        wall_f = st.submit("walls", lambda: wall_pass(dep_f.result(), model_f.result(), rules),
                           dep_f, model_f)
        hit_f = st.submit("collisions", lambda: collision_pass(
            parsed, dep_f.result(), geo, lengths, bead_area, head, radius, TIP_ANGLE), dep_f)
        fig_f = st.submit("layers", lambda: layer_pass(
            dep_f.result(), model_f.result(), ok_f.result()[0], wall_f.result()[0], rules,
            to_part), ok_f, wall_f)
        dep, (_, shell, cov), figures = dep_f.result(), ok_f.result(), fig_f.result()
        inside = wall_f.result()[1]
        n_hit, reports = hit_f.result()
    coverage, shell_coverage = shares(cov, shell) if dep.n else (
        (1.0, 1.0) if len(cov) == 0 else (0.0, 0.0))
    return _report(parsed, dep, figures, inside, (coverage, shell_coverage), n_hit,
                   [r.message() for r in reports], to_part, time.perf_counter() - t0, st)


def _report(parsed: ParsedGcode, dep: Deposits, fig: LayerFigures, inside: int,
            cov: tuple[float, float], collisions: int, messages: list[str],
            to_part: np.ndarray | None, seconds: float, st: Stages) -> ReplayReport:
    """The :class:`ReplayReport` of the passes' figures (``inside``: judged samples inside
    the model)."""
    n = max(fig.judged, 1)
    per_layer = fig.layers
    worst = per_layer.worst()
    worst_d = None if worst is None else _layer_dict(per_layer, worst, to_part)
    return ReplayReport(
        moves=len(parsed), extruding_moves=len(dep.moves), deposited_mm=dep.deposited_mm,
        points=dep.n, inside=inside / fig.judged if fig.judged else 1.0,
        coverage=cov[0], shell_coverage=cov[1], supported=fig.supported / n,
        bridged=fig.bridged / n, wall_points=fig.wall,
        wall_supported=fig.wall_supported / fig.wall if fig.wall else 1.0,
        unsupported_wall_layers=[_name(v) for v in fig.over_air], collisions=collisions,
        collision_messages=messages,
        worst_layer_unsupported=0.0 if worst_d is None else worst_d["share"],
        worst_layer_run_mm=0.0 if worst_d is None else worst_d["run_mm"],
        worst_layer=worst_d,
        overhang_layers=[_layer_dict(per_layer, int(i), to_part)
                         for i in per_layer.overhangs()],
        wall_layers=worst_first(fig.over_air), wall_layers_over_air=len(fig.over_air),
        unsupported_walls=fig.samples, seconds=seconds, timings=st.wall, cpu_timings=st.cpu)


def _name(layer: WallLayer) -> str:
    """``sub-part 1 layer 7``."""
    return f"sub-part {layer.subpart} layer {layer.layer}"


def _fits(index: ModelIndex | None, line_width: float) -> TypeGuard[ModelIndex]:
    """Whether a prebuilt ``index`` serves a replay at ``line_width``."""
    return index is not None and math.isclose(index.inside_pitch, _inside_pitch(line_width))


def _inside_pitch(line_width: float) -> float:
    """Spacing of the inside test's lines: exact for every point farther than the inside
    slack from the surface (pitch / √2 below it), where closer ones count through the slack."""
    return INSIDE_SLACK * line_width * math.sqrt(2.0) * (1.0 - 1e-9)


def _measured(parsed: ParsedGcode, geo: MachineGeometry,
              lengths: tuple[np.ndarray, np.ndarray], bead_area: float, line_width: float,
              layer_height: float) -> Deposits:
    """The file's deposits, sampled every half line width (:func:`~.stream.measure`)."""
    return measure(parsed, geo, lengths, bead_area, 0.5 * line_width, TIP_ANGLE,
                   (H_MIN * layer_height, H_MAX * layer_height))


def _deposits(parsed: ParsedGcode, geo: MachineGeometry,
              lengths: tuple[np.ndarray, np.ndarray], bead_area: float, line_width: float,
              layer_height: float) -> tuple[tuple[int, float], Samples]:
    """(number of extruding moves, their length in mm) and all their samples at once (for
    tests and small files: the check itself never holds them all)."""
    dep = _measured(parsed, geo, lengths, bead_area, line_width, layer_height)
    return (len(dep.moves), dep.deposited_mm), dep.samples(0, dep.n)


def memory_estimate(parsed: ParsedGcode, lengths: tuple[np.ndarray, np.ndarray],
                    line_width: float) -> tuple[int, int]:
    """(deposited samples, bytes) the replay of ``parsed`` needs at its peak, from the
    moves alone (nothing is sampled): :func:`memory_parts` together."""
    n, scaling, fixed = memory_parts(parsed, lengths, line_width)
    return n, scaling + fixed


def memory_parts(parsed: ParsedGcode, lengths: tuple[np.ndarray, np.ndarray],
                 line_width: float) -> tuple[int, int, int]:
    """(deposited samples, bytes that scale with the number of layers, bytes that do not)
    of the replay's peak, from the moves alone.

    The first bytes: ``BYTES_PER_SAMPLE`` per deposited sample and ``BYTES_PER_MOVE`` per
    move, the verdicts and the numbers per move kept for the whole file (and
    ``BYTES_PER_HELD`` per sample of a file held whole, :data:`~.stream.HOLD_SAMPLES`). The
    others:
    ``WINDOW_BYTES`` (a tile, a chunk of layers and a chunk of the head's samples, the
    passes' windows, two at once) and ``BYTES_PER_BEAD`` per bead of the collision check's
    material, at most ``BEADS_PER_MM3`` per mm³ deposited (or one per sample). They bound
    the traced peak of the check on ``bench/slice_memory.py``'s parts, rounded up; the model
    index is counted apart (:func:`check_budget`), the parsed file not at all (the caller
    holds it anyway).
    """
    moves = extruding_moves(parsed, lengths)
    n = sample_count(lengths[0][moves], lengths[1][moves], 0.5 * line_width, TIP_ANGLE)
    proc = parsed.headers.get(PROCESS, {})
    filament = _number(proc, "filament_diameter") or 1.75
    volume = float(np.maximum(parsed.e[moves], 0.0).sum()) * math.pi * filament ** 2 / 4.0
    beads = min(n, math.ceil(BEADS_PER_MM3 * volume))
    held = n * BYTES_PER_HELD if n <= stream.HOLD_SAMPLES else 0
    return (n, n * BYTES_PER_SAMPLE + held + len(parsed) * BYTES_PER_MOVE,
            WINDOW_BYTES + beads * BYTES_PER_BEAD)


def check_budget(parsed: ParsedGcode, lengths: tuple[np.ndarray, np.ndarray],
                 line_width: float, budget: float, index_bytes: int = 0) -> None:
    """Raise :class:`ReplayBudgetError` when :func:`memory_estimate` plus ``index_bytes``
    (a prebuilt model index) exceeds ``budget`` bytes. The message says what would fit
    (:func:`budget_advice`: of the bytes, those that scale with the number of layers)."""
    n, scaling, fixed = memory_parts(parsed, lengths, line_width)
    need = scaling + fixed
    if need + index_bytes > budget:
        proc = parsed.headers.get(PROCESS, {})
        advice = budget_advice(scaling, budget - index_bytes - fixed,
                               _number(proc, "layer_height"), _number(proc, "nozzle_diameter"))
        raise ReplayBudgetError(
            f"too large to replay-check: {n / 1e6:.1f} M bead samples would need about "
            f"{(need + index_bytes) / 2**30:.1f} GiB, above the check's budget of "
            f"{budget / 2**30:.1f} GiB ({advice})")


def budget_advice(need: float, room: float, layer_height: float | None,
                  nozzle_diameter: float | None) -> str:
    """What fits the replay's memory budget when the bytes that scale with the number of
    layers (the samples' verdicts, the moves) are ``need`` and have ``room`` beside the
    rest: a layer height of ``layer_height · need / room`` would, if the nozzle allows it
    (at most :data:`~slicer.settings.MAX_BEAD_SHARE` × ``nozzle_diameter``); else only a
    smaller part. Unknown heights (a file without them) give the general advice."""
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


def judged_samples(n: int) -> np.ndarray:
    """Indices of the samples judged (inside, support, walls) of ``n`` deposited ones: those
    of the slice ``[::JUDGE_STRIDE]``, which the stages take of the sample arrays."""
    return np.arange(0, n, JUDGE_STRIDE)


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


def replay_file(path: str | Path, mesh: trimesh.Trimesh, head: Printhead | None = None,
                platform_radius: float | None = None) -> ReplayReport:
    """Read ``path`` and replay it against ``mesh``."""
    return replay_check(read_gcode(path), mesh, head, platform_radius)
