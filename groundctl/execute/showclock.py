"""The show clock: show time as a warped function of our time, held by braking along the plan.

Every drone flies its plan as a function of one shared show time ``s``.  Any
common warp ``s(t)`` of that time, slowed, stopped, even stepped back, keeps
the fleet in configurations the plan itself passes through, and the plan is
collision-free at every instant.  So holding the show (the operator's hold, a
ground station that fell behind, a fleet that went silent, a safety response)
never freezes the setpoints at one point: the clock's *rate* ramps from 1 to 0,
each drone decelerates along its own trajectory (velocity feed-forward
``rate * p'(s)``, acceleration ``rate**2 * p''(s) + rate' * p'(s)``) and stops on
it, and resuming ramps the rate back up.  The ramp is long enough that braking
along the path needs no more than ``brake_accel`` on top of the plan's own
acceleration.

Pure: our time is always an argument.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Shortest ramp between full speed and a stop, s.
MIN_RAMP_S = 0.5


@dataclass(frozen=True)
class ClockSample:
    """The show clock at one instant of our time."""

    show_time: float
    """Show time, s (not capped at the plan's duration: callers clamp)."""
    rate: float
    """Show seconds per second of our time, 0 (held) .. 1 (running)."""
    rate_change: float
    """Derivative of the rate, 1/s (non-zero only while ramping)."""

    @property
    def moving(self) -> bool:
        return self.rate > 0.0


@dataclass(frozen=True)
class _Segment:
    # From our time ``t`` at show time ``s`` and rate ``r``, the rate ramps towards
    # ``target`` by ``slope`` per second (sign included), then stays there.
    t: float
    s: float
    r: float
    target: float
    slope: float

    @property
    def ramp_end(self) -> float:
        if self.slope == 0.0:
            return self.t
        return self.t + (self.target - self.r) / self.slope

    def at(self, now: float) -> ClockSample:
        dt = max(now - self.t, 0.0)
        ramp = self.ramp_end - self.t
        if dt <= ramp:
            return ClockSample(self.s + self.r * dt + 0.5 * self.slope * dt * dt,
                               self.r + self.slope * dt, self.slope)
        s = self.s + self.r * ramp + 0.5 * self.slope * ramp * ramp
        return ClockSample(s + self.target * (dt - ramp), self.target, 0.0)

    def at_many(self, now: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        dt = np.maximum(now - self.t, 0.0)
        ramp = self.ramp_end - self.t
        within = dt <= ramp
        d = np.minimum(dt, ramp)
        s = self.s + self.r * d + 0.5 * self.slope * d * d + self.target * (dt - d)
        rate = np.where(within, self.r + self.slope * d, self.target)
        return s, rate, np.where(within, self.slope, 0.0)


class ShowClock:
    """Show time that runs, brakes, holds and resumes; see the module docstring.

    Holds have reasons (``"operator"``, ``"overload"``, ``"silence"``,
    ``"safety"``...): the clock runs only when none is left.  History is kept,
    so :meth:`at` answers for past instants too (LED timing, reports).
    """

    def __init__(self, ramp_s: float = 2.0) -> None:
        if not ramp_s >= MIN_RAMP_S:
            raise ValueError(f"`ramp_s` must be at least {MIN_RAMP_S}, got {ramp_s}")
        self.default_ramp_s = ramp_s
        self._segments: list[_Segment] = []
        self._times: list[float] = []
        self._revision = 0
        self.holds: set[str] = set()
        """Why the clock is held (empty: it runs, or ramps up to running)."""

    # -- reading ---------------------------------------------------------------------
    @property
    def started(self) -> bool:
        return bool(self._segments)

    @property
    def started_at(self) -> float | None:
        """Our time of show time 0, None before :meth:`start`."""
        return self._segments[0].t if self._segments else None

    def at(self, now: float) -> ClockSample:
        """The clock at our time ``now`` (show time 0 and rate 0 before the start)."""
        if not self._segments:
            return ClockSample(0.0, 0.0, 0.0)
        k = bisect.bisect_right(self._times, now) - 1
        return self._segments[max(k, 0)].at(now)

    def at_many(self, now: ArrayLike
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(show time, rate, rate change) at each of the instants ``now``: :meth:`at`
        over an array (one lead per vehicle)."""
        t = np.asarray(now, dtype=float)
        out = (np.zeros_like(t), np.zeros_like(t), np.zeros_like(t))
        if not self._segments:
            return out
        ks = np.maximum(np.searchsorted(self._times, t, side="right") - 1, 0)
        for k in np.unique(ks):  # the few segments a lead's span reaches
            sel = ks == k
            for dst, src in zip(out, self._segments[int(k)].at_many(t[sel]), strict=True):
                dst[sel] = src
        return out

    def show_time(self, now: float) -> float:
        return self.at(now).show_time

    @property
    def revision(self) -> int:
        """How many times the clock's course was set (start, hold, release, put back):
        a change says that what was predicted on it no longer holds."""
        return self._revision

    @property
    def held(self) -> bool:
        """True when some hold is in force (the clock is stopped or braking)."""
        return bool(self.holds)

    def stopped(self, now: float) -> bool:
        """True when held and the braking ramp is over."""
        return self.held and self.at(now).rate == 0.0

    def stop_time(self, now: float) -> float:
        """Show time at which the clock comes (came) to rest if held now."""
        seg = self._segments[-1] if self._segments else None
        if seg is None:
            return 0.0
        if not self.held:
            return self.at(now).show_time
        return seg.at(max(now, seg.ramp_end)).show_time

    def rest_at(self) -> float:
        """Our time at which the current ramp ends (the clock at rest if held)."""
        return self._segments[-1].ramp_end if self._segments else 0.0

    # -- driving ---------------------------------------------------------------------
    def start(self, now: float) -> None:
        """Show time 0 at our time ``now``, running at full rate."""
        if self._segments:
            raise ValueError("the show clock has already started")
        self._push(_Segment(now, 0.0, 1.0, 1.0, 0.0))

    def hold(self, now: float, reason: str, ramp_s: float | None = None) -> bool:
        """Brake to a stop over ``ramp_s`` (from full rate); returns True if newly held."""
        fresh = not self.holds
        self.holds.add(reason)
        if fresh and self._segments:
            self._ramp(self._not_before(now), 0.0, ramp_s)
        return fresh

    def stop_at(self, now: float, show_time: float, reason: str, rate: float = 0.0,
                ramp_s: float | None = None) -> None:
        """Hold from ``show_time`` at ``rate``, braking from there: after a stall of the
        ground station the clock is re-synchronised to where the fleet really is (found
        from telemetry), not where it would have been, and brakes from the speed the
        drones really have along their paths (0: they already stand)."""
        self.holds.add(reason)
        if self._segments:
            rate = min(max(rate, 0.0), 1.0)
            ramp = max(self.default_ramp_s if ramp_s is None else ramp_s, MIN_RAMP_S)
            self._push(_Segment(self._not_before(now), show_time, rate, 0.0,
                                -1.0 / ramp if rate > 0 else 0.0))

    def release(self, now: float, reason: str, ramp_s: float | None = None) -> bool:
        """Drop one hold; the clock ramps back up once none is left.  True if it resumes."""
        if reason not in self.holds:
            return False
        self.holds.discard(reason)
        if self.holds or not self._segments:
            return False
        self._ramp(self._not_before(now), 1.0, ramp_s)
        return True

    def _not_before(self, now: float) -> float:
        # A clock started for a later instant (a return that begins once the fleet has
        # braked) takes a hold from its start on.
        return max(now, self._times[-1]) if self._times else now

    def _ramp(self, now: float, target: float, ramp_s: float | None) -> None:
        here = self.at(now)
        ramp = max(self.default_ramp_s if ramp_s is None else ramp_s, MIN_RAMP_S)
        if math.isclose(here.rate, target):
            self._push(_Segment(now, here.show_time, target, target, 0.0))
            return
        slope = (1.0 if target > here.rate else -1.0) / ramp
        self._push(_Segment(now, here.show_time, here.rate, target, slope))

    def _push(self, seg: _Segment) -> None:
        if self._times and seg.t < self._times[-1]:
            raise ValueError("the show clock's time went backwards")
        self._revision += 1
        if self._times and seg.t == self._times[-1]:
            self._segments[-1] = seg
            return
        self._segments.append(seg)
        self._times.append(seg.t)


def brake_ramp(max_speed: float, brake_accel: float) -> float:
    """Ramp duration, s, so that braking a drone flying ``max_speed`` along its path
    needs at most ``brake_accel`` m/s^2 beyond the plan's own acceleration."""
    if not brake_accel > 0:
        raise ValueError(f"`brake_accel` must be positive, got {brake_accel}")
    return max(max_speed / brake_accel, MIN_RAMP_S)
