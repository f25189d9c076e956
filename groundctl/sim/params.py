"""Autopilot parameters, served over the MAVLink parameter protocol.

Each flavour lists the parameters a show operator (or a ground station's
connect-time checks) looks at, under the real autopilot's names, units and
MAV_PARAM_TYPE, with the real defaults: ArduCopter 4.x (``ArduCopter/Parameters.cpp``,
``AC_Fence``, ``AC_WPNav``, ``AP_Arming``), PX4 v1.15 (the modules' parameter
definitions).  Every entry's ``doc`` says whether the simulator *uses* the
value (then setting it changes the behaviour) or only *reports* it.

The flight-dynamics limits (``WPNAV_SPEED``, ``MPC_XY_VEL_MAX``...) start at the
values of the fleet's :class:`~groundctl.sim.config.Dynamics`, so a parameter
fetch says what the simulated vehicle really does; they are reported, not
applied (the physics is configured through ``SimConfig.dynamics``).

Integer encoding differs between the autopilots and matters to clients:
ArduPilot sends an integer's *value* as a float (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST``),
PX4 copies its *bytes* into the float field (``..._PARAM_ENCODE_BYTEWISE``); MAVSDK
and QGroundControl decode PX4 parameters bytewise.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour
from groundctl.link.paramnames import (
    ARDUCOPTER_48_RENAMES,
    ARDUCOPTER_SI_NAMES,
    convert,
    si_name,
)
from groundctl.sim.config import Dynamics

REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32
INT8 = mavlink.MAV_PARAM_TYPE_INT8
INT16 = mavlink.MAV_PARAM_TYPE_INT16


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name (at most 16 characters), default, MAV_PARAM_TYPE, meaning."""

    name: str
    """Parameter id as the autopilot names it."""
    default: float
    """Value at boot (the autopilot's own default unless ``doc`` says otherwise)."""
    type: int
    """MAV_PARAM_TYPE."""
    doc: str
    """Meaning and unit, and what the simulator does with it ("used" or "reported")."""


