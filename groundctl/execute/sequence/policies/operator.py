"""The operator's per-vehicle commands: what `land SYSID`, `land-here SYSID` and `kill
SYSID` do to the vehicle as it is (bad input and commands overtaken come back as a
notice, never an exception)."""

from __future__ import annotations

import enum
from collections.abc import Callable

from groundctl.execute.sequence.types import _DONE, VehiclePhase


class LandOne(enum.Enum):
    """What `land SYSID` does."""

    UNKNOWN = "unknown"
    """No such vehicle in this show."""
    IN_COLUMNS = "in_columns"
    """The fleet lands by the last resort, column by column: it lands with it
    (land-here brings it down now)."""
    ALREADY_LEAVING = "already_leaving"
    """Mid-show, its way out is already set."""
    NO_FORMATION_LEFT = "no_formation_left"
    """Mid-show, no formation left to leave from: it lands with the others."""
    LEAVE_AT_NEXT = "leave_at_next"
    """Mid-show: on to the next instant it rests on a formation, then out on a way out
    planned around the others (a straight line home would cut through the show)."""
    LAND_NOW = "land_now"
    """Not in the show (before it, after it, or returning): back to its landing slot and
    down now."""


def land_one_asked(*, known: bool, in_columns: bool, mid_show: bool, leaving: bool,
                   next_instant: Callable[[], float | None]) -> LandOne:
    """``mid_show``: the vehicle is streamed in the show and the show is not over;
    ``leaving``: its way out instant is set; ``next_instant()``: the next show time it
    could leave at (None: no formation left), asked only mid-show and not leaving."""
    if not known:
        return LandOne.UNKNOWN
    if in_columns:
        return LandOne.IN_COLUMNS
    if not mid_show:
        return LandOne.LAND_NOW
    if leaving:
        return LandOne.ALREADY_LEAVING
    return LandOne.NO_FORMATION_LEFT if next_instant() is None else LandOne.LEAVE_AT_NEXT


class LandHere(enum.Enum):
    """What `land-here SYSID` does."""

    UNKNOWN = "unknown"
    ALREADY = "already"
    """Down, given up, or landing already."""
    STAND_DOWN = "stand_down"
    """On the ground still (pre-flight, arming): stood down (disarmed if armed)."""
    DOWN_HERE = "down_here"
    """In the air: it stops following the plan at once and goes straight down where it
    is (the operator must know the column below it is clear)."""


def land_here_asked(phase: VehiclePhase | None) -> LandHere:
    """What `land-here` does to a vehicle in ``phase`` (None: no such vehicle)."""
    if phase is None:
        return LandHere.UNKNOWN
    if phase in _DONE or phase is VehiclePhase.LANDING:
        return LandHere.ALREADY
    if phase in (VehiclePhase.PREFLIGHT, VehiclePhase.ARMING):
        return LandHere.STAND_DOWN
    return LandHere.DOWN_HERE


class KillVerdict(enum.Enum):
    """What `kill SYSID` does."""

    UNKNOWN = "unknown"
    NEEDS_CONFIRM = "needs_confirm"
    """Not sent: the motors stop and the drone falls; the operator must confirm."""
    KILL = "kill"


def kill_asked(known: bool, confirm: bool) -> KillVerdict:
    """What `kill` does to a vehicle (``known``: in this show), confirmed or not."""
    if not known:
        return KillVerdict.UNKNOWN
    return KillVerdict.KILL if confirm else KillVerdict.NEEDS_CONFIRM
