"""STL → checked G-code in one call: decompose, plan, write, replay-check.

Used by ``hostctl slice`` and the daemon's slicing worker: a plain function with a plain-data,
picklable result. A file whose replay finds a head collision is refused
(:class:`CollisionError`), never returned, and so is one with a layer printed in the air
(:class:`OverhangError`); so is a part wider than the platform, a program
that prints nothing or moves an axis beyond its travel (:class:`~slicer.envelope.EnvelopeError`,
a :class:`~slicer.mesh.errors.MeshError`: bad input), checked by :mod:`slicer.envelope`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from kinematics.machine import MachineGeometry
from slicer import envelope
from slicer.gcode import Draft, E, MachineSetup, draft, parse_words
from slicer.hugepages import small_pages
from slicer.paths import LEAN, NO_HINTS, LeanHints, SlicingError, plan_print
from slicer.plan import PrintPlan
from slicer.printhead import Printhead
from slicer.replay import (
    ModelIndex,
    ReplayReport,
    model_index,
    overhang_text,
    replay_check,
    shell_depth,
    shell_grid,
)
from slicer.settings import ProcessSettings

if TYPE_CHECKING:
    from slicer.decompose import DecomposeSettings
    from slicer.mesh import BaseChoice, Placement

T = TypeVar("T")
log = logging.getLogger(__name__)

REPAIR_ROUNDS = 3  # plans again, leaning, with hints from the replay (the closed loop)
Progress = Callable[[str, float], None]
"""``progress(stage, percent)``: a slice's stage as it starts, and how far the whole is."""
STAGES = (("reading the part", 0.0), ("decomposing and planning", 5.0),
          ("writing G-code", 55.0), ("replay check", 65.0), ("repair", 90.0),
          ("done", 100.0))
"""The stages :func:`slice_model` reports, with the share of a typical slice done before
each (the plan and the replay take most of it: ``bench/slice.py``)."""
_PERCENT = dict(STAGES)


def _no_progress(stage: str, percent: float) -> None:
    """A :data:`Progress` that tells no one."""


class SliceError(ValueError):
    """The part cannot be sliced into a checked file; ``str()`` is one line."""


class CollisionError(SliceError):
    """The replay found head collisions: the file is refused."""


class OverhangError(SliceError):
    """The replay found a layer printed in the air (over both of
    :data:`~slicer.replay.support.OVERHANG_SHARE` and ``OVERHANG_RUN``): the file is
    refused."""


@dataclass
class SliceResult:
    """Everything a caller reports about one slice; plain data only.

    Attributes
    ----------
    lines : list of str
        The G-code.
    subparts, layers : int
    thickness : (float, float)
        Smallest and largest local layer thickness, mm.
    estimate : dict
        ``;HOSTD_ESTIMATE`` payload (filament_mm, mass_g, time_s, per sub-part).
    replay : dict
        :class:`~slicer.replay.check.ReplayReport` as a dict.
    transitions : list of dict
    timings : dict of str to float
        Seconds per stage.
    seconds : float
        Wall time of the whole call.
    plan : PrintPlan, optional
        Kept for previews (``keep_plan``).
    merged_shells : int
        How many overlapping closed shells of the file were merged into one solid (0: the
        file held one).
    base_note : str or None
        Why the part stands on another flat face than its own bottom, or a much larger face
        it could stand on (:class:`~slicer.mesh.placement.BaseChoice`); None when there is nothing
        to say.
    """

    lines: list[str]
    subparts: int
    layers: int
    thickness: tuple[float, float]
    estimate: dict[str, object]
    replay: dict[str, object]
    transitions: list[dict[str, object]] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0
    plan: PrintPlan | None = None
    merged_shells: int = 0
    base_note: str | None = None

    def summary(self) -> dict[str, object]:
        """The result without the G-code lines and the plan."""
        d = asdict(self)
        d.pop("lines")
        d.pop("plan")
        return d


def _load(mesh_or_path: trimesh.Trimesh | str | Path, min_size: float,
          build_volume: np.ndarray | None) -> tuple[trimesh.Trimesh, Placement]:
    """(placed mesh, placement)."""
    from slicer.mesh import load_mesh, place_on_platform, repair

    if isinstance(mesh_or_path, str | Path):
        return load_mesh(mesh_or_path, build_volume, min_size)
    return place_on_platform(repair(mesh_or_path))


