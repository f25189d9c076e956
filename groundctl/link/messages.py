"""Builders for every message groundctl sends: pure, no codec, no socket.

Each function returns a pymavlink message object; :class:`~groundctl.link.codec.Encoder`
turns it into bytes.  The non-obvious parts are the type masks of the
position-target messages and the layout of LED_CONTROL.
"""

from __future__ import annotations

from collections.abc import Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

# POSITION_TARGET_TYPEMASK bits (common.xml): a set bit means "ignore this field".
IGNORE_POSITION = 0x007  # X, Y, Z
IGNORE_VELOCITY = 0x038  # VX, VY, VZ
IGNORE_ACCELERATION = 0x1C0  # AX, AY, AZ
FORCE_SET = 0x200  # accelerations are forces: never wanted here
IGNORE_YAW = 0x400
IGNORE_YAW_RATE = 0x800

#: Position only, yaw and yaw rate ignored.
TYPE_MASK_POSITION = IGNORE_VELOCITY | IGNORE_ACCELERATION | IGNORE_YAW | IGNORE_YAW_RATE
#: Position + velocity feed-forward.
TYPE_MASK_POSITION_VELOCITY = IGNORE_ACCELERATION | IGNORE_YAW | IGNORE_YAW_RATE
#: Position + velocity + acceleration feed-forward.
TYPE_MASK_POSITION_VELOCITY_ACCELERATION = IGNORE_YAW | IGNORE_YAW_RATE

#: MAV_CMD_COMPONENT_ARM_DISARM param2 that overrides pre-arm/disarm checks.
FORCE_MAGIC = 21196

#: LED_CONTROL.custom_bytes is a fixed array of this many bytes.
LED_CUSTOM_BYTES = 24

Vec3 = Sequence[float]


def _vec3(name: str, value: Vec3 | None) -> tuple[float, float, float]:
    if value is None:
        return (0.0, 0.0, 0.0)
    if len(value) != 3:
        raise ValueError(f"`{name}` must have 3 components (north, east, down), got {len(value)}")
    return (float(value[0]), float(value[1]), float(value[2]))


def position_type_mask(
    *,
    position: bool = True,
    velocity: bool = False,
    acceleration: bool = False,
    yaw: bool = False,
    yaw_rate: bool = False,
) -> int:
    """POSITION_TARGET_TYPEMASK for the fields that are set (everything else ignored)."""
    mask = 0
    if not position:
        mask |= IGNORE_POSITION
    if not velocity:
        mask |= IGNORE_VELOCITY
    if not acceleration:
        mask |= IGNORE_ACCELERATION
    if not yaw:
        mask |= IGNORE_YAW
    if not yaw_rate:
        mask |= IGNORE_YAW_RATE
    return mask


def _feed_forward(
    vel_ned: Vec3 | None, acc_ned: Vec3 | None, yaw: float | None, yaw_rate: float | None
) -> tuple[tuple[float, float, float], tuple[float, float, float], int]:
    """Velocity, acceleration (zeros where absent) and the type_mask of a position target."""
    mask = position_type_mask(
        velocity=vel_ned is not None,
        acceleration=acc_ned is not None,
        yaw=yaw is not None,
        yaw_rate=yaw_rate is not None,
    )
    return _vec3("vel_ned", vel_ned), _vec3("acc_ned", acc_ned), mask


def position_target_local_ned(
    target_system: int,
    time_boot_ms: int,
    pos_ned: Vec3,
    vel_ned: Vec3 | None = None,
    acc_ned: Vec3 | None = None,
    yaw: float | None = None,
    yaw_rate: float | None = None,
    target_component: int = 0,
) -> mavlink.MAVLink_set_position_target_local_ned_message:
    """SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED (metres, m/s, m/s², rad).

    The frame's origin is the vehicle's own EKF origin, so the caller converts
    show coordinates per vehicle.
    """
    x, y, z = _vec3("pos_ned", pos_ned)
    (vx, vy, vz), (ax, ay, az), mask = _feed_forward(vel_ned, acc_ned, yaw, yaw_rate)
    return mavlink.MAVLink_set_position_target_local_ned_message(
        int(time_boot_ms) & 0xFFFFFFFF, target_system, target_component,
        mavlink.MAV_FRAME_LOCAL_NED, mask,
        x, y, z, vx, vy, vz, ax, ay, az,
        float(yaw or 0.0), float(yaw_rate or 0.0),
    )  # fmt: skip


