"""The PX4 flavour over real UDP on loopback: modes, OFFBOARD rules, takeoff, failsafes."""

from __future__ import annotations

import struct

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sim_fixtures import manual_fleet

from groundctl.link.flavours import Flavour, decode_mode

PX4 = Flavour.PX4
POS_ONLY = 0x0DF8
TEMP_REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED


def test_heartbeat_and_default_streams_come_unasked() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        fleet.run_until(5.0)
        peer.poll()
        hb = peer.all("HEARTBEAT")[-1]
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
        assert hb.custom_mode == (4 << 16 | 3 << 24)  # AUTO.LOITER, main/sub packed
        assert decode_mode(PX4, hb.base_mode, hb.custom_mode) == "AUTO.LOITER"
        assert 20 <= len(peer.all("GLOBAL_POSITION_INT")) <= 25  # 5 Hz
        assert peer.all("SYS_STATUS") and peer.all("EXTENDED_SYS_STATE")


def test_arming_refused_before_ready() -> None:
    with manual_fleet(1, flavour=PX4, ready_delay_s=3.0) as (fleet, peer):
        assert peer.arm(1).result == TEMP_REJECTED
        assert peer.wait("STATUSTEXT", 1, lambda m: "Arming denied" in m.text, steps=5)
        fleet.run_until(3.1)
        assert peer.arm(1).result == 0


def test_offboard_refused_without_setpoints_then_accepted_with_a_stream() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        fleet.run_until(1.1)
        assert peer.set_mode(1, PX4, "OFFBOARD").result == TEMP_REJECTED
        for _ in range(5):
            peer.setpoint_local(1, POS_ONLY, (0.0, 0.0, -3.0))
            fleet.step(0.1)
        assert peer.set_mode(1, PX4, "OFFBOARD").result == 0
        fleet.step(1.0)  # setpoints older than 0.5 s: no longer available
        assert peer.set_mode(1, PX4, "AUTO.LOITER").result == 0
        assert peer.set_mode(1, PX4, "OFFBOARD").result == TEMP_REJECTED


def test_manual_modes_need_rc() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        fleet.run_until(1.1)
        assert peer.set_mode(1, PX4, "POSCTL").result == TEMP_REJECTED


def test_takeoff_goes_to_mis_takeoff_alt_then_loiter() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        fleet.run_until(1.1)
        nan = float("nan")
        ack = peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)
        assert ack.result == TEMP_REJECTED  # not armed
        assert peer.arm(1).result == 0
        ack = peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)
        assert ack.result == 0
        assert fleet.state(1).mode == "AUTO.TAKEOFF"
        fleet.step(10.0)
        st = fleet.state(1)
        assert st.mode == "AUTO.LOITER" and abs(st.position[2] - 2.5) < 0.2


def test_offboard_flight_then_loss_holds_then_lands_and_disarms() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        fleet.run_until(1.1)
        for _ in range(5):
            peer.setpoint_local(1, POS_ONLY, (3.0, 1.0, -4.0))
            fleet.step(0.1)
        assert peer.set_mode(1, PX4, "OFFBOARD").result == 0
        assert peer.arm(1).result == 0  # armed in OFFBOARD: takes off towards the setpoint
        for _ in range(120):
            peer.setpoint_local(1, POS_ONLY, (3.0, 1.0, -4.0))
            fleet.step(0.1)
        assert np.allclose(fleet.state(1).position, (1.0, 3.0, 4.0), atol=0.15)
        t_last = fleet.time
        peer.clear()
        peer.wait("STATUSTEXT", 1, lambda m: "offboard" in m.text, steps=200)
        assert 0.9 <= fleet.time - t_last <= 1.3  # COM_OF_LOSS_T
        assert fleet.state(1).mode == "AUTO.LOITER"
        fleet.step(4.5)
        assert fleet.state(1).mode == "AUTO.LOITER"  # COM_FAIL_ACT_T hold
        fleet.step(1.0)
        assert fleet.state(1).mode == "AUTO.LAND"
        fleet.step(15.0)
        st = fleet.state(1)
        assert st.landed and not st.armed


def test_auto_disarm_without_takeoff_after_com_disarm_preland() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        fleet.run_until(1.1)
        assert peer.arm(1).result == 0
        fleet.step(9.0)
        assert fleet.state(1).armed
        fleet.step(2.0)
        assert not fleet.state(1).armed


def test_params_use_bytewise_integer_encoding() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        peer.send(mavlink.MAVLink_param_request_read_message(1, 1, b"COM_OBL_RC_ACT", -1), 1)
        m = peer.wait("PARAM_VALUE", 1, steps=5)
        assert m.param_type == mavlink.MAV_PARAM_TYPE_INT32
        assert struct.unpack("<i", struct.pack("<f", m.param_value))[0] == 0
        four = struct.unpack("<f", struct.pack("<i", 4))[0]
        peer.send(mavlink.MAVLink_param_set_message(
            1, 1, b"COM_OBL_RC_ACT", four, mavlink.MAV_PARAM_TYPE_INT32), 1)
        m = peer.wait("PARAM_VALUE", 1, steps=5)
        assert struct.unpack("<i", struct.pack("<f", m.param_value))[0] == 4
        assert fleet.vehicles[0].params["COM_OBL_RC_ACT"] == 4


def test_led_control_is_ignored_by_px4() -> None:
    with manual_fleet(1, flavour=PX4) as (fleet, peer):
        peer.send(mavlink.MAVLink_led_control_message(1, 0, 0, 0, 3, [9, 9, 9] + [0] * 21), 1)
        fleet.step(0.1)
        assert fleet.state(1).led == (0, 0, 0)


def test_rtl_returns_home_and_lands() -> None:
    with manual_fleet(1, flavour=PX4, params={"RTL_RETURN_ALT": 6.0}) as (fleet, peer):
        fleet.run_until(1.1)
        for _ in range(5):
            peer.setpoint_local(1, POS_ONLY, (8.0, 0.0, -4.0))
            fleet.step(0.1)
        assert peer.set_mode(1, PX4, "OFFBOARD").result == 0
        assert peer.arm(1).result == 0
        for _ in range(150):
            peer.setpoint_local(1, POS_ONLY, (8.0, 0.0, -4.0))
            fleet.step(0.1)
        assert peer.command_long(1, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH).result == 0
        peak = 0.0
        for _ in range(60):
            fleet.step(1.0)
            peak = max(peak, fleet.state(1).position[2])
        st = fleet.state(1)
        assert peak > 5.5 and st.landed and not st.armed
        assert np.hypot(st.position[0], st.position[1]) < 1.0
