"""The closed loop's order of tries (slicer.repair), on tries made up for the purpose: which
are planned, which is kept, what is raised."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np
import pytest

from slicer.paths import NO_HINTS, LeanHints, SlicingError
from slicer.plan import PrintPlan
from slicer.repair import (
    ALTERNATIVE_ROUNDS,
    NEAR,
    REPAIR_ROUNDS,
    Begun,
    Refused,
    Try,
    best_decomposition,
    leaning,
    started,
    thinned,
)
from slicer.replay import ReplayReport, WallSamples

FAILURES = (SlicingError, Refused)


def _report(over_air: int, bad: int, walls: float, misses: int = 3) -> ReplayReport:
    rep = ReplayReport(
        moves=1, extruding_moves=1, deposited_mm=1.0, points=1, inside=1.0, coverage=1.0,
        shell_coverage=1.0, supported=1.0, bridged=0.0, wall_points=100, wall_supported=walls,
        unsupported_wall_layers=[f"sub-part 0 layer {i}" for i in range(bad)], collisions=0,
        collision_messages=[], wall_layers_over_air=over_air)
    rep.unsupported_walls = WallSamples.empty() if not misses else _samples(misses)
    return rep


def _samples(n: int) -> WallSamples:
    rng = np.random.default_rng(n)
    return WallSamples(rng.uniform(-10.0, 10.0, (n, 3)), np.zeros(n, np.int32),
                       np.arange(n, dtype=np.int32), n)


def _try(name: str, over_air: int, bad: int, walls: float) -> Try[str]:
    return Try(name, _report(over_air, bad, walls), PrintPlan.__new__(PrintPlan))


def repaired(first: Try[str], again: Script, failures: tuple[type[Exception], ...],
             rounds: int = REPAIR_ROUNDS) -> tuple[Try[str], int]:
    """The leaning tries from ``first``: the best and the rounds taken."""
    state = leaning(started(first), again, failures, rounds)
    return state.best, state.done


@dataclass
class Script:
    """Tries handed out in order (an exception is raised instead), and what was asked."""

    tries: list[Try[str] | Exception]
    asked: list[object] = field(default_factory=list)

    def __call__(self, *args: object) -> Try[str]:
        self.asked.append(args)
        got = self.tries.pop(0)
        if isinstance(got, Exception):
            raise got
        return got


def begun(script: Script) -> Callable[[int, int], Begun[str]]:
    """Decompositions whose tries are ``script``'s, each with none left after it."""
    return lambda k, rounds: Begun(script(k, rounds))


def test_a_support_free_first_try_is_kept_without_planning_again() -> None:
    again = Script([])
    best, done = repaired(_try("upright", 0, 0, 0.999), again, FAILURES)
    assert (best.result, done, again.asked) == ("upright", 0, [])


def test_a_try_short_of_support_free_is_repaired_and_the_better_try_kept() -> None:
    # no layer over air but one unsupported wall layer: not support-free, the loop goes on
    again = Script([_try("lean", 0, 0, 0.999)])
    best, done = repaired(_try("upright", 0, 1, 0.999), again, FAILURES)
    assert (best.result, done) == ("lean", 1)


def test_hints_come_from_the_last_leaning_try_and_a_try_no_better_ends_the_loop() -> None:
    again = Script([_try("lean", 2, 2, 0.99), _try("hinted", 3, 3, 0.98),
                    _try("never", 0, 0, 1.0)])
    best, done = repaired(_try("upright", 5, 5, 0.97), again, FAILURES, rounds=3)
    assert (best.result, done) == ("lean", 2)
    first_hints, second_hints = (args[0] for args in again.asked)
    assert first_hints is NO_HINTS  # the upright try's misses are not a lean's own
    assert isinstance(second_hints, LeanHints) and second_hints is not NO_HINTS


def test_the_first_lean_needs_no_misses_a_hinted_round_does() -> None:
    # the upright try holds too few walls with no wall layer over air: no samples of it
    upright = Try("upright", _report(0, 0, 0.997, misses=0), PrintPlan.__new__(PrintPlan))
    lean = Try("lean", _report(0, 0, 0.996, misses=0), PrintPlan.__new__(PrintPlan))
    again = Script([lean, _try("never", 0, 0, 1.0)])
    best, done = repaired(upright, again, FAILURES, rounds=3)
    assert (best.result, done, len(again.asked)) == ("upright", 1, 1)