def plan_model(mesh: trimesh.Trimesh, placement: np.ndarray, settings: ProcessSettings,
               geometry: MachineGeometry, head: Printhead,
               decompose_settings: DecomposeSettings | None, planar: bool,
               build_volume: np.ndarray | None = None) -> PrintPlan:
    """Decompose and plan a placed mesh (or plan it planar, A = C = 0).

    The decomposition may stand the part on a much larger flat face when it is refused as
    placed (:func:`slicer.decompose.bases.decompose_on_bases`); the plan's ``base.turn`` then moves
    ``mesh`` to where the plan stands it (:func:`slicer.mesh.placement.moved`).
    """
    from slicer.paths import plan_planar, plan_print

    if planar:
        return plan_planar(mesh, settings, geometry, placement)
    from slicer.decompose import DecomposeSettings, decompose_on_bases

    dec_settings = decompose_settings or DecomposeSettings(
        nozzle_diameter=settings.nozzle_diameter)
    dec = decompose_on_bases(mesh, dec_settings, geometry, head, build_volume, placement)
    return plan_print(dec, settings, geometry, head)


def _thickness(plan: PrintPlan) -> tuple[float, float]:
    ranges = [sp.thickness_range for sp in plan.subparts if sp.layers]
    if not ranges:
        return (0.0, 0.0)
    return (float(min(r[0] for r in ranges)), float(max(r[1] for r in ranges)))


def slice_model(mesh_or_path: trimesh.Trimesh | str | Path, settings: ProcessSettings,
                geometry: MachineGeometry, head: Printhead | None = None,
                decompose_settings: DecomposeSettings | None = None, platform_radius: float = 150.0,
                planar: bool = False, build_volume: np.ndarray | None = None,
                check: bool = True, keep_plan: bool = False,
                travel: ArrayLike = envelope.DEFAULT_TRAVEL,
                progress: Progress | None = None) -> SliceResult:
    """Slice a part to checked G-code.

    Parameters
    ----------
    mesh_or_path : trimesh.Trimesh or path
        The part in STL coordinates (it is repaired and placed on its flat base).
    settings, geometry, head
        Process, machine geometry and collision model.
    decompose_settings : slicer.decompose.decomposition.DecomposeSettings, optional
    platform_radius : float
    planar : bool
        The 3-axis control: one sub-part, horizontal layers, A = C = 0.
    check : bool
        Run the replay check (and refuse collisions and layers printed in the air).
    keep_plan : bool
        Keep the PrintPlan in the result (for previews).
    travel : (3, 2) float
        [min, max] of machine X, Y, Z (``machine.x_range`` ...), mm.
    progress : callable, optional
        Told each stage of :data:`STAGES` as it starts (``progress(stage, percent)``).

    Raises
    ------
    SliceError, CollisionError, OverhangError
        And the loaders' MeshError / DecompositionError / SlicingError, all one line.
    slicer.envelope.EnvelopeError
        (a MeshError) The part is wider than the platform, nothing is printed, or a move
        leaves the travel; raised before any G-code is returned.
    """
    t0 = time.perf_counter()
    head = head or Printhead.default()
    timings: dict[str, float] = {}
    report = _reporter(progress)
    with small_pages(), ThreadPoolExecutor(1, "replay-index") as early:
        report("reading the part")
        mesh, placement = _load(mesh_or_path, settings.nozzle_diameter, build_volume)
        name = _name(mesh_or_path)
        envelope.refuse(name, envelope.footprint_message(
            envelope.footprint_radius(mesh.vertices), platform_radius))
        timings["load"] = time.perf_counter() - t0
        # the replay's model index needs only the placed mesh: built on the second core
        # while the decomposition and the layers (mostly one thread) are computed
        index = early.submit(model_index, mesh, settings.line_width) if check else None
        t1 = time.perf_counter()
        report("decomposing and planning")
        plan = plan_model(mesh, placement.matrix, settings, geometry, head,
                          decompose_settings, planar, build_volume)
        timings["plan"] = time.perf_counter() - t1
        if plan.base is not None and plan.base.turn is not None:  # stands on another face
            mesh = _turned(mesh, plan.base, name, platform_radius)
            index = early.submit(model_index, mesh, settings.line_width) if check else None
        if index is not None:  # and its coverage grid while the G-code is written
            index = early.submit(_with_grid, index, settings)
        travel_ranges = tuple((float(lo), float(hi)) for lo, hi in np.reshape(travel, (3, 2)))
        setup = MachineSetup(geometry, head, platform_radius, travel_ranges)
        seed = None if planar else (decompose_settings.seed if decompose_settings else 0)
        first = _finish(mesh, plan, settings, setup, index, timings, t0, keep_plan, name,
                        seed, report)

        def again(hints: LeanHints) -> tuple[SliceResult, np.ndarray]:
            assert plan.decomposition is not None
            t2 = time.perf_counter()
            report("repair")
            replanned = plan_print(plan.decomposition, settings, geometry, head, lean=LEAN,
                                   hints=hints)
            return _finish(mesh, replanned, settings, setup, index, {}, t2, keep_plan, name,
                           seed)

        result = _repaired(first, again if plan.decomposition is not None else None, timings)
        report("done")
        return replace(result, merged_shells=placement.merged_shells,
                       base_note=None if plan.base is None else plan.base.note)


