"""Vehicles off their plans and vehicles given up: a vehicle given up as disarmed whose
own telemetry says it flies after all (back in the show, stranded, or down where it is),
the fleet landed when too many are stranded at once, and where a vehicle given up goes
(by hand while landing, nowhere on the ground, straight down in the air)."""

from __future__ import annotations

import enum
from collections.abc import Callable

from groundctl.execute.sequence.types import AIRBORNE_M, STRANDED_LAND_ALL, VehiclePhase


class ArmedAgain(enum.Enum):
    """What a vehicle given up as disarmed in the air is, by its own telemetry."""

    NOT_FLYING = "not_flying"
    """Disarmed, silent, on the ground or out of our flight mode: the give-up stands."""
    LAND_HERE = "land_here"
    """Flying, with no show to rejoin (before it, after it, or its position unknown):
    down where it is."""
    BACK = "back"
    """Flying on its plan mid-show: back in the show."""
    STRANDED = "stranded"
    """Flying off its plan mid-show: it holds there and leaves on a way out."""


def armed_again(*, armed: bool, lost: bool, altitude_m: float | None, in_flight_mode: bool,
                in_show: bool, off_plan: Callable[[], bool]) -> ArmedAgain:
    """Judge a vehicle given up as disarmed in the air from its own telemetry (``armed``,
    ``lost``, ``altitude_m``, ``in_flight_mode``: in the mode our setpoints fly it in);
    ``in_show``: the show runs and its position is known; ``off_plan()``: it is farther
    than the rejoin tolerance from its plan (asked only of a vehicle flying in the show:
    it evaluates the plan, and a fallen vehicle is judged every update)."""
    if not armed or lost or altitude_m is None or altitude_m <= AIRBORNE_M \
            or not in_flight_mode:
        return ArmedAgain.NOT_FLYING
    if not in_show:
        return ArmedAgain.LAND_HERE
    return ArmedAgain.STRANDED if off_plan() else ArmedAgain.BACK


def too_many_stranded(count: int) -> bool:
    """Whether ``count`` vehicles holding off their plans at once land the whole fleet
    (:data:`STRANDED_LAND_ALL`): their ways out, planned one at a time through a show
    that flies on, would each take the others for drones on their plans."""
    return count >= STRANDED_LAND_ALL


class GivenUp(enum.Enum):
    """Where a vehicle given up goes, by the phase it was given up in."""

    BY_HAND = "by_hand"
    """Given up while landing: the operator lands it."""
    ON_THE_GROUND = "on_the_ground"
    """Given up before takeoff: it stays on its slot (an obstacle for its neighbours)."""
    LAND_HERE = "land_here"
    """In the air, or may be: straight down where it is."""
    LAND_ON_SLOT = "land_on_slot"
    """Given up climbing from its slot: straight down, onto its own takeoff spot, which
    may be where another drone lands (the same obstacle as one that never took off)."""


def given_up(was: VehiclePhase) -> GivenUp:
    """Where a vehicle given up in phase ``was`` goes."""
    if was is VehiclePhase.LANDING:
        return GivenUp.BY_HAND
    if was is VehiclePhase.ARMING:
        return GivenUp.ON_THE_GROUND
    if was is VehiclePhase.TAKEOFF:
        return GivenUp.LAND_ON_SLOT
    return GivenUp.LAND_HERE