def test_a_failing_round_ends_the_loop_keeping_the_best_so_far() -> None:
    again = Script([SlicingError("no plane clears printed part")])
    best, done = repaired(_try("upright", 1, 1, 0.99), again, FAILURES)
    assert (best.result, done) == ("upright", 1)


def test_other_decompositions_are_tried_only_while_none_is_support_free() -> None:
    decomposed = Script([_try("seed0", 1, 1, 0.99), _try("seed1", 0, 0, 0.999)])
    timings: dict[str, float] = {}
    best = best_decomposition(begun(decomposed), 2, 3, FAILURES, timings)
    assert best.result == "seed1"
    assert decomposed.asked == [(0, 3), (1, min(3, ALTERNATIVE_ROUNDS))]
    assert timings["alternatives_tried"] == 1.0


@dataclass
class Clock:
    """``time.perf_counter`` for the loop: each try takes the seconds given with it."""

    now: float = 100.0

    def __call__(self) -> float:
        return self.now


@dataclass
class TimedScript(Script):
    """A :class:`Script` whose tries take the seconds given with them on ``clock``."""

    clock: Clock = field(default_factory=Clock)
    seconds: list[float] = field(default_factory=list)

    def __call__(self, *args: object) -> Try[str]:
        self.clock.now += self.seconds[len(self.asked)]
        return super().__call__(*args)


def _timed_script(clock: Clock, tries: list[tuple[Try[str] | Exception, float]]
                  ) -> TimedScript:
    return TimedScript([t for t, _ in tries], clock=clock, seconds=[s for _, s in tries])


@pytest.mark.parametrize("first", [_try("seed0", 1, 1, 0.99),
                                   SlicingError("sub-part 2, layer 6: no plane clears it")])
def test_the_first_decompositions_seconds_are_named_when_another_is_kept(
        monkeypatch: pytest.MonkeyPatch, first: Try[str] | Exception) -> None:
    """The kept try's stages count its own decomposition's work only: the first one's tries,
    set aside, are named apart (they were time no stage listed)."""
    clock = Clock()
    monkeypatch.setattr("slicer.repair.time", SimpleNamespace(perf_counter=clock))
    decomposed = _timed_script(clock, [(first, 40.0), (_try("seed1", 0, 0, 0.999), 7.0)])
    timings: dict[str, float] = {}
    assert best_decomposition(begun(decomposed), 2, 3, FAILURES, timings).result == "seed1"
    assert timings["first_decomposition"] == pytest.approx(40.0)
    assert timings["alternatives"] == pytest.approx(7.0)
    clock2 = Clock()
    monkeypatch.setattr("slicer.repair.time", SimpleNamespace(perf_counter=clock2))
    kept = _timed_script(clock2, [(_try("seed0", 1, 1, 0.99), 40.0),
                                  (_try("seed1", 2, 2, 0.99), 7.0),
                                  (Refused("refused"), 3.0)])
    timings = {}
    assert best_decomposition(begun(kept), 2, 3, FAILURES, timings).result == "seed0"
    assert "first_decomposition" not in timings  # its stages are the kept try's own


def test_a_support_free_first_decomposition_tries_no_other() -> None:
    decomposed = Script([_try("seed0", 0, 0, 0.999)])
    timings: dict[str, float] = {}
    assert best_decomposition(begun(decomposed), 2, 3, FAILURES, timings).result == "seed0"
    assert len(decomposed.asked) == 1 and "alternatives_tried" not in timings


def test_no_better_alternative_keeps_the_first() -> None:
    decomposed = Script([_try("seed0", 1, 1, 0.99), _try("seed1", 2, 2, 0.99),
                         Refused("another decomposition refused")])
    assert best_decomposition(begun(decomposed), 2, 3, FAILURES, {}).result == "seed0"


def test_a_first_decomposition_that_plans_nothing_gives_way_to_one_that_does() -> None:
    decomposed = Script([SlicingError("sub-part 2, layer 6: no plane clears platform"),
                         _try("seed1", 1, 1, 0.99), _try("seed2", 0, 2, 0.99)])
    assert best_decomposition(begun(decomposed), 2, 3, FAILURES, {}).result == "seed2"


