"""What standard ground stations see of ``groundctl sim`` (issue 16), over real loopback UDP.

A plain pymavlink ground station (``GcsPeer``), groundctl's own ``FleetLink`` and
MAVSDK talk to the simulator the way they talk to ArduCopter / PX4 SITL: mode
changes before the EKF is ready, SYS_STATUS geofence bits, the parameter list,
chunked STATUSTEXT, offboard / GUIDED yaw, boot text before MAVLink.
"""

from __future__ import annotations

import math
import struct
import time
from typing import Any

import numpy as np
import pytest
from link_fixtures import EventList, eventually, run
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sim_fixtures import GcsPeer, manual_fleet

from groundctl.clock import ScaledClock
from groundctl.link import Flavour, FleetLink
from groundctl.sim import SimConfig, SimFleet
from groundctl.sim.config import ARDUPILOT_DYNAMICS, dynamics_profile
from groundctl.sim.params import ParamStore

AP = Flavour.ARDUPILOT
PX4 = Flavour.PX4
Msg = mavlink.MAVLink_message

POS_ONLY = 0x0DF8  # x, y, z; velocity, acceleration, yaw and yaw rate ignored
POS_YAW = POS_ONLY & ~mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
POS_YAW_RATE = POS_ONLY & ~mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
GEOFENCE = mavlink.MAV_SYS_STATUS_GEOFENCE
ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
GPI = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
LPN = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
SYS_STATUS = mavlink.MAVLINK_MSG_ID_SYS_STATUS
VFR_HUD = mavlink.MAVLINK_MSG_ID_VFR_HUD


def _setpoint(peer: GcsPeer, mask: int, ned: tuple[float, float, float], yaw: float = 0.0,
              yaw_rate: float = 0.0) -> None:
    peer.send(mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, *ned, 0, 0, 0, 0, 0, 0, yaw, yaw_rate), 1)


def _fly_ardupilot(fleet: SimFleet, peer: GcsPeer, alt: float = 5.0) -> None:
    fleet.run_until(max(fleet.time, fleet.config.ready_delay_s + 0.1))
    assert peer.set_mode(1, AP, "GUIDED").result == 0
    assert peer.arm(1).result == 0
    assert peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt).result == 0
    for _ in range(2000):
        fleet.step(fleet.dt)
        if fleet.state(1).estimated_position[2] > alt - 0.1:
            return
    raise AssertionError("the takeoff did not reach its altitude")


def _last(peer: GcsPeer, mtype: str) -> Any:
    peer.poll()
    msgs = peer.all(mtype, 1)
    assert msgs, f"no {mtype} received"
    return msgs[-1]


def _params(fleet: SimFleet, peer: GcsPeer) -> dict[str, Msg]:
    peer.send(mavlink.MAVLink_param_request_list_message(1, 1), 1)
    fleet.step(0.1)
    peer.poll()
    return {m.param_id: m for m in peer.all("PARAM_VALUE", 1)}


def _texts(peer: GcsPeer) -> list[Msg]:
    peer.poll()
    return peer.all("STATUSTEXT", 1)


def _reassemble(chunks: list[Msg], chunk_id: int) -> tuple[str, list[int]]:
    """The text and the chunk_seq values of STATUSTEXT group ``chunk_id``."""
    mine = sorted((m for m in chunks if m.id == chunk_id), key=lambda m: m.chunk_seq)
    return "".join(m.text for m in mine), [m.chunk_seq for m in mine]


# -- 1. ArduCopter takes GUIDED while disarmed, arming waits for the position ------------