ARDUPILOT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("SYSID_THISMAV", 1, INT16, "MAVLink system id (read-only here: needs a reboot)"),
    ParamSpec("SYSID_MYGCS", 255, INT16,
              "used: system id of the ground station whose HEARTBEATs keep the GCS "
              "failsafe away"),
    ParamSpec("FRAME_CLASS", 1, INT8, "reported: 1 quad"),
    ParamSpec("FRAME_TYPE", 1, INT8, "reported: 1 X"),
    ParamSpec("ARMING_CHECK", 1, INT32,
              "used: pre-arm checks bitmask, 1 all, 0 none (the mandatory position check "
              "still runs; arming then warns \"Arming Checks Disabled\")"),
    ParamSpec("DISARM_DELAY", 10, INT8,
              "used: seconds armed on the ground without taking off before disarming (0 off)"),
    ParamSpec("ANGLE_MAX", 3000, INT16, "reported: lean-angle limit (cdeg)"),
    ParamSpec("GUID_TIMEOUT", 3.0, REAL32,
              "used: GUIDED velocity/acceleration setpoint timeout (s), then brake"),
    ParamSpec("GUID_OPTIONS", 0, INT32, "reported: GUIDED options bitmask"),
    ParamSpec("WP_YAW_BEHAVIOR", 2, INT8,
              "used: yaw when a GUIDED setpoint ignores yaw: 0 keep heading, 1 and 2 face "
              "the direction of travel, 3 face along the ground course"),
    ParamSpec("ATC_SLEW_YAW", 6000, REAL32, "used: yaw target slew-rate limit (cdeg/s)"),
    ParamSpec("ATC_ANG_YAW_P", 4.5, REAL32, "used: yaw angle gain (1/s)"),
    ParamSpec("FENCE_ENABLE", 0, INT8, "used: geofence 0 off, 1 on"),
    ParamSpec("FENCE_TYPE", 7, INT8,
              "used: fence types bitmask: 1 max altitude, 2 circle around home, 4 polygon "
              "(once uploaded with the mission protocol), 8 min altitude"),
    ParamSpec("FENCE_ACTION", 1, INT8,
              "used: breach action 0 report only, 1 RTL or land, 2 land, 3 SmartRTL or RTL "
              "(RTL here), 4 brake or land, 5 SmartRTL or land (land here)"),
    ParamSpec("FENCE_ALT_MAX", 100.0, REAL32, "used: maximum height above home (m)"),
    ParamSpec("FENCE_ALT_MIN", -10.0, REAL32, "reported: minimum altitude (m)"),
    ParamSpec("FENCE_RADIUS", 300.0, REAL32, "used: circle fence radius around home (m)"),
    ParamSpec("FENCE_MARGIN", 2.0, REAL32, "reported: distance kept from the fence (m)"),
    ParamSpec("FENCE_AUTOENABLE", 0, INT8, "reported: auto-enable (0 off)"),
    ParamSpec("FENCE_OPTIONS", 0, INT16, "reported: fence options bitmask"),
    ParamSpec("FENCE_TOTAL", 0, INT8, "reported: polygon points stored (set by an upload)"),
    ParamSpec("FS_GCS_ENABLE", 0, INT8,
              "used: GCS failsafe 0 off, 1 RTL, 2 RTL (continue in AUTO), 3 SmartRTL or RTL "
              "(RTL here), 4 SmartRTL or land (land here), 5 land, 6 RTL, 7 brake or land"),
    ParamSpec("FS_GCS_TIMEOUT", 5.0, REAL32,
              "used: seconds without GCS HEARTBEAT before the failsafe"),
    ParamSpec("FS_THR_ENABLE", 1, INT8,
              "reported: RC throttle failsafe (1 RTL; the simulated vehicle has no RC)"),
    ParamSpec("FS_THR_VALUE", 975, INT16, "reported: throttle failsafe PWM"),
    ParamSpec("FS_EKF_ACTION", 1, INT8, "reported: EKF failsafe action (1 land)"),
    ParamSpec("FS_EKF_THRESH", 0.8, REAL32, "reported: EKF failsafe variance threshold"),
    ParamSpec("FS_OPTIONS", 16, INT32,
              "reported: failsafe options bitmask (16: continue in pilot-controlled modes "
              "on GCS failsafe)"),
    ParamSpec("FS_CRASH_CHECK", 1, INT8, "reported: crash check (the simulator always "
                                         "disarms on a crash)"),
    ParamSpec("FS_VIBE_ENABLE", 1, INT8, "reported: vibration failsafe"),
    ParamSpec("RTL_ALT", 1500, INT32, "used: RTL return height above home (cm)"),
    ParamSpec("RTL_ALT_FINAL", 0, INT16, "reported: final RTL height (cm, 0 lands)"),
    ParamSpec("RTL_CLIMB_MIN", 0, INT16, "reported: minimum RTL climb (cm)"),
    ParamSpec("RTL_SPEED", 0, INT16, "reported: RTL horizontal speed (cm/s, 0 WPNAV_SPEED)"),
    ParamSpec("RTL_CONE_SLOPE", 3.0, REAL32, "reported: RTL cone slope"),
    ParamSpec("RTL_LOIT_TIME", 5000, INT32, "reported: loiter above home before landing (ms)"),
    ParamSpec("RTL_ALT_TYPE", 0, INT8, "reported: 0 relative to home"),
    ParamSpec("RTL_OPTIONS", 0, INT32, "reported: RTL options bitmask"),
    ParamSpec("WPNAV_SPEED", 1000, REAL32, "reported: horizontal speed limit (cm/s)"),
    ParamSpec("WPNAV_SPEED_UP", 250, REAL32, "reported: climb-rate limit (cm/s)"),
    ParamSpec("WPNAV_SPEED_DN", 150, REAL32, "reported: descent-rate limit (cm/s)"),
    ParamSpec("WPNAV_ACCEL", 250, REAL32, "reported: horizontal acceleration (cm/s/s)"),
    ParamSpec("WPNAV_ACCEL_Z", 100, REAL32, "reported: vertical acceleration (cm/s/s)"),
    ParamSpec("WPNAV_RADIUS", 200, REAL32, "reported: waypoint radius (cm)"),
    ParamSpec("WPNAV_JERK", 1.0, REAL32, "reported: waypoint jerk (m/s/s/s)"),
    ParamSpec("PILOT_SPEED_UP", 250, INT16, "reported: pilot climb rate (cm/s)"),
    ParamSpec("PILOT_SPEED_DN", 0, INT16, "reported: pilot descent rate (cm/s, 0 "
                                          "PILOT_SPEED_UP)"),
    ParamSpec("LAND_SPEED", 50, INT16, "reported: final landing descent rate (cm/s)"),
    ParamSpec("LAND_SPEED_HIGH", 0, INT16,
              "reported: landing descent rate above LAND_ALT_LOW (cm/s, 0 WPNAV_SPEED_DN)"),
    ParamSpec("LAND_ALT_LOW", 1000, INT16, "reported: height of the slow final descent (cm)"),
    ParamSpec("BATT_MONITOR", 4, INT8, "reported: 4 analog voltage and current"),
    ParamSpec("BATT_CAPACITY", 5000, INT32, "reported: pack capacity (mAh; the simulated "
                                            "4S pack)"),
    ParamSpec("BATT_LOW_VOLT", 14.4, REAL32,
              "used: low-battery failsafe voltage (V; ArduCopter's default is 10.5, set here "
              "for the simulated 4S pack)"),
    ParamSpec("BATT_CRT_VOLT", 0.0, REAL32, "reported: critical-battery voltage (V, 0 off)"),
    ParamSpec("BATT_FS_LOW_ACT", 0, INT8, "used: low-battery action: 0 none, 1 LAND, 2 RTL"),
    ParamSpec("BATT_FS_CRT_ACT", 0, INT8, "reported: critical-battery action"),
)

