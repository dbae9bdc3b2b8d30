"""STL → checked G-code in one call: decompose, plan, write, replay-check.

Used by ``hostctl slice`` and the daemon's slicing worker: a plain function with a plain-data,
picklable result. A file whose replay finds a head collision is refused
(:class:`CollisionError`), never returned, and so is one with a layer printed in the air
(:class:`OverhangError`), and one with unsupported wall layers unless the caller allows them
(:class:`UnsupportedWallsError`; ``allow_overhang`` writes it with a warning); so is a part
wider than the platform, a program
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
from slicer import envelope, repair
from slicer.advice import (
    CONFIG_KEYS,
    THINNEST,
    Knobs,
    overhang_message,
    thinner_layers,
    walls_message,
    walls_warning,
)
from slicer.gcode import Draft, E, MachineSetup, draft, parse_words
from slicer.hugepages import small_pages
from slicer.paths import (
    LEAN,
    NO_HINTS,
    LeanHints,
    SlicingError,
    Thinning,
    any_height,
    plan_print,
)
from slicer.plan import PrintPlan
from slicer.printhead import Printhead
from slicer.repair import (
    ALTERNATIVES,
    FIRST_ROUNDS,
    REPAIR_ROUNDS,
    Begun,
    Try,
    best_decomposition,
    leaned_instead,
    leaning,
    started,
    thinned,
)
from slicer.replay import (
    ModelIndex,
    ReplayReport,
    WallSamples,
    held_heights,
    model_index,
    overhang_deg,
    replay_check,
    shell_depth,
    shell_grid,
    thickness_step,
)
from slicer.settings import ProcessSettings

if TYPE_CHECKING:
    from slicer.decompose import DecomposeSettings, Decomposition
    from slicer.mesh import BaseChoice, Placement

T = TypeVar("T")
log = logging.getLogger(__name__)

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


class ReplayRefusal(SliceError):
    """The replay check refused the file.

    Attributes
    ----------
    plan : PrintPlan or None
        The plan refused, for a preview.
    marks : (k, 3) float
        Platform-frame points of the failing region (for a preview to mark; may be empty).
    """

    def __init__(self, message: str, plan: PrintPlan | None = None,
                 marks: np.ndarray | None = None) -> None:
        super().__init__(message)
        self.plan = plan
        self.marks = np.zeros((0, 3)) if marks is None else marks

    def __reduce__(self) -> tuple[type[ReplayRefusal], tuple[str]]:
        return type(self), (str(self),)  # the message alone crosses a process boundary


class CollisionError(ReplayRefusal):
    """The replay found head collisions: the file is refused."""


class OverhangError(ReplayRefusal):
    """The replay found a layer printed in the air (over both of
    :data:`~slicer.replay.support.OVERHANG_SHARE` and ``OVERHANG_RUN``): the file is
    refused."""


class UnsupportedWallsError(ReplayRefusal):
    """The replay found unsupported wall layers and the caller did not allow them: the file
    is refused; ``marks`` are the unsupported wall samples."""


@dataclass(frozen=True)
class OverhangPolicy:
    """What unsupported wall layers do: refuse the file, or with ``allow`` let it through
    with a warning; ``knobs`` name what a refusal suggests (:class:`~slicer.advice.Knobs`)."""

    allow: bool = False
    knobs: Knobs = CONFIG_KEYS


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
    walls : WallSamples or None
        The replay's unsupported wall samples (platform frame), for a preview; None unchecked.
    warning : str or None
        One line: the file has unsupported wall layers and was written as the caller allowed.
    seed : int or None
        The decomposition seed that planned the file (``decompose.seed``: another one than
        asked for when the closed loop found a better decomposition; None: planar).
    parts : int or None
        With ``seed``, the K that decomposes it again when the file was planned from another
        attempt of the decomposition than the first (``decompose.parts``); else None.
    thinned : (int, float)
        Layers marched thinner than the layer height where the surface overhangs a little
        past what it holds (:mod:`slicer.paths.thin_layers`), and the thinnest of them, mm
        ((0, 0.0): none).
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
    walls: WallSamples | None = None
    warning: str | None = None
    seed: int | None = None
    parts: int | None = None
    thinned: tuple[int, float] = (0, 0.0)

    def summary(self) -> dict[str, object]:
        """The result without the G-code lines, the plan and the wall samples."""
        d = asdict(replace(self, walls=None))
        d.pop("lines")
        d.pop("plan")
        d.pop("walls")
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


def _thinned(plan: PrintPlan, t: float) -> tuple[int, float]:
    """How many layers of ``plan`` were marched thinner than ``t``, and the thinnest."""
    thin = [layer.nominal for sp in plan.subparts for layer in sp.layers
            if 0.0 < layer.nominal < t - 1e-9]
    return len(thin), min(thin, default=0.0)


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
                travel: ArrayLike = envelope.DEFAULT_TRAVEL, allow_overhang: bool = False,
                knobs: Knobs | None = None, repair_rounds: int | None = None,
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
    allow_overhang : bool
        Return a file with unsupported wall layers (with ``warning``) instead of refusing it.
    knobs : slicer.advice.Knobs, optional
        How a refusal names what to try (default: the config keys).
    repair_rounds : int, optional
        Leaning tries of the closed loop at most (default :data:`REPAIR_ROUNDS`; 0: the
        paper's upright root only).
    progress : callable, optional
        Told each stage of :data:`STAGES` as it starts (``progress(stage, percent)``).

    Raises
    ------
    SliceError, CollisionError, OverhangError, UnsupportedWallsError
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
        travel_ranges = tuple((float(lo), float(hi)) for lo, hi in np.reshape(travel, (3, 2)))
        job = _Slicing(mesh, placement, index, early, settings, geometry, head,
                       MachineSetup(geometry, head, platform_radius, travel_ranges),
                       OverhangPolicy(allow_overhang, knobs or CONFIG_KEYS), name, keep_plan,
                       planar, build_volume, decompose_settings, report, t0, timings)
        rounds = REPAIR_ROUNDS if repair_rounds is None else repair_rounds
        fixed = planar or rounds == 0 or (decompose_settings is not None
                                          and decompose_settings.root is not None)
        best = best_decomposition(job.decomposed, 0 if fixed else ALTERNATIVES, rounds,
                                  (SliceError, SlicingError, repair.Refused), timings)
        for key, value in timings.items():  # the slice's, where the kept try has none
            best.result.timings.setdefault(key, value)
        asked = None if planar else (decompose_settings.seed if decompose_settings else 0)
        tried = int(timings.get("alternatives_tried", 0))
        result = _judged(best, job.policy, None if asked is None else asked + tried)
        report("done")
        base = best.plan.base
        return replace(result, merged_shells=placement.merged_shells,
                       base_note=None if base is None else base.note,
                       seconds=time.perf_counter() - t0)


@dataclass
class _Slicing:
    """One part being sliced: what every decomposition tried of it shares."""

    mesh: trimesh.Trimesh
    placement: Placement
    index: Future[ModelIndex] | None
    early: ThreadPoolExecutor
    settings: ProcessSettings
    geometry: MachineGeometry
    head: Printhead
    setup: MachineSetup
    policy: OverhangPolicy
    name: str
    keep_plan: bool
    planar: bool
    build_volume: np.ndarray | None
    decompose_settings: DecomposeSettings | None
    report: Callable[[str], None]
    t0: float
    timings: dict[str, float]
    runners_up: list[Decomposition] = field(default_factory=list)
    tried: set[tuple[object, ...]] = field(default_factory=set)
    """Signatures of the decompositions planned (:meth:`Decomposition.signature`)."""

    def seeded(self, k: int) -> DecomposeSettings | None:
        """The decomposition settings of the ``k``-th decomposition tried: the seed asked
        for, then the next ones."""
        if k == 0:
            return self.decompose_settings
        from slicer.decompose import DecomposeSettings

        base = self.decompose_settings or DecomposeSettings(
            nozzle_diameter=self.settings.nozzle_diameter)
        return replace(base, seed=base.seed + k)

    def decomposed(self, k: int, rounds: int) -> Begun[SliceResult]:
        """The ``k``-th decomposition begun (:func:`repair.best_decomposition`): planned
        upright, then leaning, at most ``rounds`` leaning tries with its rest. The first is
        the one asked for; the next ones are its runners-up (the decomposition's other valid
        attempts, :attr:`Decomposition.runners_up`, at no new cost), then the next seeds.
        The first one's stage timings are the slice's; another one's refusals of the part
        itself (its decomposition, its travel) are :class:`repair.Refused`, passed over."""
        if k == 0:
            return self._decomposed(self.decompose_settings, rounds, self.timings, self.t0)
        from slicer.decompose import DecompositionError
        from slicer.mesh import MeshError

        runners = len(self.runners_up)
        which = self.runners_up[k - 1] if k <= runners else self.seeded(k - runners)
        try:
            return self._decomposed(which, rounds, {}, time.perf_counter())
        except (DecompositionError, MeshError) as exc:
            raise repair.Refused(str(exc)) from None

    def _decomposed(self, dec: DecomposeSettings | Decomposition | None, rounds: int,
                    timings: dict[str, float], t0: float) -> Begun[SliceResult]:
        """Plan ``dec`` (a decomposition made, or the settings of one to make), then write,
        check and repair it: its first tries, and the rest of them to make when the loop
        asks (:func:`repair.best_decomposition`)."""
        from slicer.decompose import Decomposition

        self.report("decomposing and planning")
        t1 = time.perf_counter()
        if isinstance(dec, Decomposition):
            self._unseen(dec)
        plan, seed, parts = self._plan(dec)
        timings["plan"] = time.perf_counter() - t1
        if plan.decomposition is not None and not isinstance(dec, Decomposition):
            self._unseen(plan.decomposition)
        mesh, index = self.mesh, self.index
        if plan.base is not None and plan.base.turn is not None:  # stands on another face
            mesh = _turned(mesh, plan.base, self.name, self.setup.platform_radius)
            index = (self.early.submit(model_index, mesh, self.settings.line_width)
                     if index is not None else None)
        if index is not None:  # and its coverage grid while the G-code is written
            index = self.early.submit(_with_grid, index, self.settings)
        # the closures hold the decomposition, not the first plan: a decomposition left for
        # later keeps only its best try (:class:`Begun`)
        decomposition = plan.decomposition

        def replanned(hints: LeanHints | None, thin: Thinning | None = None
                      ) -> Try[SliceResult]:
            """The decomposition planned again, leaning with ``hints`` (None: upright)."""
            assert decomposition is not None
            t2 = time.perf_counter()
            self.report("repair")
            made = plan_print(decomposition, self.settings, self.geometry, self.head,
                              lean=None if hints is None else LEAN, hints=hints or NO_HINTS,
                              thin=thin)
            return replace(self._finish(mesh, made, index, {}, t2, seed), parts=parts,
                           hints=hints)

        def again(hints: LeanHints) -> Try[SliceResult]:
            return replanned(hints)

        def thin(base: Try[SliceResult], spots: bool) -> Try[SliceResult]:
            rule = base.thinning or self.thinning(slopes=not spots)
            if spots:
                rule = replace(rule, spots=base.spots(), first=self.first_thickness(rule))
            return replace(replanned(base.hints, rule), thinning=rule)

        retry = again if decomposition is not None and rounds != 0 else None
        leaned = 0
        try:
            first = replace(self._finish(mesh, plan, index, timings, t0, seed,
                                         stage=self.report), parts=parts)
        except OverhangError as exc:  # a layer in the air upright: leaning may hold it
            if retry is None:
                raise
            first, leaned = leaned_instead(exc, retry, (SliceError, SlicingError)), 1
        t3 = time.perf_counter()
        state = leaning(started(first, leaned), retry, (SliceError, SlicingError),
                        min(rounds, FIRST_ROUNDS))
        _count_rounds(state.best, state.done, timings, t3)
        if retry is None:
            return Begun(state.best)

        def rest() -> Try[SliceResult]:
            """The decomposition's further leaning tries, then thinner layers."""
            t4 = time.perf_counter()
            more = leaning(state, retry, (SliceError, SlicingError), rounds)
            best = thinned(more.best, thin, (SliceError, SlicingError))
            return _count_rounds(best, more.done, timings, t4)

        return Begun(state.best, rest)

    def thinning(self, slopes: bool = True) -> Thinning:
        """Thinner layers where the replay's support rule holds the surface at a height no
        thinner than :data:`~slicer.advice.THINNEST` (``slopes``; else nowhere yet: spots
        are added to it)."""
        width = self.settings.line_width

        def held(angles: np.ndarray) -> np.ndarray:
            return held_heights(angles, width)

        return Thinning(held if slopes else any_height, THINNEST, thickness_step(width))

    def first_thickness(self, rule: Thinning) -> float:
        """How thick a first layer on a parent's beads is made through a spot
        (``Thinning.first``): the thickest bead the settings allow
        (:meth:`~slicer.settings.ProcessSettings.max_layer_share`), no more than a nominal
        layer plus ``rule.step``, mm."""
        t = self.settings.layer_height
        return min(self.settings.max_layer_share() * t, t + rule.step)

    def _unseen(self, dec: Decomposition) -> None:
        """Remember ``dec``; :class:`repair.Refused` when one with the same sub-parts was
        tried (another seed or K often ends in them): its tries would repeat."""
        signature = dec.signature()
        if signature in self.tried:
            raise repair.Refused("the same sub-parts as a decomposition tried")
        self.tried.add(signature)

    def _plan(self, dec: DecomposeSettings | Decomposition | None
              ) -> tuple[PrintPlan, int | None, int | None]:
        """The plan of ``dec``, with the seed (and, for a runner-up, the K) that make its
        decomposition again; the first plan's runners-up are kept."""
        from slicer.decompose import Decomposition

        if isinstance(dec, Decomposition):
            return plan_print(dec, self.settings, self.geometry, self.head), dec.seed, dec.k
        plan = plan_model(self.mesh, self.placement.matrix, self.settings, self.geometry,
                          self.head, dec, self.planar, self.build_volume)
        if plan.decomposition is not None and not self.runners_up:
            self.runners_up = list(plan.decomposition.runners_up)
        return plan, None if self.planar else (0 if dec is None else dec.seed), None

    def _finish(self, mesh: trimesh.Trimesh, plan: PrintPlan,
                index: Future[ModelIndex] | None, timings: dict[str, float], t0: float,
                seed: int | None, stage: Callable[[str], None] | None = None
                ) -> Try[SliceResult]:
        return _finish(mesh, plan, self.settings, self.setup, index, timings, t0,
                       self.keep_plan, self.name, seed, self.policy, judge=False,
                       stage=stage)


