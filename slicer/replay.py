"""Replay check: map a file's moves back to the part and judge what they would build.

Reads only the file and the model: the ``;HOSTD_KINEMATICS`` header gives the inverse
kinematics, ``;HOSTD_PROCESS`` the bead sizes, ``;HOSTD_PLACEMENT`` the STL → platform
placement. Reported (all shares in [0, 1]):

* ``inside``: deposited samples inside the model (or within 0.1 w of its surface), measured
  on every third sample;
* ``coverage`` / ``shell_coverage``: model volume reached by the beads (:mod:`.replay_coverage`);
* ``supported``: samples with support beneath them or bridging sparse infill, and the wall
  figures of the strict rule (:mod:`.replay_support`);
* ``collisions``: head samples that hit printed material or the platform
  (:mod:`.replay_collide`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from slicer.gcode_reader import GcodeFormatError, ParsedGcode, read_gcode
from slicer.printhead import Printhead
from slicer.replay_collide import find_collisions
from slicer.replay_coverage import coverage
from slicer.replay_geometry import INSIDE_PITCH, ModelIndex
from slicer.replay_kdtree import point_tree
from slicer.replay_samples import (
    Samples,
    extruding_moves,
    geometry_from_header,
    map_moves,
    move_lengths,
    positioned_moves,
    sample_moves,
)
from slicer.replay_support import WALL_SLACK, bad_wall_layers, bridged, strict_support

INSIDE_SLACK = 0.1  # × line width
INSIDE_STRIDE = 3  # the inside share is measured on every third deposited sample
TIP_SPACING = 1.0  # mm between head samples along moves
FAR_TIP_SPACING = 3.0  # mm between samples of the carriage (radius ≥ 15 mm by default)
TIP_ANGLE = 1.0  # degrees between head samples while the table turns
H_MIN, H_MAX = 0.25, 2.0  # bead heights read from E are clipped to these × layer height


@dataclass
class ReplayReport:
    """Figures of one replay; plain data (picklable, JSON-friendly via :meth:`to_dict`)."""

    moves: int
    extruding_moves: int
    deposited_mm: float
    points: int
    inside: float
    coverage: float
    shell_coverage: float
    supported: float
    bridged: float
    wall_points: int
    wall_supported: float
    unsupported_wall_layers: list[str]
    collisions: int
    collision_messages: list[str]
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    cpu_timings: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether the file may be emitted (no collisions)."""
        return self.collisions == 0

    def to_dict(self) -> dict[str, object]:
        """The report as a plain dict."""
        return asdict(self)

    def summary(self) -> str:
        """One line of the main figures."""
        return (f"inside {100 * self.inside:.2f}%, coverage {100 * self.coverage:.2f}% "
                f"(shell {100 * self.shell_coverage:.2f}%), supported "
                f"{100 * self.supported:.2f}% (bridging {100 * self.bridged:.2f}%), walls "
                f"supported {100 * self.wall_supported:.2f}% with "
                f"{len(self.unsupported_wall_layers)} unsupported wall layers, "
                f"{self.collisions} collisions")


def _process(parsed: ParsedGcode) -> dict[str, float]:
    proc = parsed.require("PROCESS")
    try:
        out = {k: float(proc[k]) for k in ("layer_height", "line_width", "filament_diameter")}
    except (KeyError, TypeError, ValueError) as exc:
        raise GcodeFormatError(f";HOSTD_PROCESS: bad or missing key {exc}") from None
    out["perimeters"] = float(proc.get("perimeters", 2))
    out["infill_density"] = float(proc.get("infill_density", 0.2))
    return out