PX4_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("MAV_SYS_ID", 1, INT32, "MAVLink system id (read-only here: needs a reboot)"),
    ParamSpec("MAV_TYPE", 2, INT32, "reported: 2 quadrotor"),
    ParamSpec("COM_OF_LOSS_T", 1.0, REAL32,
              "used: offboard setpoint loss timeout (s) before the offboard-loss failsafe"),
    ParamSpec("COM_OBL_RC_ACT", 0, INT32,
              "used: offboard-loss action: 0 position (no RC: hold then land), 3 return, "
              "4 land, 5 hold"),
    ParamSpec("COM_FAIL_ACT_T", 5.0, REAL32,
              "used: failsafe delay: hold this long before the failsafe action (s)"),
    ParamSpec("NAV_DLL_ACT", 0, INT32,
              "used: GCS link-loss action: 0 off, 1 hold, 2 return, 3 land"),
    ParamSpec("COM_DL_LOSS_T", 10, INT32, "used: GCS link-loss timeout (s)"),
    ParamSpec("NAV_RCL_ACT", 2, INT32, "reported: RC-loss action (2 return; no RC here)"),
    ParamSpec("COM_RC_LOSS_T", 0.5, REAL32, "reported: RC-loss timeout (s)"),
    ParamSpec("COM_RCL_EXCEPT", 0, INT32, "reported: modes exempt from the RC-loss failsafe"),
    ParamSpec("COM_RC_IN_MODE", 3, INT32, "reported: manual control source"),
    ParamSpec("COM_ARM_WO_GPS", 1, INT32, "reported: arming without GPS"),
    ParamSpec("COM_DISARM_PRELAND", 10.0, REAL32,
              "used: disarm after this long armed without taking off (s, 0 off)"),
    ParamSpec("COM_DISARM_LAND", 2.0, REAL32, "used: disarm this long after landing (s)"),
    ParamSpec("COM_LOW_BAT_ACT", 0, INT32,
              "used: low-battery action: 0 warning, 2 land, 3 return"),
    ParamSpec("BAT_LOW_THR", 0.15, REAL32, "used: low-battery threshold (fraction)"),
    ParamSpec("BAT_CRIT_THR", 0.07, REAL32, "reported: critical-battery threshold (fraction)"),
    ParamSpec("BAT_EMERGEN_THR", 0.05, REAL32,
              "reported: emergency-battery threshold (fraction)"),
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, REAL32, "used: takeoff altitude above home (m)"),
    ParamSpec("RTL_RETURN_ALT", 60.0, REAL32, "used: return altitude above home (m)"),
    ParamSpec("RTL_DESCEND_ALT", 30.0, REAL32, "reported: loiter altitude before landing (m)"),
    ParamSpec("RTL_LAND_DELAY", 0.0, REAL32, "reported: hover before landing (s)"),
    ParamSpec("RTL_TYPE", 0, INT32, "reported: 0 return to home"),
    ParamSpec("RTL_CONE_ANG", 45, INT32, "reported: return cone half-angle (deg)"),
    ParamSpec("GF_ACTION", 2, INT32,
              "used: geofence breach action 0 none, 1 warning, 2 hold, 3 return, "
              "4 terminate (disarm here), 5 land"),
    ParamSpec("GF_MAX_HOR_DIST", 0.0, REAL32, "used: maximum distance from home (m, 0 off)"),
    ParamSpec("GF_MAX_VER_DIST", 0.0, REAL32, "used: maximum height above home (m, 0 off)"),
    ParamSpec("GF_ALTMODE", 0, INT32, "reported: geofence altitude reference"),
    ParamSpec("GF_SOURCE", 0, INT32, "reported: geofence position source"),
    ParamSpec("MPC_XY_VEL_MAX", 12.0, REAL32, "reported: horizontal speed limit (m/s)"),
    ParamSpec("MPC_XY_CRUISE", 5.0, REAL32, "reported: mission cruise speed (m/s)"),
    ParamSpec("MPC_Z_VEL_MAX_UP", 3.0, REAL32, "reported: climb-rate limit (m/s)"),
    ParamSpec("MPC_Z_VEL_MAX_DN", 1.5, REAL32, "reported: descent-rate limit (m/s)"),
    ParamSpec("MPC_ACC_HOR", 3.0, REAL32, "reported: horizontal acceleration (m/s²)"),
    ParamSpec("MPC_ACC_HOR_MAX", 5.0, REAL32, "reported: maximum horizontal acceleration (m/s²)"),
    ParamSpec("MPC_ACC_UP_MAX", 4.0, REAL32, "reported: upward acceleration (m/s²)"),
    ParamSpec("MPC_ACC_DOWN_MAX", 3.0, REAL32, "reported: downward acceleration (m/s²)"),
    ParamSpec("MPC_JERK_AUTO", 4.0, REAL32, "reported: jerk in auto modes (m/s³)"),
    ParamSpec("MPC_JERK_MAX", 8.0, REAL32, "reported: maximum jerk (m/s³)"),
    ParamSpec("MPC_TILTMAX_AIR", 45.0, REAL32, "reported: tilt limit in the air (deg)"),
    ParamSpec("MPC_TKO_SPEED", 1.5, REAL32, "reported: takeoff climb rate (m/s)"),
    ParamSpec("MPC_LAND_SPEED", 0.7, REAL32, "reported: landing descent rate (m/s)"),
    ParamSpec("MPC_LAND_ALT1", 10.0, REAL32, "reported: slow-down height when landing (m)"),
    ParamSpec("MPC_LAND_ALT2", 5.0, REAL32, "reported: land-speed height when landing (m)"),
    ParamSpec("MPC_YAWRAUTO_MAX", 45.0, REAL32, "reported: yaw-rate limit in auto modes (deg/s)"),
    ParamSpec("MC_YAWRATE_MAX", 200.0, REAL32, "used: yaw-rate limit (deg/s)"),
    ParamSpec("MC_YAW_P", 2.8, REAL32, "used: yaw angle gain (1/s)"),
    ParamSpec("MC_YAW_WEIGHT", 0.4, REAL32,
              "used: share of the yaw error commanded at once (scales MC_YAW_P)"),
)

