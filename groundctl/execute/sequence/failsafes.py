"""When a vehicle does not do what the sequence asked: a command refused or
unanswered (retried, or the vehicle given up; a refused takeoff judged by the climb),
its flight mode left by itself (a link-loss failsafe taken back; a fence, a pilot or
any other failsafe respected), and a low battery.  Whether to take a vehicle back and
what a battery asks for are judged by :mod:`.policies`; this layer carries them out."""

from __future__ import annotations

from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.lost import OffPlan
from groundctl.execute.sequence.policies.battery import BatteryMove, BatteryView, battery_move
from groundctl.execute.sequence.policies.refusals import Refused, refused, takeoff_verdict
from groundctl.execute.sequence.types import (
    _FLIGHT_MODE,
    _STREAMED,
    Action,
    Command,
    Land,
    Notice,
    SetMode,
    Takeoff,
    VehiclePhase,
    VehicleRun,
    _describe,
)
from groundctl.link.state import VehicleState


class Failsafes(OffPlan):
    """Refusals, failsafes and low batteries (a layer of :class:`ShowSequence`)."""

    def command_failed(self, command: Command, reason: str, now: float) -> list[Action]:
        """A command was refused or timed out: carry out what :mod:`.policies.refusals`
        says (nothing, a verdict by the climb later, a retry, or the vehicle given up)."""
        v = self.vehicles.get(command.sysid)
        move = refused(v, command, self.config.max_attempts)
        if v is None or move in (Refused.STALE, Refused.DONE):
            return []
        v.reason = reason
        if move is Refused.JUDGE_LATER:  # by _retake_off
            v.retry_at = now + self.config.takeoff_retry_after_s
            return []
        if move is Refused.GIVE_UP:
            return self._give_up(v, f"{_describe(command)} failed {v.attempts} times: {reason}",
                                 now)
        v.retry_at = now + self.config.retry_after_s
        return []

    def _taken_over(self, v: VehicleRun, state: VehicleState) -> list[Action]:
        """The vehicle left its flight mode by itself: a failsafe (offboard or GCS loss,
        battery, geofence) or a pilot took over.  It is out of the show, and we do not
        fight its autopilot for it: no more setpoints, and it counts as down once it has
        disarmed wherever its own mode brings it."""
        was = v.phase
        self._to(v, Event.TAKEN_OVER)
        v.pending, v.leave_at = None, None
        v.retaking = None
        v.reason = f"left {_FLIGHT_MODE[v.flavour]} for {state.mode} during {was}"
        return [Notice(v.sysid, f"vehicle {v.sysid} switched to {state.mode} by itself "
                                f"(failsafe or pilot) during {was}: out of the show, its "
                                "autopilot is in charge until it is down")]

    def _retake(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        """Back in touch after a link loss that tripped its failsafe (a hold, or a blind
        descent or return through the formation): the ground station knows where everyone
        is and takes it back into its flight mode, setpoints already flowing."""
        flight = _FLIGHT_MODE[v.flavour]
        if v.retaking is not None:
            if now - v.sent_at < self.config.step_timeout_s:
                return []
            if v.attempts >= self.config.max_attempts:
                v.retaking = None
                return self._taken_over(v, state)  # it will not come back: its autopilot's
            return [self._send(v, SetMode(v.sysid, flight), now)]
        v.retakes += 1
        v.retaking = state.mode
        actions: list[Action] = [
            Notice(v.sysid, f"vehicle {v.sysid} went to {state.mode} on its own after the "
                            f"link loss: taking it back into {flight}", "retaking",
                   f"in a link-loss failsafe: taking it back into {flight}")]
        if v.phase is VehiclePhase.SHOW and (off := self._off_plan(v, now)) is not None:
            # Its failsafe stopped it short of the plan: back in the flight mode it must
            # not dash to catch up; it holds where it is and leaves on a way out.
            actions += self._strand(v, off, now, "taken back")
        return [*actions, self._send(v, SetMode(v.sysid, flight), now)]

    def _retake_off(self, v: VehicleRun, cmd: Takeoff, now: float) -> list[Action]:
        """``takeoff_retry_after_s`` after a refused takeoff: climbing, the refusal was
        not the vehicle's last word (a forged ACK, or its answer to a repeat of a
        takeoff it had accepted) and its takeoff goes on; still on the ground, it is
        re-sent, or given up after ``max_attempts``."""
        verdict = takeoff_verdict(v, self.config.max_attempts)
        if verdict is Refused.DONE:
            return self._refusal_overruled(v)
        v.retry_at = None
        if verdict is Refused.GIVE_UP:
            return self._give_up(v, f"{_describe(cmd)} failed {v.attempts} times: "
                                    f"{v.reason}", now)
        return [self._send(v, cmd, now)]

    @staticmethod
    def _refusal_overruled(v: VehicleRun) -> list[Action]:
        """Its takeoff was refused, but it climbs: the refusal is dropped, not retried."""
        why, v.reason, v.retry_at = v.reason, None, None
        return [Notice(v.sysid, f"vehicle {v.sysid} climbs although its takeoff was "
                                f"refused ({why}): its takeoff goes on",
                       "takeoff_refusal_overruled",
                       "climbing although the takeoff was refused: it goes on")]

    def _battery_landing(self, v: VehicleRun, view: BatteryView, now: float) -> list[Action]:
        """Carry out what a due low battery asks for (:mod:`.policies.battery`)."""
        v.battery_low = True
        pct, minimum = view.pct, view.minimum
        # Spares standing by are not in the show: they neither count towards land-all nor
        # make the fleet larger.
        low = [u for u in self.vehicles.values() if u.battery_low and u.phase in _STREAMED
               and not u.standing_by]
        fleet = sum(not u.standing_by for u in self.vehicles.values())
        move = battery_move(view, low_in_flight=len(low), fleet=fleet,
                            show_over=self._ended,
                            column_clear=view.below_half and self._column_clear(v))
        if move is BatteryMove.LAND_ALL:
            # The batteries are running out across the fleet: one planned return for all,
            # not a way out (or a descent in place) each.
            v.reason = f"battery {pct:.0f} %"
            return [Notice(None, f"batteries low across the fleet ({len(low)} vehicles below "
                                 f"{minimum:.0f} %): landing every vehicle"),
                    *self.land_all(now)]
        if move is BatteryMove.LAND_HERE:
            v.battery_critical = True
            self._to(v, Event.LAND)
            v.reason = f"battery {pct:.0f} % (critical)"
            v.leave_at = None
            return [Notice(v.sysid, f"vehicle {v.sysid}: battery {pct:.0f} % is below half "
                                    f"the show's {minimum:.0f} %: landing where it is "
                                    "(nobody below it)", "battery_critical",
                           "battery critical: landing where it is"),
                    self._send(v, Land(v.sysid), now)]
        if move is BatteryMove.NOTHING:
            return []  # already leaving or returning: that is the fastest safe way down
        v.reason = f"battery {pct:.0f} % (minimum {minimum:.0f} %)"
        actions: list[Action] = [Notice(
            v.sysid, f"vehicle {v.sysid}: battery {pct:.0f} % is below the show's "
                     f"{minimum:.0f} %: it leaves the show", "battery_low",
            "battery low: leaving the show")]
        return actions + self.land_one(v.sysid, now)
