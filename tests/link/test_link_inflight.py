"""The in-flight bookkeeping against a plain list model, with and without rewinds."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from hostd.link.inflight import InFlight, Item, Sent

# an operation: ("add", line number) — numbers may go back, as after a rewind — or
# ("drop", line number) or ("uncount", n): n odd keeps the latest transmission's credit
_OPS = st.lists(st.tuples(st.sampled_from(["add", "add", "add", "drop", "uncount"]),
                          st.integers(0, 12)), max_size=60)


def _sent(number: int, size: int) -> Sent:
    return Sent(Item(f"G1 X{number}", number, "line", number), number, 0, 0.0, size)


class _Model:
    """The obvious implementation: scan everything every time."""

    def __init__(self) -> None:
        self.entries: list[Sent] = []

    def drop_through(self, number: int) -> Sent | None:
        latest = None
        for s in self.entries:
            if s.number == number:
                latest = s
        self.entries = [s for s in self.entries if s.number > number]
        return latest


@settings(max_examples=300, deadline=None)
@given(_OPS)
def test_drop_through_matches_a_full_scan(ops: list[tuple[str, int]]) -> None:
    flight, model = InFlight(), _Model()
    for k, (op, number) in enumerate(ops):
        if op == "add":
            sent = _sent(number, 10 + k)
            flight.add(sent)
            model.entries.append(sent)
        elif op == "drop":
            want = model.drop_through(number)
            assert flight.drop_through(number) is want
        else:  # an odd number keeps the latest transmission's credit (a line in parts)
            keep = model.entries[-1] if number % 2 and model.entries else None
            kept = keep is not None and keep.counted
            flight.uncount(keep=keep)
            assert [s for s in model.entries if s.counted] == ([keep] if kept else [])
        live = [s for s in model.entries if s.counted]
        assert flight.lines == len(live)
        assert flight.bytes == sum(s.written for s in live)
        assert bool(flight) == bool(model.entries)
        # the oldest transmission at or after each number is the model's
        for n in range(14):
            first = next((s for s in model.entries if s.number >= n), None)
            assert flight.first_from(n) is first


def test_after_a_rewind_the_old_and_new_copies_of_a_line_both_go() -> None:
    flight = InFlight()
    old = [_sent(n, 10) for n in (5, 6, 7)]
    new = [_sent(n, 10) for n in (5, 6, 7)]
    for s in old + new:
        flight.add(s)
    assert flight.drop_through(5) is new[0]
    assert flight.lines == 4 and flight.bytes == 40
    assert flight.first_from(0) is old[1]
    assert flight.drop_through(7) is new[2]
    assert not flight and flight.lines == 0 and flight.bytes == 0