def _reporter(progress: Progress | None) -> Callable[[str], None]:
    """``report(stage)``: ``progress`` told the stage and its percentage, each stage once
    (the repair rounds run the later stages again)."""
    told: set[str] = set()
    tell = progress or _no_progress

    def report(stage: str) -> None:
        if stage not in told:
            told.add(stage)
            tell(stage, _PERCENT[stage])

    return report


def _turned(mesh: trimesh.Trimesh, base: BaseChoice, name: str,
            platform_radius: float) -> trimesh.Trimesh:
    """``mesh`` stood on the face ``base`` names (the very mesh the decomposition used),
    refused when it no longer fits the platform."""
    from slicer.mesh import moved

    assert base.turn is not None
    turned = moved(mesh, base.turn)
    wide = envelope.footprint_message(envelope.footprint_radius(turned.vertices),
                                      platform_radius)
    envelope.refuse(name, None if wide is None else f"{wide} ({base.note})")
    return turned


def _name(mesh_or_path: trimesh.Trimesh | str | Path) -> str:
    """How errors name the part (as the loader does)."""
    return str(mesh_or_path) if isinstance(mesh_or_path, str | Path) else "<mesh>"


def check_envelope(moves: Draft, name: str = "<mesh>") -> None:
    """Refuse a program that prints nothing or leaves the machine's travel.

    Raises
    ------
    slicer.envelope.EnvelopeError
        One line: ``"<name>: nothing to print: ..."`` or ``"<name>: machine Z reaches ...
        outside machine.z_range [lo, hi] (sub-part k, layer i)"``.
    """
    tab = moves.program.table()
    xyz = tab.vals[:, :3]
    if envelope.extruded_length(xyz, tab.rows[:, E]) <= 0.0:
        layers = sum(len(sp.layers) for sp in moves.plan.subparts)
        envelope.refuse(name, envelope.nothing_to_print_message(moves.settings.line_width,
                                                                 layers))
    envelope.refuse(name, _travel_message(moves, xyz, tab.at, tab.texts))


def _travel_message(moves: Draft, xyz: np.ndarray, at: np.ndarray,
                    texts: list[str]) -> str | None:
    """Why the moves ``xyz`` (n, 3) or the scripts' ``{safe_z}`` leave the travel, if so."""
    travel = moves.machine.travel
    out = envelope.travel_violation(xyz, travel)
    if out is not None:
        where = envelope.place_of(out.row, at, texts)
        if out.axis == 2 and where.startswith("transition"):
            where += (f": the lift clears the part by process.safe_height "
                      f"{moves.settings.safe_height:g} mm")
        return out.message(where)
    for script, z in moves.script_safe_z().items():
        out = envelope.travel_violation([[np.nan, np.nan, z]], travel)
        if out is not None:
            return out.message(f"{{safe_z}} of the {script} G-code")
    return None


def _with_grid(index: Future[ModelIndex], settings: ProcessSettings) -> ModelIndex:
    """``index`` once built, with the coverage grid the replay will ask for."""
    model = index.result()
    shell_grid(model, shell_depth(settings.perimeters, settings.line_width))
    return model


def _repaired(first: tuple[SliceResult, np.ndarray],
              again: Callable[[LeanHints], tuple[SliceResult, np.ndarray]] | None,
              timings: dict[str, float], rounds: int | None = None) -> SliceResult:
    """The closed loop: while the best result so far has walls printed in the air (the
    replay's unsupported wall layers), plan again with the root's layers leaning
    (:mod:`slicer.paths.upright`) and hints at the unsupported walls of every try
    (:class:`~slicer.paths.LeanHints`: it leans harder there; the first lean takes none),
    at most ``rounds`` times;
    the best result (fewest such layers, then most walls supported) is kept. A try that
    fails outright (a collision, a layer in the air) ends the loop. The rounds' seconds
    are ``timings["repair"]`` and their number ``timings["repair_rounds"]``; ``rounds``
    defaults to :data:`REPAIR_ROUNDS`."""
    best, misses = first
    hints = NO_HINTS
    t0 = time.perf_counter()
    done = 0
    rounds = REPAIR_ROUNDS if rounds is None else rounds
    while again is not None and done < rounds and _bad_walls(best) and len(misses):
        if done:  # the first lean has no hints: the upright try's misses are not its own
            hints = hints.more(misses)
        done += 1
        try:
            result, misses = again(hints)
        except (SliceError, SlicingError) as exc:
            log.info("repair round %d failed: %s", done, exc)
            break
        log.info("repair round %d: %d unsupported wall layers (best so far %d)", done,
                 _bad_walls(result), _bad_walls(best))
        if _rank(result) < _rank(best):
            best = result
    if done:
        timings["repair"] = time.perf_counter() - t0
        timings["repair_rounds"] = float(done)
        best.timings.update({k: timings[k] for k in ("repair", "repair_rounds")})
    return best


