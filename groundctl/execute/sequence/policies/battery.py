"""A low battery: whether it calls for anything, and what -- the vehicle leaves the show
on a way out, lands where it is (critical, nobody below it), or, when batteries run low
across the fleet, everyone lands on one planned return."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from groundctl.execute.sequence.types import LOW_BATTERY_FLEET, VehiclePhase


class BatteryMove(enum.Enum):
    """What a low battery asks for."""

    NOTHING = "nothing"
    """Already leaving or returning: that is the fastest safe way down."""
    LEAVE = "leave"
    """Below the show's threshold mid-show: it leaves on a way out (land-one)."""
    LAND_HERE = "land_here"
    """Below half the threshold with nobody below it: straight down where it is."""
    LAND_ALL = "land_all"
    """Low across the fleet (:data:`LOW_BATTERY_FLEET`, at least two): one return for all."""


@dataclass(frozen=True)
class BatteryView:
    """What the battery policy looks at for one vehicle."""

    pct: float
    """Its battery, % remaining."""
    minimum: float
    """The show's threshold, %."""
    phase: VehiclePhase
    low: bool
    """Already counted low (told to land for it)."""
    critical: bool
    """Already landed where it is for it."""

    @property
    def below_half(self) -> bool:
        """Below half the threshold: critical, wherever it is."""
        return self.pct < self.minimum / 2


def battery_due(view: BatteryView) -> bool:
    """Whether the battery calls for a decision now (only for a vehicle flying our
    setpoints): newly below half the threshold, or newly below it mid-show."""
    if view.below_half and not view.critical:
        return True
    return view.phase is VehiclePhase.SHOW and not view.low and view.pct < view.minimum


def battery_move(view: BatteryView, *, low_in_flight: int, fleet: int, show_over: bool,
                 column_clear: bool) -> BatteryMove:
    """The move a due low battery asks for.  ``low_in_flight``: vehicles flying our
    setpoints whose battery is low, this one included; ``column_clear``: nobody within
    the separation limit below it (only asked when it is critical)."""
    if not show_over and low_in_flight >= max(2, math.ceil(LOW_BATTERY_FLEET * fleet)):
        return BatteryMove.LAND_ALL
    if view.below_half and column_clear:
        return BatteryMove.LAND_HERE
    if view.phase is not VehiclePhase.SHOW:
        return BatteryMove.NOTHING
    return BatteryMove.LEAVE