def _placement(parsed: ParsedGcode) -> np.ndarray:
    try:
        m = np.asarray(parsed.require("PLACEMENT")["matrix"], dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise GcodeFormatError(f";HOSTD_PLACEMENT: bad matrix ({exc})") from None
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise GcodeFormatError(";HOSTD_PLACEMENT: the matrix must be 4 × 4 and finite")
    return m


def _head(parsed: ParsedGcode, head: Printhead | None) -> Printhead:
    if head is not None:
        return head
    segs = parsed.headers.get("KINEMATICS", {}).get("printhead")
    return Printhead(tuple(tuple(map(float, s)) for s in segs)) if segs else Printhead()


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


def replay_check(parsed: ParsedGcode, mesh: trimesh.Trimesh, head: Printhead | None = None,
                 platform_radius: float | None = None, placed: bool = False) -> ReplayReport:
    """Replay ``parsed`` against ``mesh`` and report the figures.

    ``mesh`` is in STL coordinates (moved by the file's placement), or already in the
    platform frame with ``placed``. ``head`` and ``platform_radius`` default to the file's
    ``;HOSTD_KINEMATICS`` values.
    """
    t0 = time.perf_counter()
    clock = _Stages()
    geo = geometry_from_header(parsed)
    proc = _process(parsed)
    w, t = proc["line_width"], proc["layer_height"]
    head = _head(parsed, head)
    radius = platform_radius if platform_radius is not None else float(
        parsed.headers.get("KINEMATICS", {}).get("platform_radius", 150.0))
    bead_area = math.pi * proc["filament_diameter"] ** 2 / 4.0 / w
    with clock("sample"):
        lengths = move_lengths(parsed)
        ext = extruding_moves(parsed, lengths)
        beads = map_moves(parsed, geo, ext, lengths, bead_area, (H_MIN * t, H_MAX * t))
        s = sample_moves(parsed, geo, beads, 0.5 * w, TIP_ANGLE)
    with clock("index"):
        model = ModelIndex(*_placed_mesh(mesh, np.eye(4) if placed else _placement(parsed)))
    with clock("wall"):
        bound = model.nearest_bound(s.p, WALL_SLACK * w)
        wall = model.within(s.p, WALL_SLACK * w, bound)
    with clock("inside"):
        inside_share = _inside_share(model, s.p[::INSIDE_STRIDE], bound[::INSIDE_STRIDE],
                                     INSIDE_SLACK * w)
    with clock("support"):
        tree = point_tree(s.p)
        ok = strict_support(s, t, w, radius, tree)
        cand = ~ok & ~wall
        cand[cand] = _inside_far(model, s.p[cand], WALL_SLACK * w)
        bridge = bridged(s, cand, t, w, proc["infill_density"])
    with clock("coverage"):
        cov, shell_cov = coverage(model, s, w, t, int(proc["perimeters"]),
                                  proc["infill_density"], tree)
    with clock("collisions"):
        moved = map_moves(parsed, geo, positioned_moves(parsed, lengths), lengths, bead_area)
        near = sample_moves(parsed, geo, moved, TIP_SPACING, TIP_ANGLE, ends=True)
        far = sample_moves(parsed, geo, moved, FAR_TIP_SPACING, TIP_ANGLE, ends=True)
        n_hit, reports = find_collisions(parsed, near, far, s, head, radius)

    bad_layers = [_layer_name(s, k) for k in bad_wall_layers(s, wall, ok)]
    n = max(len(s), 1)
    return ReplayReport(
        moves=len(parsed), extruding_moves=len(ext), deposited_mm=float(beads.length.sum()),
        points=len(s), inside=inside_share, coverage=cov, shell_coverage=shell_cov,
        supported=float((ok | bridge).sum() / n), bridged=float((bridge & ~ok).sum() / n),
        wall_points=int(wall.sum()),
        wall_supported=float(ok[wall].mean()) if wall.any() else 1.0,
        unsupported_wall_layers=bad_layers, collisions=n_hit,
        collision_messages=[r.message() for r in reports],
        seconds=time.perf_counter() - t0, timings=clock.wall, cpu_timings=clock.cpu)


class _Stages:
    """Wall and process CPU seconds of named stages (``with stages("name"): ...``)."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        yield
        self.wall[name] = time.perf_counter() - wall
        self.cpu[name] = time.process_time() - cpu


def _inside_share(model: ModelIndex, points: np.ndarray, bound: np.ndarray, slack: float
                  ) -> float:
    """Share of points (n, 3) inside the model or within ``slack`` of its surface.

    ``bound`` is the points' :meth:`~ModelIndex.nearest_bound`. The column test is exact
    for points farther than ``INSIDE_PITCH / √2`` from the surface; with that below
    ``slack`` every closer point counts through the slack, so no ray is cast.
    """
    if len(points) == 0:
        return 1.0
    near = np.isfinite(model.distance(points, slack, bound))
    if INSIDE_PITCH / math.sqrt(2.0) > slack:
        return float(np.mean(model.inside(points) | near))
    return float(np.mean(model.parity_inside(points) | near))


def _inside_far(model: ModelIndex, points: np.ndarray, clearance: float) -> np.ndarray:
    """Inside test of points known to lie farther than ``clearance`` from the surface: the
    column test alone is exact there when ``clearance ≥ INSIDE_PITCH / √2`` (no distances)."""
    if clearance >= INSIDE_PITCH / math.sqrt(2.0):
        return model.parity_inside(points)
    return model.inside(points)


def _layer_name(s: Samples, seq: int) -> str:
    i = int(np.flatnonzero(s.seq == seq)[0])
    return f"sub-part {int(s.subpart[i])} layer {int(s.layer[i])}"


def replay_file(path: str | Path, mesh: trimesh.Trimesh, head: Printhead | None = None,
                platform_radius: float | None = None) -> ReplayReport:
    """Read ``path`` and replay it against ``mesh``."""
    return replay_check(read_gcode(path), mesh, head, platform_radius)
