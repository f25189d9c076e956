"""Ways out of the show mid-flight: whether a way out handed over is taken, what follows
when one could not be planned before its instant (the next instant, a bounded number of
times), and where a vehicle without one goes (on with the show, or down where it holds)."""

from __future__ import annotations

import enum
from collections.abc import Callable

from groundctl.execute.sequence.types import VehiclePhase


class Offered(enum.Enum):
    """What is done with a way out the planner hands over."""

    OVERTAKEN = "overtaken"
    """The vehicle no longer awaits it (landed, lost, stranded meanwhile, a way out
    already taken, the show over), or it was planned for the other kind of start (its
    plan point, or where it holds off its plan): dropped."""
    TOO_LATE = "too_late"
    """Ready after its instant: the next instant is tried (:func:`late`)."""
    TAKE = "take"
    """Flown from its show time on, then the vehicle lands."""


def offered(*, awaits: bool, planned_held: bool, holds_off_plan: bool, show_time: float,
            starts_at: float) -> Offered:
    """The verdict on a way out starting at show time ``starts_at``, handed over at
    ``show_time``; ``awaits``: the vehicle still awaits one (a leave instant set, none
    taken, the show not over, streamed in the show or holding off its plan);
    ``planned_held``: planned from where the vehicle holds (not its plan point);
    ``holds_off_plan``: the vehicle holds off its plan."""
    if not awaits or planned_held != holds_off_plan:
        return Offered.OVERTAKEN
    if show_time > starts_at:
        return Offered.TOO_LATE
    return Offered.TAKE


class Late(enum.Enum):
    """What follows a way out not planned before its instant."""

    NEXT_INSTANT = "next_instant"
    """Leave at the next instant it can (the next formation it rests on, or a moment
    from now where it holds off its plan)."""
    TOO_MANY = "too_many"
    """Late too many times: no way out (:func:`without_way_out`)."""
    NO_INSTANT = "no_instant"
    """No instant left to leave from before the show ends: no way out."""


def late(times_late: int, max_late: int, next_instant: Callable[[], float | None]) -> Late:
    """After its way out was late ``times_late`` times (this one included);
    ``next_instant()``: the next show time it could leave at (None: none before the show
    ends), asked only while it may still try."""
    if times_late >= max_late:
        return Late.TOO_MANY
    return Late.NO_INSTANT if next_instant() is None else Late.NEXT_INSTANT


class WithoutWayOut(enum.Enum):
    """Where a vehicle that has no safe way out goes."""

    LAND_WHERE_IT_HOLDS = "land_where_it_holds"
    """Off its plan and holding (stranded): the show flying on is not known to be clear
    of it, and it has no path back into it: straight down where it is."""
    FLY_ON = "fly_on"
    """On its plan: it flies on with the show and lands with the others at the end
    (the plan keeps it apart), the operator told loudly."""


def without_way_out(phase: VehiclePhase, holds_off_plan: bool) -> WithoutWayOut:
    """Where a vehicle in ``phase`` goes without a way out."""
    if holds_off_plan and phase is VehiclePhase.LEAVING:
        return WithoutWayOut.LAND_WHERE_IT_HOLDS
    return WithoutWayOut.FLY_ON
