"""FleetLink against forged packets over real UDP on 127.0.0.1 (the security issue, items 1-4).

The forger sends from the vehicle's own socket (what a raw socket with a forged
source address achieves on a real network) or from a port of its own, with a
pymavlink codec of its own: its own sequence numbers, a wrong signing key.
"""

from __future__ import annotations

import asyncio
import socket
import time
from pathlib import Path
from typing import Any

from link_fixtures import EventList, VehiclePeer, eventually, run
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from test_execute_support import HOME, make_vehicle

from groundctl.clock import ScaledClock
from groundctl.execute.mapping import auto_assign
from groundctl.execute.preflight import run_preflight
from groundctl.link import Endpoint, Flavour, FleetLink
from groundctl.link.codec import DatagramParser, new_codec
from groundctl.link.fleetfile import load_fleet_file
from groundctl.link.signing import SigningConfig, signing_timestamp
from groundctl.link.state import VehicleState

LOOPBACK = ("127.0.0.1", 0)
KEY = bytes(range(32))


def new_link(**kw: Any) -> FleetLink:
    kw.setdefault("clock", ScaledClock())
    kw.setdefault("heartbeat_period", 0.1)
    kw.setdefault("timesync_period", 0.1)
    kw.setdefault("tick", 0.01)
    return FleetLink(LOOPBACK, **kw)


def peer_for(link: FleetLink, sysid: int, **kw: Any) -> VehiclePeer:
    assert link.local_address is not None
    return VehiclePeer(sysid, link.local_address, Flavour.ARDUPILOT, clock=link.clock, **kw)


def forger(sysid: int, *, seq: int = 0, key: bytes | None = None,
           timestamp_s: float | None = None) -> mavlink.MAVLink:
    """Someone else's codec under ``sysid`` (component 1), optionally signing."""
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    mav.seq = seq
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 0
        mav.signing.timestamp = signing_timestamp(time.time() if timestamp_s is None
                                                  else timestamp_s)
    return mav


def heartbeat_bytes(mav: mavlink.MAVLink, mode: int, armed: bool) -> bytes:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    data = bytes(mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR,
                                      mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base, mode,
                                      mavlink.MAV_STATE_ACTIVE).pack(mav))
    mav.seq = (mav.seq + 1) % 256
    return data


LOITER, GUIDED = 5, 4  # ArduCopter custom modes


# -- item 1 -----------------------------------------------------------------------------


@run
async def test_forged_heartbeats_from_the_vehicles_own_address_change_nothing() -> None:
    events = EventList()
    async with new_link(events=events) as link:
        with peer_for(link, 1, mode="GUIDED") as vehicle:
            vehicle.armed = True
            vehicle.heartbeat_period = 0.05
            await link.wait_for_vehicles([1], 2.0)
            await eventually(lambda: link.vehicles[1].armed, what="armed")
            fake = forger(1, seq=200)
            vehicle.send_raw(heartbeat_bytes(fake, LOITER, armed=True))
            vehicle.send_raw(heartbeat_bytes(fake, GUIDED, armed=False))
            await eventually(lambda: link.vehicles[1].link_conflicts >= 1, what="conflict")
            await asyncio.sleep(0.3)  # the vehicle's own heartbeats go on meanwhile
            state = link.vehicles[1]
            assert (state.mode, state.armed) == ("GUIDED", True)
            assert [e["new"] for e in events.named("mode_changed")] == ["GUIDED"]
            assert events.named("disarmed") == []
            assert events.named("link_conflict")[0]["system_id"] == 1
            assert link.stats.link_conflicts == state.link_conflicts


# -- item 2 -----------------------------------------------------------------------------


