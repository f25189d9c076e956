"""The land-all return: the vehicles awaiting a return plan and where each starts
it from, the plan handed over and flown, and what is done when none can be planned."""

from __future__ import annotations

import numpy as np

from groundctl.execute.paths import position_on_show_clock
from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.policies.homing import NoReturn, no_return
from groundctl.execute.sequence.spots import PathsAndSpots
from groundctl.execute.sequence.types import (
    FLEET_HOLDS,
    Action,
    Disarm,
    Land,
    Notice,
    VehiclePhase,
    VehicleRun,
)
from groundctl.execute.showclock import ShowClock
from groundctl.plan.trajectory import Trajectories


class Returns(PathsAndSpots):
    """The land-all return (a layer of :class:`ShowSequence`)."""

    # -- land-all return ---------------------------------------------------------------
    @property
    def return_needed(self) -> list[tuple[int, int]] | None:
        """(system id, track) of the vehicles needing a return plan, if one is awaited.

        After :meth:`land_all` interrupts the show, straight lines home could
        cross; the driver plans a return (from the frozen plan points at
        :meth:`show_time`) and hands it over with :meth:`set_return`, or calls
        :meth:`return_failed`.
        """
        if not self._return_wanted or self._return is not None:
            return None
        return [(v.sysid, v.track) for v in self.vehicles.values()
                if self.streamed_as(v) is VehiclePhase.RETURNING and v.track >= 0]

    def return_start(self, sysid: int, now: float) -> np.ndarray:
        """Where vehicle ``sysid`` starts its return from (show frame): where its path is
        when the braking show clock stops (its plan, its way out, the point it holds)."""
        v = self.vehicles[sysid]
        path = self.path(sysid, now)
        if self._after_return or path is None or not path.on_show_clock:
            return np.asarray(self._landing_point(v), dtype=float)  # hovering over it
        t = min(self.clock.stop_time(now) if self.started_at is not None else 0.0,
                self.plan.duration)
        if self._stopped_at is not None:
            t = min(t, self._stopped_at)
        return position_on_show_clock(path, self.plan, t)

    def set_return(self, trajectories: Trajectories, sysids: list[int], now: float,
                   goals: np.ndarray | None = None) -> list[Action]:
        """Fly ``trajectories`` (row i for ``sysids[i]``) once the fleet has braked to a
        stop, then land; ``goals`` (n, 3) are the landing points it ends over when a
        return re-assigned them (blocked spots)."""
        if self._return is not None:
            return []
        self._return = (trajectories, {s: i for i, s in enumerate(sysids)})
        clock = ShowClock(self.clock.default_ramp_s)
        clock.start(max(now, self.clock.rest_at()) if self.started_at is not None else now)
        for reason in self.clock.holds & FLEET_HOLDS:  # the ground station's own trouble
            clock.hold(now, reason)
        self._return_clock = clock
        if goals is not None:
            for row, sysid in enumerate(sysids):
                v = self.vehicles[sysid]
                point = tuple(float(x) for x in goals[row])
                v.landing_point = None if np.allclose(point, self._slots[v.track]) \
                    else point  # type: ignore[assignment]
        for sysid in sysids:
            self.vehicles[sysid].returning_since = now
        return [Notice(None, f"flying the {trajectories.end:.1f} s return to the landing "
                             "points")]

    def return_failed(self, reason: str, now: float | None = None) -> list[Action]:
        """No return plan.  Interrupted mid-show, the show itself is the one way home known
        to be collision-free: it flies on to its end (ramping up from the hold), where
        every drone is over its landing spot, and lands from there.  Otherwise (spots
        re-planned after the show) each flies straight to its landing point, loudly."""
        interrupted = self._stopped_at is not None and self._stopped_at < self.plan.duration \
            and not self._after_return and now is not None
        how = no_return(interrupted, any(
            v.hold_point is not None and v.before_return is VehiclePhase.LEAVING
            for v in self.vehicles.values()))
        if how is NoReturn.COLUMNS:
            # Where each holds is read while the return is still awaited (then every
            # path is where it braked, not the landing spot a failed return falls back to).
            assert now is not None
            return self._land_in_columns(reason, now)
        self._return_wanted = False
        if how is NoReturn.STRAIGHT:
            return [Notice(None, f"no collision-free return could be planned ({reason}); "
                                 "flying straight to the landing points: watch the fleet")]
        assert now is not None
        self._ended, self._stopped_at = False, None
        for v in self.vehicles.values():
            if v.phase is VehiclePhase.RETURNING and v.before_return is not None:
                self._to(v, Event.RETURN_FAILED, v.before_return)
                if v.phase is VehiclePhase.READY:
                    self._to(v, Event.SHOW_STARTS)
            elif v.phase is VehiclePhase.LOST and v.lost_from is VehiclePhase.RETURNING \
                    and v.before_return is not None:
                self._lost_to(v, Event.RETURN_FAILED, v.before_return)
            v.before_return = None
        self.release("land-all", now)
        return [Notice(None, f"no collision-free return could be planned ({reason}): the "
                             "show flies on to its end, the one way known to be clear, and "
                             "every drone lands from there")]

    def _land(self, v: VehicleRun, now: float) -> list[Action]:
        if v.phase is VehiclePhase.PREFLIGHT:
            self._to(v, Event.STAND_DOWN)
            return []
        if v.phase is VehiclePhase.ARMING:
            # Still on the ground (takeoff was never sent): nothing to land, but
            # it may already be armed.
            self._to(v, Event.STAND_DOWN)
            v.pending = None
            return [Disarm(v.sysid), Notice(v.sysid, f"vehicle {v.sysid} stood down on the ground")]
        if v.phase in (VehiclePhase.ARMING, VehiclePhase.TAKEOFF):
            self._to(v, Event.LAND)
            return [self._send(v, Land(v.sysid), now)]
        if v.pad is not None and v.phase is VehiclePhase.READY:
            # A spare over its pad (at its standby point, or up and not on its way yet):
            # straight back down onto it.
            self._to(v, Event.LAND)
            v.pending = None
            return [self._send(v, Land(v.sysid), now)]
        if v.pad is not None and v.phase is VehiclePhase.LOST \
                and v.lost_from is VehiclePhase.READY:
            # Silent over its pad: told to land there (if it hears us); never on a return.
            self._lost_to(v, Event.LAND)
            return [self._send(v, Land(v.sysid), now)]
        if v.leave is None:
            v.leave_at = None  # a way out not planned yet: the landing replaces it
        if v.phase in (VehiclePhase.READY, VehiclePhase.JOINING, VehiclePhase.SHOW,
                       VehiclePhase.LEAVING):
            v.before_return = v.phase
            self._to(v, Event.RETURN)
            v.pending = None
        if v.phase is VehiclePhase.LOST and v.lost_from in (
                VehiclePhase.READY, VehiclePhase.JOINING, VehiclePhase.SHOW,
                VehiclePhase.LEAVING):
            v.before_return = v.lost_from
            self._lost_to(v, Event.RETURN)
        return []