def test_when_none_plans_the_first_failure_is_raised() -> None:
    first = SlicingError("sub-part 2, layer 20: no plane clears printed part")
    decomposed = Script([first, Refused("decomposition refused"), SlicingError("other")])
    with pytest.raises(SlicingError) as caught:
        best_decomposition(begun(decomposed), 2, 3, FAILURES, {})
    assert caught.value is first


def test_a_failure_not_listed_stops_at_once() -> None:
    decomposed = Script([ValueError("a bug"), _try("seed1", 0, 0, 1.0)])
    with pytest.raises(ValueError, match="a bug"):
        best_decomposition(begun(decomposed), 2, 3, FAILURES, {})


RING = (0.13, 53.2)  # (layer height, overhang °) that holds the unsupported walls


def test_a_failing_try_on_a_surface_thinner_layers_hold_is_made_again_thinned() -> None:
    best = replace(_try("lean", 1, 1, 0.999), thinner=RING, hints=NO_HINTS)
    again = Script([_try("thin", 0, 0, 1.0)])
    assert thinned(best, again, FAILURES).result == "thin"
    # the try itself (its lean and hints are made again), thinned by slope; support-free,
    # so not at its spots as well
    assert again.asked == [(best, False)]


@pytest.mark.parametrize("outcome", ["worse", "fails"])
def test_a_thinned_try_no_better_or_failing_leaves_the_best(outcome: str) -> None:
    best = replace(_try("lean", 1, 1, 0.999), thinner=RING)
    other = _try("thin", 2, 2, 0.99) if outcome == "worse" else SlicingError("no plane")
    again = Script([other, _try("spots", 1, 2, 0.998)])
    assert thinned(best, again, FAILURES) is best
    assert again.asked == [(best, False), (best, True)]


def test_walls_over_air_on_a_surface_the_height_holds_are_thinned_where_they_are() -> None:
    """No ``thinner`` (the slope there is within what the layer height holds, or far past
    what any printable layer holds): the try is made again thinner at its spots only."""
    best = _try("lean", 1, 1, 0.999)
    again = Script([_try("spots", 0, 0, 1.0)])
    assert thinned(best, again, FAILURES).result == "spots"
    assert again.asked == [(best, True)]


def test_the_spots_come_from_the_slope_thinned_try_when_it_is_kept() -> None:
    best = replace(_try("lean", 2, 2, 0.99), thinner=RING)
    by_slope = _try("thin", 1, 1, 0.999)
    again = Script([by_slope, _try("spots", 0, 0, 1.0)])
    assert thinned(best, again, FAILURES).result == "spots"
    assert again.asked == [(best, False), (by_slope, True)]


def test_a_tries_spots_carry_its_unsupported_walls_and_their_sub_parts() -> None:
    rep = _report(1, 1, 0.99, misses=5)
    rep.unsupported_walls = replace(rep.unsupported_walls,
                                    subpart=np.array([0, 0, 2, 2, 3], np.int32))
    spots = Try("x", rep, PrintPlan.__new__(PrintPlan)).spots()
    assert np.array_equal(spots.points, rep.unsupported_walls.p)
    assert np.array_equal(spots.of(2), rep.unsupported_walls.p[2:4])
    assert len(spots.of(1)) == 0


@pytest.mark.parametrize("case", ["support-free", "no misses", "no loop"])
def test_no_thinned_try_where_it_cannot_help(case: str) -> None:
    """A support-free try, a try whose report names no unsupported wall sample, or a slice
    without the loop."""
    best = _try("lean", 0, 0, 1.0) if case == "support-free" else _try("lean", 1, 1, 0.99)
    if case == "no misses":
        best = replace(best, report=_report(1, 1, 0.99, misses=0))
    again = Script([])
    assert thinned(best, None if case == "no loop" else again, FAILURES) is best
    assert again.asked == []


