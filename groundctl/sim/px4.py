"""PX4 (v1.15 multicopter) behaviour: OFFBOARD, AUTO.TAKEOFF / LOITER / LAND / RTL.

Quirks reproduced on purpose (PX4 docs "Offboard Mode", "Safety", commander):

* a UDP link in "normal" mode streams a default message set without being
  asked (SYS_STATUS, ATTITUDE, GLOBAL_POSITION_INT, ...), unlike ArduPilot;
* custom_mode packs main and sub mode (flavours.px4_custom_mode);
* OFFBOARD is refused unless setpoints arrived in the last 0.5 s ("the
  vehicle must be receiving a stream of setpoints (> 2 Hz) before the mode
  switch"); when they stop for COM_OF_LOSS_T the offboard-loss failsafe holds
  for COM_FAIL_ACT_T and then runs COM_OBL_RC_ACT (with no RC, position mode
  is unavailable, so the default falls through to LAND);
* setpoints are accepted in any mode (they make OFFBOARD available) and flown
  only in OFFBOARD;
* NAV_TAKEOFF param7 is an AMSL altitude; NaN means MIS_TAKEOFF_ALT above home;
  the vehicle switches to AUTO.LOITER when it gets there;
* offboard yaw: the setpoint's yaw / yaw rate (NaN when type_mask ignores them,
  mavlink_receiver.cpp) is flown; with both ignored the heading is held; the
  attitude controller turns at MC_YAW_P x MC_YAW_WEIGHT of the heading error, at
  most MC_YAWRATE_MAX;
* STATUSTEXT: every message gets the next id of the link, texts over 50 bytes
  are sent in 50-byte chunks (streams/STATUSTEXT.hpp), at most 126 bytes (the
  mavlink_log text);
* SYS_STATUS has no geofence bits (the health report has no geofence component);
* refusals answer TEMPORARILY_REJECTED; manual modes need RC, which a
  simulated vehicle does not have; parameters are encoded bytewise;
* LED_CONTROL is an ArduPilot message: PX4 ignores it.
"""

from __future__ import annotations

import math
from typing import ClassVar

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour
from groundctl.sim import physics as P
from groundctl.sim.fence import inside
from groundctl.sim.vehicle import (
    ACCEPTED,
    FORCE_MAGIC,
    STATUSTEXT_LEN,
    TEMP_REJECTED,
    Setpoint,
    Vehicle,
    as_int,
)

#: OFFBOARD needs a setpoint at most this old to engage (s).
OFFBOARD_FRESH_S = 0.5

#: Default streams of a PX4 "normal" MAVLink instance (mavlink_main.cpp), Hz.
_DEFAULT_STREAMS: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 15.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
}

#: Longest text a PX4 log message carries (mavlink_log.text is char[127]).
_TEXT_MAX = 126

#: Modes that need RC input, refused by a vehicle without RC.
_MANUAL = frozenset({"MANUAL", "ALTCTL", "POSCTL", "ACRO", "STABILIZED"})
#: Modes that need a position estimate.
_NEEDS_POSITION = frozenset({"OFFBOARD", "AUTO.TAKEOFF", "AUTO.LOITER", "AUTO.MISSION",
                             "AUTO.RTL", "AUTO.PRECLAND"})


