"""Autopilot parameters the simulator reads, served over the MAVLink parameter protocol.

Only parameters the simulated behaviour actually uses are listed, under the
real autopilots' names and units, so a ground station can tune the failsafes
and delays exactly as on a real vehicle.

Integer encoding differs between the autopilots and matters to clients:
ArduPilot sends an integer's *value* as a float (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST``),
PX4 copies its *bytes* into the float field (``..._PARAM_ENCODE_BYTEWISE``); MAVSDK
and QGroundControl decode PX4 parameters bytewise.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour

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
    """Value at boot."""
    type: int
    """MAV_PARAM_TYPE."""
    doc: str
    """What the simulator does with it."""


ARDUPILOT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("SYSID_THISMAV", 1, INT16, "MAVLink system id (read-only here)"),
    ParamSpec("SYSID_MYGCS", 255, INT16,
              "system id of the ground station whose HEARTBEATs keep the GCS failsafe away"),
    ParamSpec("FS_GCS_ENABLE", 0, INT8,
              "GCS failsafe: 0 off, 1 RTL, 2 continue in AUTO (RTL here), 5 LAND"),
    ParamSpec("FS_GCS_TIMEOUT", 5.0, REAL32, "seconds without GCS HEARTBEAT before the failsafe"),
    ParamSpec("DISARM_DELAY", 10, INT8,
              "seconds armed on the ground without taking off before disarming (0 off)"),
    ParamSpec("GUID_TIMEOUT", 3.0, REAL32,
              "GUIDED velocity/acceleration setpoint timeout (s), then brake"),
    ParamSpec("RTL_ALT", 1500, INT16, "RTL return altitude above home (cm)"),
    ParamSpec("LAND_SPEED", 50, INT16, "final landing descent rate (cm/s)"),
    ParamSpec("WPNAV_SPEED", 1000, REAL32, "horizontal speed limit (cm/s)"),
    ParamSpec("WPNAV_ACCEL", 250, REAL32, "horizontal acceleration limit (cm/s/s)"),
    ParamSpec("BATT_LOW_VOLT", 14.4, REAL32, "low-battery failsafe voltage (V)"),
    ParamSpec("BATT_FS_LOW_ACT", 0, INT8, "low-battery action: 0 none, 1 LAND, 2 RTL"),
)

PX4_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("MAV_SYS_ID", 1, INT32, "MAVLink system id (read-only here)"),
    ParamSpec("COM_OF_LOSS_T", 1.0, REAL32,
              "offboard setpoint loss timeout (s) before the offboard-loss failsafe"),
    ParamSpec("COM_OBL_RC_ACT", 0, INT32,
              "offboard-loss action: 0 position (no RC: hold then land), 3 return, 4 land, 5 hold"),
    ParamSpec("COM_FAIL_ACT_T", 5.0, REAL32,
              "failsafe delay: hold this long before the failsafe action (s)"),
    ParamSpec("NAV_DLL_ACT", 0, INT32, "GCS link-loss action: 0 off, 1 hold, 2 return, 3 land"),
    ParamSpec("COM_DL_LOSS_T", 10, INT32, "GCS link-loss timeout (s)"),
    ParamSpec("COM_DISARM_PRELAND", 10.0, REAL32,
              "disarm after this long armed without taking off (s, 0 off)"),
    ParamSpec("COM_DISARM_LAND", 2.0, REAL32, "disarm this long after landing (s)"),
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, REAL32, "takeoff altitude above home (m)"),
    ParamSpec("RTL_RETURN_ALT", 60.0, REAL32, "return altitude above home (m)"),
    ParamSpec("MPC_LAND_SPEED", 0.7, REAL32, "landing descent rate (m/s)"),
    ParamSpec("COM_LOW_BAT_ACT", 0, INT32, "low-battery action: 0 warning, 2 land, 3 return"),
    ParamSpec("BAT_LOW_THR", 0.15, REAL32, "low-battery threshold (fraction)"),
)


class ParamStore:
    """The parameter values of one vehicle, in declaration order."""

    def __init__(self, flavour: Flavour, sysid: int,
                 overrides: dict[str, float] | None = None) -> None:
        self.flavour = flavour
        specs = ARDUPILOT_PARAMS if flavour is Flavour.ARDUPILOT else PX4_PARAMS
        self.specs: dict[str, ParamSpec] = {s.name: s for s in specs}
        self.values: dict[str, float] = {s.name: float(s.default) for s in specs}
        self.values["SYSID_THISMAV" if flavour is Flavour.ARDUPILOT else "MAV_SYS_ID"] = sysid
        for name, value in (overrides or {}).items():
            if name not in self.specs:
                continue  # the other flavour's parameter in a fleet-wide dict
            self.values[name] = float(value)

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def names(self) -> list[str]:
        """Parameter ids in index order."""
        return list(self.specs)

    def index(self, name: str) -> int:
        """Index of ``name`` (-1 if unknown)."""
        try:
            return self.names().index(name)
        except ValueError:
            return -1

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
        return float(int(wire_value)) if spec.type != REAL32 else float(wire_value)

    def wire(self, name: str) -> tuple[float, int]:
        """``(param_value, param_type)`` for PARAM_VALUE."""
        spec = self.specs[name]
        value = self.values[name]
        if spec.type == REAL32:
            return value, REAL32
        if self.flavour is Flavour.PX4:
            return struct.unpack("<f", struct.pack("<i", int(value)))[0], spec.type
        return float(int(value)), spec.type
