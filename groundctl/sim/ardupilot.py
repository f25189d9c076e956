"""ArduCopter behaviour (4.7, as measured on SITL): GUIDED, LAND, RTL, fence, failsafes.

Quirks reproduced on purpose:

* nothing but HEARTBEAT, STATUSTEXT and PARAM_VALUE is sent unasked;
* mode changes are checked only when armed (``Copter::set_mode``: "allow
  switching to any mode if disarmed. We rely on the arming check"): GUIDED is
  accepted right after boot, and arming is what waits for the position
  estimate (COMMAND_ACK FAILED, STATUSTEXT "Arm: Need Position Estimate");
  asking for the current mode again changes nothing (a takeoff goes on);
* arming with ARMING_CHECK 0 (or forced) skips the pre-arm checks but not the
  mandatory one: a mode that needs a position still needs the estimate;
* NAV_TAKEOFF only in GUIDED (or another mode with a user takeoff), armed and
  landed; param7 is metres above home; DISARM_DELAY (10 s) disarms a vehicle
  armed on the ground that does not take off;
* setpoints outside GUIDED are dropped silently (never ACKed); type_mask picks
  position / position+velocity(+accel) / velocity(+accel) / accel control and
  any other combination makes GUIDED stop (mode_guided "init(true)");
* yaw: a setpoint's yaw (and yaw rate) is flown (``ModeGuided::set_yaw_state``);
  with both ignored the auto yaw follows WP_YAW_BEHAVIOR (by default: face the
  direction of travel once faster than 5 % of WPNAV_SPEED); the heading target
  slews at ATC_SLEW_YAW; after GUID_TIMEOUT without a setpoint a commanded yaw
  or yaw rate turns into "hold the current heading";
* velocity and acceleration setpoints time out after GUID_TIMEOUT (3 s): the
  vehicle brakes; position targets are held for good;
* GCS failsafe (FS_GCS_ENABLE) counts only HEARTBEATs from SYSID_MYGCS;
* the geofence (FENCE_ENABLE, FENCE_TYPE max altitude and circle) is reported in
  SYS_STATUS as AC_Fence does (present when a fence type is configured, enabled
  only when on and not report-only, healthy unless breached) and a breach runs
  FENCE_ACTION;
* STATUSTEXT longer than 50 bytes goes out in chunks (``GCS::send_textv``).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour
from groundctl.sim import physics as P
from groundctl.sim.fence import inside
from groundctl.sim.vehicle import (
    ACCEPTED,
    FAILED,
    FORCE_MAGIC,
    STATUSTEXT_LEN,
    Setpoint,
    Vehicle,
    as_int,
)


def firmware_text(version: tuple[int, int, int]) -> str:
    """Firmware string of the boot text and the first STATUSTEXT."""
    major, minor, patch = version
    return f"ArduCopter V{major}.{minor}.{patch}-dev (groundctl sim)"

#: Modes that need a position estimate (Mode::requires_GPS()).
_NEEDS_POSITION = frozenset({"GUIDED", "LOITER", "RTL", "AUTO", "POSHOLD", "BRAKE", "CIRCLE",
                             "SMART_RTL", "FOLLOW", "ZIGZAG", "AUTO_RTL", "DRIFT"})
#: Modes from which arming is refused (Mode::allows_arming() false).
_NOT_ARMABLE = frozenset({"LAND", "RTL", "SMART_RTL", "AUTO_RTL", "BRAKE", "CIRCLE", "FOLLOW",
                          "AUTO"})
#: Modes with a user takeoff (Mode::has_user_takeoff()).
_USER_TAKEOFF = frozenset({"GUIDED", "LOITER", "ALT_HOLD", "POSHOLD", "SPORT", "FLOWHOLD"})

#: AC_Fence fence types (FENCE_TYPE bits).
FENCE_ALT_MAX = 1
FENCE_CIRCLE = 2
FENCE_POLYGON = 4
FENCE_ALT_MIN = 8
#: Types that count as present without an upload (AC_Fence::present(): a polygon only
#: once one is uploaded, see ``_fence_present``).
_FENCE_PRESENT = FENCE_ALT_MAX | FENCE_CIRCLE | FENCE_ALT_MIN
#: FENCE_ENABLE enables the configured fences except the floor (enabled on reaching it).
_FENCE_ENABLED_BY_PARAM = FENCE_ALT_MAX | FENCE_CIRCLE | FENCE_POLYGON

#: GCS::send_textv: the text is formatted into 256 bytes and queued in at most this many
#: chunks (the SITL / small-board statustext queue capacity).
_TEXT_MAX = 256
_TEXT_CHUNKS = 7

#: FS_GCS_ENABLE -> the mode the failsafe switches to (SmartRTL is not simulated, so its
#: fallbacks are taken).
_GCS_FAILSAFE_MODE = {1: "RTL", 2: "RTL", 3: "RTL", 4: "LAND", 5: "LAND", 6: "RTL",
                      7: "BRAKE"}
#: FENCE_ACTION -> the mode a breach switches to (0 reports only).
_FENCE_ACTION_MODE = {1: "RTL", 2: "LAND", 3: "RTL", 4: "BRAKE", 5: "LAND"}
#: WP_YAW_BEHAVIOR 3 (face along GPS course) needs this ground speed (YAW_LOOK_AHEAD_MIN_SPEED).
_LOOK_AHEAD_MIN_SPEED = 1.0


class ArduPilotVehicle(Vehicle):
    """A simulated ArduCopter."""

    flavour = Flavour.ARDUPILOT
    foreign_messages = frozenset({mavlink.MAVLINK_MSG_ID_WIND_COV})
    unknown_mode_result = FAILED
    land_mode = "LAND"
    rtl_mode = "RTL"
    boot_mode = "STABILIZE"
    guided_modes: ClassVar[frozenset[str]] = frozenset({"GUIDED", "AUTO", "RTL", "LAND",
                                                        "SMART_RTL"})
    #: What SITL prints on its first serial port while it boots ("\n\nInit %s\n\nFree RAM:
    #: %u\n" of the vehicle's init), before the port speaks MAVLink.
    @property
    def boot_text(self) -> tuple[str, ...]:  # type: ignore[override]
        return (f"Init {firmware_text(self.ph.dyn.firmware)}", "Free RAM: 131072")

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._battery_warned = False
        self.fence_breaches = 0
        """Bitmask of the fence types breached now (FENCE_TYPE bits)."""

    def _is_my_gcs(self, sysid: int) -> bool:
        return sysid == int(self.params["SYSID_MYGCS"])

    def _boot_messages(self, now: float) -> None:
        info = mavlink.MAV_SEVERITY_INFO
        self.statustext(info, firmware_text(self.ph.dyn.firmware))
        self.statustext(info, "Frame: QUAD/X")

    def _on_origin_set(self, now: float) -> None:
        info = mavlink.MAV_SEVERITY_INFO
        self.statustext(info, "EKF3 IMU0 origin set")
        self.statustext(info, "EKF3 IMU0 is using GPS")

    def statustext_chunks(self, text: bytes) -> list[tuple[int, int, bytes]]:
        """GCS::send_textv: a text over 50 bytes gets a fresh non-zero id shared by its
        chunks (chunk_seq 0, 1, ...); the last chunk is shorter than 50 bytes (empty when
        the text fills its chunks exactly), so a receiver knows the text is complete."""
        text = text[:_TEXT_MAX]
        chunk_id = self._next_statustext_id(skip_zero=True) if len(text) > STATUSTEXT_LEN else 0
        chunks: list[tuple[int, int, bytes]] = []
        rest = text
        for seq in range(_TEXT_CHUNKS):
            n = min(STATUSTEXT_LEN, len(rest))
            if seq == _TEXT_CHUNKS - 1 and n == STATUSTEXT_LEN:
                n -= 1  # the last chunk the queue holds must end the text
            chunks.append((chunk_id, seq, rest[:n]))
            if len(rest) < STATUSTEXT_LEN or chunk_id == 0:
                break
            rest = rest[n:]
        return chunks

    # -- facts --------------------------------------------------------------------------------

    def prearm_checks_enabled(self) -> bool:
        return int(self.params["ARMING_CHECK"]) != 0

    def yaw_control(self) -> tuple[float, float]:
        return (math.radians(self.params["ATC_SLEW_YAW"] / 100.0),
                float(self.params["ATC_ANG_YAW_P"]))

    def travel_heading(self) -> float | None:
        """AC_PosControl's yaw target: along the velocity once above 5 % of WPNAV_SPEED
        (WP_YAW_BEHAVIOR 1, 2), or along the ground course above 1 m/s (3)."""
        if not self.heading.face_travel:
            return None
        vned = self.frames.vec_enu_to_ned(self.i, self.ph.vel[self.i])
        north, east = float(vned[0]), float(vned[1])
        speed = math.hypot(north, east)
        if int(self.params["WP_YAW_BEHAVIOR"]) == 3:
            threshold = _LOOK_AHEAD_MIN_SPEED
        else:
            threshold = 0.05 * self.params.si("WPNAV_SPEED")
        if speed <= threshold:
            return None
        return math.atan2(east, north)

    def fence_bits(self, now: float) -> tuple[bool, bool, bool]:
        """AC_Fence::sys_status_present / _enabled / !_failed."""
        configured = int(self.params["FENCE_TYPE"])
        present = bool(configured & self._fence_present())
        enabled = (present and self._fence_enabled_types() != 0
                   and int(self.params["FENCE_ACTION"]) != 0)
        healthy = not (present and self.fence_breaches)
        return present, enabled, healthy

    def _fence_present(self) -> int:
        return _FENCE_PRESENT | (FENCE_POLYGON if self.fence_polygon() is not None else 0)

    def _fence_enabled_types(self) -> int:
        if int(self.params["FENCE_ENABLE"]) != 1:
            return 0
        return int(self.params["FENCE_TYPE"]) & _FENCE_ENABLED_BY_PARAM & self._fence_present()

    def _on_fence_changed(self) -> None:
        self.params.values["FENCE_TOTAL"] = float(len(self.fence.vertices))

    def _auto_yaw(self) -> None:
        """AutoYaw::set_mode_to_default for GUIDED: WP_YAW_BEHAVIOR 0 holds the heading."""
        self.heading.hold()
        self.heading.face_travel = int(self.params["WP_YAW_BEHAVIOR"]) != 0

    # -- commands -----------------------------------------------------------------------------

    def set_mode(self, name: str, now: float) -> int:
        """Copter::set_mode: the checks apply only when armed; returns the MAV_RESULT."""
        if name == self.mode:
            return ACCEPTED  # "return immediately if we are already in the desired mode"
        if self.armed and name in _NEEDS_POSITION and not self.origin_set(now):
            self.statustext(mavlink.MAV_SEVERITY_WARNING,
                            f"Mode change failed: {name} requires position")
            return FAILED
        self.mode = name
        self.setpoint_kind = "none"
        if name == "LAND":
            self.start_land()
        elif name == "RTL":
            self.start_rtl(self._rtl_height())
        else:
            self.hold()
        if name == "GUIDED":
            self._auto_yaw()
        elif name == "RTL" and int(self.params["WP_YAW_BEHAVIOR"]) in (1, 3):
            self._auto_yaw()  # 2 (the default) is "face next waypoint except RTL"
        else:
            self.heading.hold()
        return ACCEPTED

    def _rtl_height(self) -> float:
        """ModeRTL's return height above home (m): RTL_ALT, but not above the altitude
        fence less its margin (a vehicle already higher returns at its height)."""
        height = self.params.si("RTL_ALT")
        if self._fence_enabled_types() & FENCE_ALT_MAX:
            height = min(height, self.params["FENCE_ALT_MAX"] - self.params["FENCE_MARGIN"])
        return height

    def _arm_disarm(self, p: list[float], now: float) -> int:
        forced = as_int(p[1]) == FORCE_MAGIC
        if p[0] == 1:
            if self.armed:
                return ACCEPTED
            checks = not forced and self.prearm_checks_enabled()
            # AP_Arming_Copter::mandatory_checks runs even when forced or with ARMING_CHECK
            # 0: a mode that needs a position needs the estimate.
            needs_position = checks or self.mode in _NEEDS_POSITION
            if needs_position and not self.ready_to_arm(now):
                self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Arm: Need Position Estimate")
                return FAILED
            if not forced and self.mode in _NOT_ARMABLE:
                self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Arm: Mode not armable")
                return FAILED
            self.arm(now)
            self.heading.hold()
            if not forced and not checks:
                self.statustext(mavlink.MAV_SEVERITY_WARNING, "Warning: Arming Checks Disabled")
            return ACCEPTED
        if p[0] == 0:
            if self.flying and not forced:
                return FAILED
            self.disarm(now)
            return ACCEPTED
        return FAILED

    def _takeoff(self, alt: float, now: float) -> int:
        if (not self.armed or self.mode not in _USER_TAKEOFF or self.flying
                or not alt > 0 or self.takeoff_alt is not None):
            return FAILED
        self.start_takeoff(alt)
        return ACCEPTED

    # -- setpoints ----------------------------------------------------------------------------

    def setpoint(self, sp: Setpoint, type_mask: int, now: float) -> None:
        if self.mode != "GUIDED":
            self.setpoints_dropped += 1  # dropped silently: no ACK, no STATUSTEXT
            return
        if not self.flying:
            return  # landed in GUIDED: targets are ignored until a takeoff
        pos, vel, acc = sp.pos is not None, sp.vel is not None, sp.acc is not None
        if pos and vel:
            kind = "posvel"
        elif vel:
            kind = "vel"
        elif acc and not pos:
            kind = "acc"
        elif pos and not acc:
            kind = "pos"
        else:
            kind = "invalid"
        self.last_setpoint = now
        self.setpoint_kind = kind
        if kind == "invalid":
            self.hold()
            self._auto_yaw()  # GUIDED re-initialised
            return
        self.apply_setpoint(sp, now)
        if sp.yaw is not None or sp.yaw_rate is not None:
            self.heading.command(sp.yaw, sp.yaw_rate)
        else:
            self._auto_yaw()

    # -- timers -------------------------------------------------------------------------------

    def _flight_logic(self, now: float) -> None:
        i = self.i
        ph = self.ph
        if self.takeoff_reached():
            self.end_takeoff()
        if self.rtl_phase is not None:
            self._rtl_logic()
        timed_out = (self.mode == "GUIDED" and self.last_setpoint is not None
                     and now - self.last_setpoint > self.params["GUID_TIMEOUT"])
        if timed_out and self.setpoint_kind in ("vel", "acc", "posvel"):
            # mode_guided: "stop rotating if no updates received within timeout":
            # velocity and acceleration targets are zeroed, a position target stays.
            if self.setpoint_kind == "posvel":
                ph.set_target(i, ph.tgt_pos[i].copy(), None, None)
                self.setpoint_kind = "timeout"
            else:
                ph.set_target(i, None, np.zeros(3), None)  # brake on the velocity loop
                self.setpoint_kind = "braking"
        if timed_out and not self.heading.face_travel and (
                self.heading.target is not None or self.heading.target_rate != 0.0):
            self.heading.hold()  # a commanded yaw (RATE / ANGLE_RATE) becomes HOLD
        if self.setpoint_kind == "braking" and np.linalg.norm(ph.vel[i]) < 0.05:
            ph.hold(i)  # stopped: hold here
            self.setpoint_kind = "timeout"
        if self.armed and ph.on_ground[i] and not self.flying:
            landing = ph.mode[i] == P.CTRL_LAND
            delay = self.ph.dyn.land_detect_s if landing else self.params["DISARM_DELAY"]
            if ph.mode[i] == P.CTRL_TRACK and ph.spool[i] > 0:
                pass  # spooling up for a takeoff
            elif (landing or delay > 0) and ph.ground_time[i] >= delay:
                self.disarm(now)
        if ph.mode[i] == P.CTRL_LAND and ph.on_ground[i] and not self.armed:
            ph.mode[i] = P.CTRL_OFF
        self._fence_check(now)
        self._gcs_failsafe(now)
        self._battery_failsafe(now)

    def _fence_check(self, now: float) -> None:
        """AC_Fence::check (max altitude and circle around home) and Copter::fence_check."""
        enabled = self._fence_enabled_types()
        breaches = 0
        if enabled:
            rel = self.ph.est_pos[self.i] - self.home_enu
            if enabled & FENCE_ALT_MAX and rel[2] >= self.params["FENCE_ALT_MAX"]:
                breaches |= FENCE_ALT_MAX
            if enabled & FENCE_CIRCLE and math.hypot(rel[0], rel[1]) >= self.params[
                    "FENCE_RADIUS"]:
                breaches |= FENCE_CIRCLE
            poly = self.fence_polygon()
            pos = self.ph.est_pos[self.i]
            if enabled & FENCE_POLYGON and poly is not None and not inside(
                    poly, float(pos[0]), float(pos[1])):
                breaches |= FENCE_POLYGON
        new = breaches & ~self.fence_breaches
        self.fence_breaches = breaches
        if not new or not self.armed:
            return  # breaches are tracked while disarmed, acted on only when armed
        if self.flying:
            self.statustext(mavlink.MAV_SEVERITY_NOTICE, "Fence Breached")  # Copter::fence_check
        mode = _FENCE_ACTION_MODE.get(int(self.params["FENCE_ACTION"]))
        if mode is None:
            return  # report only
        if not self.flying:
            self.disarm(now)  # "disarm immediately if we think we are on the ground"
        elif self.set_mode(mode, now) != ACCEPTED:
            self.set_mode("LAND", now)

    def _gcs_failsafe(self, now: float) -> None:
        action = int(self.params["FS_GCS_ENABLE"])
        if action == 0 or self.last_gcs_heartbeat is None:
            return
        lost = now - self.last_gcs_heartbeat > self.params["FS_GCS_TIMEOUT"]
        if lost and not self.failsafe and self.armed:
            self.failsafe = True
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "GCS Failsafe")
            if not self.flying:
                self.disarm(now)
            else:
                self.set_mode(_GCS_FAILSAFE_MODE.get(action, "RTL"), now)
        elif not lost and self.failsafe:
            self.failsafe = False
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "GCS Failsafe Cleared")

    def _battery_failsafe(self, now: float) -> None:
        if self._battery_warned:
            return  # once
        volt = self.battery_mv() / 1000.0
        if volt >= self.params["BATT_LOW_VOLT"]:
            return
        self._battery_warned = True
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"Battery 1 is low {volt:.2f}V used")
        action = int(self.params["BATT_FS_LOW_ACT"])
        if self.flying and action == 1:
            self.set_mode("LAND", now)
        elif self.flying and action == 2:
            self.set_mode("RTL", now)
