"""ArduCopter behaviour (4.7, as measured on SITL): GUIDED, LAND, RTL, failsafes.

Quirks reproduced on purpose:

* nothing but HEARTBEAT, STATUSTEXT and PARAM_VALUE is sent unasked;
* arming before the EKF has a position is refused with COMMAND_ACK FAILED and
  STATUSTEXT "Arm: Need Position Estimate";
* NAV_TAKEOFF only in GUIDED (or another mode with a user takeoff), armed and
  landed; param7 is metres above home; DISARM_DELAY (10 s) disarms a vehicle
  armed on the ground that does not take off;
* setpoints outside GUIDED are dropped silently (never ACKed); type_mask picks
  position / position+velocity(+accel) / velocity(+accel) / accel control and
  any other combination makes GUIDED stop (mode_guided "init(true)");
* velocity and acceleration setpoints time out after GUID_TIMEOUT (3 s): the
  vehicle brakes; position targets are held for good;
* GCS failsafe (FS_GCS_ENABLE) counts only HEARTBEATs from SYSID_MYGCS.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour
from groundctl.sim import physics as P
from groundctl.sim.vehicle import (
    ACCEPTED,
    FAILED,
    FORCE_MAGIC,
    Setpoint,
    Vehicle,
    as_int,
)

#: Modes that need a position estimate (Mode::requires_GPS()).
_NEEDS_POSITION = frozenset({"GUIDED", "LOITER", "RTL", "AUTO", "POSHOLD", "BRAKE", "CIRCLE",
                             "SMART_RTL", "FOLLOW", "ZIGZAG", "AUTO_RTL", "DRIFT"})
#: Modes from which arming is refused (Mode::allows_arming() false).
_NOT_ARMABLE = frozenset({"LAND", "RTL", "SMART_RTL", "AUTO_RTL", "BRAKE", "CIRCLE", "FOLLOW",
                          "AUTO"})
#: Modes with a user takeoff (Mode::has_user_takeoff()).
_USER_TAKEOFF = frozenset({"GUIDED", "LOITER", "ALT_HOLD", "POSHOLD", "SPORT", "FLOWHOLD"})


class ArduPilotVehicle(Vehicle):
    """A simulated ArduCopter."""

    flavour = Flavour.ARDUPILOT
    unknown_mode_result = FAILED
    land_mode = "LAND"
    rtl_mode = "RTL"
    boot_mode = "STABILIZE"
    guided_modes: ClassVar[frozenset[str]] = frozenset({"GUIDED", "AUTO", "RTL", "LAND",
                                                        "SMART_RTL"})

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._battery_warned = False

    def _is_my_gcs(self, sysid: int) -> bool:
        return sysid == int(self.params["SYSID_MYGCS"])

    def _boot_messages(self, now: float) -> None:
        info = mavlink.MAV_SEVERITY_INFO
        self.statustext(info, "ArduCopter V4.7.0-dev (groundctl sim)")
        self.statustext(info, "Frame: QUAD/X")

    def _on_origin_set(self, now: float) -> None:
        info = mavlink.MAV_SEVERITY_INFO
        self.statustext(info, "EKF3 IMU0 origin set")
        self.statustext(info, "EKF3 IMU0 is using GPS")

    # -- commands -----------------------------------------------------------------------------

    def set_mode(self, name: str, now: float) -> int:
        """Switch to mode ``name`` if its checks pass; returns the MAV_RESULT."""
        if name in _NEEDS_POSITION and not self.origin_set(now):
            self.statustext(mavlink.MAV_SEVERITY_WARNING,
                            f"Mode change to {name} failed: requires position")
            return FAILED
        self.mode = name
        self.setpoint_kind = "none"
        if name == "LAND":
            self.start_land()
        elif name == "RTL":
            self.start_rtl(self.params["RTL_ALT"] / 100.0)
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
                    self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Arm: Need Position Estimate")
                    return FAILED
                if self.mode in _NOT_ARMABLE:
                    self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Arm: Mode not armable")
                    return FAILED
            self.arm(now)
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
            return
        self.apply_setpoint(sp, now)

    # -- timers -------------------------------------------------------------------------------

    def _flight_logic(self, now: float) -> None:
        i = self.i
        ph = self.ph
        if self.takeoff_reached():
            self.end_takeoff()
        if self.rtl_phase is not None:
            self._rtl_logic()
        if (self.mode == "GUIDED" and self.setpoint_kind in ("vel", "acc", "posvel")
                and self.last_setpoint is not None
                and now - self.last_setpoint > self.params["GUID_TIMEOUT"]):
            # mode_guided: "stop rotating if no updates received within timeout":
            # velocity and acceleration targets are zeroed, a position target stays.
            if self.setpoint_kind == "posvel":
                ph.set_target(i, ph.tgt_pos[i].copy(), None, None)
                self.setpoint_kind = "timeout"
            else:
                ph.set_target(i, None, np.zeros(3), None)  # brake on the velocity loop
                self.setpoint_kind = "braking"
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
        self._gcs_failsafe(now)
        self._battery_failsafe(now)

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
            elif action == 5:
                self.set_mode("LAND", now)
            else:
                self.set_mode("RTL", now)
        elif not lost and self.failsafe:
            self.failsafe = False
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "GCS Failsafe Cleared")

    def _battery_failsafe(self, now: float) -> None:
        volt = self.battery_readings()[0] / 1000.0
        if self._battery_warned or volt >= self.params["BATT_LOW_VOLT"]:
            return
        self._battery_warned = True
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"Battery 1 is low {volt:.2f}V used")
        action = int(self.params["BATT_FS_LOW_ACT"])
        if self.flying and action == 1:
            self.set_mode("LAND", now)
        elif self.flying and action == 2:
            self.set_mode("RTL", now)
