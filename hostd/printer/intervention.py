"""What an operator's raw G-code during a pause asks of the resume.

A paused job takes any raw command (jog, purge, heat, home...). The pause recorded the job's
modal state, and the resume must bring the machine back to it whatever was done meanwhile:

- ``NONE``: queries, messages, fan and modes (the resume restores fan, G90/G91, M82/M83, E);
  moves of E or F alone (a purge: the resume sets E back with ``G92``);
- ``HEAT``: a heater's target changed: the resume sets the job's targets back and waits;
- ``RETURN``: the head or platform may have moved (a move of X/Y/Z/A/C, or a command this
  module does not know, such as ``M600``): the resume reheats, lifts to the safe Z, turns the
  platform back, approaches the paused point from above and lowers onto it;
- ``RESTART``: the machine's position is no longer known or no longer means the same (``G28``,
  probing, motors off, ``G92`` of an axis, settings reloaded): the resume re-homes first, then
  goes on as ``RETURN``.

Levels only grow during one pause; the resume acts on the highest.
"""

from __future__ import annotations

from collections.abc import Iterable
from enum import IntEnum


class Need(IntEnum):
    """What the resume must do, in increasing order."""

    NONE = 0
    HEAT = 1
    RETURN = 2
    RESTART = 3


HARMLESS = frozenset({
    "M105", "M114", "M115", "M117", "M118", "M119", "M155", "M220", "M221", "M400", "M503",
    "M106", "M107", "G90", "G91", "M82", "M83", "G4", "M300", "M31", "M27", "M73",
})
"""Commands that leave nothing for the resume to restore beyond its modes."""
HEATING = frozenset({"M104", "M109", "M140", "M190", "M141", "M191", "M303"})
LOSES_POSITION = frozenset({"G28", "G29", "G30", "G38.2", "G38.3", "M84", "M18", "M17",
                            "M501", "M502", "M999", "G92.1"})
MOVES = frozenset({"G0", "G1"})  # an arc (G2/G3) moves even without an axis word
AXES = frozenset("XYZAC")


def need_of(command: str) -> Need:
    """What one comment-free command asks of the resume (``g28`` as ``G28``: the link sends
    parameter letters upper-cased)."""
    words = command.upper().split()
    if not words:
        return Need.NONE
    code = words[0]
    if code in HARMLESS:
        return Need.NONE
    if code in HEATING:
        return Need.HEAT
    if code in LOSES_POSITION:
        return Need.RESTART
    axes = {w[0] for w in words[1:]} & AXES
    if code == "G92":
        return Need.RESTART if axes or len(words) == 1 else Need.NONE
    if code in MOVES:
        return Need.RETURN if axes else Need.NONE
    return Need.RETURN


def need_of_all(commands: Iterable[str]) -> Need:
    """The highest need of ``commands`` (``NONE`` for none)."""
    return max((need_of(c) for c in commands), default=Need.NONE)
