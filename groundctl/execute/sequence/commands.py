"""The operator's commands (hold, resume, land-all, land-one, land-here, kill):
each returns actions, and bad input comes back as a Notice, never an exception."""

from __future__ import annotations

from functools import cache

from groundctl.execute.leaving import leave_time
from groundctl.execute.sequence.leaves import WaysOut
from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.policies.operator import (
    KillVerdict,
    LandHere,
    LandOne,
    kill_asked,
    land_here_asked,
    land_one_asked,
)
from groundctl.execute.sequence.types import Action, Kill, Land, Notice, VehiclePhase


class OperatorCommands(WaysOut):
    """The operator's commands (a layer of :class:`ShowSequence`)."""

    # -- operator --------------------------------------------------------------------
    def hold(self, now: float) -> list[Action]:
        """Brake the show to a stop: every drone decelerates along its own trajectory and
        hovers on it (the plan keeps them apart at every instant)."""
        if "operator" in self.holds:
            return [Notice(None, "already holding")]
        if self.started_at is None:
            self._pre_start_hold = True
            return [Notice(None, "holding: the show clock will not start until resume")]
        self.hold_for("operator", now)
        return [Notice(None, f"holding: braking along the plan, stopped at show time "
                             f"{min(self.clock.stop_time(now), self.plan.duration):.1f} s")]

    def resume(self, now: float) -> list[Action]:
        """Run the show clock again (ramping up) from where it was held."""
        if self._pre_start_hold:
            self._pre_start_hold = False
            others = sorted(self.holds)
            if others:
                return [Notice(None, "operator hold released; the show starts once the "
                                     f"fleet is ready and no longer held for {', '.join(others)}")]
            return [Notice(None, "resumed: the show starts once the fleet is ready")]
        if "operator" not in self.holds:
            return [Notice(None, "not holding: nothing to resume")]
        self.release("operator", now)
        others = sorted(self.holds)
        if others:
            return [Notice(None, f"operator hold released; still holding for {', '.join(others)}")]
        return [Notice(None, f"resuming at show time {self.show_time(now):.1f} s")]

    def land_all(self, now: float) -> list[Action]:
        """Every vehicle back to its landing slot and down; the show is over."""
        if self._columns:
            return [Notice(None, "already landing every vehicle, one column at a time")]
        if self._stopped_at is None:
            interrupted = self.started_at is not None and not self._ended \
                and self.clock.show_time(now) < self.plan.duration
            self._pre_start_hold = False
            self.release("operator", now)
            self.hold_for("land-all", now)
            self._stopped_at = min(self.clock.stop_time(now), self.plan.duration)
            # Interrupted mid-show: the way home needs planning (see return_needed).
            self._return_wanted = self._return_wanted or interrupted
        self._ended = True
        actions: list[Action] = [Notice(None, "landing all vehicles")]
        for v in self.vehicles.values():
            actions += self._land(v, now)
        return actions

    def land_one(self, sysid: int, now: float, *, after_hold: bool = False) -> list[Action]:
        """Vehicle ``sysid`` back to its landing slot and down; the others go on.

        Mid-show it first flies on to the next instant it rests on a formation and
        leaves from there on a way out planned around the others (see
        :attr:`leave_needed`); a straight line home would cut through the show.
        ``after_hold``: at the end of that formation's hold if it can (a healthy drone a
        spare replaces holds the formation whole).
        """
        v = self.vehicles.get(sysid)

        def instant() -> tuple[float, bool] | None:
            """When it leaves, and whether that is the end of a hold it was asked for."""
            if v is None:
                return None
            t = self.show_time(now)
            late = leave_time(self.plan, v.track, t, after_hold=True) if after_hold else None
            if late is not None:
                return late, True
            at = leave_time(self.plan, v.track, t)
            return None if at is None else (at, False)

        chosen = cache(instant)
        verdict = land_one_asked(
            known=v is not None, in_columns=self._columns,
            mid_show=v is not None and self.streamed_as(v) is VehiclePhase.SHOW
            and not self._ended,
            leaving=v is not None and v.leave_at is not None,
            next_instant=lambda: None if (c := chosen()) is None else c[0])
        if verdict is LandOne.UNKNOWN:
            return [Notice(None, f"no vehicle {sysid} in this show")]
        assert v is not None
        if verdict is LandOne.IN_COLUMNS:
            return [Notice(sysid, f"every vehicle lands straight down, one column at a time; "
                                  f"land-here {sysid} brings it down now")]
        if verdict is LandOne.ALREADY_LEAVING:
            assert v.leave_at is not None
            return [Notice(sysid, f"vehicle {sysid} already leaves the show at show time "
                                  f"{v.leave_at:.1f} s")]
        if verdict is LandOne.NO_FORMATION_LEFT:
            return [Notice(sysid, f"vehicle {sysid}: no formation left to leave the show "
                                  "from; it lands with the others at the end (land-here "
                                  f"{sysid} brings it straight down now)")]
        if verdict is LandOne.LEAVE_AT_NEXT:
            pick = chosen()
            assert pick is not None
            v.leave_at, at_hold_end = pick
            held = " at the end of its formation's hold," if at_hold_end else ","
            return [Notice(sysid, f"vehicle {sysid} leaves the show at show time "
                                  f"{v.leave_at:.1f} s{held} on a way out planned around "
                                  "the others")]
        return [Notice(sysid, f"landing vehicle {sysid}"), *self._land(v, now)]

    def land_here(self, sysid: int, now: float) -> list[Action]:
        """Vehicle ``sysid`` straight down where it is (not over its slot); the others go on.

        For a drone that misbehaves: it stops following the plan at once, so
        the operator must know the column below it is clear.
        """
        v = self.vehicles.get(sysid)
        verdict = land_here_asked(None if v is None else v.phase)
        if verdict is LandHere.UNKNOWN:
            return [Notice(None, f"no vehicle {sysid} in this show")]
        assert v is not None
        if verdict is LandHere.ALREADY:
            return [Notice(sysid, f"vehicle {sysid} is already {v.phase}")]
        if verdict is LandHere.STAND_DOWN:
            return [Notice(sysid, f"landing vehicle {sysid} here"), *self._land(v, now)]
        self._to(v, Event.LAND)
        return [Notice(sysid, f"landing vehicle {sysid} where it is"),
                self._send(v, Land(sysid), now)]

    def kill(self, sysid: int, now: float, confirm: bool = False) -> list[Action]:
        """Stop ``sysid``'s motors in flight; needs ``confirm`` because the drone falls."""
        v = self.vehicles.get(sysid)
        verdict = kill_asked(v is not None, confirm)
        if verdict is KillVerdict.UNKNOWN:
            return [Notice(None, f"no vehicle {sysid} in this show")]
        if verdict is KillVerdict.NEEDS_CONFIRM:
            return [Notice(sysid, f"kill vehicle {sysid} not sent: it stops the motors and "
                                  "the drone falls; confirm to kill")]
        assert v is not None
        self._to(v, Event.KILL)
        v.pending = None
        return [Kill(sysid), Notice(sysid, f"vehicle {sysid} killed by the operator")]
