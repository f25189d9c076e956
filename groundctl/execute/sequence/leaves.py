"""Ways out: a vehicle that leaves mid-show (land-one, off its plan, a low battery)
flies a way out planned around the others, from the instant it leaves to its landing."""

from __future__ import annotations

from functools import cache

import numpy as np

from groundctl.execute.leaving import LEAVE_LEAD_S, Leave, leave_duration, leave_time
from groundctl.execute.sequence.columns import Columns
from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.policies.waysout import (
    Late,
    Offered,
    WithoutWayOut,
    late,
    offered,
    without_way_out,
)
from groundctl.execute.sequence.types import (
    LATE_LEAVE_S,
    MAX_LATE_LEAVES,
    Action,
    Land,
    Notice,
    VehiclePhase,
    VehicleRun,
)
from groundctl.link.state import VehicleState


class WaysOut(Columns):
    """Ways out of the show mid-flight (a layer of :class:`ShowSequence`)."""

    # -- land-one mid-show: a way out -------------------------------------------------------
    @property
    def leave_needed(self) -> list[tuple[int, int, float, tuple[float, float, float] | None]]:
        """(system id, track, show time, start) of each vehicle whose way out awaits
        planning; start is None for its plan point at that time (land-one), or where it
        hovers (heard again off its plan).

        The driver plans it (around the others as they will fly, and
        :attr:`leaves`) and hands it over with :meth:`set_leave`, or calls
        :meth:`leave_failed`.
        """
        if self._ended:
            return []
        return [(v.sysid, v.track, v.leave_at, v.hold_point) for v in self.vehicles.values()
                if v.leave_at is not None and v.leave is None and self._awaits_leave(v)]

    def _awaits_leave(self, v: VehicleRun) -> bool:
        phase = self.streamed_as(v)
        return phase is VehiclePhase.SHOW or (phase is VehiclePhase.LEAVING
                                              and v.hold_point is not None)

    @property
    def leaves(self) -> dict[int, Leave]:
        """Planned ways out by *track*, of the drone that flies it now (obstacles for the
        next one, starts for a return).  A drone a spare replaced is not its track's any
        more: its way out is in :attr:`replaced_leaves`, and the track, flown by the
        spare, stays on its plan for the planners."""
        return {v.track: v.leave for v in self.vehicles.values()
                if v.leave is not None and v.replaced_by is None and v.track >= 0}

    @property
    def replaced_leaves(self) -> list[tuple[int, Leave]]:
        """(track it flew, way out) of every drone a spare replaced that is still up on
        its way out (or still on the track's plan before it, or lost meanwhile): moving
        obstacles of their own for the planners, beside the spare on the track.  Once
        it comes down it is where it is, like any drone down."""
        return [(v.track, v.leave) for v in self.vehicles.values()
                if v.leave is not None and v.replaced_by is not None and v.track >= 0
                and v.phase not in (VehiclePhase.LANDING, VehiclePhase.LANDED,
                                    VehiclePhase.FAILED, VehiclePhase.KILLED)]

    def set_leave(self, sysid: int, leave: Leave, now: float) -> list[Action]:
        """Fly ``leave`` from its show time on, then land."""
        v = self.vehicles.get(sysid)
        verdict = Offered.OVERTAKEN if v is None else offered(
            awaits=v.leave_at is not None and v.leave is None and not self._ended
            and self._awaits_leave(v), planned_held=leave.held,
            holds_off_plan=v.hold_point is not None, show_time=self.show_time(now),
            starts_at=leave.at)
        if verdict is Offered.OVERTAKEN:
            return []
        if verdict is Offered.TOO_LATE:
            return self.leave_late(sysid, "its way out was ready too late", now)
        assert v is not None
        v.leave = leave
        return [Notice(sysid, f"way out for vehicle {sysid} planned: from show time "
                              f"{leave.at:.1f} s, {leave.trajectory.end:.1f} s to its landing "
                              "spot")]

    def leave_late(self, sysid: int, reason: str, now: float) -> list[Action]:
        """Its way out could not be planned before its instant: the next instant, a bounded
        number of times, then as :meth:`leave_failed`."""
        v = self.vehicles.get(sysid)
        if v is None or v.leave is not None or v.leave_at is None:
            return []
        v.leave_late += 1
        held = v.hold_point is not None
        # Each time it was planned too late, its next instant twice as far ahead (at x8 on
        # a busy machine the next rest 2 s of show ahead is a quarter second of planning).
        ahead = LATE_LEAVE_S * 2 ** (v.leave_late - 1)
        next_instant = cache(lambda: self._hold_leave_time(v, now) if held
                             else leave_time(self.plan, v.track, self.show_time(now) + ahead))
        verdict = late(v.leave_late, MAX_LATE_LEAVES, next_instant)
        if verdict is Late.TOO_MANY:
            return self.leave_failed(sysid, f"{reason}; {v.leave_late} times", now)
        if verdict is Late.NO_INSTANT:
            return self.leave_failed(sysid, f"{reason}; no formation left to leave from",
                                     now)
        v.leave_at = next_instant()
        assert v.leave_at is not None
        return [Notice(sysid, f"vehicle {sysid}: {reason}; leaving at show time "
                              f"{v.leave_at:.1f} s instead", "leave_late",
                       "way out not planned in time: leaving later")]

    def leave_failed(self, sysid: int, reason: str, now: float) -> list[Action]:
        """No safe way out: it flies on with the show and lands at the end, loudly."""
        v = self.vehicles.get(sysid)
        if v is None or v.leave is not None:
            return []
        v.leave_at = None
        if without_way_out(v.phase, v.hold_point is not None) \
                is WithoutWayOut.LAND_WHERE_IT_HOLDS:
            self._to(v, Event.LAND)
            return [Notice(sysid, f"no safe way out of the show for vehicle {sysid} ({reason}); "
                                  "landing it where it holds"),
                    self._send(v, Land(sysid), now)]
        return [Notice(sysid, f"no safe way out of the show for vehicle {sysid} ({reason}); it "
                              f"flies on and lands with the others (land-here {sysid} brings "
                              "it straight down now)")]

    def _hold_leave_time(self, v: VehicleRun, now: float) -> float | None:
        """When a vehicle holding off its plan leaves: LEAVE_LEAD_S from now, if its way out
        ends before the plan does (a way out runs on the show clock, which stops there).
        None: it holds until the show ends and then returns with the others."""
        assert v.hold_point is not None
        at = self.show_time(now) + LEAVE_LEAD_S
        if at + leave_duration(self.plan, v.track, at, np.asarray(v.hold_point)) \
                > self.plan.duration:
            return None
        return at

    def _leaving(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        if v.leave is None:
            return []  # holding where it was heard again, its way out being planned
        if self.show_time(now) < v.leave.until:
            return []
        return self._returning(v, state, now)

    def _begin_leaves(self, now: float) -> list[Action]:
        if self.started_at is None or self._ended:
            return []
        t = self.show_time(now)
        actions: list[Action] = []
        for v in self.vehicles.values():
            if v.leave is None or t < v.leave.at:
                continue
            if v.phase is VehiclePhase.SHOW:
                self._to(v, Event.LEAVES)
                actions.append(Notice(v.sysid, f"vehicle {v.sysid} leaves the show"))
            elif v.phase is VehiclePhase.LOST and v.lost_from is VehiclePhase.SHOW:
                self._lost_to(v, Event.LEAVES)
        return actions