def test_guided_right_after_boot_then_arm_when_ready_then_takeoff_climbs() -> None:
    with manual_fleet(1, ekf_origin_delay_s=3.0, ready_delay_s=5.0) as (fleet, peer):
        assert fleet.time < 1.0
        ack = peer.set_mode(1, AP, "GUIDED")  # no position yet: real ArduCopter accepts it
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        hb = peer.wait("HEARTBEAT", 1, lambda m: m.custom_mode == 4, steps=100)
        assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        refusals = 0
        while True:  # what a ground station does: retry ARM until the EKF is ready
            ack = peer.arm(1)
            if ack.result == mavlink.MAV_RESULT_ACCEPTED:
                break
            assert ack.result == mavlink.MAV_RESULT_FAILED
            refusals += 1
            assert fleet.time < 8.0, "arming never accepted"
            fleet.step(0.5)
        assert refusals >= 5 and fleet.time >= 5.0
        reasons = {m.text for m in _texts(peer) if m.text.startswith("Arm")}
        assert reasons == {"Arm: Need Position Estimate"}
        assert peer.set_interval(1, LPN, 10).result == 0
        ack = peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5.0)
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        up = peer.wait("LOCAL_POSITION_NED", 1, lambda m: m.z < -4.8, steps=2000)
        assert abs(up.x) < 0.3 and abs(up.y) < 0.3
        assert fleet.state(1).mode == "GUIDED" and fleet.state(1).armed
        # Asking for GUIDED again mid-climb changes nothing (Copter::set_mode returns
        # at once for the current mode): the climb goes on.
        assert peer.set_mode(1, AP, "GUIDED").result == 0


def test_arming_checks_off_skip_prearm_failures_but_not_the_position_estimate() -> None:
    with manual_fleet(1, ekf_origin_delay_s=1.0, ready_delay_s=2.0,
                      params={"ARMING_CHECK": 0}) as (fleet, peer):
        fleet.refuse_arming(1, reason="PreArm: Gyros inconsistent")
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        assert peer.arm(1).result == mavlink.MAV_RESULT_FAILED  # mandatory: GUIDED needs it
        assert _texts(peer)[-1].text == "Arm: Need Position Estimate"
        fleet.run_until(2.1)
        assert peer.arm(1).result == mavlink.MAV_RESULT_ACCEPTED  # the pre-arm fault skipped
        warning = peer.wait("STATUSTEXT", 1, lambda m: "Disabled" in m.text, steps=5)
        assert warning.text == "Warning: Arming Checks Disabled"
        assert warning.severity == mavlink.MAV_SEVERITY_WARNING
        assert not [m for m in _texts(peer) if "Gyros" in m.text]


# -- 2. SYS_STATUS geofence bits ----------------------------------------------------------


def _fence_bits(fleet: SimFleet, peer: GcsPeer) -> tuple[bool, bool, bool]:
    assert peer.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE, SYS_STATUS).result == 0
    m = peer.wait("SYS_STATUS", 1, steps=5)
    return (bool(m.onboard_control_sensors_present & GEOFENCE),
            bool(m.onboard_control_sensors_enabled & GEOFENCE),
            bool(m.onboard_control_sensors_health & GEOFENCE))


@pytest.mark.parametrize(("params", "bits"), [
    ({}, (True, False, True)),  # FENCE_ENABLE 0: present, not enabled, not breached
    ({"FENCE_ENABLE": 1}, (True, True, True)),
    ({"FENCE_ENABLE": 1, "FENCE_ACTION": 0}, (True, False, True)),  # report only
    ({"FENCE_TYPE": 4}, (False, False, True)),  # a polygon, but none uploaded
])
def test_sys_status_geofence_bits_as_ac_fence_reports_them(
        params: dict[str, float], bits: tuple[bool, bool, bool]) -> None:
    with manual_fleet(1, params=params) as (fleet, peer):
        fleet.run_until(1.5)
        assert _fence_bits(fleet, peer) == bits


def test_fence_breach_clears_the_health_bit_and_returns_then_lands() -> None:
    params = {"FENCE_ENABLE": 1, "FENCE_ALT_MAX": 4.0}
    with manual_fleet(1, params=params) as (fleet, peer):
        fleet.run_until(1.1)
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        assert peer.arm(1).result == 0
        assert peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 8).result == 0
        for _ in range(1500):
            fleet.step(fleet.dt)
            if fleet.state(1).mode != "GUIDED":
                break
        st = fleet.state(1)
        assert st.mode == "RTL" and 3.9 < st.estimated_position[2] < 4.3  # FENCE_ACTION 1
        assert _fence_bits(fleet, peer) == (True, True, False)
        # RTL never climbs on: it brakes the climb it was in (its stopping distance at
        # the vertical acceleration limit) and comes back below the fence.
        climb = max(st.velocity[2], 0.0)
        stop = climb * climb / (2 * ARDUPILOT_DYNAMICS.max_accel_z)
        peak = 0.0
        for _ in range(150):
            fleet.step(fleet.dt * 2)
            peak = max(peak, fleet.state(1).position[2])
        assert peak < st.position[2] + stop + 0.3, (peak, stop)
        for _ in range(100):
            fleet.step(0.1)
            if fleet.state(1).position[2] < 4.0:
                break
        assert fleet.state(1).position[2] < 4.0  # back inside the fence
        for _ in range(60):
            fleet.step(1.0)
            if not fleet.state(1).armed:
                break
        assert fleet.state(1).landed and not fleet.state(1).armed
        assert _fence_bits(fleet, peer) == (True, True, True)


