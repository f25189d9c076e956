"""The show's wind limit in the air: hold while the fleet's wind is above it, land when it
stays there.  Pure: the guard feeds it the vehicles' own estimates each tick.

Each vehicle's autopilot estimates the wind it flies in (ArduPilot's WIND, PX4's
WIND_COV; :mod:`groundctl.link.state`).  The *fleet's wind* is the estimate that a
quarter of the reporting vehicles reach (the highest of one or two, the third highest
of nine): a drone high up in a stronger layer counts, one estimator gone astray alone
does not.  Above ``limit`` for ``over_for_s`` the show holds (before its start, at once:
it does not start), every drone braking along its path; once the wind has been at most
``clear_fraction`` of the limit for ``clear_for_s`` the hold is released; a hold that has
not cleared after ``land_after_s`` lands the fleet.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum


@dataclass(frozen=True)
class WindConfig:
    """Timing of the wind hold; times are seconds of the flight's clock."""

    over_for_s: float = 2.0
    """The fleet's wind above the limit this long holds the show (before its start, any
    moment above holds it: waiting costs nothing then)."""
    clear_fraction: float = 0.9
    """The hold clears once the wind is at most this fraction of the limit ..."""
    clear_for_s: float = 10.0
    """... for this long."""
    land_after_s: float = 30.0
    """A wind hold not cleared after this long lands the fleet."""


class WindVerdict(Enum):
    """What the watch says this tick."""

    NONE = "none"
    HOLD = "hold"
    RELEASE = "release"
    LAND = "land"


def fleet_wind(speeds: Iterable[float]) -> float | None:
    """The wind a quarter of the reporting vehicles reach, m/s; None without any."""
    ordered = sorted(speeds, reverse=True)
    if not ordered:
        return None
    return ordered[max(math.ceil(len(ordered) / 4), 1) - 1]


class WindWatch:
    """See the module docstring."""

    def __init__(self, limit: float | None, config: WindConfig | None = None) -> None:
        self.limit = limit
        """The show's ``limits.max_wind`` (None: not watched)."""
        self.config = config or WindConfig()
        self.held_since: float | None = None
        """Our time the wind hold started (None: not held for the wind)."""
        self.strongest: float = 0.0
        """The strongest fleet wind seen in the air, m/s (for the report)."""
        self.wind: float | None = None
        """The fleet's wind at the last tick, m/s."""
        self.holds = 0
        """Wind holds so far."""
        self.hold_peak = 0.0
        """The strongest fleet wind during the current (or last) hold, m/s."""
        self.landed = False
        """The wind landed the fleet."""
        self.stopped = False
        """No longer watched (the fleet is landing, for whatever reason)."""
        self._over_since: float | None = None
        self._clear_since: float | None = None

    def tick(self, now: float, speeds: Iterable[float], airborne: bool,
             started: bool = True) -> WindVerdict:
        """One tick: ``speeds`` the fresh estimates of the vehicles in the air; ``airborne``:
        drones are in the air for the show (not landing after it); ``started``: the show
        clock has started."""
        self.wind = fleet_wind(speeds)
        if self.wind is not None:
            self.strongest = max(self.strongest, self.wind)
        if self.limit is None or self.stopped:
            return WindVerdict.NONE
        cfg = self.config
        wind = self.wind
        over = airborne and wind is not None and wind > self.limit
        self._over_since = (self._over_since if self._over_since is not None else now) \
            if over else None
        clear = wind is None or wind <= self.limit * cfg.clear_fraction
        self._clear_since = (self._clear_since if self._clear_since is not None else now) \
            if clear else None
        if self.held_since is None:
            wait = cfg.over_for_s if started else 0.0
            if self._over_since is not None and now - self._over_since >= wait:
                self.held_since = now
                self.holds += 1
                self.hold_peak = wind if wind is not None else 0.0
                return WindVerdict.HOLD
            return WindVerdict.NONE
        if wind is not None:
            self.hold_peak = max(self.hold_peak, wind)
        if not airborne or (self._clear_since is not None
                            and now - self._clear_since >= cfg.clear_for_s):
            self.held_since = None
            return WindVerdict.RELEASE
        if now - self.held_since >= cfg.land_after_s:
            self.landed = self.stopped = True
            self.held_since = None
            return WindVerdict.LAND
        return WindVerdict.NONE