class PX4Vehicle(Vehicle):
    """A simulated PX4 multicopter."""

    flavour = Flavour.PX4
    arm_refused_result = TEMP_REJECTED
    land_mode = "AUTO.LAND"
    rtl_mode = "AUTO.RTL"
    boot_mode = "AUTO.LOITER"
    guided_modes: ClassVar[frozenset[str]] = frozenset({
        "OFFBOARD", "AUTO.TAKEOFF", "AUTO.LOITER", "AUTO.MISSION", "AUTO.RTL", "AUTO.LAND"})
    supports_led = False
    foreign_messages = frozenset({mavlink.MAVLINK_MSG_ID_WIND})

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._offboard_sp: Setpoint | None = None
        self._failsafe_action_at: float | None = None
        self._took_off = False
        self._battery_warned = False
        self._dl_lost = False
        self.geofence_breached = False
        """Outside the uploaded polygon or beyond GF_MAX_HOR_DIST / GF_MAX_VER_DIST now."""

    def _boot_messages(self, now: float) -> None:
        for msgid, hz in _DEFAULT_STREAMS.items():
            self.set_stream(msgid, 1.0 / hz, now)

    def default_interval(self, msgid: int) -> float | None:
        hz = _DEFAULT_STREAMS.get(msgid)
        return 1.0 / hz if hz else None

    def _on_origin_set(self, now: float) -> None:
        self.statustext(mavlink.MAV_SEVERITY_INFO, "[ekf2] EKF origin set, GNSS fusion started")

    def statustext_chunks(self, text: bytes) -> list[tuple[int, int, bytes]]:
        """MavlinkStreamStatustext: id = the link's counter (incremented for every text,
        starting at 0), then 50-byte chunks; a text of a multiple of 50 bytes ends on a full
        chunk (no empty terminator, unlike ArduPilot)."""
        text = text[:_TEXT_MAX]
        chunk_id = self._statustext_id
        self._next_statustext_id(skip_zero=False)
        chunks = []
        seq = 0
        while text:
            chunks.append((chunk_id, seq, text[:STATUSTEXT_LEN]))
            text = text[STATUSTEXT_LEN:]
            seq += 1
        return chunks

    def yaw_control(self) -> tuple[float, float]:
        return (math.radians(self.params["MC_YAWRATE_MAX"]),
                float(self.params["MC_YAW_P"] * self.params["MC_YAW_WEIGHT"]))

    # -- commands -----------------------------------------------------------------------------

    def _refuse_mode(self, name: str) -> int:
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL,
                        f"Switching to {name} is currently not possible")
        return TEMP_REJECTED

    def set_mode(self, name: str, now: float) -> int:
        """Switch to ``name`` if PX4 would; returns the MAV_RESULT."""
        if name in _MANUAL:
            return self._refuse_mode(name)  # no RC
        if name in _NEEDS_POSITION and not self.origin_set(now):
            return self._refuse_mode(name)
        if name == "OFFBOARD" and (self.last_setpoint is None
                                   or now - self.last_setpoint > OFFBOARD_FRESH_S):
            return self._refuse_mode(name)
        self.mode = name
        self._failsafe_action_at = None
        self.failsafe = False
        self.heading.hold()
        if name == "OFFBOARD":
            if self._offboard_sp is not None and self.armed:
                self._fly_offboard(self._offboard_sp)
        elif name == "AUTO.TAKEOFF":
            if self.armed and not self.flying:
                self.start_takeoff(self.params["MIS_TAKEOFF_ALT"])
                self._took_off = True
            elif self.flying:
                self.hold()
        elif name == "AUTO.LAND":
            self.start_land()
        elif name == "AUTO.RTL":
            self.start_rtl(self.params["RTL_RETURN_ALT"])
        else:
            self.hold()
        return ACCEPTED

    def _arm_disarm(self, p: list[float], now: float) -> int:
        forced = as_int(p[1]) == FORCE_MAGIC
        if p[0] == 1:
            if self.armed:
                return ACCEPTED
            if not forced:
                if not self.ready_to_arm(now):
                    self.statustext(mavlink.MAV_SEVERITY_CRITICAL,
                                    "Arming denied: Resolve system health failures first")
                    return TEMP_REJECTED
                if self.mode in ("AUTO.LAND", "AUTO.RTL"):
                    self.statustext(mavlink.MAV_SEVERITY_CRITICAL,
                                    "Arming denied: not available in this mode")
                    return TEMP_REJECTED
            self.arm(now)
            self._took_off = False
            if self.mode == "OFFBOARD" and self._offboard_sp is not None:
                self._fly_offboard(self._offboard_sp)
            return ACCEPTED
        if p[0] == 0:
            if self.flying and not forced:
                self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
                return TEMP_REJECTED
            self.disarm(now)
            return ACCEPTED
        return TEMP_REJECTED

    def _takeoff(self, alt_amsl: float, now: float) -> int:
        if not self.armed or self.flying:
            return TEMP_REJECTED
        if not self.origin_set(now):
            return self._refuse_mode("AUTO.TAKEOFF")
        height = self.params["MIS_TAKEOFF_ALT"]
        if math.isfinite(alt_amsl):
            height = max(alt_amsl - self.home_lla[2], height)
        self.mode = "AUTO.TAKEOFF"
        self.heading.hold()
        self.start_takeoff(height)
        self._took_off = True
        return ACCEPTED

    # -- setpoints ----------------------------------------------------------------------------

    def setpoint(self, sp: Setpoint, type_mask: int, now: float) -> None:
        # PX4 takes setpoints in any mode: they keep OFFBOARD available.
        self.last_setpoint = now
        self._offboard_sp = sp
        if self.mode == "OFFBOARD" and self.armed:
            self._fly_offboard(sp)

    def _fly_offboard(self, sp: Setpoint) -> None:
        i = self.i
        if not self.flying:
            wants_up = (sp.pos is not None and sp.pos[2] > self.ph.ground_z[i] + 0.1) or (
                sp.vel is not None and sp.vel[2] > 0.1)
            if not wants_up:
                return
            if self.ph.on_ground[i] and self.ph.mode[i] != P.CTRL_TRACK:
                self.ph.spool[i] = self.ph.dyn.takeoff_spool_s  # start spooling up once
            self._took_off = True
        self.apply_setpoint(sp, 0.0)
        self.ph.mode[i] = P.CTRL_TRACK
        # trajectory_setpoint.yaw / yawspeed; NaN for both: the heading is held.
        self.heading.command(sp.yaw, sp.yaw_rate)

    # -- timers -------------------------------------------------------------------------------

    def _flight_logic(self, now: float) -> None:
        i = self.i
        ph = self.ph
        if self.takeoff_reached():
            self.end_takeoff()
            if self.mode == "AUTO.TAKEOFF":
                self.mode = "AUTO.LOITER"
                self.hold()
        if self.rtl_phase is not None:
            self._rtl_logic()
        self._offboard_loss(now)
        if self._failsafe_action_at is not None and now >= self._failsafe_action_at:
            self._failsafe_action_at = None
            self._run_failsafe_action(int(self.params["COM_OBL_RC_ACT"]), now)
        if self.armed and ph.on_ground[i] and not self.flying:
            spooling = ph.mode[i] == P.CTRL_TRACK and ph.spool[i] > 0
            if self._took_off:
                delay = ph.dyn.land_detect_s + self.params["COM_DISARM_LAND"]
            else:
                delay = self.params["COM_DISARM_PRELAND"]
            if not spooling and delay > 0 and ph.ground_time[i] >= delay:
                self.disarm(now)
        self._datalink_loss(now)
        self._geofence(now)
        self._battery(now)

    def _offboard_loss(self, now: float) -> None:
        if self.mode != "OFFBOARD" or not self.armed or self.last_setpoint is None:
            return
        if now - self.last_setpoint <= self.params["COM_OF_LOSS_T"]:
            return
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Failsafe activated: no offboard signal")
        self.failsafe = True
        # Hold first (COM_FAIL_ACT_T), then the configured action.
        self.mode = "AUTO.LOITER"
        self.hold()
        self.heading.hold()
        self._failsafe_action_at = now + self.params["COM_FAIL_ACT_T"]

    def _run_failsafe_action(self, action: int, now: float) -> None:
        if action == 5:
            return  # hold
        if action == 3:
            self.set_mode("AUTO.RTL", now)
        elif action in (6, 7):
            self.disarm(now)
        else:
            # Position / altitude / manual mode need RC, which is absent: PX4 falls back to
            # land (and 4 is land anyway).
            self.set_mode("AUTO.LAND", now)
        self.failsafe = True

    def _datalink_loss(self, now: float) -> None:
        action = int(self.params["NAV_DLL_ACT"])
        if action == 0 or self.last_gcs_heartbeat is None:
            return
        lost = now - self.last_gcs_heartbeat > self.params["COM_DL_LOSS_T"]
        if lost and not self._dl_lost and self.flying:
            self._dl_lost = True
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL,
                            "Failsafe activated: no connection to ground station")
            self.set_mode({1: "AUTO.LOITER", 2: "AUTO.RTL"}.get(action, "AUTO.LAND"), now)
            self.failsafe = True
        elif not lost:
            self._dl_lost = False

    def _geofence_present(self) -> bool:
        return (self.fence_polygon() is not None or self.params["GF_MAX_HOR_DIST"] > 0
                or self.params["GF_MAX_VER_DIST"] > 0)

    def _geofence(self, now: float) -> None:
        """Navigator's geofence check and the commander's breach action (GF_ACTION): a
        warning, then (2) hold, (3) return, (4) terminate, (5) land, once per breach."""
        action = int(self.params["GF_ACTION"])
        if action == 0 or not self._geofence_present():
            self.geofence_breached = False
            return
        pos = self.ph.est_pos[self.i]
        rel = pos - self.home_enu
        poly = self.fence_polygon()
        max_h, max_v = self.params["GF_MAX_HOR_DIST"], self.params["GF_MAX_VER_DIST"]
        breached = ((poly is not None and not inside(poly, float(pos[0]), float(pos[1])))
                    or (max_h > 0 and math.hypot(rel[0], rel[1]) > max_h)
                    or (max_v > 0 and rel[2] > max_v))
        new = breached and not self.geofence_breached
        self.geofence_breached = breached
        if not new or not self.armed or not self.flying:
            return
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Geofence violated")
        if action == 4:
            self.disarm(now)
            return
        mode = {2: "AUTO.LOITER", 3: "AUTO.RTL", 5: "AUTO.LAND"}.get(action)
        if mode is not None:
            self.set_mode(mode, now)
            self.failsafe = True

    def _battery(self, now: float) -> None:
        if self._battery_warned or self.ph.battery[self.i] >= self.params["BAT_LOW_THR"]:
            return
        self._battery_warned = True
        self.statustext(mavlink.MAV_SEVERITY_WARNING, "Low battery level")
        action = int(self.params["COM_LOW_BAT_ACT"])
        if self.flying and action == 2:
            self.set_mode("AUTO.LAND", now)
        elif self.flying and action == 3:
            self.set_mode("AUTO.RTL", now)