def test_stopped_leaning_tries_go_on_as_if_they_had_not_stopped() -> None:
    """The loop leaves a decomposition after its first lean and may come back to it: the
    rounds then are those it would have made at once, with the same hints."""
    def tries() -> list[Try[str] | Exception]:
        return [_try("lean", 4, 4, 0.99), _try("hinted", 3, 3, 0.99),
                _try("hinted2", 2, 2, 0.99)]

    at_once = Script(tries())
    whole = leaning(started(_try("upright", 5, 5, 0.98)), at_once, FAILURES, 3)
    again = Script(tries())
    state = leaning(started(_try("upright", 5, 5, 0.98)), again, FAILURES, 1)
    assert (state.best.result, state.done, len(again.asked)) == ("lean", 1, 1)
    resumed = leaning(state, again, FAILURES, 3)
    assert (resumed.best.result, resumed.done) == (whole.best.result, whole.done) == (
        "hinted2", 3)
    for (a,), (b,) in zip(at_once.asked, again.asked, strict=True):
        assert len(a.rounds) == len(b.rounds)
        assert all(np.array_equal(p, q) for p, q in zip(a.rounds, b.rounds, strict=True))


def test_a_leaning_try_after_a_failed_upright_one_hints_the_next_round() -> None:
    """``started(first, 1)``: ``first`` is the first lean; its misses hint round two."""
    first = _try("lean", 3, 3, 0.99)
    again = Script([_try("hinted", 0, 0, 1.0)])
    state = leaning(started(first, 1), again, FAILURES, 3)
    assert (state.best.result, state.done) == ("hinted", 2)
    (hints,), = again.asked
    assert len(hints.rounds) == 1 and np.array_equal(hints.rounds[0], first.misses())


@dataclass
class Decompositions:
    """Scripted decompositions: each ``(first tries' best, its best in the end)`` (None in
    the end: nothing left to try; an exception: it fails), and the order of the calls."""

    script: list[tuple[Try[str], Try[str] | None] | Exception]
    calls: list[str] = field(default_factory=list)

    def __call__(self, k: int, rounds: int) -> Begun[str]:
        self.calls.append(f"begin {k}")
        got = self.script[k]
        if isinstance(got, Exception):
            raise got
        first, end = got
        if end is None:
            return Begun(first)

        def rest() -> Try[str]:
            self.calls.append(f"rest {k}")
            return end

        return Begun(first, rest)


FAR = NEAR + 1  # wall layers over air after a first lean: left for later


def test_a_decomposition_far_from_support_free_is_finished_after_the_others_begin() -> None:
    steps = Decompositions([(_try("d0", FAR, FAR, 0.98), _try("d0 end", 3, 3, 0.99)),
                            (_try("d1", FAR + 2, 9, 0.97), _try("d1 end", 5, 5, 0.98)),
                            (_try("d2", NEAR, 3, 0.99), _try("d2 end", 1, 1, 0.995))])
    timings: dict[str, float] = {}
    best = best_decomposition(steps, 2, 3, FAILURES, timings)
    assert steps.calls == ["begin 0", "begin 1", "begin 2", "rest 2", "rest 0", "rest 1"]
    assert best.result == "d2 end" and timings["alternatives_tried"] == 2.0
    assert "first_decomposition" in timings


def test_a_support_free_alternative_spares_the_far_decompositions_rest() -> None:
    steps = Decompositions([(_try("d0", FAR, FAR, 0.98), _try("never", 0, 0, 1.0)),
                            (_try("d1", 0, 0, 0.999), None)])
    assert best_decomposition(steps, 3, 3, FAILURES, {}).result == "d1"
    assert steps.calls == ["begin 0", "begin 1"]


def test_a_decomposition_near_support_free_is_finished_before_the_next_begins() -> None:
    steps = Decompositions([(_try("d0", NEAR, NEAR, 0.99), _try("d0 end", 0, 0, 0.999)),
                            (_try("never", 0, 0, 1.0), None)])
    assert best_decomposition(steps, 2, 3, FAILURES, {}).result == "d0 end"
    assert steps.calls == ["begin 0", "rest 0"]


def test_of_tries_ranked_alike_the_earlier_decompositions_is_kept_whenever_it_ended() -> None:
    """A far decomposition finished last keeps its place: the one asked for wins a tie."""
    steps = Decompositions([(_try("d0", FAR, FAR, 0.98), _try("d0 end", 1, 1, 0.99)),
                            (_try("d1", 1, 1, 0.99), _try("d1 end", 1, 1, 0.99)),
                            Refused("the same sub-parts as a decomposition tried")])
    timings: dict[str, float] = {}
    assert best_decomposition(steps, 2, 3, FAILURES, timings).result == "d0 end"
    assert steps.calls == ["begin 0", "begin 1", "rest 1", "begin 2", "rest 0"]
    assert "first_decomposition" not in timings and timings["alternatives_tried"] == 2.0