def test_px4_sys_status_has_no_geofence_bits() -> None:
    with manual_fleet(1, flavour=PX4) as (_fleet, peer):
        m = peer.wait("SYS_STATUS", 1, steps=200)  # streamed by default
        assert not m.onboard_control_sensors_present & GEOFENCE
        assert not m.onboard_control_sensors_enabled & GEOFENCE
        assert not m.onboard_control_sensors_health & GEOFENCE


# -- 3. Parameters an operator checks -------------------------------------------------------


#: The names ArduCopter 4.8 gave the parameters below (SI units), and before it (cm, cm/s).
_RENAMED = {"RTL_ALT": "RTL_ALT_M", "RTL_ALT_FINAL": "RTL_ALT_FINAL_M",
            "RTL_SPEED": "RTL_SPEED_MS", "WPNAV_SPEED": "WP_SPD", "WPNAV_SPEED_UP": "WP_SPD_UP",
            "WPNAV_SPEED_DN": "WP_SPD_DN", "WPNAV_ACCEL": "WP_ACC", "WPNAV_RADIUS": "WP_RADIUS_M",
            "LAND_SPEED": "LAND_SPD_MS", "LAND_SPEED_HIGH": "LAND_SPD_HIGH_MS"}


@pytest.mark.parametrize("profile", ["ardupilot-4.8", "ardupilot-4.7"])
def test_ardupilot_parameter_fetch_has_what_an_operator_checks(profile: str) -> None:
    dyn = dynamics_profile(profile)
    new = dyn.firmware >= (4, 8, 0)
    name = (lambda old: _RENAMED.get(old, old)) if new else (lambda old: old)
    unit = 0.01 if new else 1.0  # a renamed parameter's value in m or m/s, not cm
    with manual_fleet(1, dynamics=dyn) as (fleet, peer):
        values = _params(fleet, peer)
        count = values["ARMING_CHECK"].param_count
        assert count == len(values) > 50
        assert sorted(m.param_index for m in values.values()) == list(range(count))
        wanted = {"ARMING_CHECK", "FENCE_ENABLE", "FENCE_TYPE", "FENCE_ACTION",
                  "FENCE_ALT_MAX", "FENCE_RADIUS", "FENCE_MARGIN", "FS_GCS_ENABLE",
                  "FS_GCS_TIMEOUT", "FS_THR_ENABLE", "FS_EKF_ACTION", "FS_EKF_THRESH",
                  "FS_OPTIONS", "FS_CRASH_CHECK", "RTL_ALT", "RTL_ALT_FINAL", "RTL_SPEED",
                  "RTL_LOIT_TIME", "WPNAV_SPEED", "WPNAV_SPEED_UP", "WPNAV_SPEED_DN",
                  "WPNAV_ACCEL", "WPNAV_RADIUS", "LAND_SPEED", "LAND_SPEED_HIGH",
                  "SYSID_THISMAV", "SYSID_MYGCS", "DISARM_DELAY", "GUID_TIMEOUT"}
        assert {name(w) for w in wanted} <= values.keys()
        # Under one name only: a 4.8 vehicle does not answer to the old ones, nor 4.7 to
        # the new (a ground station asking the wrong one gets no PARAM_VALUE).
        other = set(_RENAMED) if new else set(_RENAMED.values())
        assert other.isdisjoint(values)
        real = {"ARMING_CHECK": 1, "FENCE_ENABLE": 0, "FENCE_TYPE": 7, "FENCE_ACTION": 1,
                "FENCE_ALT_MAX": 100, "FENCE_RADIUS": 300, "FENCE_MARGIN": 2,
                "FS_GCS_TIMEOUT": 5, "FS_THR_ENABLE": 1, "FS_EKF_ACTION": 1,
                "FS_EKF_THRESH": 0.8, "FS_OPTIONS": 16, "FS_CRASH_CHECK": 1, "RTL_ALT": 1500,
                "RTL_LOIT_TIME": 5000, "WPNAV_RADIUS": 200, "LAND_SPEED_HIGH": 0,
                "SYSID_MYGCS": 255, "SYSID_THISMAV": 1}
        for old, value in real.items():
            scale = unit if old in _RENAMED else 1.0
            assert values[name(old)].param_value == pytest.approx(value * scale), old
        assert values["ARMING_CHECK"].param_type == mavlink.MAV_PARAM_TYPE_INT32
        assert values["FENCE_ALT_MAX"].param_type == mavlink.MAV_PARAM_TYPE_REAL32
        assert values[name("RTL_ALT")].param_type == (mavlink.MAV_PARAM_TYPE_REAL32 if new
                                                      else mavlink.MAV_PARAM_TYPE_INT32)
        # The dynamics limits report what the simulated vehicle really flies.
        assert values[name("WPNAV_SPEED")].param_value == pytest.approx(
            dyn.max_speed_xy * 100 * unit)
        assert values[name("WPNAV_SPEED_UP")].param_value == pytest.approx(
            dyn.max_speed_up * 100 * unit)
        assert values[name("LAND_SPEED")].param_value == pytest.approx(
            dyn.land_speed * 100 * unit)
        # The version it reports is the one whose names it answers to.
        texts = [m.text for m in _texts(peer)]
        major, minor, patch = dyn.firmware
        assert any(t.startswith(f"ArduCopter V{major}.{minor}.{patch}") for t in texts), texts
        # Read back by index: the same parameter at the same index.
        index = values["FENCE_RADIUS"].param_index
        peer.clear()
        peer.send(mavlink.MAVLink_param_request_read_message(1, 1, b"", index), 1)
        m = peer.wait("PARAM_VALUE", 1, steps=5)
        assert (m.param_id, m.param_index, m.param_count) == ("FENCE_RADIUS", index, count)