def _count_rounds(best: Try[SliceResult], done: int, timings: dict[str, float],
                  t0: float) -> Try[SliceResult]:
    """``best``, after ``done`` leaning rounds in all that (with thinner layers) began at
    ``t0``: ``timings`` (and the try's own) count their seconds and rounds."""
    if done:
        timings["repair"] = timings.get("repair", 0.0) + time.perf_counter() - t0
        timings["repair_rounds"] = float(done)
        best.result.timings.update({k: timings[k] for k in ("repair", "repair_rounds")})
    return best


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


def _judged(attempt: Try[SliceResult], policy: OverhangPolicy, last_seed: int | None
            ) -> SliceResult:
    """The kept try's result with the decomposition seed that planned it, refused
    (:class:`UnsupportedWallsError`) or warned about as ``policy`` says when it has wall
    layers over air (:func:`walls_verdict`; its advice names the seed after ``last_seed``,
    the last one the closed loop could have tried)."""
    result = replace(attempt.result, seed=attempt.seed, parts=attempt.parts)
    if attempt.report is None:
        return result
    warning = walls_verdict(attempt.report, attempt.plan, last_seed, policy, attempt.thinner)
    return replace(result, warning=warning)


def _finish(mesh: trimesh.Trimesh, plan: PrintPlan, settings: ProcessSettings,
            setup: MachineSetup, index: Future[ModelIndex] | None, timings: dict[str, float],
            t0: float, keep_plan: bool, name: str = "<mesh>", seed: int | None = None,
            policy: OverhangPolicy = OverhangPolicy(), judge: bool = True,
            stage: Callable[[str], None] | None = None) -> Try[SliceResult]:
    """G-code for ``plan``, its envelope check and, when ``index`` is given, its replay check.

    ``seed`` is the decomposition's (``None`` for the planar control), for the advice of a
    refusal; ``policy`` says what unsupported wall layers do, when ``judge`` (else the
    caller judges the try it keeps, :func:`_judged`).

    The replay reads the program's numbers, so the estimate and the text are computed on a
    thread of their own meanwhile (mostly numpy: the replay loses little of the GIL to it).
    """
    t1 = time.perf_counter()
    stage = stage or (lambda name: None)
    stage("writing G-code")
    moves = draft(plan, settings, setup)
    check_envelope(moves, name)
    timings["gcode"] = time.perf_counter() - t1
    report: ReplayReport | None = None
    warning: str | None = None
    thinner: tuple[float, float] | None = None
    if index is None:
        res = _timed(moves.finish, timings, "text")
    else:
        with ThreadPoolExecutor(1, "gcode-text") as writer:
            text = writer.submit(_timed, moves.finish, timings, "text")
            stage("replay check")
            report = _replayed(moves, mesh, setup, index, timings, seed, policy.knobs)
            thinner = _thinner(report, plan, mesh, settings)
            warning = walls_verdict(report, plan, seed, policy, thinner) if judge else None
            res = text.result()
    result = SliceResult(res.lines, len(plan.subparts),
                         sum(len(sp.layers) for sp in plan.subparts), _thickness(plan),
                         res.estimate.header(), {} if report is None else report.to_dict(),
                         res.transitions,
                         {**{f"plan.{k}": v for k, v in plan.timings.items()}, **timings},
                         time.perf_counter() - t0, plan if keep_plan else None,
                         walls=None if report is None else report.unsupported_walls,
                         warning=warning, thinned=_thinned(plan, settings.layer_height))
    return Try(result, report, plan, seed, thinner=thinner)


