"""When a vehicle does not do what the sequence asked: a command refused or
unanswered (retried, or the vehicle given up; a refused takeoff judged by the climb),
its flight mode left by itself (a link-loss failsafe taken back; a fence, a pilot or
any other failsafe respected), and a low battery."""

from __future__ import annotations

import math

from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.lost import OffPlan
from groundctl.execute.sequence.types import (
    _FLIGHT_MODE,
    _LAND_MODES,
    _LINK_FAILSAFE_MODES,
    _STREAMED,
    AIRBORNE_M,
    CLIMB_SEEN_M,
    FENCE_NOTICE_S,
    LINK_FAILSAFE_GAP_S,
    LOW_BATTERY_FLEET,
    MAX_RETAKES,
    RETAKE_WINDOW_S,
    STARVED_WINDOW_S,
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
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState


def _fence_acted(state: VehicleState, now: float) -> bool:
    """The vehicle's own fence fired: ArduPilot's "Fence Breached", PX4's "Geofence ..."."""
    st = state.last_statustext
    return st is not None and "fence" in st.text.lower() and now - st.at <= FENCE_NOTICE_S


class Failsafes(OffPlan):
    """Refusals, failsafes and low batteries (a layer of :class:`ShowSequence`)."""

    def command_failed(self, command: Command, reason: str, now: float) -> list[Action]:
        """A command was refused or timed out; retry it later or give the vehicle up."""
        v = self.vehicles.get(command.sysid)
        if v is None or v.pending != command:
            return []  # a stale answer: the vehicle has moved on
        if isinstance(command, Takeoff):
            if self._climbing(v):
                # Climbing already: the first NAV_TAKEOFF was accepted but its ACK lost,
                # and the autopilot refuses a repeat in flight.  Its effect is what counts.
                return []
            # Judged once the vehicle has had the time to lift off (_retake_off).
            v.reason = reason
            v.retry_at = now + self.config.takeoff_retry_after_s
            return []
        if isinstance(command, Land) and v.mode in _LAND_MODES:
            # In its land mode already: the LAND was carried out and only its ACK was
            # lost (half the packets lost, say).  Its effect is what counts: counting the
            # timeouts gave a vehicle that went on to land up as "land failed 3 times".
            return []
        v.reason = reason
        if v.attempts >= self.config.max_attempts:
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

    def _link_failsafe(self, v: VehicleRun, state: VehicleState, now: float) -> bool:
        """Whether a mode change looks like the vehicle's own reaction to losing us (an
        offboard- or GCS-loss failsafe: hold, land or return where it was), as opposed to
        a pilot or a battery failsafe: it came while the whole fleet was silent or right
        after a silence of its own, and its battery is fine."""
        if state.mode not in _LINK_FAILSAFE_MODES[v.flavour]:
            return False
        if v.retakes >= MAX_RETAKES or _fence_acted(state, now):
            return False
        battery = state.battery_remaining_pct
        if battery is not None and self._battery is not None and battery < self._battery:
            return False
        own_silence = state.last_stream_gap_s >= LINK_FAILSAFE_GAP_S and (
            state.stream_gaps > v.gap_seen
            or (v.gap_at is not None and now - v.gap_at <= RETAKE_WINDOW_S))
        # Our own stall starves it of setpoints without any gap in its telemetry: the
        # hold says so while it lasts, and the setpoints we did not send say so after
        # (or now, on the first tick after the stall, before any is sent again).  Only
        # PX4 leaves its flight mode for want of setpoints (ArduPilot's GUIDED holds).
        starved = v.flavour is Flavour.PX4 and (
            (v.starved_at is not None and now - v.starved_at <= STARVED_WINDOW_S)
            or (v.streamed_at is not None and now - v.streamed_at >= LINK_FAILSAFE_GAP_S))
        return own_silence or starved or bool(self.holds & {"stall", "silence"})

    def _retake_goes_on(self, v: VehicleRun, state: VehicleState) -> bool:
        """A retake under way goes on, until its own attempts run out, even once the silence
        that explained it is over: while the vehicle is still in the failsafe mode it was
        being taken back from (or PX4's hold moved on to its land), and its battery is
        fine (a battery failsafe is never fought)."""
        if v.retaking is None or _fence_acted(state, v.sent_at):
            return False
        battery = state.battery_remaining_pct
        if battery is not None and self._battery is not None and battery < self._battery:
            return False
        return state.mode == v.retaking or (
            v.flavour is Flavour.PX4 and v.retaking == "AUTO.LOITER"
            and state.mode == "AUTO.LAND")

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

    def _climbing(self, v: VehicleRun) -> bool:
        """Whether its telemetry says it is taking off (or flying)."""
        alt = v.altitude
        if alt is None:
            return False
        return alt > AIRBORNE_M or (v.takeoff_from is not None
                                    and alt - v.takeoff_from >= CLIMB_SEEN_M)

    def _retake_off(self, v: VehicleRun, cmd: Takeoff, now: float) -> list[Action]:
        """``takeoff_retry_after_s`` after a refused takeoff: climbing, the refusal was
        not the vehicle's last word (a forged ACK, or its answer to a repeat of a
        takeoff it had accepted) and its takeoff goes on; still on the ground, it is
        re-sent, or given up after ``max_attempts``."""
        if self._climbing(v):
            return self._refusal_overruled(v)
        v.retry_at = None
        if v.attempts >= self.config.max_attempts:
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

    def _battery_landing(self, v: VehicleRun, state: VehicleState,
                         now: float) -> list[Action]:
        assert self._battery is not None and state.battery_remaining_pct is not None
        v.battery_low = True
        pct = state.battery_remaining_pct
        low = [u for u in self.vehicles.values() if u.battery_low and u.phase in _STREAMED]
        if not self._ended and len(low) >= max(2, math.ceil(LOW_BATTERY_FLEET * len(
                self.vehicles))):
            # The batteries are running out across the fleet: one planned return for all,
            # not a way out (or a descent in place) each.
            v.reason = f"battery {pct:.0f} %"
            return [Notice(None, f"batteries low across the fleet ({len(low)} vehicles below "
                                 f"{self._battery:.0f} %): landing every vehicle"),
                    *self.land_all(now)]
        if pct < self._battery / 2 and self._column_clear(v):
            v.battery_critical = True
            self._to(v, Event.LAND)
            v.reason = f"battery {pct:.0f} % (critical)"
            v.leave_at = None
            return [Notice(v.sysid, f"vehicle {v.sysid}: battery {pct:.0f} % is below half "
                                    f"the show's {self._battery:.0f} %: landing where it is "
                                    "(nobody below it)", "battery_critical",
                           "battery critical: landing where it is"),
                    self._send(v, Land(v.sysid), now)]
        if v.phase is not VehiclePhase.SHOW:
            return []  # already leaving or returning: that is the fastest safe way down
        v.reason = f"battery {pct:.0f} % (minimum {self._battery:.0f} %)"
        actions: list[Action] = [Notice(
            v.sysid, f"vehicle {v.sysid}: battery {pct:.0f} % is below the show's "
                     f"{self._battery:.0f} %: it leaves the show", "battery_low",
            "battery low: leaving the show")]
        return actions + self.land_one(v.sysid, now)