#: Parameters that describe the flight dynamics: name -> (Dynamics field, scale to the
#: parameter's unit).  Their boot value is the simulated vehicle's.
DYNAMICS_PARAMS: dict[Flavour, dict[str, tuple[str, float]]] = {
    Flavour.ARDUPILOT: {
        "WPNAV_SPEED": ("max_speed_xy", 100.0),
        "WPNAV_SPEED_UP": ("max_speed_up", 100.0),
        "WPNAV_SPEED_DN": ("max_speed_down", 100.0),
        "WPNAV_ACCEL": ("max_accel_xy", 100.0),
        "LAND_SPEED": ("land_speed", 100.0),
    },
    Flavour.PX4: {
        "MPC_XY_VEL_MAX": ("max_speed_xy", 1.0),
        "MPC_Z_VEL_MAX_UP": ("max_speed_up", 1.0),
        "MPC_Z_VEL_MAX_DN": ("max_speed_down", 1.0),
        "MPC_ACC_HOR": ("max_accel_xy", 1.0),
        "MPC_ACC_UP_MAX": ("max_accel_z", 1.0),
        "MPC_TKO_SPEED": ("takeoff_speed", 1.0),
        "MPC_LAND_SPEED": ("land_speed", 1.0),
    },
}


#: Parameters of the table above that the 4.8 build no longer has under any name found.
ARDUPILOT_48_GONE = frozenset({"WPNAV_JERK", "PILOT_SPEED_UP", "PILOT_SPEED_DN"})


