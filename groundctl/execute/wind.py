"""The show's wind limit in the air: hold while the fleet's wind is above it, land when it
stays there.  Pure: the guard feeds it the vehicles' own estimates each tick.

Each vehicle's autopilot estimates the wind it flies in (ArduPilot's WIND, PX4's
WIND_COV; :mod:`groundctl.link.state`).  The *fleet's wind* is the estimate that a
quarter of the reporting vehicles reach (the highest of up to four, the third highest
of nine): a drone high up in a stronger layer counts; from five reporting on, one
estimator gone astray alone does not.  Above ``limit`` for ``over_for_s`` the show holds
(before its start, at once: it does not start), every drone braking along its path;
once the wind has been at most ``clear_fraction`` of the limit for ``clear_for_s`` the
hold is released (no estimate at all is no sign of calm: the hold stays); a hold that
has not cleared after ``land_after_s`` lands the fleet, and so does ``max_held_s`` held
for the wind in all (a wind gusting about the limit would otherwise hold and release
until the batteries ran down).
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
    max_held_s: float = 90.0
    """Held for the wind this long in all, over every wind hold, lands the fleet."""


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
        self.strongest: float | None = None
        """The strongest fleet wind seen in the air, m/s (for the report; None: no
        vehicle reported one)."""
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
        self.held_s = 0.0
        """Time held for the wind so far, over every hold, s."""
        self.released_why = ""
        """Why the last hold was released: ``clear`` or ``grounded``."""
        self._last_tick: float | None = None
        self._over_since: float | None = None
        self._clear_since: float | None = None

    def tick(self, now: float, speeds: Iterable[float], airborne: bool,
             started: bool = True) -> WindVerdict:
        """One tick: ``speeds`` the fresh estimates of the vehicles in the air; ``airborne``:
        drones are in the air for the show (not landing after it); ``started``: the show
        clock has started."""
        self.wind = fleet_wind(speeds)
        if self.wind is not None:
            self.strongest = max(self.strongest or 0.0, self.wind)
        if self.limit is None or self.stopped:
            return WindVerdict.NONE
        cfg = self.config
        wind = self.wind
        over = airborne and wind is not None and wind > self.limit
        self._over_since = (self._over_since if self._over_since is not None else now) \
            if over else None
        clear = wind is not None and wind <= self.limit * cfg.clear_fraction
        self._clear_since = (self._clear_since if self._clear_since is not None else now) \
            if clear else None
        if self.held_since is None:
            wait = cfg.over_for_s if started else 0.0
            if self._over_since is not None and now - self._over_since >= wait:
                self.held_since = self._last_tick = now
                self.holds += 1
                self.hold_peak = wind if wind is not None else 0.0
                return WindVerdict.HOLD
            return WindVerdict.NONE
        if wind is not None:
            self.hold_peak = max(self.hold_peak, wind)
        if self._last_tick is not None:
            self.held_s += now - self._last_tick
        self._last_tick = now
        if not airborne or (self._clear_since is not None
                            and now - self._clear_since >= cfg.clear_for_s):
            self.held_since = self._last_tick = None
            self.released_why = "clear" if airborne else "grounded"
            return WindVerdict.RELEASE
        if now - self.held_since >= cfg.land_after_s or self.held_s >= cfg.max_held_s:
            self.landed = self.stopped = True
            self.held_since = self._last_tick = None
            return WindVerdict.LAND
        return WindVerdict.NONE
