"""G-code writer: a :class:`~slicer.plan.PrintPlan` as joint-space G-code (X Y Z A C, mm/deg).

The file is self-describing (see ``docs/gcode-format.md``): the headers give the kinematics,
the process, the STL → platform placement and the estimate, and markers delimit sub-parts,
layers, interface layers and the transitions between sub-parts. Only G0/G1 moves, G90
absolute axes, M83 relative extrusion.

Extrusion of a segment of length L between vertices of local thickness h0, h1 is
``E = w · (h0 + h1)/2 · L · flow / (π d² / 4)`` (filament diameter d).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path as FsPath

import numpy as np

from kinematics.linearize import linearize_move
from kinematics.machine import MachineGeometry
from kinematics.transform import inverse, table_rotation
from slicer.envelope import DEFAULT_TRAVEL
from slicer.gcode.estimate import Estimate, MotionLimits, estimate_program
from slicer.gcode.extrusions import Extrusions, joint_poses
from slicer.gcode.markers import (
    ESTIMATE,
    INTERFACE,
    KINEMATICS,
    LAYER,
    PLACEMENT,
    PROCESS,
    SUBPART,
    TRANSITION,
    TRANSITION_END,
    InterfacePayload,
    LayerPayload,
    PlacementPayload,
    SubpartPayload,
    TransitionPayload,
    marker_line,
)
from slicer.gcode.merge import kept_vertices, merged_filament
from slicer.gcode.program import AC_DECIMALS, XYZ_DECIMALS, MoveWords, Program
from slicer.gcode.transitions import obstacle_hull, plan_transition, platform_rim, safe_height_z
from slicer.plan import Layer, Path, PrintPlan, SubpartPlan
from slicer.printhead import Printhead
from slicer.settings import ProcessSettings

RETRACT_MIN_TRAVEL = 2.0  # mm: shorter travels neither retract nor hop
PLA_DENSITY = 1.24e-3  # g/mm³


class GcodeError(ValueError):
    """A plan or setting the writer cannot turn into G-code."""


@dataclass(frozen=True)
class MachineSetup:
    """What the writer needs to know about the machine beyond the kinematics.

    ``travel`` is [min, max] of machine X, Y and Z (``machine.x_range`` ...), mm: the writer
    does not use it, :mod:`slicer.envelope` checks the program against it.
    """

    geometry: MachineGeometry = field(default_factory=MachineGeometry)
    head: Printhead = field(default_factory=Printhead)
    platform_radius: float = 150.0
    travel: tuple[tuple[float, float], ...] = DEFAULT_TRAVEL


@dataclass
class GcodeResult:
    """The formatted file and what was computed on the way.

    Attributes
    ----------
    lines : list of str
    estimate : Estimate
    transitions : list of dict
        One record per sub-part transition: from, to, a, c, x, y, z, safe_z.
    """

    lines: list[str]
    estimate: Estimate
    transitions: list[dict[str, object]]
    header: int = 0
    program: Program | None = None

    def words(self) -> Iterator[str | MoveWords]:
        """The file as raw lines and numeric move blocks (for
        :func:`slicer.gcode.reader.parse_words`)."""
        if self.program is None:
            yield from self.lines
            return
        yield from self.lines[:self.header]
        yield from self.program.words()


def filament_area(settings: ProcessSettings) -> float:
    """Cross-section of the filament, mm²."""
    return math.pi * settings.filament_diameter ** 2 / 4.0


def path_extrusion(path: Path, area: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (k, 3) in print order (closed paths return to the start) and E per segment.

    Returns
    -------
    points : (k, 3) float
    e : (k - 1,) float
        mm of filament per segment.
    """
    ext = Extrusions.of([path], area)
    return ext.points, ext.e[1:]


