"""The closed loop: plan again where the replay finds walls that are not held.

:func:`slicer.pipeline.slice_model` hands this module callables that plan, write and check
one file (a :class:`Try`); here they are tried in turn and the best file is kept:

1. the paper's try (the root upright), then up to :data:`REPAIR_ROUNDS` tries with the root's
   layers leaning (:mod:`slicer.paths.upright`), each after the first hinted at the
   unsupported walls of the last (:func:`leaning`);
2. when no lean of that decomposition holds every wall, **other decompositions**, up to
   :data:`ALTERNATIVES`: the decomposition's runners-up (its other valid attempts, made
   already), then the part decomposed with the next seeds (another k-means partition, so
   other groups, planes and build order), each tried upright and leaning for at most
   :data:`ALTERNATIVE_ROUNDS` rounds (:func:`best_decomposition`). A seed whose plan fails
   outright (the planner's veto: no plane clears the printed part or the platform) is
   passed over when another one plans;
3. within each decomposition, once its leaning tries are done and none is support-free,
   the best made again with thinner layers: where the surface overhangs a little past
   what the height holds, then through the points where its walls are over air
   (:func:`thinned`).

The tries after a decomposition's first lean (its hinted leans, its thinner layers) are local
repairs: they come at once when its best try by then leaves at most :data:`NEAR` wall layers
over air, else only after every other decomposition has begun (:func:`best_decomposition`).

Beyond the paper, which decomposes once and never looks back. The tries are ranked by
:meth:`Try.rank`: fewest wall layers over air (what a file is refused for), then fewest
unsupported wall layers by the strict rule, then most walls held; the loop stops as soon as
a try is support-free by the strict rule (:attr:`ReplayReport.support_free`).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Generic, TypeVar

import numpy as np

from slicer.paths import NO_HINTS, LeanHints, Spots, Thinning
from slicer.plan import PrintPlan
from slicer.replay import ReplayReport

log = logging.getLogger(__name__)
R = TypeVar("R")

REPAIR_ROUNDS = 3
"""Leaning tries of one decomposition at most (the first decomposition's)."""
ALTERNATIVES = 4
"""Other decompositions tried when the first holds no file support-free: the runners-up, then
the next seeds. Two were tried until 2026-12-07; the third and fourth (next seeds) hold
five more slices of the sweep's 64 (tree10 and elbow13 at both heights, tree26 at 0.3 mm)
and cost a part that stays unsupported about twice its time (``bench/hard_sweep.py``)."""
ALTERNATIVE_ROUNDS = 1
"""Leaning tries of each other decomposition at most."""
FIRST_ROUNDS = 1
"""Leaning tries of a decomposition before the loop judges how near support-free it is."""
NEAR = 2
"""Wall layers over air at most, after a decomposition's first lean, for its further tries
(hinted leans, thinner layers) to come before the next decomposition's; one farther off is
tried further only once every other decomposition has begun. See docs/decomposition.md,
*Near or far*."""


class Refused(Exception):
    """A try that produced no file: the caller's refusal (one line), kept to be raised when
    no try produces one."""


@dataclass
class Try(Generic[R]):
    """One plan's file: the result (the caller's type), its replay report (None unchecked),
    the plan, the decomposition seed (None: planar) and K (None: as configured) that
    decompose it again, and the thinner layers that would hold its worst wall layer
    ((layer height, overhang in degrees), :func:`slicer.advice.thinner_layers`), if any."""

    result: R
    report: ReplayReport | None
    plan: PrintPlan
    seed: int | None = None
    parts: int | None = None
    thinner: tuple[float, float] | None = None
    hints: LeanHints | None = None
    """The hints of a leaning try (None: upright), to plan it again."""
    thinning: Thinning | None = None
    """How its layers were thinned (None: every layer nominal), to thin them further."""

    @property
    def over_air(self) -> int:
        """Wall layers over air (what a file is refused for)."""
        return 0 if self.report is None else self.report.wall_layers_over_air

    @property
    def support_free(self) -> bool:
        """Whether the replay holds every wall by the strict rule (unchecked: taken so)."""
        return self.report is None or self.report.support_free

    def rank(self) -> tuple[int, int, float]:
        """Fewer wall layers over air, then fewer unsupported wall layers, then more walls
        held."""
        if self.report is None:
            return (0, 0, 0.0)
        return (self.over_air, len(self.report.unsupported_wall_layers),
                -self.report.wall_supported)

    def __str__(self) -> str:
        """What the log says of the try: its wall layers over air and unsupported."""
        if self.report is None:
            return "unchecked"
        free = ", support-free" if self.support_free else ""
        return (f"{self.over_air} wall layers over air, "
                f"{len(self.report.unsupported_wall_layers)} unsupported{free}")

    def misses(self) -> np.ndarray:
        """The try's unsupported wall samples (platform frame), (k, 3)."""
        if self.report is None:
            return np.zeros((0, 3))
        return np.asarray(self.report.unsupported_walls.p, dtype=float).reshape(-1, 3)

    def spots(self) -> Spots:
        """The try's unsupported wall samples with their sub-parts, to thin layers at."""
        if self.report is None:
            return Spots(np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
        walls = self.report.unsupported_walls
        return Spots(self.misses(), np.asarray(walls.subpart, dtype=np.int64))




def leaned_instead(error: Exception, again: Callable[[LeanHints], Try[R]],
                   failures: tuple[type[Exception], ...]) -> Try[R]:
    """The first leaning try, for a part whose upright try failed (a layer in the air);
    ``error`` again when that fails too (one of ``failures``)."""
    try:
        return again(NO_HINTS)
    except failures as exc:
        log.info("leaning after %s failed: %s", error, exc)
        raise error from None


@dataclass(frozen=True)
class Leaning(Generic[R]):
    """Where the leaning tries of one decomposition stand (:func:`leaning`): the best try so
    far, the rounds taken, the hints of the next round (None: none can be made, the last try
    named no unsupported wall), and whether a failing or no better round ended them."""

    best: Try[R]
    done: int = 0
    hints: LeanHints | None = NO_HINTS
    ended: bool = False

    def go_on(self, rounds: int) -> bool:
        """Whether another round is to be tried, ``rounds`` in all at most."""
        return (not self.ended and self.done < rounds and not self.best.support_free
                and self.hints is not None)


def leaning(state: Leaning[R], again: Callable[[LeanHints], Try[R]] | None,
            failures: tuple[type[Exception], ...], rounds: int) -> Leaning[R]:
    """While the best try so far is not support-free, plan again with the root's layers
    leaning (:mod:`slicer.paths.upright`) and hints at the unsupported walls of every
    leaning try (:class:`~slicer.paths.LeanHints`: it leans harder there; the first lean
    takes none, the upright try's misses are not its own), ``rounds`` tries in all at most,
    counting those of ``state``. A try that fails outright (one of ``failures``), or a
    hinted one no better than the best, ends them: :attr:`Leaning.ended`.

    A state returned may be handed back with more ``rounds``: the tries go on as if they
    had not stopped (the loop leaves a decomposition far from support-free for others and
    comes back to it, :func:`best_decomposition`)."""
    while again is not None and state.go_on(rounds):
        assert state.hints is not None
        done = state.done + 1
        try:
            last = again(state.hints)
        except failures as exc:
            log.info("repair round %d failed: %s", done, exc)
            return replace(state, done=done, ended=True)
        log.info("repair round %d: %s (best so far %d over air)", done, last,
                 state.best.over_air)
        hints = _hinted(state.hints, last)
        if last.rank() >= state.best.rank() and done > 1:
            # hints that bring nothing: more of them would not either
            return replace(state, done=done, hints=hints, ended=True)
        best = last if last.rank() < state.best.rank() else state.best
        state = Leaning(best, done, hints)
    return state


def started(first: Try[R], done: int = 0) -> Leaning[R]:
    """The leaning tries of a decomposition whose first try is ``first`` (an upright try, or
    with ``done`` = 1 its first leaning try: the upright one failed)."""
    log.info("first try (%s): %s", "leaning" if done else "upright", first)
    return Leaning(first, done, _hinted(NO_HINTS, first) if done else NO_HINTS)


def _hinted(hints: LeanHints, last: Try[R]) -> LeanHints | None:
    """``hints`` and the unsupported walls of the leaning try ``last``; None when it names
    none (a hinted round would repeat it)."""
    return hints.more(last.misses()) if last.misses().size else None


def thinned(best: Try[R], again: Callable[[Try[R], bool], Try[R]] | None,
            failures: tuple[type[Exception], ...]) -> Try[R]:
    """``best``, or the same plan made with thinner layers when that ranks better
    (:meth:`Try.rank`), while it is not support-free, in two steps
    (:mod:`slicer.paths.thin_layers`):

    1. ``again(best, False)``: thinner where the surface overhangs a little past what the
       layer height holds, tried when ``best``'s unsupported walls lie on such a surface
       (``best.thinner``: a ring at 50–60°, not a bore's arch);
    2. ``again(kept, True)``: thinner, besides, through the points where the walls of the
       try kept so far are over air (:meth:`Try.spots`), whatever the slope there.
    """
    if again is None:
        return best
    if not best.support_free and best.thinner is not None:
        best = _better(best, again, False, failures)
    if not best.support_free and best.misses().size:
        best = _better(best, again, True, failures)
    return best


def _better(best: Try[R], again: Callable[[Try[R], bool], Try[R]], spots: bool,
            failures: tuple[type[Exception], ...]) -> Try[R]:
    """``again(best, spots)`` when it ranks better than ``best``, else ``best``."""
    what = "at the unsupported walls" if spots else "on the steep surface"
    try:
        other = again(best, spots)
    except failures as exc:
        log.info("thinner layers %s failed: %s", what, exc)
        return best
    log.info("thinner layers %s: %s (%d over air before)", what, other, best.over_air)
    return other if other.rank() < best.rank() else best


@dataclass
class Begun(Generic[R]):
    """A decomposition's tries up to its first lean: the best of them, and the rest of its
    tries (more leaning rounds, thinner layers) as a callable returning its best try in the
    end (None: none left)."""

    best: Try[R]
    rest: Callable[[], Try[R]] | None = None


def best_decomposition(decomposed: Callable[[int, int], Begun[R]], alternatives: int,
                       rounds: int, failures: tuple[type[Exception], ...],
                       timings: dict[str, float]) -> Try[R]:
    """``decomposed(k, rounds)`` begins the ``k``-th decomposition (0: the one asked for),
    allowed at most ``rounds`` leaning tries, and raises one of ``failures`` when it plans no
    file.

    The best try (:meth:`Try.rank`, then the earlier decomposition) of the first
    decomposition and, while none is support-free, of the next ``alternatives`` (each with
    :data:`ALTERNATIVE_ROUNDS` leaning tries at most). A decomposition is tried to its end
    (:attr:`Begun.rest`) at once when its first tries come within :data:`NEAR` wall layers
    over air of support-free, else only once every other has begun: a local repair seldom
    holds a part that far off, another decomposition often does. The first decomposition's
    failure is raised when none plans a file; ``timings`` gains ``alternatives`` (seconds)
    and ``alternatives_tried``, and when the try kept is not the first decomposition's,
    ``first_decomposition``: the seconds its tries took, which the kept try's own stages do
    not count."""
    search = _Search(decomposed, failures, timings)
    for k in range(alternatives + 1):
        if search.support_free():
            break
        search.begin(k, rounds if k == 0 else min(rounds, ALTERNATIVE_ROUNDS))
    for k, rest in search.later:
        if search.support_free():
            break
        search.finish(k, rest)
    return search.kept()


@dataclass
class _Search(Generic[R]):
    """:func:`best_decomposition`'s decompositions: the best try so far (of tries ranked
    alike, the earlier decomposition's), those left for later, the seconds each took. Only
    the best try is kept, and a decomposition left for later its own best (its rest needs
    it): a try holds its plan and G-code."""

    decomposed: Callable[[int, int], Begun[R]]
    failures: tuple[type[Exception], ...]
    timings: dict[str, float]
    best: tuple[int, Try[R]] | None = None
    later: list[tuple[int, Callable[[], Try[R]]]] = field(default_factory=list)
    seconds: dict[int, float] = field(default_factory=dict)
    first_error: Exception | None = None

    def support_free(self) -> bool:
        return self.best is not None and self.best[1].support_free

    def begin(self, k: int, rounds: int) -> None:
        """The ``k``-th decomposition's first tries, and its rest now or later."""
        with self._timed(k):
            try:
                begun = self.decomposed(k, rounds)
            except self.failures as exc:
                if k == 0:
                    self.first_error = exc
                log.info("decomposition %d failed: %s", k, exc)
                return
        if begun.rest is None or begun.best.support_free:
            self._ended(k, begun.best)
        elif begun.best.over_air <= NEAR:
            self.finish(k, begun.rest)
        else:
            log.info("decomposition %d left for later: %s", k, begun.best)
            self._keep(k, begun.best)
            self.later.append((k, begun.rest))

    def finish(self, k: int, rest: Callable[[], Try[R]]) -> None:
        """The rest of the ``k``-th decomposition's tries."""
        with self._timed(k):
            end = rest()
        self._ended(k, end)

    def kept(self) -> Try[R]:
        """The best try of all (raises the first decomposition's failure: none planned)."""
        others = [s for k, s in self.seconds.items() if k]
        if others:
            self.timings["alternatives"] = sum(others)
            self.timings["alternatives_tried"] = float(len(others))
        if self.best is None:
            assert self.first_error is not None
            raise self.first_error
        k, best = self.best
        if k:
            self.timings["first_decomposition"] = self.seconds.get(0, 0.0)
        return best

    def _ended(self, k: int, end: Try[R]) -> None:
        log.info("decomposition %d: %s", k, end)
        self._keep(k, end)

    def _keep(self, k: int, got: Try[R]) -> None:
        """``got`` of the ``k``-th decomposition, when it ranks before the best so far."""
        if self.best is None or (got.rank(), k) < (self.best[1].rank(), self.best[0]):
            self.best = (k, got)

    @contextlib.contextmanager
    def _timed(self, k: int) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[k] = self.seconds.get(k, 0.0) + time.perf_counter() - t0