def test_a_parameter_override_under_the_other_versions_name_is_taken_in_this_ones() -> None:
    # `groundctl sim --param RTL_ALT=3000` on a 4.8 vehicle (RTL_ALT_M in m), and the
    # other way round.
    new = ParamStore(Flavour.ARDUPILOT, 1, {"RTL_ALT": 3000, "WPNAV_SPEED": 800},
                     dynamics_profile("ardupilot-4.8"))
    assert (new["RTL_ALT_M"], new["WP_SPD"], new.si("RTL_ALT")) == (30.0, 8.0, 30.0)
    old = ParamStore(Flavour.ARDUPILOT, 1, {"RTL_ALT_M": 12.5},
                     dynamics_profile("ardupilot-4.7"))
    assert (old["RTL_ALT"], old.si("RTL_ALT")) == (1250, 12.5)


@pytest.mark.parametrize("profile", ["ardupilot-4.8", "ardupilot-4.7"])
def test_rtl_alt_set_by_the_ground_station_is_flown(profile: str) -> None:
    dyn = dynamics_profile(profile)
    param, wire, ptype = ((b"RTL_ALT_M", 8.0, mavlink.MAV_PARAM_TYPE_REAL32)
                          if dyn.firmware >= (4, 8, 0)
                          else (b"RTL_ALT", 800.0, mavlink.MAV_PARAM_TYPE_INT32))
    with manual_fleet(1, dynamics=dyn) as (fleet, peer):
        peer.send(mavlink.MAVLink_param_set_message(1, 1, param, wire, ptype), 1)
        reply = peer.wait("PARAM_VALUE", 1, lambda m: m.param_id == param.decode(), steps=5)
        assert reply.param_value == wire
        _fly_ardupilot(fleet, peer, 3.0)
        for _ in range(40):
            _setpoint(peer, POS_ONLY, (6.0, 0.0, -3.0))
            fleet.step(0.1)
        assert peer.command_long(1, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH).result == 0
        peak = 0.0
        for _ in range(80):
            fleet.step(0.5)
            peak = max(peak, fleet.state(1).position[2])
        assert 7.7 < peak < 8.3
        assert fleet.state(1).landed