def _renamed(spec: ParamSpec) -> ParamSpec:
    new, scale = ARDUCOPTER_48_RENAMES[spec.name]
    return ParamSpec(new, spec.default / scale, REAL32,
                     f"{spec.doc} [ArduCopter 4.8 name, SI unit: {spec.name} / {scale:g}]")


#: The ArduCopter table under 4.8's names and SI units (see :mod:`groundctl.link.paramnames`).
ARDUPILOT_48_PARAMS: tuple[ParamSpec, ...] = tuple(
    _renamed(s) if s.name in ARDUCOPTER_48_RENAMES else s
    for s in ARDUPILOT_PARAMS if s.name not in ARDUPILOT_48_GONE)


def specs_for(flavour: Flavour, firmware: tuple[int, int, int] | None = None
              ) -> tuple[ParamSpec, ...]:
    """The parameter table of ``flavour`` at version ``firmware`` (None: the names before
    ArduCopter 4.8), in PARAM_VALUE index order."""
    if flavour is not Flavour.ARDUPILOT:
        return PX4_PARAMS
    if firmware is not None and firmware >= ARDUCOPTER_SI_NAMES:
        return ARDUPILOT_48_PARAMS
    return ARDUPILOT_PARAMS


class ParamStore:
    """The parameter values of one vehicle, in declaration order.

    Boot values: the table's defaults, then the dynamics-derived ones (``dynamics``),
    then ``overrides`` (``SimConfig.params``; names of the other flavour are skipped).
    """

    def __init__(self, flavour: Flavour, sysid: int,
                 overrides: Mapping[str, float] | None = None,
                 dynamics: Dynamics | None = None) -> None:
        self.flavour = flavour
        specs = specs_for(flavour, dynamics.firmware if dynamics is not None else None)
        self.specs: dict[str, ParamSpec] = {s.name: s for s in specs}
        self._names = [s.name for s in specs]
        self._index = {name: i for i, name in enumerate(self._names)}
        self.values: dict[str, float] = {s.name: float(s.default) for s in specs}
        self._si_names: dict[str, tuple[str, str | None]] = {}
        """:meth:`si`'s names: asked for -> (held as, the SI-named one to convert to)."""
        self.values["SYSID_THISMAV" if flavour is Flavour.ARDUPILOT else "MAV_SYS_ID"] = sysid
        if dynamics is not None:
            for name, (attr, scale) in DYNAMICS_PARAMS[flavour].items():
                self._put(name, float(getattr(dynamics, attr)) * scale)
        for name, value in (overrides or {}).items():
            self._put(name, float(value))  # the other flavour's names are skipped

    def _held_as(self, name: str) -> str | None:
        """The name this vehicle holds parameter ``name`` under: itself, its name in the
        other ArduCopter version (RTL_ALT_M for RTL_ALT on 4.8), or None."""
        if name in self.specs:
            return name
        renamed = si_name(name) if self.flavour is Flavour.ARDUPILOT else None
        if renamed is None:
            return None
        return next((n for n in renamed[:2] if n in self.specs), None)

    def _put(self, name: str, value: float) -> None:
        """Set ``name`` to ``value`` (in ``name``'s unit) under the name this vehicle
        holds it by; a name it does not know is skipped."""
        held = self._held_as(name)
        if held is not None:
            self.values[held] = self._stored(self.specs[held], convert(name, value, held))

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def si(self, name: str) -> float:
        """The value of the parameter called ``name`` before ArduCopter 4.8, in SI units
        (m, m/s) whichever name this vehicle's firmware gives it: ``si("RTL_ALT")`` is
        RTL_ALT / 100 on 4.7 and RTL_ALT_M on 4.8."""
        resolved = self._si_names.get(name)
        if resolved is None:  # (the names a vehicle holds never change: resolved once)
            held = self._held_as(name)
            if held is None:
                raise KeyError(name)
            renamed = si_name(name)
            resolved = self._si_names[name] = (held, renamed[0] if renamed else None)
        held, unit_name = resolved
        value = self.values[held]
        return convert(held, value, unit_name) if unit_name is not None else value

    def __len__(self) -> int:
        return len(self._names)

    def names(self) -> list[str]:
        """Parameter ids in index order."""
        return list(self._names)

    def index(self, name: str) -> int:
        """Index of ``name`` (-1 if unknown)."""
        return self._index.get(name, -1)

    def set(self, name: str, wire_value: float, wire_type: int) -> bool:
        """Apply a PARAM_SET; False if the parameter is unknown."""
        spec = self.specs.get(name)
        if spec is None:
            return False
        self.values[name] = self.decode(spec, wire_value, wire_type)
        return True

    def decode(self, spec: ParamSpec, wire_value: float, wire_type: int) -> float:
        """The value a PARAM_SET carries, read the way this flavour encodes integers."""
        if (self.flavour is Flavour.PX4 and spec.type != REAL32
                and wire_type in (INT32, INT16, INT8)):
            return float(struct.unpack("<i", struct.pack("<f", wire_value))[0])
        return self._stored(spec, wire_value)

    @staticmethod
    def _stored(spec: ParamSpec, value: float) -> float:
        return float(int(value)) if spec.type != REAL32 else float(value)

    def wire(self, name: str) -> tuple[float, int]:
        """``(param_value, param_type)`` for PARAM_VALUE."""
        spec = self.specs[name]
        value = self.values[name]
        if spec.type == REAL32:
            return value, REAL32
        if self.flavour is Flavour.PX4:
            return struct.unpack("<f", struct.pack("<i", int(value)))[0], spec.type
        return float(int(value)), spec.type
