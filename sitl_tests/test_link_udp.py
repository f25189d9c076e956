"""FleetLink over real UDP on 127.0.0.1 (ephemeral ports) against hand-written peers."""

from __future__ import annotations

import asyncio
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from link_fixtures import EventList, ScriptedAck, VehiclePeer, eventually, run
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import ScaledClock
from groundctl.errors import CommandRefused, CommandTimeout, LinkError
from groundctl.link import Endpoint, Flavour, FleetLink
from groundctl.record.events import EventLog, read_events
from groundctl.record.tlog import TlogWriter

LOOPBACK = ("127.0.0.1", 0)
KEY = bytes(range(32))


def new_link(**kw: Any) -> FleetLink:
    kw.setdefault("clock", ScaledClock())
    kw.setdefault("heartbeat_period", 0.1)
    kw.setdefault("timesync_period", 0.1)
    kw.setdefault("tick", 0.01)
    return FleetLink(LOOPBACK, **kw)


def peer_for(link: FleetLink, sysid: int, flavour: Flavour = Flavour.ARDUPILOT,
             **kw: Any) -> VehiclePeer:
    assert link.local_address is not None
    return VehiclePeer(sysid, link.local_address, flavour, clock=link.clock, **kw)


@run
async def test_vehicles_appear_and_modes_decode_for_both_flavours() -> None:
    events = EventList()
    async with new_link(events=events) as link:
        assert link.local_address is not None and link.local_address[1] != 0
        with peer_for(link, 1, Flavour.ARDUPILOT, mode="GUIDED") as ap, \
             peer_for(link, 2, Flavour.PX4, mode="OFFBOARD") as px4:
            ap.heartbeat()
            px4.heartbeat()
            found = await link.wait_for_vehicles([1, 2], timeout=2.0)
            assert found[1].flavour is Flavour.ARDUPILOT and found[1].mode == "GUIDED"
            assert found[2].flavour is Flavour.PX4 and found[2].mode == "OFFBOARD"
            assert link.address_of(1) == ap.address
            # the ground station heartbeats every known vehicle
            hb = await ap.wait_for("HEARTBEAT")
            assert hb.type == mavlink.MAV_TYPE_GCS and hb.get_srcSystem() == 255
            assert hb.get_srcComponent() == 190
            await px4.wait_for("HEARTBEAT")
        assert {f["system_id"] for f in events.named("vehicle_appeared")} == {1, 2}


@run
async def test_wait_for_vehicles_names_the_missing() -> None:
    async with new_link() as link:
        with peer_for(link, 1) as p:
            p.heartbeat()
            with pytest.raises(LinkError, match=r"no HEARTBEAT from vehicles \[2\]"):
                await link.wait_for_vehicles([1, 2], timeout=0.3)
            assert 1 in await link.wait_for_vehicles(1, timeout=1.0)


@run
async def test_commands_accepted_refused_and_timed_out() -> None:
    events = EventList()
    async with new_link(events=events) as link:
        with peer_for(link, 1, mode="STABILIZE") as p:
            p.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            await link.set_mode(1, "GUIDED")
            assert p.mode == "GUIDED"
            p.script(mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                     ScriptedAck(mavlink.MAV_RESULT_FAILED, "Arm: Need Position Estimate"))
            with pytest.raises(CommandRefused) as info:
                await link.arm(1)
            assert info.value.reason == "Arm: Need Position Estimate"
            assert info.value.result == "MAV_RESULT_FAILED"
            await link.arm(1)
            assert p.armed
            p.script(mavlink.MAV_CMD_NAV_TAKEOFF,
                     ScriptedAck(mavlink.MAV_RESULT_ACCEPTED, in_progress_first=True))
            await link.takeoff(1, 5.0)
            takeoff = p.messages("COMMAND_LONG")[-1]
            assert takeoff.command == mavlink.MAV_CMD_NAV_TAKEOFF and takeoff.param7 == 5.0

            p.script(mavlink.MAV_CMD_REQUEST_MESSAGE, *[ScriptedAck(None)] * 3)
            with pytest.raises(CommandTimeout) as tinfo:
                await link.request_message(1, mavlink.MAVLINK_MSG_ID_HOME_POSITION,
                                           timeout=0.05, retries=2)
            assert tinfo.value.attempts == 3
            sent = [m for m in p.messages("COMMAND_LONG")
                    if m.command == mavlink.MAV_CMD_REQUEST_MESSAGE]
            assert [m.confirmation for m in sent] == [0, 1, 2]
            assert sent[0].param1 == mavlink.MAVLINK_MSG_ID_HOME_POSITION

            p.script(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ScriptedAck(None))  # one lost ACK
            await link.set_message_interval(1, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20,
                                            timeout=0.05)
            iv = [m for m in p.messages("COMMAND_LONG")
                  if m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL]
            assert [(m.confirmation, m.param2) for m in iv] == [(0, 50_000.0), (1, 50_000.0)]
            await link.land(1)
            assert p.mode == "LAND"
        assert events.named("command_refused") and events.named("command_timeout")
        assert any(f["text"] == "Arm: Need Position Estimate" for f in events.named("statustext"))