@run
async def test_one_badly_signed_packet_with_a_fresh_timestamp_locks_nobody_out() -> None:
    async with new_link(signing_key=KEY) as link:
        with peer_for(link, 1, signing_key=KEY) as vehicle:
            vehicle.heartbeat()
            await link.wait_for_vehicles([1], 2.0)
            # A wrong key and a timestamp an hour ahead, from the vehicle's own address.
            fake = forger(1, seq=vehicle.mav.seq, key=bytes(32),
                          timestamp_s=time.time() + 3600)
            vehicle.send_raw(heartbeat_bytes(fake, LOITER, armed=False))
            await eventually(lambda: link.vehicles[1].bad_signatures == 1, what="refused")
            before = link.vehicles[1].packets
            for _ in range(5):
                vehicle.heartbeat()
            await eventually(lambda: link.vehicles[1].packets >= before + 5,
                             what="the vehicle's own packets still accepted")
            state = link.vehicles[1]
            assert state.mode == "STABILIZE" and state.bad_signatures == 1
            assert link.stats.bad_signatures == 1
            await link.arm(1)  # commands still answered
            assert vehicle.armed


def test_the_signature_is_verified_before_the_replay_guard_moves() -> None:
    real = forger(1, key=KEY)
    genuine = heartbeat_bytes(real, GUIDED, armed=True)
    forged = heartbeat_bytes(forger(1, seq=9, key=bytes(32), timestamp_s=time.time() + 3600),
                             LOITER, armed=True)
    codec = new_codec(255, 190, SigningConfig(KEY))
    parser = DatagramParser(codec)
    bad = parser.feed(forged)
    assert bad.messages == [] and bad.refused_signatures == [1]
    assert "bad signature" in bad.bad[0]
    ok = parser.feed(genuine)
    assert [m.get_type() for m in ok.messages] == ["HEARTBEAT"]
    # Replayed (from anywhere: the guard is per stream, not per address) is refused.
    other = DatagramParser(new_codec(255, 190, SigningConfig(KEY), guard=codec.guard))
    replay = other.feed(genuine)
    assert replay.messages == [] and "replayed" in replay.bad[0]
    # A badly signed packet is refused even where unsigned ones are allowed.
    lax = DatagramParser(new_codec(255, 190, SigningConfig(KEY, allow_unsigned=True)))
    assert lax.feed(forged).messages == []


# -- item 3 -----------------------------------------------------------------------------


@run
async def test_a_fleet_file_address_pins_its_vehicle_whoever_speaks_first() -> None:
    events = EventList()
    clock = ScaledClock()
    with VehiclePeer(3, ("127.0.0.1", 9), clock=clock, mode="GUIDED") as real, \
         VehiclePeer(3, ("127.0.0.1", 9), clock=clock, mode="LAND") as impostor:
        async with new_link(clock=clock, events=events, expected_ids={3},
                            endpoints=[Endpoint(3, *real.address)]) as link:
            assert link.local_address is not None
            real.gcs = impostor.gcs = link.local_address
            impostor.heartbeat()  # before the real vehicle
            await eventually(lambda: link.stats.address_conflicts == 1, what="refused")
            assert 3 not in link.vehicles
            for _ in range(32):
                real.heartbeat()
            await link.wait_for_vehicles([3], 2.0)
            await eventually(lambda: link.vehicles[3].packets == 32, what="all 32 believed")
            assert link.vehicles[3].mode == "GUIDED" and link.address_of(3) == real.address
            assert link.stats.address_conflicts == 1
            (conflict,) = events.named("address_conflict")
            assert conflict["address"] == "{}:{}".format(*impostor.address)
            assert conflict["known"] == "{}:{}".format(*real.address)


@run
async def test_a_pin_after_the_start_forgets_a_stranger_heard_first() -> None:
    """The dry-run's case: the simulator's ports are known only once it runs, after the
    link is up, and a stranger may have spoken for its vehicles by then."""
    events = EventList()
    clock = ScaledClock()
    with VehiclePeer(3, ("127.0.0.1", 9), clock=clock, mode="GUIDED") as real, \
         VehiclePeer(3, ("127.0.0.1", 9), clock=clock, mode="LAND") as stranger:
        async with new_link(clock=clock, events=events, expected_ids={3}) as link:
            assert link.local_address is not None
            real.gcs = stranger.gcs = link.local_address
            stranger.heartbeat()
            await link.wait_for_vehicles([3], 2.0)
            assert link.address_of(3) == stranger.address and link.vehicles[3].mode == "LAND"
            link.pin({3: real.address})
            assert link.address_of(3) is None and 3 not in link.vehicles  # all it said
            (forgotten,) = events.named("address_forgotten")
            assert forgotten["address"] == "{}:{}".format(*stranger.address)
            assert forgotten["pinned"] == "{}:{}".format(*real.address)
            stranger.heartbeat()
            await eventually(lambda: link.stats.address_conflicts == 1, what="refused")
            real.heartbeat()
            await link.wait_for_vehicles([3], 2.0)
            assert link.address_of(3) == real.address and link.vehicles[3].mode == "GUIDED"
            link.pin({3: real.address})  # pinning it again where it is forgets nothing
            assert link.vehicles[3].mode == "GUIDED"
            assert len(events.named("address_forgotten")) == 1