def test_px4_parameter_fetch_has_what_an_operator_checks() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        values = _params(fleet, peer)
        count = values["NAV_RCL_ACT"].param_count
        assert count == len(values) > 40
        assert sorted(m.param_index for m in values.values()) == list(range(count))
        assert {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "COM_DL_LOSS_T", "COM_DISARM_LAND",
                "COM_RC_LOSS_T", "NAV_RCL_ACT", "NAV_DLL_ACT", "GF_ACTION", "GF_MAX_HOR_DIST",
                "GF_MAX_VER_DIST", "RTL_RETURN_ALT", "RTL_DESCEND_ALT", "MPC_XY_VEL_MAX",
                "MPC_Z_VEL_MAX_UP", "MPC_LAND_SPEED", "MIS_TAKEOFF_ALT",
                "MC_YAWRATE_MAX"} <= values.keys()

        def as_int(m: Msg) -> int:
            assert m.param_type == mavlink.MAV_PARAM_TYPE_INT32
            return int(struct.unpack("<i", struct.pack("<f", m.param_value))[0])

        assert as_int(values["NAV_RCL_ACT"]) == 2 and as_int(values["GF_ACTION"]) == 2
        assert as_int(values["MAV_SYS_ID"]) == 1
        assert values["RTL_RETURN_ALT"].param_value == pytest.approx(60.0)
        assert values["MPC_XY_VEL_MAX"].param_value == pytest.approx(fleet.physics.dyn.max_speed_xy)


# -- 4. STATUSTEXT chunks ------------------------------------------------------------------


def test_ardupilot_long_statustext_is_sent_in_chunks() -> None:
    long = ("PreArm: Gyros inconsistent by 0.31 deg/s (limit 0.09): keep the vehicle still, "
            "recalibrate the IMUs, then reboot")
    exact = "PreArm: " + "x" * 92  # 100 bytes: two full chunks and an empty last one
    assert len(long) > 100 and len(exact) == 100
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(1.1)
        fleet.refuse_arming(1, times=1, reason=long)
        fleet.refuse_arming(1, times=1, reason=exact)
        assert peer.arm(1).result == mavlink.MAV_RESULT_FAILED
        assert peer.arm(1).result == mavlink.MAV_RESULT_FAILED
        chunks = [m for m in _texts(peer) if m.id != 0]
        ids = sorted({m.id for m in chunks})
        assert len(ids) == 2 and 0 not in ids
        text, seqs = _reassemble(chunks, ids[0])
        assert text == long and seqs == [0, 1, 2]
        last = max((m for m in chunks if m.id == ids[0]), key=lambda m: m.chunk_seq)
        assert len(last.text) < 50
        assert all(m.severity == mavlink.MAV_SEVERITY_CRITICAL for m in chunks)
        text, seqs = _reassemble(chunks, ids[1])
        assert text == exact and seqs == [0, 1, 2]
        assert [len(m.text) for m in sorted((m for m in chunks if m.id == ids[1]),
                                            key=lambda m: m.chunk_seq)] == [50, 50, 0]
        # Short texts are not chunked: id 0.
        assert [m.id for m in _texts(peer) if m.text == "Frame: QUAD/X"] == [0]


def test_px4_long_statustext_is_sent_in_chunks() -> None:
    long = "x" * 150
    with manual_fleet(1, flavour=PX4, ready_delay_s=3.0) as (fleet, peer):
        assert peer.arm(1).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        denied = [m for m in _texts(peer) if m.text.startswith("Arming denied")]
        assert len(denied) == 1
        text, seqs = _reassemble(_texts(peer), denied[0].id)
        assert text == "Arming denied: Resolve system health failures first"
        assert seqs == [0, 1]
        fleet.run_until(3.1)
        fleet.refuse_arming(1, reason=long)
        assert peer.arm(1).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        last_id = _texts(peer)[-1].id
        text, seqs = _reassemble(_texts(peer), last_id)
        assert text == long[:126] and seqs == [0, 1, 2]  # a PX4 log line holds 126 bytes
        ids = [m.id for m in _texts(peer) if m.chunk_seq == 0]
        assert ids == sorted(set(ids))  # every PX4 text takes the next id


# -- 5. Yaw --------------------------------------------------------------------------------


def _yaw_streams(peer: GcsPeer) -> None:
    for msgid in (ATTITUDE, GPI, VFR_HUD):
        assert peer.set_interval(1, msgid, 10).result == 0


