"""Autopilot flavours: how ArduPilot (Copter) and PX4 encode flight modes.

Both report their mode in HEARTBEAT.custom_mode with MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
set in base_mode, and both accept MAV_CMD_DO_SET_MODE with param1 = that flag
(1) and the custom mode in param2 (PX4 also reads the sub-mode from param3).

* ArduCopter: custom_mode is the Copter mode number (GUIDED = 4, LAND = 9, ...).
* PX4: custom_mode is the ``px4_custom_mode`` union from PX4's
  ``src/modules/commander/px4_custom_mode.h``: a little-endian uint32 with
  bytes ``reserved(16 bits) | main_mode(8 bits) | sub_mode(8 bits)``, i.e.
  ``custom_mode = main << 16 | sub << 24``.  DO_SET_MODE carries main_mode in
  param2 and sub_mode in param3.

This module is pure data and arithmetic: the simulator encodes with it, the
link layer decodes with it, so the two can never disagree by construction.
A test pins the numbers against the autopilots' published tables.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

MODE_FLAG_CUSTOM = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED  # 1


class Flavour(enum.StrEnum):
    """The autopilot families groundctl flies and simulates."""

    ARDUPILOT = "ardupilot"
    PX4 = "px4"

    @property
    def mav_autopilot(self) -> int:
        """HEARTBEAT.autopilot value this flavour reports."""
        if self is Flavour.ARDUPILOT:
            return mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        return mavlink.MAV_AUTOPILOT_PX4

    @classmethod
    def from_heartbeat(cls, autopilot: int) -> Flavour | None:
        """Flavour from HEARTBEAT.autopilot, or None for anything else (GCS, generic)."""
        if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
            return cls.ARDUPILOT
        if autopilot == mavlink.MAV_AUTOPILOT_PX4:
            return cls.PX4
        return None


#: ArduCopter flight modes (ArduCopter/mode.h, enum class Mode::Number).
COPTER_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "DRIFT": 11,
    "SPORT": 13,
    "FLIP": 14,
    "AUTOTUNE": 15,
    "POSHOLD": 16,
    "BRAKE": 17,
    "THROW": 18,
    "AVOID_ADSB": 19,
    "GUIDED_NOGPS": 20,
    "SMART_RTL": 21,
    "FLOWHOLD": 22,
    "FOLLOW": 23,
    "ZIGZAG": 24,
    "SYSTEMID": 25,
    "AUTOROTATE": 26,
    "AUTO_RTL": 27,
    "TURTLE": 28,
}
_COPTER_NAMES = {v: k for k, v in COPTER_MODES.items()}


class PX4Main(enum.IntEnum):
    """PX4_CUSTOM_MAIN_MODE."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE = 8
    SIMPLE = 9
    TERMINATION = 10


class PX4Auto(enum.IntEnum):
    """PX4_CUSTOM_SUB_MODE_AUTO (sub-modes of main mode AUTO)."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8
    PRECLAND = 9
    VTOL_TAKEOFF = 10


#: PX4 modes by the names QGroundControl and MAVSDK show.
PX4_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (PX4Main.MANUAL, 0),
    "ALTCTL": (PX4Main.ALTCTL, 0),
    "POSCTL": (PX4Main.POSCTL, 0),
    "ACRO": (PX4Main.ACRO, 0),
    "OFFBOARD": (PX4Main.OFFBOARD, 0),
    "STABILIZED": (PX4Main.STABILIZED, 0),
    "AUTO.READY": (PX4Main.AUTO, PX4Auto.READY),
    "AUTO.TAKEOFF": (PX4Main.AUTO, PX4Auto.TAKEOFF),
    "AUTO.LOITER": (PX4Main.AUTO, PX4Auto.LOITER),
    "AUTO.MISSION": (PX4Main.AUTO, PX4Auto.MISSION),
    "AUTO.RTL": (PX4Main.AUTO, PX4Auto.RTL),
    "AUTO.LAND": (PX4Main.AUTO, PX4Auto.LAND),
    "AUTO.PRECLAND": (PX4Main.AUTO, PX4Auto.PRECLAND),
    "TERMINATION": (PX4Main.TERMINATION, 0),
}
_PX4_NAMES = {(int(m), int(s)): k for k, (m, s) in PX4_MODES.items()}


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """Pack PX4's (main_mode, sub_mode) into HEARTBEAT.custom_mode."""
    return (int(main) & 0xFF) << 16 | (int(sub) & 0xFF) << 24


def px4_split(custom_mode: int) -> tuple[int, int]:
    """Unpack HEARTBEAT.custom_mode into PX4's (main_mode, sub_mode)."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


@dataclass(frozen=True)
class ModeRequest:
    """The DO_SET_MODE parameters that select a mode on a given flavour."""

    param1: float
    """MAV_MODE_FLAG_CUSTOM_MODE_ENABLED."""
    param2: float
    """Custom (ArduPilot) or main (PX4) mode."""
    param3: float
    """PX4 sub-mode; 0 on ArduPilot."""


def mode_request(flavour: Flavour, name: str) -> ModeRequest:
    """DO_SET_MODE parameters for mode ``name`` (``GUIDED``, ``OFFBOARD``, ``AUTO.LAND``...)."""
    key = name.upper()
    if flavour is Flavour.ARDUPILOT:
        if key not in COPTER_MODES:
            raise ValueError(f"`name` {name!r} is not an ArduCopter mode")
        return ModeRequest(MODE_FLAG_CUSTOM, COPTER_MODES[key], 0)
    if key not in PX4_MODES:
        raise ValueError(f"`name` {name!r} is not a PX4 mode")
    main, sub = PX4_MODES[key]
    return ModeRequest(MODE_FLAG_CUSTOM, int(main), int(sub))


def encode_mode(flavour: Flavour, name: str) -> int:
    """HEARTBEAT.custom_mode for mode ``name`` on ``flavour``."""
    req = mode_request(flavour, name)
    if flavour is Flavour.ARDUPILOT:
        return int(req.param2)
    return px4_custom_mode(int(req.param2), int(req.param3))


def decode_mode(flavour: Flavour | None, base_mode: int, custom_mode: int) -> str:
    """Mode name from HEARTBEAT fields, decoded the way ``flavour`` encodes it.

    Unknown numbers come back as ``MODE(n)`` (or ``PX4(main,sub)``) rather than
    raising: a newer autopilot may report a mode this table does not know.
    """
    if not base_mode & MODE_FLAG_CUSTOM:
        return "UNKNOWN"
    if flavour is Flavour.ARDUPILOT:
        return _COPTER_NAMES.get(custom_mode, f"MODE({custom_mode})")
    if flavour is Flavour.PX4:
        main, sub = px4_split(custom_mode)
        if main != PX4Main.AUTO:
            sub = 0  # PX4 leaves stale sub-mode bits outside AUTO
        return _PX4_NAMES.get((main, sub), f"PX4({main},{sub})")
    return f"MODE({custom_mode})"


def mode_from_set_mode(flavour: Flavour, param2: float, param3: float) -> str | None:
    """Mode name requested by DO_SET_MODE (param1 custom flag set), None if unknown."""
    if flavour is Flavour.ARDUPILOT:
        return _COPTER_NAMES.get(int(param2))
    main, sub = int(param2), int(param3)
    if main != PX4Main.AUTO:
        sub = 0
    return _PX4_NAMES.get((main, sub))