def _thinner(report: ReplayReport, plan: PrintPlan, mesh: trimesh.Trimesh,
             settings: ProcessSettings) -> tuple[float, float] | None:
    """The thinner layers that would hold the report's wall layers
    (:func:`~slicer.advice.thinner_layers` of the overhang of the surface around their
    unsupported wall samples, each below its own layer's plane), or None."""
    walls = report.unsupported_walls
    if not report.wall_layers or not len(walls):
        return None
    normals = {(sp.index, k): layer.normal for sp in plan.subparts
               for k, layer in enumerate(sp.layers)}
    keys = list(zip(walls.subpart.tolist(), walls.layer.tolist(), strict=True))
    known = np.array([key in normals for key in keys], dtype=bool)
    if not known.any():
        return None
    axes = np.array([normals[key] for key, ok in zip(keys, known, strict=True) if ok])
    angle = overhang_deg(walls.p[known], axes, mesh)
    return thinner_layers(angle, settings.layer_height, settings.line_width)


def _timed(fn: Callable[[], T], timings: dict[str, float], name: str) -> T:
    """``fn()``, its wall seconds recorded as ``timings[name]``."""
    t1 = time.perf_counter()
    try:
        return fn()
    finally:
        timings[name] = time.perf_counter() - t1


def _replayed(moves: Draft, mesh: trimesh.Trimesh, setup: MachineSetup,
              index: Future[ModelIndex], timings: dict[str, float], seed: int | None = None,
              knobs: Knobs = CONFIG_KEYS) -> ReplayReport:
    """The replay report of ``moves``; raises :class:`CollisionError` if the head hits,
    :class:`OverhangError` if a layer prints in the air (advice for decomposition ``seed``,
    ``None``: the planar control, in the caller's ``knobs``)."""
    parsed = _timed(lambda: parse_words(moves.words()), timings, "read")
    rep = _timed(lambda: replay_check(parsed, mesh, setup.head, setup.platform_radius,
                                      placed=True, index=index.result()), timings, "replay")
    if not rep.ok:
        first = rep.collision_messages[0] if rep.collision_messages else ""
        if rep.collisions:
            raise CollisionError(f"replay found {rep.collisions} head collision(s); "
                                 f"refusing to write the file: {first}", moves.plan)
        raise OverhangError(overhang_message(rep.overhang_layers, seed, knobs), moves.plan,
                            _platform_points([d["point"] for d in rep.overhang_layers],
                                             moves.plan.placement))
    return rep


def walls_verdict(rep: ReplayReport, plan: PrintPlan, seed: int | None,
                  policy: OverhangPolicy, thinner: tuple[float, float] | None = None
                  ) -> str | None:
    """``None`` for a file without unsupported wall layers; for one with them, the warning
    line when ``policy`` allows them, else :class:`UnsupportedWallsError` (one line: the
    worst layer and what to try, thinner layers among it when ``thinner`` says they hold
    it; ``marks`` the unsupported wall samples)."""
    if not rep.wall_layers:
        return None
    if policy.allow:
        return walls_warning(rep, policy.knobs)
    raise UnsupportedWallsError(walls_message(rep, seed, policy.knobs, thinner), plan,
                                rep.unsupported_walls.p)


def _platform_points(points: list[list[float] | None], placement: np.ndarray) -> np.ndarray:
    """Part-frame points (those not None) moved by ``placement`` (4, 4), (k, 3)."""
    p = np.array([q for q in points if q is not None], dtype=float).reshape(-1, 3)
    return p @ placement[:3, :3].T + placement[:3, 3]
