"""Telemetry messages built from a vehicle's state (no I/O: messages out, the codec packs).

Positions reported are the autopilot's *estimate* (truth + GPS error), as a
real EKF reports; LOCAL_POSITION_NED is relative to the vehicle's own EKF
origin, GLOBAL_POSITION_INT is absolute (AMSL) with ``relative_alt`` above home.
The heading (the vehicle's :class:`~groundctl.sim.vehicle.Heading`) is where both
autopilots put it: ATTITUDE.yaw (rad, [-pi, pi)), GLOBAL_POSITION_INT.hdg (cdeg,
0..35999) and VFR_HUD.heading (deg, 0..359); LOCAL_POSITION_NED has no yaw.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeAlias

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour
from groundctl.sim.physics import GRAVITY

if TYPE_CHECKING:
    from groundctl.sim.vehicle import Vehicle

Msg: TypeAlias = mavlink.MAVLink_message

_SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
            | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
            | mavlink.MAV_SYS_STATUS_AHRS | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
            | mavlink.MAV_SYS_STATUS_PREARM_CHECK)
_NEEDS_POSITION = mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_AHRS

_CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                 | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)

#: The FIRMWARE_VERSION_TYPE reported with the calibration's version (Dynamics.firmware).
_VERSION_TYPE = {Flavour.ARDUPILOT: mavlink.FIRMWARE_VERSION_TYPE_DEV,
                 Flavour.PX4: mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL}


def _ms(v: Vehicle, now: float) -> int:
    return int(v.time_since_boot(now) * 1000) & 0xFFFFFFFF


def heartbeat(v: Vehicle, now: float) -> Msg:
    """HEARTBEAT: quadrotor, the flavour's autopilot id, custom mode, armed flag."""
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    if v.armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    if v.guided_flag():
        base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
    status = mavlink.MAV_STATE_ACTIVE if v.armed else mavlink.MAV_STATE_STANDBY
    if v.failsafe:
        status = mavlink.MAV_STATE_CRITICAL
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, v.flavour.mav_autopilot, base, v.custom_mode(), status, 3)


def sys_status(v: Vehicle, now: float) -> Msg:
    """SYS_STATUS: sensors (GPS and AHRS healthy once the EKF has an origin), geofence,
    battery."""
    present = enabled = _SENSORS
    healthy = _SENSORS if v.origin_set(now) else _SENSORS & ~_NEEDS_POSITION
    if not v.ready_to_arm(now):
        healthy &= ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
    fence_present, fence_enabled, fence_healthy = v.fence_bits(now)
    fence = mavlink.MAV_SYS_STATUS_GEOFENCE
    # ArduPilot (GCS_MAVLINK::update_sensor_status_flags) sets each bit on its own: a
    # fence that is off is present but not enabled, and healthy unless breached.
    present |= fence if fence_present else 0
    enabled |= fence if fence_enabled else 0
    healthy |= fence if fence_healthy else 0
    volt, current, pct = v.battery_readings()
    return mavlink.MAVLink_sys_status_message(
        present, enabled, healthy, 250, volt, current, pct, 0, 0, 0, 0, 0, 0)


def battery_status(v: Vehicle, now: float) -> Msg:
    """BATTERY_STATUS: total voltage in cell 0, the others unused (ArduPilot's layout)."""
    volt, current, pct = v.battery_readings()
    cells = [volt] + [65535] * 9
    used_mah = int((1.0 - v.ph.battery[v.i]) * 5000)
    return mavlink.MAVLink_battery_status_message(
        0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 32767, cells,
        current, used_mah, -1, pct)


