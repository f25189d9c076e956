"""The land-all return when none can be planned: the show itself flies on to its end (the
one way home known to be clear, every drone over its landing spot there), unless drones
off their plans hover in it; after the show, straight to the landing points."""

from __future__ import annotations

import enum


class NoReturn(enum.Enum):
    """How the fleet gets home without a planned return."""

    COLUMNS = "columns"
    """Interrupted mid-show with drones off their plans hovering where they were stopped:
    the show flying on is not known to be clear of them (and they would be stranded again
    at once: land-all, no return, the show again -- a livelock).  Every drone lands
    straight down, one column at a time."""
    SHOW_ON = "show_on"
    """Interrupted mid-show, every drone on its plan: the show flies on to its end
    (ramping up from the hold) and every drone lands from there."""
    STRAIGHT = "straight"
    """Not interrupted (the return after the show, or spots re-planned): each flies
    straight to its landing point, the operator told to watch the fleet."""


def no_return(interrupted: bool, off_plan_hovering: bool) -> NoReturn:
    """``interrupted``: the land-all stopped the show before its end; ``off_plan_hovering``:
    a drone that was leaving off its plan hovers where the fleet stopped."""
    if not interrupted:
        return NoReturn.STRAIGHT
    return NoReturn.COLUMNS if off_plan_hovering else NoReturn.SHOW_ON
