"""The ArduPilot flavour over real UDP on loopback, against what ArduCopter SITL does."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sim_fixtures import GcsPeer, manual_fleet, ready_and_flying, running_fleet, wait_until

from groundctl.clock import ManualClock
from groundctl.link.flavours import Flavour, decode_mode, mode_request
from groundctl.sim import SimFleet

AP = Flavour.ARDUPILOT
POS_ONLY, POS_VEL, POS_VEL_ACC, VEL_ONLY = 0x0DF8, 0x0DC0, 0x0C00, 0x0DC7
LPN = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
GPI = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT


def test_only_heartbeat_and_statustext_come_unasked() -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(30.0)
        peer.poll()
        kinds = {r.msg.get_type() for r in peer.history}
        # TIMESYNC: the vehicle's own clock-sync requests (tc1 = 0) every ~10 s.
        assert kinds <= {"HEARTBEAT", "STATUSTEXT", "TIMESYNC"}
        hbs = peer.all("HEARTBEAT")
        assert 29 <= len(hbs) <= 32  # 1 Hz in simulated time
        hb = hbs[-1]
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert hb.type == mavlink.MAV_TYPE_QUADROTOR
        assert decode_mode(AP, hb.base_mode, hb.custom_mode) == "STABILIZE"
        assert all(m.tc1 == 0 for m in peer.all("TIMESYNC"))
        assert 2 <= len(peer.all("TIMESYNC")) <= 4
        assert peer.history[0].msg.get_header().mlen >= 0 and hb.get_msgbuf()[0] == 0xFD


def test_set_message_interval_is_acked_and_sets_the_rate() -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(1.0)
        ack = peer.set_interval(1, LPN, 10)
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        assert (ack.target_system, ack.target_component) == (255, 190)
        peer.clear()
        fleet.run_until(fleet.time + 5.0)
        peer.poll()
        n = len(peer.all("LOCAL_POSITION_NED"))
        assert 48 <= n <= 52
        assert peer.set_interval(1, LPN, 0).result == 0  # -1 us: stop
        peer.clear()
        fleet.run_until(fleet.time + 2.0)
        peer.poll()
        assert len(peer.all("LOCAL_POSITION_NED")) <= 1


def test_local_position_starts_only_once_the_ekf_origin_is_set() -> None:
    with manual_fleet(1, ekf_origin_delay_s=3.0, ready_delay_s=4.0) as (_fleet, peer):
        assert peer.set_interval(1, LPN, 5).result == 0
        first = peer.wait("LOCAL_POSITION_NED", 1, steps=1000)
        assert first.time_boot_ms >= 3000
        texts = [m.text for m in peer.all("STATUSTEXT")]
        assert "EKF3 IMU0 origin set" in texts


def test_request_data_stream_position_group_is_not_acked() -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(1.0)
        peer.send(mavlink.MAVLink_request_data_stream_message(
            1, 1, mavlink.MAV_DATA_STREAM_POSITION, 4, 1), 1)
        fleet.run_until(4.0)
        peer.poll()
        assert not peer.all("COMMAND_ACK")
        assert 10 <= len(peer.all("LOCAL_POSITION_NED")) <= 13
        assert 10 <= len(peer.all("GLOBAL_POSITION_INT")) <= 13
        assert not peer.all("ATTITUDE")
        peer.send(mavlink.MAVLink_request_data_stream_message(
            1, 1, mavlink.MAV_DATA_STREAM_POSITION, 4, 0), 1)
        fleet.run_until(5.0)
        peer.clear()
        fleet.run_until(7.0)
        peer.poll()
        assert not peer.all("LOCAL_POSITION_NED")


def test_arming_is_refused_until_the_position_estimate_is_ready() -> None:
    with manual_fleet(1, ekf_origin_delay_s=1.0, ready_delay_s=3.0) as (fleet, peer):
        ack = peer.arm(1)
        assert ack.result == mavlink.MAV_RESULT_FAILED
        text = peer.wait("STATUSTEXT", 1, lambda m: "Arm" in m.text, steps=10)
        assert text.text == "Arm: Need Position Estimate"
        assert text.severity == mavlink.MAV_SEVERITY_CRITICAL
        fleet.run_until(3.1)
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        assert peer.arm(1).result == mavlink.MAV_RESULT_ACCEPTED
        hb = peer.wait("HEARTBEAT", 1, lambda m: m.base_mode & 128, steps=100)
        assert decode_mode(AP, hb.base_mode, hb.custom_mode) == "GUIDED"


def test_guided_mode_needs_a_position_only_when_armed() -> None:
    # Copter::set_mode: "allow switching to any mode if disarmed. We rely on the arming
    # check": disarmed, GUIDED is accepted before the EKF has a position.
    with manual_fleet(1, ekf_origin_delay_s=2.0, ready_delay_s=2.0) as (fleet, peer):
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        assert peer.set_mode(1, AP, "STABILIZE").result == 0
        # Forced arming in STABILIZE (a mode without GPS) skips the position check...
        ack = peer.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
        assert ack.result == 0
        # ...and armed, GUIDED needs the position estimate.
        assert peer.set_mode(1, AP, "GUIDED").result == mavlink.MAV_RESULT_FAILED
        text = peer.wait("STATUSTEXT", 1, lambda m: "Mode change" in m.text, steps=5)
        assert text.text == "Mode change failed: GUIDED requires position"
        fleet.run_until(2.1)
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        assert peer.set_mode(1, AP, "LAND").result == 0
        # Unknown custom mode number: refused.
        assert peer.command_long(1, mavlink.MAV_CMD_DO_SET_MODE, 1, 77).result == \
            mavlink.MAV_RESULT_FAILED


def test_vehicle_disarms_itself_without_takeoff_within_the_disarm_delay() -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(1.1)
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        assert peer.arm(1).result == 0
        t_arm = fleet.time
        peer.clear()
        peer.wait("HEARTBEAT", 1, lambda m: m.base_mode & 128, steps=100)
        peer.wait("HEARTBEAT", 1, lambda m: not m.base_mode & 128, steps=1000)
        assert 9.5 <= fleet.time - t_arm <= 11.5
        assert not fleet.state(1).armed


def test_takeoff_refused_unless_armed_in_guided() -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(1.1)
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        ack = peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5)
        assert ack.result == mavlink.MAV_RESULT_FAILED
        assert peer.set_mode(1, AP, "LOITER").result == 0
        assert peer.arm(1).result == 0
        assert peer.set_mode(1, AP, "RTL").result == 0
        ack = peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5)
        assert ack.result == mavlink.MAV_RESULT_FAILED


def test_arm_refused_in_land_mode() -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(1.1)
        assert peer.set_mode(1, AP, "LAND").result == 0
        assert peer.arm(1).result == mavlink.MAV_RESULT_FAILED
        assert peer.wait("STATUSTEXT", 1, lambda m: m.text == "Arm: Mode not armable", steps=5)


def _takeoff(fleet: SimFleet, peer: GcsPeer, alt: float = 5.0) -> None:
    fleet.run_until(max(fleet.time, 1.1))
    assert peer.set_mode(1, AP, "GUIDED").result == 0
    assert peer.arm(1).result == 0
    ack = peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    for _ in range(1500):
        fleet.step(fleet.dt)
        if fleet.state(1).estimated_position[2] > alt - 0.1:
            break
    assert fleet.state(1).position[2] > alt - 0.3


def test_takeoff_then_land_disarms_on_the_ground() -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 5.0)
        assert fleet.state(1).mode == "GUIDED"
        assert not fleet.state(1).landed
        assert peer.set_mode(1, AP, "LAND").result == 0
        t0 = fleet.time
        peer.clear()
        peer.wait("HEARTBEAT", 1, lambda m: not m.base_mode & 128, steps=2000)
        st = fleet.state(1)
        assert st.landed and not st.armed and st.mode == "LAND"
        assert 10.0 < fleet.time - t0 < 16.0


def test_nav_land_command_switches_to_land() -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 3.0)
        assert peer.command_long(1, mavlink.MAV_CMD_NAV_LAND).result == 0
        assert fleet.state(1).mode == "LAND"


def _local(fleet: SimFleet, peer: GcsPeer) -> np.ndarray:
    s = fleet.state(1)
    return fleet.frames.enu_to_ned(0, np.array(s.position))


@pytest.mark.parametrize("mask", [POS_ONLY, POS_VEL, POS_VEL_ACC])
def test_position_setpoints_are_flown_in_local_ned(mask: int) -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 5.0)
        for _ in range(100):  # 10 s at 10 Hz
            peer.setpoint_local(1, mask, (4.0, -3.0, -6.0))
            fleet.step(0.1)
        ned = _local(fleet, peer)
        assert np.allclose(ned, [4.0, -3.0, -6.0], atol=0.1)
        assert not peer.all("COMMAND_ACK") or all(
            m.command != 0 for m in peer.all("COMMAND_ACK"))


def test_velocity_setpoints_time_out_after_3_s_and_the_vehicle_brakes() -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 5.0)
        for _ in range(30):
            peer.setpoint_local(1, VEL_ONLY, vel=(1.0, 0.0, 0.0))
            fleet.step(0.1)
        assert abs(fleet.state(1).velocity[1] - 1.0) < 0.1  # north in ENU
        fleet.step(2.5)
        assert fleet.state(1).velocity[1] > 0.8  # still going before GUID_TIMEOUT
        fleet.step(3.0)
        assert abs(fleet.state(1).velocity[1]) < 0.05
        n1 = _local(fleet, peer)[0]
        fleet.step(4.0)
        assert abs(_local(fleet, peer)[0] - n1) < 0.05


def test_position_is_held_when_position_setpoints_stop() -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 5.0)
        for _ in range(80):
            peer.setpoint_local(1, POS_ONLY, (2.0, 2.0, -5.0))
            fleet.step(0.1)
        fleet.step(10.0)
        p0 = np.array(fleet.state(1).estimated_position)
        fleet.step(4.0)
        p1 = np.array(fleet.state(1).estimated_position)
        # Held: it wanders a couple of centimetres about the point as a real airframe
        # does (SITL's median 2 s drift in a hold: 0.021 m), where one creeping on at
        # even 2 cm/s would have gone 0.08 m.
        assert np.linalg.norm(p1 - p0) < 0.05


def test_setpoints_outside_guided_are_dropped_silently() -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 5.0)
        assert peer.set_mode(1, AP, "LOITER").result == 0
        peer.clear()
        p0 = np.array(fleet.state(1).position)
        for _ in range(30):
            peer.setpoint_local(1, POS_ONLY, (10.0, 0.0, -5.0))
            fleet.step(0.1)
        peer.poll()
        assert np.linalg.norm(np.array(fleet.state(1).position) - p0) < 0.1
        assert not peer.all("COMMAND_ACK")
        assert fleet.state(1).setpoints_dropped == 30


def test_global_int_setpoint() -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 5.0)
        target_enu = np.array([6.0, -4.0, 8.0])
        lat, lon, _alt = fleet.frames.geodetic(target_enu)
        for _ in range(120):
            peer.send(mavlink.MAVLink_set_position_target_global_int_message(
                0, 1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, POS_ONLY,
                round(lat * 1e7), round(lon * 1e7), 8.0, 0, 0, 0, 0, 0, 0, 0, 0), 1)
            fleet.step(0.1)
        assert np.allclose(fleet.state(1).position, target_enu, atol=0.15)


def test_gcs_failsafe_lands_after_5_s_without_heartbeat() -> None:
    with manual_fleet(1, params={"FS_GCS_ENABLE": 5}) as (fleet, peer):
        _takeoff(fleet, peer, 4.0)
        for _ in range(20):
            peer.heartbeat(1)
            fleet.step(0.5)
        assert fleet.state(1).mode == "GUIDED"
        t0 = fleet.time
        peer.wait("STATUSTEXT", 1, lambda m: m.text == "GCS Failsafe", steps=1000)
        assert 4.5 < fleet.time - t0 < 6.0
        assert fleet.state(1).mode == "LAND"


def test_gcs_failsafe_rtl_and_other_gcs_ids_do_not_count() -> None:
    other = GcsPeer(sysid=200)
    with manual_fleet(1, params={"FS_GCS_ENABLE": 1}) as (fleet, peer):
        other.addrs = peer.addrs
        _takeoff(fleet, peer, 4.0)
        peer.heartbeat(1)
        for _ in range(20):
            other.heartbeat(1)  # not SYSID_MYGCS (255): ignored by the failsafe
            fleet.step(0.5)
        assert fleet.state(1).mode == "RTL"
    other.close()


def test_gcs_failsafe_off_by_default() -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer, 4.0)
        peer.heartbeat(1)
        fleet.step(10.0)
        assert fleet.state(1).mode == "GUIDED"


def test_timesync_answers_with_time_since_boot_in_ns() -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(12.34)
        peer.send(mavlink.MAVLink_timesync_message(0, 123456789), 1)
        reply = peer.wait("TIMESYNC", 1, lambda m: m.tc1 != 0, steps=5)
        assert reply.ts1 == 123456789
        assert abs(reply.tc1 / 1e9 - 12.34) < 0.05
        own = peer.all("TIMESYNC", 1)
        requests = [m for m in own if m.tc1 == 0]
        assert len(requests) == 1 and abs(requests[0].ts1 / 1e9 - 10.0) < 0.05


def test_physics_behind_its_clock_answers_timesync_with_the_clock_and_acts_on_arrival(
        ) -> None:
    """A busy machine: the clock ran on 2 s while the physics stood at 5 s.  The vehicle's
    own clock never lags -- a TIMESYNC answer carries the clock's time, not the physics'
    last step (read by the ground station as its clock offset, it dated every sample
    that much wrong) -- and a message is acted on from the step it arrived in, never at
    a step before it (a setpoint taken early flew the vehicle ahead of its plan)."""
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(5.0)
        assert isinstance(fleet.clock, ManualClock)
        fleet.clock.advance(2.0)  # the physics is still at 5 s
        arrived = fleet.clock.now()
        peer.send(mavlink.MAVLink_timesync_message(0, 42), 1)
        req = mode_request(AP, "GUIDED")
        peer.send(mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, req.param1, req.param2, req.param3,
            0, 0, 0, 0), 1)
        reply = peer.wait("TIMESYNC", 1, lambda m: m.ts1 == 42, steps=3)
        assert reply.tc1 / 1e9 == pytest.approx(arrived - fleet.boot_time, abs=1e-6)
        assert fleet.clock.now() - fleet.t > 1.9  # answered while the physics lagged
        assert fleet.state(1).mode != "GUIDED" and not peer.all("COMMAND_ACK", 1)
        peer.wait("COMMAND_ACK", 1, lambda m: m.command == mavlink.MAV_CMD_DO_SET_MODE,
                  steps=200)
        assert fleet.state(1).mode == "GUIDED"
        assert arrived <= fleet.t <= arrived + 2 * fleet.dt


@pytest.mark.parametrize("target", [1, 0])
def test_led_control_rgb_and_blink_never_acked(target: int) -> None:
    with manual_fleet(2) as (fleet, peer):
        def led(sysid: int, target_system: int, data: list[int]) -> None:
            peer.send(mavlink.MAVLink_led_control_message(
                target_system, 0, 0, 0, len(data), data + [0] * (24 - len(data))), sysid)
        led(1, target, [255, 10, 20])
        fleet.step(0.1)
        assert fleet.state(1).led == (255, 10, 20)
        assert fleet.state(1).led_blink_hz == 0
        led(1, target, [1, 2, 3, 4])
        fleet.step(0.1)
        assert fleet.state(1).led == (1, 2, 3) and fleet.state(1).led_blink_hz == 4
        led(1, 2, [9, 9, 9])  # for vehicle 2 but sent to vehicle 1's socket: ignored
        led(1, target, [7, 7, 7, 7, 7])  # custom_len 5: ignored
        fleet.step(0.1)
        assert fleet.state(1).led == (1, 2, 3)
        assert fleet.state(2).led == (0, 0, 0)
        peer.poll()
        assert not peer.all("COMMAND_ACK")


def test_parameters_list_read_set() -> None:
    with manual_fleet(1) as (fleet, peer):
        peer.send(mavlink.MAVLink_param_request_list_message(1, 1), 1)
        fleet.step(0.1)
        peer.poll()
        values = {m.param_id: m for m in peer.all("PARAM_VALUE")}
        assert {"FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "DISARM_DELAY", "GUID_TIMEOUT",
                "SYSID_MYGCS"} <= values.keys()
        count = values["FS_GCS_ENABLE"].param_count
        assert count == len(values)
        assert sorted(m.param_index for m in values.values()) == list(range(count))
        assert values["DISARM_DELAY"].param_value == 10.0
        assert values["DISARM_DELAY"].param_type == mavlink.MAV_PARAM_TYPE_INT8
        peer.clear()
        peer.send(mavlink.MAVLink_param_set_message(
            1, 1, b"DISARM_DELAY", 3.0, mavlink.MAV_PARAM_TYPE_INT8), 1)
        reply = peer.wait("PARAM_VALUE", 1, lambda m: m.param_id == "DISARM_DELAY", steps=5)
        assert reply.param_value == 3.0
        peer.send(mavlink.MAVLink_param_request_read_message(1, 1, b"FS_GCS_TIMEOUT", -1), 1)
        assert peer.wait("PARAM_VALUE", 1, lambda m: m.param_id == "FS_GCS_TIMEOUT",
                         steps=5).param_value == 5.0
        # The new delay takes effect: disarms after 3 s.
        fleet.run_until(1.1)
        assert peer.set_mode(1, AP, "GUIDED").result == 0
        assert peer.arm(1).result == 0
        fleet.step(3.5)
        assert not fleet.state(1).armed


@pytest.mark.parametrize("name", ["AUTOPILOT_VERSION", "HOME_POSITION", "GPS_GLOBAL_ORIGIN",
                                  "SYS_STATUS", "BATTERY_STATUS", "GPS_RAW_INT", "ATTITUDE",
                                  "EXTENDED_SYS_STATE", "SYSTEM_TIME", "GLOBAL_POSITION_INT"])
def test_request_message(name: str) -> None:
    with manual_fleet(1) as (fleet, peer):
        fleet.run_until(1.5)
        msgid = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
        ack = peer.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE, msgid)
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        msg = peer.wait(name, 1, steps=5)
        if name == "AUTOPILOT_VERSION":
            assert msg.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            assert msg.flight_sw_version >> 24 == 4
        if name == "HOME_POSITION":
            assert abs(msg.latitude / 1e7 - fleet.config.origin[0]) < 1e-6
        if name == "SYS_STATUS":
            assert msg.battery_remaining == 100 and msg.voltage_battery > 16000


def test_unsupported_command_is_acked_unsupported() -> None:
    with manual_fleet(1) as (_fleet, peer):
        ack = peer.command_long(1, mavlink.MAV_CMD_DO_FENCE_ENABLE, 1)
        assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED


def test_each_vehicle_has_its_own_ekf_origin() -> None:
    with manual_fleet(2, spacing=10.0) as (fleet, peer):
        fleet.run_until(1.0)
        for sid in (1, 2):
            assert peer.set_interval(sid, LPN, 5).result == 0
            assert peer.set_interval(sid, GPI, 5).result == 0
        fleet.step(1.0)
        peer.poll()
        l1, l2 = peer.all("LOCAL_POSITION_NED", 1)[-1], peer.all("LOCAL_POSITION_NED", 2)[-1]
        assert abs(l1.x) < 0.1 and abs(l1.y) < 0.1 and abs(l2.x) < 0.1 and abs(l2.y) < 0.1
        g1, g2 = peer.all("GLOBAL_POSITION_INT", 1)[-1], peer.all("GLOBAL_POSITION_INT", 2)[-1]
        # Vehicle 2 booted 10 m east of vehicle 1: ~10 m of longitude apart.
        dlon_m = (g2.lon - g1.lon) / 1e7 * 111_320 * np.cos(np.radians(g1.lat / 1e7))
        assert abs(dlon_m - 10.0) < 0.2


@pytest.mark.parametrize("origin", [(47.3977, 8.5456, 488.0), (-35.363261, 149.16523, 584.0),
                                    (0.0, -179.9999, 0.0), (89.5, 15.6, 10.0)])
def test_the_simulators_geodetic_positions_agree_with_pymap3d(origin: tuple[float, ...]) -> None:
    # The simulator converts its own way (closed form through ECEF, for speed and so that
    # a bug shared with the ground station's pymap3d conversion cannot cancel out); both
    # must say the same, to well under a millimetre, over a show field and beyond.
    import pymap3d

    from groundctl.sim.frames import FleetFrames

    frames = FleetFrames.build(origin, np.zeros((3, 3)))
    enu = np.random.default_rng(7).uniform(-3000.0, 3000.0, (500, 3))
    enu[:, 2] = np.linspace(-50.0, 800.0, 500)
    lat, lon, alt = pymap3d.enu2geodetic(enu[:, 0], enu[:, 1], enu[:, 2], *origin)
    ours = frames.geodetic(enu)
    assert np.abs(ours[:, 0] - lat).max() < 1e-10  # degrees: 10 micrometres
    assert np.abs((ours[:, 1] - lon + 180.0) % 360.0 - 180.0).max() < 1e-10
    assert np.abs(ours[:, 2] - alt).max() < 1e-6
    assert frames.geodetic(enu[3]) == pytest.approx(ours[3], abs=1e-12)  # one point


def test_ekf_origin_override() -> None:
    origin = (-35.363261, 149.165230, 584.0)
    shifted = (origin[0] + 10 / 111_320, origin[1], origin[2])  # 10 m north
    with manual_fleet(1, ekf_origins=[shifted]) as (fleet, peer):
        fleet.run_until(1.0)
        assert peer.set_interval(1, LPN, 5).result == 0
        m = peer.wait("LOCAL_POSITION_NED", 1, steps=100)
        assert abs(m.x + 10.0) < 0.1  # the vehicle is 10 m south of its EKF origin


def test_message_signing_rejects_unsigned_and_badly_signed() -> None:
    key = bytes(range(32))
    with manual_fleet(1, signing_key=key, peer=GcsPeer(signing_key=key)) as (fleet, peer):
        fleet.run_until(1.0)
        hb = peer.all("HEARTBEAT", 1)[-1]
        assert hb.get_signed()
        assert peer.set_mode(1, AP, "GUIDED").result == 0  # signed: accepted
        for bad in (GcsPeer(), GcsPeer(signing_key=bytes(32))):
            bad.addrs = peer.addrs
            bad.send(mavlink.MAVLink_command_long_message(
                1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 9, 0, 0, 0, 0, 0), 1)
            fleet.step(0.2)
            bad.poll()
            bad.close()
        peer.poll()
        assert fleet.state(1).mode == "GUIDED"
        assert fleet.state(1).rejected_signature == 2
        assert not [m for m in peer.all("COMMAND_ACK") if m.command == 176 and
                    m.result != 0]


def test_malformed_truncated_and_unknown_packets_are_counted_and_ignored() -> None:
    with manual_fleet(1) as (fleet, peer):
        good = mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0).pack(peer.mav)
        bad_crc = bytearray(good)
        bad_crc[-1] ^= 0xFF
        unknown = bytearray(good)
        unknown[7:10] = struct.pack("<I", 0xABCDE)[:3]  # msgid 0x0ABCDE does not exist
        junk = [b"\x00" * 5, b"hello world", good[:7], good[:-3], bytes(bad_crc), bytes(unknown),
                b"\xfd\xff" + bytes(300), b"\xfe\x09"]
        for data in junk:
            peer.send(None, 1, raw=data)  # type: ignore[arg-type]
        fleet.step(0.1)
        st = fleet.state(1)
        assert st.bad_packets >= len(junk) - 1
        ack = peer.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE,
                                mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == 0  # still answering


def test_nan_command_params_do_not_crash() -> None:
    with manual_fleet(1) as (fleet, peer):
        peer.send(mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, float("nan"), float("nan"), 0, 0, 0, 0, 0), 1)
        peer.setpoint_local(1, POS_ONLY, (float("nan"), 0.0, 0.0))
        fleet.step(0.2)
        assert peer.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE, 148).result == 0


def test_vehicle_replies_to_the_address_it_last_heard_from() -> None:
    with manual_fleet(1) as (fleet, peer):
        other = GcsPeer()
        other.addrs = dict(peer.addrs)
        other.send(mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0), 1)
        fleet.step(0.05)
        other.poll()
        assert other.find("AUTOPILOT_VERSION", 1) is not None
        assert fleet.state(1).gcs_address == other.address
        other.close()


def test_threaded_fleet_at_speed_flies_and_reports() -> None:
    with running_fleet(3, speed=20) as (fleet, peer):
        assert sorted(peer.addrs) == [1, 2, 3]
        assert fleet.running and len(set(fleet.ports)) == 3
        ready_and_flying(fleet, peer, 2, alt=3.0)
        states = {s.sysid: s for s in fleet.snapshot()}
        assert states[2].armed and not states[2].landed
        assert states[1].landed and not states[1].armed
        t0 = time.monotonic()
        sim0 = fleet.time
        lag0 = fleet.clock.now() - fleet.boot_time - sim0  # how far the physics was behind
        wait_until(lambda: fleet.time > sim0 + 10, timeout=60)
        # At x20, never faster than that, but for catching up the lag it had at the start
        # (on a busy machine tens of milliseconds of a descheduled thread are a second of
        # simulated time at x20: measured, not assumed; a busy machine may make it slower,
        # and the speed is a benchmark's figure, benchmarks/bench_sim.py).
        assert fleet.time - sim0 <= 20.0 * (time.monotonic() - t0) + lag0 + 1e-6