def _est(v: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    return v.ph.est_pos[v.i], v.ph.ground_vel[v.i]


def _geodetic(v: Vehicle) -> np.ndarray:
    """Vehicle ``v``'s estimated (lat, lon, alt).

    Converted for the whole fleet at once and cached per physics tick: pymap3d on
    one point costs as much as on a thousand, and was most of the telemetry cost.
    """
    frames = v.frames
    cache = frames.geodetic_cache
    if cache is None or cache[0] != v.ph.t:
        cache = (v.ph.t, frames.geodetic(v.ph.est_pos))
        frames.geodetic_cache = cache
    return cache[1][v.i]


def _heading_deg(v: Vehicle) -> float:
    """The heading in degrees, [0, 360)."""
    return math.degrees(v.heading.yaw) % 360.0


def global_position_int(v: Vehicle, now: float) -> Msg:
    """GLOBAL_POSITION_INT: absolute position (AMSL mm), height above home, NED cm/s,
    heading (cdeg)."""
    pos, vel = _est(v)
    lat, lon, alt = _geodetic(v)
    vned = v.frames.vec_enu_to_ned(v.i, vel)
    hdg = round(_heading_deg(v) * 100) % 36000
    return mavlink.MAVLink_global_position_int_message(
        _ms(v, now), round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
        round((pos[2] - v.home_enu[2]) * 1000), round(vned[0] * 100), round(vned[1] * 100),
        round(vned[2] * 100), hdg)


def local_position_ned(v: Vehicle, now: float) -> Msg:
    """LOCAL_POSITION_NED: metres from the vehicle's own EKF origin."""
    pos, vel = _est(v)
    ned = v.frames.enu_to_ned(v.i, pos)
    vned = v.frames.vec_enu_to_ned(v.i, vel)
    return mavlink.MAVLink_local_position_ned_message(
        _ms(v, now), float(ned[0]), float(ned[1]), float(ned[2]),
        float(vned[0]), float(vned[1]), float(vned[2]))


def attitude(v: Vehicle, now: float) -> Msg:
    """ATTITUDE: the heading, and the tilt a multirotor needs for its horizontal
    acceleration (in the body frame: forward acceleration pitches the nose down)."""
    a = v.ph.acc[v.i]
    an = v.frames.vec_enu_to_ned(v.i, a)
    yaw = v.heading.yaw
    cy, sy = math.cos(yaw), math.sin(yaw)
    forward = an[0] * cy + an[1] * sy
    right = -an[0] * sy + an[1] * cy
    lift = GRAVITY - an[2]
    roll = math.atan2(right, lift)
    pitch = -math.atan2(forward, lift)
    return mavlink.MAVLink_attitude_message(_ms(v, now), roll, pitch, yaw, 0.0, 0.0,
                                            v.heading.rate)


#: Throttle a healthy simulated vehicle hovers at (ArduCopter's MOT_THST_HOVER default
#: 0.35), as a fraction of full thrust.
HOVER_THROTTLE = 0.35


def throttle_pct(v: Vehicle) -> int:
    """VFR_HUD.throttle of a flying vehicle, %: the thrust it makes (gravity plus its
    acceleration) over the thrust it can make.  A weak motor or battery (authority
    below 1) hovers higher, which is how a ground station sees it before it falls
    behind (ArduCopter reports its motor output here, and learns a higher
    MOT_THST_HOVER)."""
    a = v.ph.acc[v.i]
    thrust = float(np.linalg.norm(a + np.array([0.0, 0.0, GRAVITY]))) / GRAVITY
    return int(min(100, round(100 * HOVER_THROTTLE * thrust / float(v.ph.authority[v.i]))))


def vfr_hud(v: Vehicle, now: float) -> Msg:
    """VFR_HUD: speeds, heading, throttle, altitude AMSL, climb."""
    _pos, vel = _est(v)
    ground = float(np.hypot(vel[0], vel[1]))
    alt = float(_geodetic(v)[2])
    throttle = throttle_pct(v) if v.flying else 0
    heading = int(_heading_deg(v)) % 360
    return mavlink.MAVLink_vfr_hud_message(ground, ground, heading, throttle, alt,
                                           float(vel[2]))


def gps_raw_int(v: Vehicle, now: float) -> Msg:
    """GPS_RAW_INT: a 3D fix with SITL-like accuracy (RTK float / fixed on corrections)."""
    _, vel = _est(v)
    lat, lon, alt = _geodetic(v)
    fix = v.gps_fix(now)
    cog = int(math.degrees(math.atan2(vel[0], vel[1])) % 360 * 100)
    return mavlink.MAVLink_gps_raw_int_message(
        int(v.time_since_boot(now) * 1e6), fix, round(lat * 1e7), round(lon * 1e7),
        round(alt * 1000), 121, 200, round(float(np.hypot(vel[0], vel[1])) * 100), cog, 10)


def extended_sys_state(v: Vehicle, now: float) -> Msg:
    """EXTENDED_SYS_STATE: multirotor, landed state."""
    return mavlink.MAVLink_extended_sys_state_message(
        mavlink.MAV_VTOL_STATE_UNDEFINED, v.landed_state())


def ekf_status_report(v: Vehicle, now: float) -> Msg:
    """EKF_STATUS_REPORT (ArduPilot): healthy attitude / velocity / position flags once the
    origin is set, small variances."""
    flags = mavlink.EKF_ATTITUDE | mavlink.EKF_VELOCITY_HORIZ | mavlink.EKF_VELOCITY_VERT
    if v.origin_set(now):
        flags |= (mavlink.EKF_POS_HORIZ_REL | mavlink.EKF_POS_HORIZ_ABS | mavlink.EKF_POS_VERT_ABS
                  | mavlink.EKF_PRED_POS_HORIZ_REL | mavlink.EKF_PRED_POS_HORIZ_ABS)
    return mavlink.MAVLink_ekf_status_report_message(flags, 0.05, 0.05, 0.05, 0.02, 0.0, 0.0)


def estimator_status(v: Vehicle, now: float) -> Msg:
    """ESTIMATOR_STATUS (PX4): solution flags and test ratios."""
    flags = mavlink.ESTIMATOR_ATTITUDE | mavlink.ESTIMATOR_VELOCITY_HORIZ \
        | mavlink.ESTIMATOR_VELOCITY_VERT
    if v.origin_set(now):
        flags |= (mavlink.ESTIMATOR_POS_HORIZ_REL | mavlink.ESTIMATOR_POS_HORIZ_ABS
                  | mavlink.ESTIMATOR_POS_VERT_ABS)
    return mavlink.MAVLink_estimator_status_message(
        int(v.time_since_boot(now) * 1e6), flags, 0.1, 0.1, 0.1, 0.1, 0.1, 0.0, 0.5, 0.5)


def wind(v: Vehicle, now: float) -> Msg:
    """WIND (ArduPilot, GCS_MAVLINK::send_wind): where the estimated wind comes *from*
    (degrees), its speed (the whole vector's length) and its vertical part."""
    w = v.frames.vec_enu_to_ned(v.i, v.ph.wind_est[v.i])
    direction = math.degrees(math.atan2(-w[1], -w[0]))
    return mavlink.MAVLink_wind_message(direction, float(np.linalg.norm(w)), float(w[2]))


def wind_cov(v: Vehicle, now: float) -> Msg:
    """WIND_COV (PX4): the estimated air velocity, NED, with its variances."""
    w = v.frames.vec_enu_to_ned(v.i, v.ph.wind_est[v.i])
    return mavlink.MAVLink_wind_cov_message(
        int(v.time_since_boot(now) * 1e6), float(w[0]), float(w[1]), float(w[2]), 0.25, 0.25,
        float(v.ph.pos[v.i][2]), 0.5, 0.5)


def system_time(v: Vehicle, now: float) -> Msg:
    """SYSTEM_TIME: Unix time (from GPS on a real vehicle) and time since boot."""
    unix_us = int((v.unix_at_boot + v.time_since_boot(now)) * 1e6)
    return mavlink.MAVLink_system_time_message(unix_us, _ms(v, now))


def home_position(v: Vehicle, now: float) -> Msg:
    """HOME_POSITION: where the vehicle booted, absolute and in its local frame."""
    lat, lon, alt = v.home_lla
    ned = v.frames.enu_to_ned(v.i, v.home_enu)
    return mavlink.MAVLink_home_position_message(
        round(lat * 1e7), round(lon * 1e7), round(alt * 1000), float(ned[0]), float(ned[1]),
        float(ned[2]), [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(v.time_since_boot(now) * 1e6))


def gps_global_origin(v: Vehicle, now: float) -> Msg:
    """GPS_GLOBAL_ORIGIN: the EKF origin LOCAL_POSITION_NED is relative to."""
    lat, lon, alt = v.frames.ekf_origins[v.i]
    return mavlink.MAVLink_gps_global_origin_message(
        round(lat * 1e7), round(lon * 1e7), round(alt * 1000), int(v.time_since_boot(now) * 1e6))


def autopilot_version(v: Vehicle, now: float) -> Msg:
    """AUTOPILOT_VERSION: capabilities and a firmware version of the imitated autopilot."""
    major, minor, patch = v.ph.dyn.firmware
    kind = _VERSION_TYPE[v.flavour]
    caps = _CAPABILITIES | (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
                            if v.flavour is Flavour.PX4
                            else mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
    version = major << 24 | minor << 16 | patch << 8 | kind
    return mavlink.MAVLink_autopilot_version_message(
        caps, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5A1D0000 + v.sysid)


#: Messages a ground station can stream or request, by id.
BUILDERS: dict[int, Callable[[Vehicle, float], Msg]] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: heartbeat,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: sys_status,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: battery_status,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: global_position_int,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: local_position_ned,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: attitude,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: vfr_hud,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: gps_raw_int,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: extended_sys_state,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: system_time,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: home_position,
    mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: gps_global_origin,
    mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: autopilot_version,
    mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT: ekf_status_report,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: estimator_status,
    mavlink.MAVLINK_MSG_ID_WIND: wind,
    mavlink.MAVLINK_MSG_ID_WIND_COV: wind_cov,
}

#: Messages that exist only once the EKF has an origin (nothing to report before).
NEEDS_ORIGIN = frozenset({
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION, mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN,
})

#: ArduPilot's REQUEST_DATA_STREAM groups (GCS_MAVLink/GCS_Common.cpp stream entries),
#: restricted to the messages this simulator implements.
DATA_STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (
        mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
        mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE),
    mavlink.MAV_DATA_STREAM_POSITION: (
        mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    mavlink.MAV_DATA_STREAM_EXTRA1: (mavlink.MAVLINK_MSG_ID_ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA2: (mavlink.MAVLINK_MSG_ID_VFR_HUD,),
    mavlink.MAV_DATA_STREAM_EXTRA3: (
        mavlink.MAVLINK_MSG_ID_WIND, mavlink.MAVLINK_MSG_ID_SYSTEM_TIME,
        mavlink.MAVLINK_MSG_ID_BATTERY_STATUS),
}