@run
async def test_timesync_offset_and_answers() -> None:
    async with new_link(timesync_period=0.02) as link:
        with peer_for(link, 1, timesync_offset_s=1234.5) as p:
            p.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            state = link.vehicles[1]
            await eventually(lambda: len(state.timesync.samples) >= 5, what="timesync samples")
            assert state.clock_offset_s == pytest.approx(1234.5, abs=0.01)
            assert state.rtt_s is not None and 0 <= state.rtt_s < 0.05
            # the vehicle's own request (tc1 = 0) gets our time back
            before = round(link.clock.now() * 1e9)
            p.send(p.mav.timesync_encode(0, 4242))
            reply = await p.wait_for("TIMESYNC", lambda m: m.ts1 == 4242 and m.tc1 != 0)
            assert before <= reply.tc1 <= round(link.clock.now() * 1e9)


@run
async def test_a_busy_loop_does_not_lengthen_the_measured_round_trip() -> None:
    # Answers that wait in our socket while our loop is busy are dated from when they
    # arrived (the kernel's stamp): the round trip is the link's, not our backlog's.
    async with new_link(timesync_period=0.02) as link:
        with peer_for(link, 1) as p:
            p.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            state = link.vehicles[1]
            await eventually(lambda: len(state.timesync.samples) >= 3, what="timesync samples")
            before = len(state.timesync.samples)
            transport = link._transports[0]
            send = transport.send
            busy = {"left": 8}

            def send_then_be_busy(data: bytes, addr: tuple[str, int]) -> None:
                send(data, addr)
                if busy["left"] > 0 and data[0] == 0xFD and \
                        int.from_bytes(data[7:10], "little") == mavlink.MAVLINK_MSG_ID_TIMESYNC:
                    busy["left"] -= 1
                    time.sleep(0.2)  # the answer arrives while our loop is busy
            transport.send = send_then_be_busy  # type: ignore[method-assign]
            await eventually(lambda: busy["left"] == 0, timeout=10.0, what="busy spells")
            await eventually(lambda: len(state.timesync.samples) >= before + 5,
                             what="timesync samples after the busy spells")
            rtts = [s.rtt_ns / 1e9 for s in list(state.timesync.samples)[before:]]
            assert max(rtts) < 0.1, rtts


@run
async def test_setpoints_and_led_reach_the_vehicles() -> None:
    async with new_link() as link:
        with peer_for(link, 1) as a, peer_for(link, 2) as b:
            a.heartbeat()
            b.heartbeat()
            await link.wait_for_vehicles([1, 2], 2.0)
            link.send_position_target_local_ned(1, 1500, (1.0, 2.0, -3.0), (0.5, 0.0, 0.0))
            link.send_position_target_global_int(2, 1500, 47.0, 8.0, 500.0)
            link.send_led_rgb(0, 10, 20, 30)
            link.send_led_rgb(2, 255, 0, 0)
            sp = await a.wait_for("SET_POSITION_TARGET_LOCAL_NED")
            assert sp.type_mask == 0x0DC0 and sp.target_system == 1 and sp.x == 1.0
            gi = await b.wait_for("SET_POSITION_TARGET_GLOBAL_INT")
            assert gi.lat_int == 470000000 and gi.type_mask == 0x0DF8
            for peer in (a, b):
                led = await peer.wait_for("LED_CONTROL", lambda m: m.target_system == 0)
                assert list(led.custom_bytes[:3]) == [10, 20, 30] and led.custom_len == 3
            await b.wait_for("LED_CONTROL", lambda m: m.target_system == 2)
            with pytest.raises(LinkError, match="vehicle 9: address unknown"):
                link.send_led_rgb(9, 0, 0, 0)


