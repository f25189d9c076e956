"""The arbiter, :class:`ShowSequence`: it starts the sequence and, every update,
drives each vehicle's lifecycle from its telemetry (arming, takeoff, show, return,
landing), calling on the policies of the layers it is built from."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from groundctl.execute.frames import show_positions
from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.policies.battery import BatteryView, battery_due
from groundctl.execute.sequence.policies.modes import ModeLeft, mode_left
from groundctl.execute.sequence.spares import Spares
from groundctl.execute.sequence.types import (
    _FLIGHT_MODE,
    _IDLE,
    _LAND_MODES,
    _STREAMED,
    FLEET_HOLDS,
    Action,
    Arm,
    Command,
    Land,
    Notice,
    SetMode,
    Takeoff,
    VehiclePhase,
    VehicleRun,
)
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState


class ShowSequence(Spares):
    """The whole show's flight sequence; see the :mod:`groundctl.execute.sequence`
    docstring for the protocol."""

    # -- driver interface ------------------------------------------------------------
    def start(self, now: float) -> list[Action]:
        """Begin arming every vehicle (pre-flight checks have passed)."""
        if self._started or self._ended:
            return [Notice(None, "the sequence has already started or been stopped")]
        self._started = True
        actions: list[Action] = []
        for v in self.vehicles.values():
            self._to(v, Event.START)
            v.started_at = now
            first: Command = SetMode(v.sysid, "GUIDED") if v.flavour is Flavour.ARDUPILOT \
                else Arm(v.sysid)
            actions.append(self._send(v, first, now))
        return actions

    def update(self, now: float, states: Mapping[int, VehicleState]) -> list[Action]:
        """Advance every vehicle from its telemetry; returns the actions to perform."""
        actions: list[Action] = []
        self._positions = show_positions(self.plan.origin, states)
        # Losses first: one may abort the show, and then nobody should be
        # told to arm or take off in the same breath.
        for v in self.vehicles.values():
            state = states.get(v.sysid)
            if v.phase is VehiclePhase.LOST and state is not None and not state.lost:
                actions += self._rejoin(v, now, state)
                continue
            if v.phase in _IDLE:
                continue
            if state is None or state.lost:
                actions += self._lose(v, now, state)
        for v in self.vehicles.values():
            if v.phase in _IDLE:
                continue
            actions += self._advance(v, states[v.sysid], now)
        for v in self.vehicles.values():
            state = states.get(v.sysid)
            if v.fell and v.phase is VehiclePhase.FAILED and state is not None:
                actions += self._armed_again(v, state, now)
        self._spares_heard = {s for s in self.standby
                              if (st := states.get(s)) is not None and not st.lost}
        self._spares_low = {s for s in self._spares_heard
                            if self._battery is not None
                            and (pct := states[s].battery_remaining_pct) is not None
                            and pct < self._battery}
        actions += self._land_all_if_stranded(now)
        actions += self._descend_columns(now)
        actions += self._maybe_start_show(now, states)
        actions += self._begin_leaves(now)
        actions += self._advance_spares(now)
        if self.started_at is not None and not self._ended \
                and self.clock.show_time(now) >= self.plan.duration:
            self._ended = True
            for v in self.vehicles.values():
                if v.phase in (VehiclePhase.SHOW, VehiclePhase.JOINING) or (
                        v.phase is VehiclePhase.LEAVING and v.leave is None):
                    self._to(v, Event.SHOW_ENDS)
                    v.returning_since = now
                if v.lost_from in (VehiclePhase.SHOW, VehiclePhase.JOINING) or (
                        v.lost_from is VehiclePhase.LEAVING and v.leave is None):
                    self._lost_to(v, Event.SHOW_ENDS)
            actions.append(Notice(None, "show finished: returning to the landing slots"))
        return actions

    def _advance(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        cfg = self.config
        v.altitude = self._altitude(state)
        v.mode = state.mode
        # Streamed phases fly our setpoints, so must be in the flight mode.
        if v.retaking is not None and state.mode == _FLIGHT_MODE[v.flavour]:
            v.retaking, v.pending = None, None
            return [Notice(v.sysid, f"vehicle {v.sysid} back in {state.mode}: in the sequence "
                                    f"again ({v.phase})", "retaken",
                           f"back in {state.mode} after its link-loss failsafe")]
        if v.phase in _STREAMED and state.mode is not None \
                and state.mode not in (_FLIGHT_MODE[v.flavour], "UNKNOWN"):
            if mode_left(v, state, now, self._battery, self.holds) is ModeLeft.RETAKE:
                return self._retake(v, state, now)
            return self._taken_over(v, state)
        if v.phase in _STREAMED and not state.armed and state.last_heartbeat is not None:
            # Disarmed while flying our setpoints: a crash, a motor failure, a pilot's
            # kill switch.  It is down where it fell: out of the show at once, and an
            # obstacle for every landing from now on (down_positions).
            was = v.phase
            self._to(v, Event.FELL)
            v.pending, v.leave_at = None, None
            v.reason, v.fell = f"disarmed during {was} (crash or motor failure)", True
            text = state.last_statustext.text if state.last_statustext is not None else ""
            return [Notice(v.sysid, f"vehicle {v.sysid} disarmed in the air during {was}"
                                    + (f" ('{text}')" if text else "")
                                    + ": out of the show; where it fell is kept clear",
                           "crashed", "disarmed in the air: out of the show")]
        if state.stream_gaps > v.gap_seen:
            # Its own telemetry (on its own clock) stopped for a while: it may have flown
            # on without us.  Our own stalls never show here (the packets were queued,
            # not missing), and a fleet-wide silence holds the whole show instead.
            v.gap_seen, v.gap_at = state.stream_gaps, now
            gap = state.last_stream_gap_s
            if v.phase is VehiclePhase.SHOW and not self.holds & FLEET_HOLDS \
                    and (off := self._off_plan(v, now)) is not None:
                return self._strand(v, off, now, f"heard again after {gap:.1f} s,")
        pct = state.battery_remaining_pct
        if self._battery is not None and pct is not None and v.phase in _STREAMED:
            battery = BatteryView(pct, self._battery, v.phase, v.battery_low,
                                  v.battery_critical)
            if battery_due(battery):
                return self._battery_landing(v, battery, now)
        cmd = v.pending
        if v.retry_at is not None and now >= v.retry_at and cmd is not None:
            if isinstance(cmd, Takeoff):
                return self._retake_off(v, cmd, now)
            return [self._send(v, cmd, now)]
        if isinstance(cmd, SetMode) and cmd.mode == "GUIDED":
            if state.mode == "GUIDED":
                return [self._send(v, Arm(v.sysid), now)]
        elif isinstance(cmd, Arm):
            if state.armed:
                self._to(v, Event.ARMED)
                v.takeoff_from = v.altitude
                return [self._send(v, Takeoff(v.sysid, self.plan.takeoff_altitude), now)]
        elif isinstance(cmd, Takeoff):
            alt = v.altitude
            if alt is not None and abs(alt - cmd.alt_m) <= cfg.takeoff_tolerance_m:
                # Up before a refusal's verdict was due: the climb overrules it too.
                notices = self._refusal_overruled(v) if v.retry_at is not None else []
                v.stream_since = now
                v.pending = None
                if v.flavour is Flavour.ARDUPILOT:
                    self._to(v, Event.UP)  # already in GUIDED since before arming
                    v.ready_at = now
                    self._took_off(v, now)
                return notices
            if now - v.sent_at >= cfg.takeoff_timeout_s:
                return self._give_up(v, f"takeoff did not reach {cmd.alt_m:.1f} m within "
                                        f"{cfg.takeoff_timeout_s:.0f} s", now)
            return []
        elif cmd is None and v.phase is VehiclePhase.TAKEOFF and v.stream_since is not None:
            # PX4 rejects OFFBOARD unless setpoints are already arriving.
            if now - v.stream_since >= cfg.offboard_lead_s:
                return [self._send(v, SetMode(v.sysid, "OFFBOARD"), now)]
            return []
        elif isinstance(cmd, SetMode) and cmd.mode == "OFFBOARD":
            if state.mode == "OFFBOARD":
                self._to(v, Event.UP)
                v.pending, v.ready_at = None, now
                self._took_off(v, now)
                return []
        elif v.phase is VehiclePhase.RETURNING:
            return self._returning(v, state, now)
        elif v.phase is VehiclePhase.LEAVING:
            return self._leaving(v, state, now)
        elif isinstance(cmd, Land) or v.phase is VehiclePhase.LANDING:
            if not state.armed:
                self._to(v, Event.DISARMED)
                v.pending = None
                return [Notice(v.sysid, f"vehicle {v.sysid} landed", "landed", "landed")]
            if state.mode in _LAND_MODES:
                return []  # descending: that takes as long as it takes
        if cmd is not None and now - v.sent_at >= cfg.step_timeout_s and v.retry_at is None:
            return self.command_failed(cmd, f"no effect after {cfg.step_timeout_s:.0f} s", now)
        return []

    def _settled(self, v: VehicleRun) -> bool:
        return self._start_distance(v) <= self.config.start_tolerance_m

    def _maybe_start_show(self, now: float, states: Mapping[int, VehicleState]) -> list[Action]:
        if self.started_at is not None or self._ended or not self._started or self.paused:
            return []
        phases = [v.phase for v in self.vehicles.values()]
        if any(p in (VehiclePhase.ARMING, VehiclePhase.TAKEOFF) for p in phases):
            return []
        # Spares waiting in the air are up with the fleet, but not in the show.
        ready = [v for v in self.vehicles.values() if v.phase is VehiclePhase.READY
                 and v.pad is None]
        if not ready:
            return []
        # Takeoff ends within takeoff_tolerance_m of the altitude; starting the
        # clock before the fleet has settled on the plan's first points would
        # put that whole offset into the first seconds of the show.
        if self._ready_since is None:
            self._ready_since = now
        if any(v.ready_at is not None and now - v.ready_at < self.config.hover_before_show_s
               for v in ready):
            return []
        if now - self._ready_since < self.config.settle_timeout_s \
                and not all(self._settled(v) for v in ready):
            return []
        # A vehicle that could not get to its first point in that time does not start
        # the show off its plan: it goes back down its own column (an exclusion, with
        # the exclusion's safety check: if the others need its slot clear, no show).
        actions: list[Action] = []
        far = [v for v in ready if self._start_distance(v) > self.config.exclude_tolerance_m]
        for v in far:
            if self._ended:
                # An exclusion before it left the show unsafe and landed the fleet: the
                # rest are returning with everyone else, not excluded one by one.
                break
            d = self._start_distance(v)
            v.reason = (
                f"{d:.1f} m from its first plan point after "
                f"{self.config.settle_timeout_s:.0f} s (tolerance "
                f"{self.config.exclude_tolerance_m:.1f} m)")
            # Back over its own takeoff slot, then down there (the exclusion check below
            # says whether the others can fly the show with it standing on it).
            self._to(v, Event.NOT_AT_START)
            v.pending, v.returning_since = None, now
            v.landing_point = tuple(float(x) for x in self._home_hover[v.track])  # type: ignore[assignment]
            actions += [Notice(v.sysid, f"vehicle {v.sysid} is {v.reason}: landing it on its "
                                        "slot instead of starting it", "start_excluded",
                               "could not reach its first plan point: landing on its slot"),
                        *self._left_on_slot(v, now)]
        if self._ended:
            return actions  # the exclusion left the show unsafe: aborted
        ready = [v for v in ready if v not in far]
        if not ready:
            return actions
        self.clock.start(now)
        for v in ready:
            self._to(v, Event.SHOW_STARTS)
        return [*actions, Notice(None, f"show started with {len(ready)} vehicle(s)")]

    def _start_distance(self, v: VehicleRun) -> float:
        pos = self._positions.get(v.sysid)
        return math.inf if pos is None else float(np.linalg.norm(pos - self._first[v.track]))