def test_ardupilot_guided_yaw_is_flown_at_the_slew_rate_and_reported() -> None:
    with manual_fleet(1) as (fleet, peer):
        _fly_ardupilot(fleet, peer, 5.0)
        _yaw_streams(peer)
        for _ in range(5):  # 0.5 s
            _setpoint(peer, POS_YAW, (0.0, 0.0, -5.0), yaw=math.pi / 2)
            fleet.step(0.1)
        turned = math.degrees(fleet.vehicles[0].heading.yaw)
        assert 25.0 < turned <= 30.5  # ATC_SLEW_YAW 60 deg/s
        for _ in range(40):
            _setpoint(peer, POS_YAW, (0.0, 0.0, -5.0), yaw=math.pi / 2)
            fleet.step(0.1)
        att, gpi, hud = _last(peer, "ATTITUDE"), _last(peer, "GLOBAL_POSITION_INT"), \
            _last(peer, "VFR_HUD")
        assert att.yaw == pytest.approx(math.pi / 2, abs=0.01)
        assert abs(gpi.hdg - 9000) <= 50
        assert hud.heading in (89, 90)
        assert abs(att.roll) < 0.02 and abs(att.pitch) < 0.02  # hovering
        assert np.allclose(fleet.state(1).position[:2], (0.0, 0.0), atol=0.2)


def test_ardupilot_yaw_ignored_faces_the_direction_of_travel_by_default() -> None:
    with manual_fleet(1) as (fleet, peer):
        _fly_ardupilot(fleet, peer, 5.0)
        _yaw_streams(peer)
        for _ in range(80):  # to 12 m east, yaw ignored (WP_YAW_BEHAVIOR 2)
            _setpoint(peer, POS_ONLY, (0.0, 12.0, -5.0))
            fleet.step(0.1)
        peer.poll()
        yaws = [m.yaw for m in peer.all("ATTITUDE", 1)]
        assert max(yaws) == pytest.approx(math.pi / 2, abs=0.03)  # nose east while moving
        # Moving forward, the vehicle pitches its nose down (ATTITUDE is body frame).
        fwd = [m for m in peer.all("ATTITUDE", 1) if abs(m.yaw - math.pi / 2) < 0.05]
        assert min(m.pitch for m in fwd) < -0.03


def test_ardupilot_wp_yaw_behavior_0_keeps_the_heading() -> None:
    with manual_fleet(1, params={"WP_YAW_BEHAVIOR": 0}) as (fleet, peer):
        _fly_ardupilot(fleet, peer, 5.0)
        for _ in range(80):
            _setpoint(peer, POS_ONLY, (0.0, 12.0, -5.0))
            fleet.step(0.1)
        assert fleet.state(1).position[0] > 6.0
        assert fleet.vehicles[0].heading.yaw == pytest.approx(0.0, abs=1e-9)


def test_ardupilot_yaw_rate_is_flown_until_guid_timeout_then_held() -> None:
    with manual_fleet(1) as (fleet, peer):
        _fly_ardupilot(fleet, peer, 5.0)
        for _ in range(20):  # 2 s at 0.3 rad/s
            _setpoint(peer, POS_YAW_RATE, (0.0, 0.0, -5.0), yaw_rate=0.3)
            fleet.step(0.1)
        assert fleet.vehicles[0].heading.yaw == pytest.approx(0.6, abs=0.03)
        fleet.step(2.5)  # no more setpoints: still turning within GUID_TIMEOUT (3 s)
        assert fleet.vehicles[0].heading.yaw == pytest.approx(1.35, abs=0.05)
        fleet.step(2.0)
        held = fleet.vehicles[0].heading.yaw
        assert held == pytest.approx(1.5, abs=0.05)
        fleet.step(2.0)
        assert fleet.vehicles[0].heading.yaw == pytest.approx(held, abs=1e-9)