@run
async def test_garbage_truncation_and_noise_are_counted_and_harmless() -> None:
    events = EventList()
    async with new_link(events=events) as link:
        with peer_for(link, 1) as bad, peer_for(link, 2) as good:
            bad.heartbeat()
            good.heartbeat()
            await link.wait_for_vehicles([1, 2], 2.0)
            rng = np.random.default_rng(1)
            hb = bad.mav.heartbeat_encode(2, 3, 0, 0, 3).pack(bad.mav)
            bad.send_raw(hb[:7])  # truncated
            bad.send_raw(b"\xfd" + b"\xff" * 40)  # a header claiming a long payload
            corrupt = bytearray(hb)
            corrupt[12] ^= 0x55
            bad.send_raw(bytes(corrupt))  # CRC mismatch
            for _ in range(50):
                bad.send_raw(rng.integers(0, 256, int(rng.integers(1, 300)), np.uint8).tobytes())
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
                assert link.local_address is not None
                stranger.sendto(b"hello, not mavlink", link.local_address)
            await eventually(lambda: link.stats.bad_packets >= 53, what="bad packets counted")
            await link.arm(2)  # other vehicles unaffected
            bad.heartbeat()
            good_before = link.vehicles[1].packets
            await eventually(lambda: link.vehicles[1].packets > good_before, what="vehicle 1")
            assert link.vehicles[1].bad_packets >= 3
            assert link._task is not None and not link._task.done()
        # a flood is logged logarithmically, not line by line
        assert 1 <= len(events.named("bad_packet")) <= 20


@run
async def test_unknown_system_id_is_ignored() -> None:
    events = EventList()
    async with new_link(expected_ids={1}, events=events) as link:
        with peer_for(link, 1) as known, peer_for(link, 9) as stranger:
            for _ in range(3):
                stranger.heartbeat()
            known.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            await eventually(lambda: link.stats.unknown_system_packets >= 3, what="unknown")
            assert set(link.vehicles) == {1}
            assert events.named("unknown_vehicle")[0]["system_id"] == 9


@run
async def test_known_id_from_new_address_is_not_hijacked() -> None:
    events = EventList()
    async with new_link(events=events) as link:
        with peer_for(link, 1, mode="GUIDED") as real, peer_for(link, 1, mode="LAND") as imp:
            real.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            imp.heartbeat()
            await eventually(lambda: link.stats.address_conflicts >= 1, what="conflict")
            assert link.vehicles[1].mode == "GUIDED" and link.address_of(1) == real.address
            host, port = imp.address
            assert events.named("address_conflict")[0]["address"] == f"{host}:{port}"
            await link.arm(1)  # commands still go to the real vehicle
            assert real.armed and not imp.armed


@run
async def test_address_change_when_allowed() -> None:
    async with new_link(allow_address_change=True) as link:
        with peer_for(link, 1, mode="GUIDED") as old, peer_for(link, 1, mode="LAND") as new:
            old.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            new.heartbeat()
            await eventually(lambda: link.vehicles[1].mode == "LAND", what="new address")
            assert link.address_of(1) == new.address


@run
async def test_explicit_endpoint_is_contacted_first() -> None:
    clock = ScaledClock()
    async with new_link(clock=clock) as link:
        with peer_for(link, 5) as p:
            link2 = new_link(clock=clock, endpoints=[Endpoint(5, *p.address)])
            async with link2:
                # the peer has never spoken to link2, yet gets its heartbeat
                await p.wait_for("HEARTBEAT", lambda m: m.type == mavlink.MAV_TYPE_GCS)
                p.gcs = link2.local_address  # type: ignore[assignment]
                p.heartbeat()
                await link2.wait_for_vehicles([5], 2.0)
                assert link2.address_of(5) == p.address