def printed_moves(start: np.ndarray, poses: np.ndarray, e: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The extruding moves of one path as written: a move whose printed pose (X Y Z to
    ``XYZ_DECIMALS``, A C to ``AC_DECIMALS``) is the one before's would be a bare
    ``G1 E..`` line at a standstill, so it is dropped and its filament goes to the next
    move written (the last ones' to the last move written): the total is the same.

    Parameters
    ----------
    start : (5,) float
        Pose before the path.
    poses : (k, 5) float
        End pose of each move.
    e : (k,) float
        Filament of each move, mm.

    Returns
    -------
    poses : (j, 5) float
    e : (j,) float
        The moves kept (j ≤ k; one at least when k > 0, even if it does not move).
    """
    if len(poses) == 0:
        return poses, e
    r = np.empty((len(poses) + 1, 5))
    r[0], r[1:] = start, poses
    r[:, :3] = np.round(r[:, :3], XYZ_DECIMALS)
    r[:, 3:] = np.round(r[:, 3:], AC_DECIMALS)
    moved = (r[1:] != r[:-1]).any(axis=1)
    moved[-1] |= not moved.any()  # a path that never moves keeps its last move
    kept = np.flatnonzero(moved)
    # every move's filament to the first kept move at or after it, the tail's to the last
    owner = np.minimum(np.searchsorted(kept, np.arange(len(poses))), len(kept) - 1)
    return poses[kept], np.bincount(owner, weights=e, minlength=len(kept))


class _Writer:
    """Walks the plan in order and fills a :class:`Program`."""

    def __init__(self, plan: PrintPlan, settings: ProcessSettings, machine: MachineSetup):
        self.plan, self.s, self.m = plan, settings, machine
        self.g = machine.geometry
        self.prog = Program()
        self.retracted = False
        self.primed = True
        self.area = filament_area(settings)
        layers = [la for sp in plan.subparts for la in sp.layers]
        self.ext = Extrusions.of([p for la in layers for p in la.paths], self.area)
        self.poses = joint_poses(self.ext, layers, machine.geometry)
        self.keep = kept_vertices(self.ext.points, self.ext.e, self.ext.start,
                                  settings.linearize_tolerance)
        self.e = merged_filament(self.ext.e, self.keep)
        self.next_path = 0
        self.hull = obstacle_hull(_all_points(plan))
        self.rim = platform_rim(machine.platform_radius)
        self.transitions: list[dict[str, object]] = []

    # -- low-level moves -------------------------------------------------------------------
    def retract(self) -> None:
        if not self.retracted and self.s.retract_length > 0:
            self.prog.extrude_only(-self.s.retract_length, self.s.retract_speed)
        self.retracted = True

    def unretract(self) -> None:
        if not self.primed:
            self.primed = True
        elif self.retracted and self.s.retract_length > 0:
            self.prog.extrude_only(self.s.retract_length, self.s.retract_speed)
        self.retracted = False

    def travel(self, xyz: np.ndarray) -> None:
        pose = self.prog.pose.copy()
        pose[:3] = xyz
        self.prog.moves(pose[None, :], 0.0, self.s.travel_speed, 0)

    def travel_to(self, target: np.ndarray) -> None:
        """Travel at the current angles to machine point ``target`` (3,) ready to extrude."""
        cur = self.prog.pose[:3]
        dist = float(np.linalg.norm(target - cur))
        if self.retracted or dist > RETRACT_MIN_TRAVEL:
            lift = max(cur[2] + (0.0 if self.retracted else self.s.z_hop),
                       target[2] + self.s.z_hop)
            self.retract()
            if cur[2] < lift - 1e-9:
                self.travel(np.array([cur[0], cur[1], lift]))
            if not _close_xy(cur, target):
                self.travel(np.array([target[0], target[1], lift]))
            self.travel(target)
            self.unretract()
        elif dist > 0.0:
            self.travel(target)

    # -- layers ----------------------------------------------------------------------------
    def reorient(self, layer: Layer, first: np.ndarray) -> None:
        """Turn the table between two layers of one sub-part along a linearised move."""
        a0, c0 = float(self.prog.pose[3]), float(self.prog.pose[4])
        self.retract()
        lift = self.prog.pose[:3] + np.array([0.0, 0.0, self.s.z_hop])
        self.travel(lift)
        p0 = inverse(lift, a0, c0, self.g)
        u1 = _nozzle_axis(layer.a, layer.c)
        p1 = first + self.s.z_hop * u1
        way = linearize_move(p0, p1, a0, c0, layer.a, layer.c, self.g,
                             self.s.linearize_tolerance)
        self.prog.moves(way[1:], 0.0, self.s.travel_speed, 0)

    def layer(self, layer: Layer) -> None:
        self.prog.line(marker_line(LAYER, LayerPayload(subpart=layer.subpart,
                                                       index=layer.index)))
        if layer.interface_child is not None:
            self.prog.line(marker_line(INTERFACE, InterfacePayload(
                parent=layer.subpart, child=int(layer.interface_child))))
        ext, j0 = self.ext, self.next_path
        self.next_path += len(layer.paths)
        for j, path in enumerate(layer.paths, start=j0):
            s, t = int(ext.start[j]), int(ext.start[j + 1])
            if t - s < 2:
                continue
            if not _same_angles(self.prog.pose, layer.a, layer.c):
                self.reorient(layer, ext.points[s])
            self.travel_to(self.poses[s, :3])
            kept = s + 1 + np.flatnonzero(self.keep[s + 1:t])
            poses, e = printed_moves(self.prog.pose, self.poses[kept], self.e[kept])
            self.prog.moves(poses, e, path.speed, 1)

    # -- sub-parts -------------------------------------------------------------------------
    def subpart(self, sp: SubpartPlan, prev: int | None) -> None:
        first = _first_point(sp)
        if first is None:
            self.next_path += sum(len(la.paths) for la in sp.layers)
            return
        layer0, point = first
        self.prog.subpart = sp.index
        parent = None if sp.parent is None else int(sp.parent)
        self.prog.line(marker_line(SUBPART, SubpartPayload(index=sp.index, parent=parent)))
        self.transition(prev, sp.index, layer0, point)
        for layer in sp.layers:
            self.layer(layer)

    def transition(self, prev: int | None, to: int, layer: Layer, point: np.ndarray) -> None:
        start = None if np.isnan(self.prog.pose).any() else self.prog.pose.copy()
        if start is None:  # nothing extruded yet: no retract, and no unretract after
            self.retracted, self.primed = True, False
        self.retract()
        tr = plan_transition(start, point, layer.a, layer.c, self.hull, self.rim, self.g,
                             self.s.safe_height, self.s.z_hop)
        x, y, z = (round(float(v), XYZ_DECIMALS) for v in tr.target[:3])
        a, c = (round(float(v), AC_DECIMALS) for v in tr.target[3:])
        record: TransitionPayload = {"from": prev, "to": to, "a": a, "c": c, "x": x, "y": y,
                                     "z": z, "safe_z": round(tr.safe_z, 3)}
        self.transitions.append(dict(record))
        self.prog.line(marker_line(TRANSITION, record))
        for pose, rotary in zip(tr.poses, tr.rotary, strict=True):
            if rotary and _same_angles(self.prog.pose, pose[3], pose[4]):
                continue
            feed = self.s.max_rotary_velocity if rotary else self.s.travel_speed
            self.prog.moves(pose[None, :], 0.0, feed, 0)
        self.prog.line(marker_line(TRANSITION_END))

    def end_safe_z(self) -> float:
        """Machine Z that clears the part and the platform while the table turns from the
        last pose back to A = C = 0 (and is not below the nozzle already)."""
        if np.isnan(self.prog.pose).any():  # nothing moved: nothing printed either
            return start_safe_z(self.s, self.m)
        a0, c0 = float(self.prog.pose[3]), float(self.prog.pose[4])
        z = safe_height_z(self.hull, self.rim, a0, c0, 0.0, 0.0, self.g, self.s.safe_height)
        return max(z, float(self.prog.pose[2]))


def start_safe_z(settings: ProcessSettings, machine: MachineSetup) -> float:
    """``{safe_z}`` of the start script: ``safe_height`` above the empty platform at
    A = C = 0 (machine Z, mm), the table surface standing in for the part not printed yet."""
    rim = platform_rim(machine.platform_radius)
    return safe_height_z(rim, rim, 0.0, 0.0, 0.0, 0.0, machine.geometry, settings.safe_height)


def _nozzle_axis(a: float, c: float) -> np.ndarray:
    """Machine +Z in the platform frame at table angles (a, c), (3,)."""
    return table_rotation(a, c).T @ np.array([0.0, 0.0, 1.0])


def _close_xy(a: np.ndarray, b: np.ndarray) -> bool:
    """``np.allclose(a[:2], b[:2], atol=1e-9)`` for two points, without its overhead."""
    return bool(np.all(np.abs(a[:2] - b[:2]) <= 1e-9 + 1e-5 * np.abs(b[:2])))


def _same_angles(pose: np.ndarray, a: float, c: float) -> bool:
    return abs(pose[3] - a) < 1e-9 and abs(pose[4] - c) < 1e-9


def _first_point(sp: SubpartPlan) -> tuple[Layer, np.ndarray] | None:
    for layer in sp.layers:
        for path in layer.paths:
            if len(path.points):
                return layer, np.asarray(path.points, dtype=float).reshape(-1, 3)[0]
    return None


def _all_points(plan: PrintPlan) -> np.ndarray:
    chunks = [np.asarray(p.points, dtype=float).reshape(-1, 3) for sp in plan.subparts
              for la in sp.layers for p in la.paths]
    return np.concatenate(chunks) if chunks else np.zeros((1, 3))


def header_lines(settings: ProcessSettings, machine: MachineSetup, placement: np.ndarray,
                 estimate: Estimate) -> list[str]:
    """The four fixed header lines (KINEMATICS, PROCESS, PLACEMENT, ESTIMATE)."""
    kin = dict(machine.geometry.header())
    kin["platform_radius"] = machine.platform_radius
    kin["printhead"] = [list(seg) for seg in machine.head.segments]
    proc = dict(settings.header())
    proc.update(perimeters=settings.perimeters, infill_density=settings.infill_density)
    matrix = [[float(v) for v in row] for row in np.asarray(placement, dtype=float)]
    return [marker_line(KINEMATICS, kin), marker_line(PROCESS, proc),
            marker_line(PLACEMENT, PlacementPayload(matrix=matrix)),
            marker_line(ESTIMATE, estimate.header())]


def _custom(template: str, settings: ProcessSettings, **extra: float) -> str:
    values = {**asdict(settings), **extra}
    try:
        return template.format_map(values)
    except (KeyError, IndexError, ValueError) as exc:
        raise GcodeError(f"start/end G-code: bad placeholder {exc} "
                         f"(known: {', '.join(sorted(values))})") from None


def build_program(plan: PrintPlan, settings: ProcessSettings,
                  machine: MachineSetup | None = None) -> tuple[Program, list[dict[str, object]],
                                                                 float]:
    """Fill a :class:`Program` with the whole print (without headers).

    Returns
    -------
    program, transition records, end safe Z
        ``{safe_z}`` of the start script is :func:`start_safe_z`, of the end script the end
        safe Z (machine Z, mm).
    """
    machine = machine or MachineSetup()
    w = _Writer(plan, settings, machine)
    w.prog.line("G90\nM83")  # G90 after M83 makes E absolute again (Marlin 2)
    w.prog.line(_custom(settings.start_gcode, settings,
                        safe_z=round(start_safe_z(settings, machine), 3)))
    w.prog.line(f"G90\nM83\nM106 S{int(settings.fan_speed)}")
    prev: int | None = None
    for sp in plan.subparts:
        w.subpart(sp, prev)
        prev = sp.index
    w.retract()
    safe_z = w.end_safe_z()
    w.prog.line(_custom(settings.end_gcode, settings, safe_z=round(safe_z, 3)))
    return w.prog, w.transitions, safe_z


@dataclass
class Draft:
    """A file's moves before its text: what a reader of moves needs is ready at once, the
    estimate and the text come from :meth:`finish`.

    :meth:`words` gives the file as :meth:`GcodeResult.words` will, but the
    ``;HOSTD_ESTIMATE`` header holds zeros (every other header, and every line's number, is
    the final one). :meth:`finish` only reads the program, so it may run on another thread
    while the moves are read: the slicer formats the text beside its replay check.
    """

    plan: PrintPlan
    settings: ProcessSettings
    machine: MachineSetup
    program: Program
    transitions: list[dict[str, object]]
    end_safe_z: float = math.nan

    def script_safe_z(self) -> dict[str, float]:
        """``{safe_z}`` (machine Z, mm) of the start and end scripts that use it."""
        used = {"start": (self.settings.start_gcode, start_safe_z(self.settings, self.machine)),
                "end": (self.settings.end_gcode, self.end_safe_z)}
        return {k: round(z, 3) for k, (text, z) in used.items() if "safe_z" in text}

    def words(self) -> Iterator[str | MoveWords]:
        """Raw lines and numeric move blocks (for :func:`slicer.gcode.reader.parse_words`),
        with a zero estimate."""
        yield from header_lines(self.settings, self.machine, self.plan.placement,
                                Estimate(0.0, 0.0, 0.0))
        yield from self.program.words()

    def finish(self) -> GcodeResult:
        """The estimate, the headers and the text of the whole file."""
        limits = MotionLimits.from_settings(self.settings)
        estimate = estimate_program(self.program.blocks(), limits,
                                    filament_area(self.settings), PLA_DENSITY)
        lines = header_lines(self.settings, self.machine, self.plan.placement, estimate)
        header = len(lines)
        lines.extend(self.program.lines())
        return GcodeResult(lines, estimate, self.transitions, header, self.program)


def draft(plan: PrintPlan, settings: ProcessSettings,
          machine: MachineSetup | None = None) -> Draft:
    """The program of the whole file (:func:`build_program`), its word table computed
    (so two threads may read it)."""
    machine = machine or MachineSetup()
    prog, transitions, safe_z = build_program(plan, settings, machine)
    prog.table()
    return Draft(plan, settings, machine, prog, transitions, safe_z)


def generate(plan: PrintPlan, settings: ProcessSettings,
             machine: MachineSetup | None = None) -> GcodeResult:
    """The whole file: headers, start G-code, sub-parts with transitions, end G-code."""
    return draft(plan, settings, machine).finish()


def gcode_lines(plan: PrintPlan, settings: ProcessSettings,
                machine: MachineSetup | None = None) -> list[str]:
    """The file as a list of lines (no newlines)."""
    return generate(plan, settings, machine).lines


def write_gcode(path: str | FsPath, lines: Iterable[str]) -> None:
    """Write ``lines`` to ``path`` with ``\\n`` endings."""
    text = "\n".join(lines)
    FsPath(path).write_text(text + "\n", encoding="ascii")


__all__: Sequence[str] = ("Draft", "GcodeError", "GcodeResult", "MachineSetup",
                          "build_program", "draft", "filament_area", "gcode_lines", "generate",
                          "header_lines", "path_extrusion", "start_safe_z", "write_gcode")