def position_target_global_int(
    target_system: int,
    time_boot_ms: int,
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    vel_ned: Vec3 | None = None,
    acc_ned: Vec3 | None = None,
    yaw: float | None = None,
    yaw_rate: float | None = None,
    frame: int = mavlink.MAV_FRAME_GLOBAL_INT,
    target_component: int = 0,
) -> mavlink.MAVLink_set_position_target_global_int_message:
    """SET_POSITION_TARGET_GLOBAL_INT: latitude/longitude in degrees, altitude in metres.

    ``frame`` is MAV_FRAME_GLOBAL_INT (altitude above mean sea level, the
    default), MAV_FRAME_GLOBAL_RELATIVE_ALT_INT (above home) or
    MAV_FRAME_GLOBAL_TERRAIN_ALT_INT.
    """
    allowed = (
        mavlink.MAV_FRAME_GLOBAL_INT,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    )
    if frame not in allowed:
        raise ValueError(f"`frame` must be one of {allowed} (a *_INT global frame), got {frame}")
    if not -90.0 <= lat_deg <= 90.0:
        raise ValueError(f"`lat_deg` must be in -90..90, got {lat_deg}")
    if not -180.0 <= lon_deg <= 180.0:
        raise ValueError(f"`lon_deg` must be in -180..180, got {lon_deg}")
    (vx, vy, vz), (ax, ay, az), mask = _feed_forward(vel_ned, acc_ned, yaw, yaw_rate)
    return mavlink.MAVLink_set_position_target_global_int_message(
        int(time_boot_ms) & 0xFFFFFFFF, target_system, target_component, frame, mask,
        round(lat_deg * 1e7), round(lon_deg * 1e7), float(alt_m),
        vx, vy, vz, ax, ay, az,
        float(yaw or 0.0), float(yaw_rate or 0.0),
    )  # fmt: skip


def led_rgb(
    target_system: int, r: int, g: int, b: int, blink_hz: int | None = None
) -> mavlink.MAVLink_led_control_message:
    """LED_CONTROL setting a colour the way stock ArduPilot reads it.

    Stock ArduPilot ignores ``instance`` and ``pattern`` and reads only
    ``custom_len`` 3 (R, G, B) or 4 (R, G, B, blink rate in Hz) from
    ``custom_bytes``; it never ACKs, so callers resend on change and refresh
    periodically.  ``target_system`` 0 addresses every vehicle.
    """
    for name, value in (("r", r), ("g", g), ("b", b)):
        if not 0 <= int(value) <= 255:
            raise ValueError(f"`{name}` must be in 0..255, got {value}")
    payload = [int(r), int(g), int(b)]
    if blink_hz is not None:
        if not 0 <= int(blink_hz) <= 255:
            raise ValueError(f"`blink_hz` must be in 0..255, got {blink_hz}")
        payload.append(int(blink_hz))
    custom = payload + [0] * (LED_CUSTOM_BYTES - len(payload))
    return mavlink.MAVLink_led_control_message(target_system, 0, 0, 0, len(payload), custom)


def gcs_heartbeat() -> mavlink.MAVLink_heartbeat_message:
    """The 1 Hz ground-station HEARTBEAT (type GCS, autopilot INVALID)."""
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
    )


def timesync(tc1: int, ts1: int) -> mavlink.MAVLink_timesync_message:
    """TIMESYNC: a request has ``tc1`` 0; an answer carries our time in ``tc1``."""
    return mavlink.MAVLink_timesync_message(int(tc1), int(ts1))


def param_set(target_system: int, name: str, value: float
              ) -> mavlink.MAVLink_param_set_message:
    """PARAM_SET of a REAL32 parameter (what ArduPilot's float parameters are)."""
    if not 0 < len(name) <= 16:
        raise ValueError(f"`name` must be 1-16 characters, got {name!r}")
    return mavlink.MAVLink_param_set_message(target_system, 1, name.encode("ascii"),
                                             float(value), mavlink.MAV_PARAM_TYPE_REAL32)


def command_long(
    target_system: int,
    command: int,
    params: Sequence[float] = (),
    *,
    confirmation: int = 0,
    target_component: int = 1,
) -> mavlink.MAVLink_command_long_message:
    """COMMAND_LONG with up to seven parameters (missing ones are 0)."""
    if len(params) > 7:
        raise ValueError(f"`params` holds at most 7 values, got {len(params)}")
    p = [float(v) for v in params] + [0.0] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(
        target_system, target_component, command, confirmation & 0xFF, *p
    )


def message_interval_us(hz: float) -> float:
    """SET_MESSAGE_INTERVAL param2 for a rate: µs between messages, -1 disables."""
    if hz < 0:
        raise ValueError(f"`hz` must be non-negative, got {hz}")
    return -1.0 if hz == 0 else 1e6 / hz


def command_name(command: int) -> str:
    """MAV_CMD_* name of ``command`` (or its number when the dialect does not know it)."""
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"MAV_CMD({command})"


def result_name(result: int) -> str:
    """MAV_RESULT_* name of ``result``."""
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name if entry is not None else f"MAV_RESULT({result})"
