"""The closed loop: plan again where the replay finds walls that are not held.

:func:`slicer.pipeline.slice_model` hands this module callables that plan, write and check
one file (a :class:`Try`); here they are tried in turn and the best file is kept:

1. the paper's try (the root upright), then up to :data:`REPAIR_ROUNDS` tries with the root's
   layers leaning (:mod:`slicer.paths.upright`), each after the first hinted at the
   unsupported walls of the last (:func:`repaired`);
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

Beyond the paper, which decomposes once and never looks back. The tries are ranked by
:meth:`Try.rank`: fewest wall layers over air (what a file is refused for), then fewest
unsupported wall layers by the strict rule, then most walls held; the loop stops as soon as
a try is support-free by the strict rule (:attr:`ReplayReport.support_free`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
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


def repaired(first: Try[R], again: Callable[[LeanHints], Try[R]] | None,
             failures: tuple[type[Exception], ...], rounds: int = REPAIR_ROUNDS,
             done: int = 0) -> tuple[Try[R], int]:
    """While the best try so far is not support-free, plan again with the root's layers
    leaning (:mod:`slicer.paths.upright`) and hints at the unsupported walls of every
    leaning try (:class:`~slicer.paths.LeanHints`: it leans harder there; the first lean
    takes none, the upright try's misses are not its own), at most ``rounds`` tries in all
    (``done`` taken before: ``first`` is then a leaning try). A try that fails outright
    (one of ``failures``), or a hinted one no better than the best, ends the loop.

    Returns
    -------
    (Try, int)
        The best try (:meth:`Try.rank`) and the rounds taken.
    """
    best = last = first
    hints = NO_HINTS
    while (again is not None and done < rounds and not best.support_free
           and (done == 0 or last.misses().size)):  # a hinted round needs misses
        if done:
            hints = hints.more(last.misses())
        done += 1
        try:
            last = again(hints)
        except failures as exc:
            log.info("repair round %d failed: %s", done, exc)
            break
        log.info("repair round %d: %d wall layers over air (best so far %d)", done,
                 last.over_air, best.over_air)
        if last.rank() >= best.rank() and done > 1:
            break  # hints that bring nothing: more of them would not either
        if last.rank() < best.rank():
            best = last
    return best, done


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
    log.info("thinner layers %s: %d wall layers over air (%d before)", what, other.over_air,
             best.over_air)
    return other if other.rank() < best.rank() else best


def best_decomposition(decomposed: Callable[[int, int], Try[R]], alternatives: int,
                       rounds: int, failures: tuple[type[Exception], ...],
                       timings: dict[str, float]) -> Try[R]:
    """``decomposed(k, rounds)`` is the best try of the ``k``-th decomposition (0: the one
    asked for) with at most ``rounds`` leaning tries, and raises one of ``failures`` when it
    plans no file.

    The first decomposition's best try, or a better one of the next ``alternatives``
    (tried only while no try is support-free, each with :data:`ALTERNATIVE_ROUNDS` leaning
    tries at most). The first decomposition's failure is raised when none plans a file;
    ``timings`` gains ``alternatives`` (seconds) and ``alternatives_tried``, and when the
    try kept is not the first decomposition's, ``first_decomposition``: the seconds its
    tries took, which the kept try's own stages do not count."""
    best: Try[R] | None = None
    first_error: Exception | None = None
    start = time.perf_counter()
    try:
        best = decomposed(0, rounds)
    except failures as exc:
        first_error = exc
    first, first_seconds = best, time.perf_counter() - start
    t0, tried = time.perf_counter(), 0
    for k in range(1, alternatives + 1):
        if best is not None and best.support_free:
            break
        tried += 1
        try:
            other = decomposed(k, min(rounds, ALTERNATIVE_ROUNDS))
        except failures as exc:
            log.info("decomposition %d failed: %s", k, exc)
            continue
        log.info("decomposition %d: %d wall layers over air", k, other.over_air)
        if best is None or other.rank() < best.rank():
            best = other
    if tried:
        timings["alternatives"] = time.perf_counter() - t0
        timings["alternatives_tried"] = float(tried)
    if best is not first:
        timings["first_decomposition"] = first_seconds
    if best is None:
        assert first_error is not None
        raise first_error
    return best