@run
async def test_a_host_only_fleet_entry_pins_the_host_and_learns_the_port() -> None:
    clock = ScaledClock()
    with VehiclePeer(4, ("127.0.0.1", 9), clock=clock, mode="LAND") as elsewhere:
        async with new_link(clock=clock, endpoints=[Endpoint(4, "127.0.0.2", None)]) as link:
            assert link.local_address is not None
            elsewhere.gcs = link.local_address
            elsewhere.heartbeat()  # 127.0.0.1: not the pinned host
            await eventually(lambda: link.stats.address_conflicts == 1, what="refused")
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                sock.bind(("127.0.0.2", 0))
                sock.sendto(heartbeat_bytes(forger(4), GUIDED, armed=False),
                            link.local_address)
                await link.wait_for_vehicles([4], 2.0)
                assert link.address_of(4) == sock.getsockname()
                assert link.vehicles[4].mode == "GUIDED"
            finally:
                sock.close()


def test_fleet_file_host_star_means_any_port_of_that_host(tmp_path: Path) -> None:
    p = tmp_path / "fleet.toml"
    p.write_text('[[vehicle]]\nsystem_id = 3\naddress = "10.0.0.3:*"\n'
                 '[[vehicle]]\nsystem_id = 4\naddress = "10.0.0.4:14550"\n')
    fleet = load_fleet_file(p)
    assert fleet.endpoints == (Endpoint(3, "10.0.0.3", None), Endpoint(4, "10.0.0.4", 14550))
    assert fleet.endpoints[0].address is None


# -- item 4 -----------------------------------------------------------------------------


def test_a_stray_system_id_is_reported_and_ignored_never_blocking_the_show() -> None:
    now = 100.0
    vehicles: dict[int, VehicleState] = {i + 1: make_vehicle(i + 1, now) for i in range(3)}
    stray = VehicleState(77, flavour=Flavour.ARDUPILOT, last_heartbeat=now, last_heard=now)
    vehicles[77] = stray  # one HEARTBEAT, nothing else
    positions = {1: HOME[0], 2: HOME[1], 3: HOME[2], 77: None}
    report = run_preflight(vehicles, auto_assign(HOME, positions), now)
    report.require_all()  # does not raise
    assert 77 not in report.results and report.failures() == {}
    assert report.lines()[-1] == ("vehicle 77: ignored: not in the show (every track has a "
                                  "vehicle; vehicle 77 has no position estimate)")
    assert report.summary() == "3/3 ready; 1 not in the show, ignored: 77"
    # While a track still has no vehicle, every vehicle is checked: it may be needed.
    del vehicles[3], positions[3]
    report = run_preflight(vehicles, auto_assign(HOME, positions), now)
    assert 77 in report.failures() and not report.extra


def test_a_stray_vehicle_with_a_position_off_every_slot_is_ignored_too() -> None:
    now, sysid = 100.0, 77
    vehicles = {i + 1: make_vehicle(i + 1, now) for i in range(3)}
    vehicles[sysid] = make_vehicle(sysid, now, ned=(40.0, 40.0, 0.0))
    positions = {1: HOME[0], 2: HOME[1], 3: HOME[2], sysid: [40.0, 40.0, 0.0]}
    report = run_preflight(vehicles, auto_assign(HOME, positions), now)
    assert report.failures() == {} and list(report.extra) == [sysid]