@run
async def test_signing_accepts_signed_and_rejects_unsigned() -> None:
    async with new_link(signing_key=KEY) as link:
        with peer_for(link, 1, signing_key=KEY) as signed, peer_for(link, 2) as unsigned, \
             peer_for(link, 3, signing_key=bytes(32)) as wrong_key:
            for p in (signed, unsigned, wrong_key):
                p.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            await eventually(lambda: link.stats.bad_packets >= 2, what="rejections")
            assert set(link.vehicles) == {1}
            hb = await signed.wait_for("HEARTBEAT")  # it verified our signature to parse it
            assert hb.get_signed()
            await link.arm(1)
            assert signed.armed


@run
async def test_lost_and_found() -> None:
    events = EventList()
    async with new_link(lost_timeout=0.15, events=events) as link:
        with peer_for(link, 1) as p:
            p.heartbeat_period = 0.02
            await link.wait_for_vehicles([1], 2.0)
            p.muted = True  # no heartbeats, no TIMESYNC answers
            await eventually(lambda: link.vehicles[1].lost, what="lost")
            assert events.named("vehicle_lost")[0]["system_id"] == 1
            p.muted = False
            await eventually(lambda: not link.vehicles[1].lost, what="found")
            assert events.named("vehicle_found")


@run
async def test_tlog_records_both_directions_and_events_file(tmp_path: Path) -> None:
    tlog_path, events_path = tmp_path / "link.tlog", tmp_path / "events.jsonl"
    clock = ScaledClock()
    tlog = TlogWriter(tlog_path)
    events = EventLog(events_path, clock.now)
    try:
        async with new_link(clock=clock, tlog=tlog, events=events) as link:
            with peer_for(link, 1) as p:
                p.statustext("hello")
                p.heartbeat()
                await link.wait_for_vehicles([1], 2.0)
                await link.arm(1)
                link.send_led_rgb(1, 1, 2, 3)
                await p.wait_for("LED_CONTROL")
                await p.wait_for("HEARTBEAT")
    finally:
        tlog.close()
        events.close()
    conn = mavutil.mavlink_connection(str(tlog_path))
    seen = set()
    while (m := conn.recv_match()) is not None:
        seen.add((m.get_type(), m.get_srcSystem()))
    conn.close()
    assert {("HEARTBEAT", 1), ("STATUSTEXT", 1), ("COMMAND_ACK", 1), ("HEARTBEAT", 255),
            ("COMMAND_LONG", 255), ("LED_CONTROL", 255)} <= seen
    names = [e["event"] for e in read_events(events_path)]
    assert {"link_started", "vehicle_appeared", "statustext", "link_closed"} <= set(names)


@run
async def test_a_fleet_wide_silence_marks_nobody_lost() -> None:
    events = EventList()
    async with new_link(lost_timeout=0.3, fleet_silence=0.1, events=events) as link:
        with peer_for(link, 1) as a, peer_for(link, 2) as b:
            a.heartbeat_period = b.heartbeat_period = 0.02
            await link.wait_for_vehicles([1, 2], 2.0)
            a.muted = b.muted = True  # the whole link is cut (or our receive path)
            await eventually(lambda: link.fleet_silent, what="fleet silent")
            await asyncio.sleep(0.6)  # twice the lost timeout
            assert not link.vehicles[1].lost and not link.vehicles[2].lost
            assert events.named("fleet_silent") and not events.named("vehicle_lost")
            a.muted = False  # one comes back: now the other's silence is its own
            await eventually(lambda: link.vehicles[2].lost, what="vehicle 2 lost")
            assert not link.vehicles[1].lost and not link.fleet_silent
            assert [e["system_id"] for e in events.named("vehicle_lost")] == [2]


@run
async def test_a_stall_of_our_loop_is_not_the_vehicles_silence() -> None:
    events = EventList()
    async with new_link(lost_timeout=0.3, fleet_silence=0.2, events=events) as link:
        with peer_for(link, 1) as a, peer_for(link, 2) as b:
            a.heartbeat_period = b.heartbeat_period = 0.02
            await link.wait_for_vehicles([1, 2], 2.0)
            time.sleep(0.6)  # the event loop is blocked; their packets wait in the socket
            assert link.check_lost(link.clock.now()) == []  # drained first
            assert not events.named("vehicle_lost") and not events.named("fleet_silent")
            assert link.vehicles[1].silent_for(link.clock.now()) < 0.1