def test_px4_offboard_yaw_is_flown_and_held_when_ignored() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        fleet.run_until(1.1)
        for _ in range(5):
            _setpoint(peer, POS_YAW, (0.0, 0.0, -3.0), yaw=math.pi / 2)
            fleet.step(0.1)
        assert peer.set_mode(1, PX4, "OFFBOARD").result == 0
        assert peer.arm(1).result == 0
        for _ in range(100):
            _setpoint(peer, POS_YAW, (0.0, 0.0, -3.0), yaw=math.pi / 2)
            fleet.step(0.1)
        att, gpi = _last(peer, "ATTITUDE"), _last(peer, "GLOBAL_POSITION_INT")  # default streams
        assert att.yaw == pytest.approx(math.pi / 2, abs=0.01)
        assert abs(gpi.hdg - 9000) <= 50
        assert _last(peer, "VFR_HUD").heading in (89, 90)
        for _ in range(30):  # yaw ignored: PX4 holds the heading
            _setpoint(peer, POS_ONLY, (4.0, 0.0, -3.0))
            fleet.step(0.1)
        assert fleet.state(1).position[1] > 1.0
        assert math.degrees(fleet.vehicles[0].heading.yaw) == pytest.approx(90.0, abs=0.6)


@pytest.mark.slow
def test_mavsdk_offboard_yaw_90_is_flown_and_reported() -> None:
    pytest.importorskip("mavsdk")
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action, ActionError
    from mavsdk.plugins.offboard import Offboard, PositionNedYaw
    from mavsdk.plugins.telemetry import FlightMode, Telemetry

    peer = GcsPeer()  # only to get a free port for MAVSDK to listen on
    port = peer.address[1]
    peer.close()
    cfg = SimConfig(count=1, flavour=PX4, gcs=("127.0.0.1", port), ekf_origin_delay_s=0.5,
                    ready_delay_s=1.0)
    fleet = SimFleet(cfg, ScaledClock(2.0))
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))

    def until(pred: Any, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if pred():
                return
            time.sleep(0.05)
        raise AssertionError(f"MAVSDK: {what} not seen within {timeout} s")

    try:
        sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        fleet.start()
        system = sdk.first_autopilot(10.0)
        assert system is not None
        telemetry, action, offboard = Telemetry(system), Action(system), Offboard(system)
        until(lambda: fleet.time > 1.2, 5, "vehicle ready")
        for _ in range(20):
            try:
                action.arm()
                break
            except ActionError:
                time.sleep(0.2)
        until(telemetry.armed, 5, "armed")
        action.takeoff()
        until(lambda: telemetry.flight_mode() == FlightMode.HOLD, 20, "HOLD after takeoff")
        offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -3.0, 90.0))
        time.sleep(0.3)
        offboard.start()
        until(lambda: telemetry.flight_mode() == FlightMode.OFFBOARD, 5, "OFFBOARD mode")
        until(lambda: abs(telemetry.heading().heading_deg - 90.0) < 1.0, 10, "heading 90")
        assert math.degrees(fleet.vehicles[0].heading.yaw) == pytest.approx(90.0, abs=1.0)
        yaw = telemetry.attitude_euler().yaw_deg
        assert yaw == pytest.approx(90.0, abs=1.5)
    finally:
        sdk.destroy()
        fleet.stop()


# -- 6. Boot text before MAVLink ----------------------------------------------------------


@run
async def test_boot_text_is_counted_as_bad_packets_and_the_vehicle_still_works() -> None:
    events = EventList()
    link = FleetLink(("127.0.0.1", 0), clock=ScaledClock(), events=events,
                     heartbeat_period=0.1, timesync_period=0.1, tick=0.01)
    async with link:
        assert link.local_address is not None
        cfg = SimConfig(count=1, gcs=link.local_address, ekf_origin_delay_s=0.5,
                        ready_delay_s=1.0)
        fleet = SimFleet(cfg, ScaledClock(4.0), boot_text=True)
        try:
            lines = fleet.vehicles[0].boot_lines()
            assert lines[0] == b"\nInit ArduCopter V4.8.0-dev (groundctl sim)\n"
            assert all(b"\xfd" not in x and b"\xfe" not in x for x in lines)  # plain text
            fleet.start()
            found = await link.wait_for_vehicles([1], timeout=5.0)
            assert found[1].flavour is Flavour.ARDUPILOT
            assert link.stats.bad_packets >= len(lines)
            host, port = fleet.addresses[1]
            bad = events.named("bad_packet")
            assert bad and bad[0]["address"] == f"{host}:{port}"
            assert link.address_of(1) == (host, port)
            # The link works as with any vehicle: commands are answered.
            await link.set_mode(1, "GUIDED")
            await link.request_message(1, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            await eventually(lambda: fleet.state(1).mode == "GUIDED", what="GUIDED")
            assert link.stats.bad_packets == len(lines)  # nothing after the boot text
        finally:
            fleet.stop()