def _bad_walls(result: SliceResult) -> int:
    """How many wall layers the result's replay found printed in the air."""
    layers = result.replay.get("unsupported_wall_layers", [])
    return len(layers) if isinstance(layers, list) else 0


def _rank(result: SliceResult) -> tuple[int, float]:
    """Fewer unsupported wall layers first, then more walls supported."""
    walls = result.replay.get("wall_supported", 1.0)
    return (_bad_walls(result), -float(walls) if isinstance(walls, int | float) else 0.0)


def _finish(mesh: trimesh.Trimesh, plan: PrintPlan, settings: ProcessSettings,
            setup: MachineSetup, index: Future[ModelIndex] | None, timings: dict[str, float],
            t0: float, keep_plan: bool, name: str = "<mesh>", seed: int | None = None,
            stage: Callable[[str], None] | None = None) -> tuple[SliceResult, np.ndarray]:
    """G-code for ``plan``, its envelope check and, when ``index`` is given, its replay check;
    with the replay's unsupported wall samples (platform frame, (k, 3)).

    ``seed`` is the decomposition's (``None`` for the planar control), for the advice of an
    :class:`OverhangError`.

    The replay reads the program's numbers, so the estimate and the text are computed on a
    thread of their own meanwhile (mostly numpy: the replay loses little of the GIL to it).
    """
    t1 = time.perf_counter()
    stage = stage or (lambda name: None)
    stage("writing G-code")
    moves = draft(plan, settings, setup)
    check_envelope(moves, name)
    timings["gcode"] = time.perf_counter() - t1
    report: dict[str, object] = {}
    misses = np.zeros((0, 3))
    if index is None:
        res = _timed(moves.finish, timings, "text")
    else:
        with ThreadPoolExecutor(1, "gcode-text") as writer:
            text = writer.submit(_timed, moves.finish, timings, "text")
            stage("replay check")
            rep = _replayed(moves, mesh, setup, index, timings, seed)
            report, misses = rep.to_dict(), rep.wall_misses
            res = text.result()
    return SliceResult(res.lines, len(plan.subparts),
                       sum(len(sp.layers) for sp in plan.subparts), _thickness(plan),
                       res.estimate.header(), report, res.transitions,
                       {**{f"plan.{k}": v for k, v in plan.timings.items()}, **timings},
                       time.perf_counter() - t0, plan if keep_plan else None), misses


def _timed(fn: Callable[[], T], timings: dict[str, float], name: str) -> T:
    """``fn()``, its wall seconds recorded as ``timings[name]``."""
    t1 = time.perf_counter()
    try:
        return fn()
    finally:
        timings[name] = time.perf_counter() - t1


def _replayed(moves: Draft, mesh: trimesh.Trimesh, setup: MachineSetup,
              index: Future[ModelIndex], timings: dict[str, float], seed: int | None = None
              ) -> ReplayReport:
    """The replay report of ``moves``; raises :class:`CollisionError` if the head hits,
    :class:`OverhangError` if a layer prints in the air (advice for decomposition ``seed``,
    ``None``: the planar control)."""
    parsed = _timed(lambda: parse_words(moves.words()), timings, "read")
    rep = _timed(lambda: replay_check(parsed, mesh, setup.head, setup.platform_radius,
                                      placed=True, index=index.result()), timings, "replay")
    if not rep.ok:
        first = rep.collision_messages[0] if rep.collision_messages else ""
        if rep.collisions:
            raise CollisionError(f"replay found {rep.collisions} head collision(s); "
                                 f"refusing to write the file: {first}")
        raise OverhangError(overhang_message(rep.overhang_layers, seed))
    return rep


def overhang_message(layers: list[dict[str, object]], seed: int | None) -> str:
    """One line for a replay's ``overhang_layers`` (worst first, at least one): the worst
    layer, how many more, and what to try (another decomposition seed; for the planar
    control (``seed`` None), the five-axis slice)."""
    worst = layers[0]
    more = f" (and {len(layers) - 1} more layers)" if len(layers) > 1 else ""
    if seed is None:
        advice = ("the planar control cannot print this overhang without support; slice it "
                  "five-axis (without --planar)")
    else:
        advice = (f"the decomposition left an overhang in sub-part {worst['subpart']}; try "
                  f"decompose.seed {seed + 1} (or another seed), or set decompose.parts")
    return (f"replay found a layer printed in the air; refusing to write the file: "
            f"{overhang_text(worst)}{more}; {advice}")
