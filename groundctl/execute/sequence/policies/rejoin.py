"""A lost vehicle heard again: lost before the show it stands down; lost mid-show and
off its plan it is stranded (holds, then leaves on a way out); otherwise it is back in
the sequence, and one that was landing is judged by what it does now."""

from __future__ import annotations

import enum

from groundctl.execute.sequence.types import (
    _FLIGHT_MODE,
    _HOLD_MODE,
    _LAND_MODES,
    VehiclePhase,
)
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState


class Rejoin(enum.Enum):
    """What a vehicle heard again after being lost rejoins as."""

    STAND_DOWN = "stand_down"
    """Lost before the show, counted as standing on its slot: it does not join a show
    planned without it."""
    STRANDED = "stranded"
    """Lost mid-show and off its plan: snapping back would be a dash across the
    formation."""
    BACK = "back"
    """Back in the sequence where it was."""


def rejoin(lost_from: VehiclePhase, off_plan: bool) -> Rejoin:
    """How a vehicle lost during ``lost_from`` rejoins; ``off_plan``: mid-show, farther
    than the rejoin tolerance from its plan."""
    if lost_from in (VehiclePhase.ARMING, VehiclePhase.TAKEOFF):
        return Rejoin.STAND_DOWN
    if off_plan and lost_from is VehiclePhase.SHOW:
        return Rejoin.STRANDED
    return Rejoin.BACK


class Landing(enum.Enum):
    """What a vehicle heard again while landing is doing."""

    DOWN = "down"
    """Disarmed: the next update counts it landed."""
    DESCENDING = "descending"
    """In its land mode."""
    LAND_LOST = "land_lost"
    """Still in our flight mode (or PX4's Hold, where losing its setpoints put it): the
    LAND was lost in the silence, and is sent again."""
    NOT_OURS = "not_ours"
    """Any other mode: its failsafe or a pilot has it, and we do not fight them."""


def heard_landing(flavour: Flavour, state: VehicleState) -> Landing:
    """What the telemetry of a vehicle heard again while landing says it is doing."""
    if not state.armed:
        return Landing.DOWN
    if state.mode in _LAND_MODES:
        return Landing.DESCENDING
    if state.mode in (_FLIGHT_MODE[flavour], _HOLD_MODE[flavour]):
        return Landing.LAND_LOST
    return Landing.NOT_OURS
