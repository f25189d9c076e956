"""Several MAVLink networks from one ground station (issue 34): the vehicle naming
(groundctl/vehicleid.py), FleetLink over one socket per network against the simulator
over real loopback UDP (the same system id on two networks is two vehicles; a command
reaches only its own; a silent network holds, not loses, its vehicles), and the
command line's spellings."""

from __future__ import annotations

import argparse
import json
import pickle

import pytest
from link_fixtures import EventList, eventually, run

from groundctl.clock import ScaledClock
from groundctl.commands.options import gust_on, push, vehicle, weak
from groundctl.errors import SimulatorError
from groundctl.flight.dryrun import network_count, network_layout
from groundctl.link import FleetLink
from groundctl.sim import LinkFaults, SimConfig, SimFleet
from groundctl.vehicleid import (
    VehicleId,
    network_of,
    parse_vehicle,
    spell,
    sysid_of,
    vehicle_id,
)

# -- naming ----------------------------------------------------------------------------


def test_network_one_is_spelled_as_it_always_was_and_the_others_with_their_network() -> None:
    assert vehicle_id(1, 17) == 17 and str(vehicle_id(1, 17)) == "17"
    v = vehicle_id(2, 17)
    assert v == 1017 and (v.network, v.sysid) == (2, 17)
    assert (network_of(v), sysid_of(v)) == (2, 17)
    assert str(v) == repr(v) == f"{v}" == spell(1017) == "2:17"
    assert f"vehicle {v} lost" == "vehicle 2:17 lost"
    assert f"{v:>6}" == "  2:17" and f"{v:d}" == "1017"  # a numeric format is the number
    assert f"{[vehicle_id(1, 3), v]}" == "[3, 2:17]"  # lists print the spelling too
    assert json.dumps({"system_id": v}) == '{"system_id": 1017}'  # JSON: the number
    back = pickle.loads(pickle.dumps(v))
    assert type(back) is VehicleId and str(back) == "2:17"
    assert {v: "x"}[1017] == "x"  # the same key as the plain number


@pytest.mark.parametrize(("text", "want"), [("17", 17), (" 17 ", 17), ("1:17", 17),
                                             ("2:17", 1017), ("1017", 1017),
                                             ("10:254", 9254)])
def test_a_vehicle_is_read_in_either_spelling(text: str, want: int) -> None:
    assert parse_vehicle(text) == want


@pytest.mark.parametrize("text", ["", "x", "0", "256", "1000", "2:", ":3", "2:0", "2:256",
                                  "11:1", "0:5", "-3", "2:3:4", "10256"])
def test_a_malformed_vehicle_gets_one_line(text: str) -> None:
    with pytest.raises(ValueError) as info:
        parse_vehicle(text)
    assert "\n" not in str(info.value) and "2:17" in str(info.value)


def test_the_command_line_spellings() -> None:
    assert vehicle("2:5") == 1005
    with pytest.raises(argparse.ArgumentTypeError):
        vehicle("2:x")
    assert push("2:5@20:3,0,0") == (1005, 20.0, (3.0, 0.0, 0.0))
    assert push("5@20:3,0,0") == (5, 20.0, (3.0, 0.0, 0.0))
    assert weak("2:1,2:2,7:0.5") == [(1001, 0.5), (1002, 0.5), (7, 0.5)]
    assert weak("3:0.5") == [(3, 0.5)]
    with pytest.raises(argparse.ArgumentTypeError):
        weak("2:1:1.5")
    assert gust_on("2:5@20:9@270,2.5") == (1005, 20.0, 9.0, 270.0, 2.5)
    assert gust_on("5@20:15@-90") == (5, 20.0, 15.0, 270.0, 4.0)  # 4 s unless told


@pytest.mark.parametrize("text", ["5@20:9", "5@20:9@", "5@20:9@w", "5:9@270", "5@x:9@270",
                                  "5@-1:9@270", "5@20:-9@270", "5@20:9@270,0",
                                  "5@20:9@270,nan", "5@20:inf@270", "0@20:9@270"])
def test_a_malformed_gust_gets_one_line_with_an_example(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError) as info:
        gust_on(text)
    message = str(info.value)
    assert "\n" not in message and "SYSID@T:SPEED@FROM[,DURATION_S]" in message
    assert repr(text) in message


def test_a_large_show_is_spread_over_as_many_networks_as_it_needs() -> None:
    assert network_count(9) == 1 and network_count(254) == 1 and network_count(255) == 2
    assert network_count(1000) == 4 and network_count(9, 2) == 2
    nets, local = network_layout(9, 2)
    assert nets == [1] * 5 + [2] * 4 and local == [1, 2, 3, 4, 5, 1, 2, 3, 4]
    nets, local = network_layout(1000, 4)
    assert max(local) == 250 and nets.count(4) == 250
    with pytest.raises(SimulatorError, match="at least 4"):
        network_count(1000, 2)
    with pytest.raises(SimulatorError, match="at most 2540"):
        network_count(3000)


# -- FleetLink over two networks, against the simulator over UDP -------------------------


def _two_networks(link: FleetLink, **kw: object) -> SimConfig:
    """Two vehicles on each of two networks, system ids 1 and 2 on both."""
    return SimConfig(count=4, system_ids=[1, 2, 1, 2], networks=[1, 1, 2, 2],
                     gcs_networks=link.local_addresses, ekf_origin_delay_s=0.5,
                     ready_delay_s=1.0, **kw)  # type: ignore[arg-type]


@run
async def test_the_same_system_id_on_two_networks_is_two_vehicles() -> None:
    events = EventList()
    link = FleetLink([("127.0.0.1", 0), ("127.0.0.1", 0)], clock=ScaledClock(),
                     events=events, heartbeat_period=0.1, timesync_period=0.1, tick=0.01)
    async with link:
        assert len(link.local_addresses) == 2
        assert link.local_addresses[0] != link.local_addresses[1]
        fleet = SimFleet(_two_networks(link), ScaledClock(4.0))
        try:
            fleet.start()
            found = await link.wait_for_vehicles([1, 2, 1001, 1002], timeout=5.0)
            assert sorted(found) == [1, 2, 1001, 1002]
            assert [str(s) for s in sorted(link.vehicles)] == ["1", "2", "2:1", "2:2"]
            # Each talks from its own socket, to its own network's port.
            assert link.address_of(1) != link.address_of(1001)
            # A command to 2:1 reaches network 2's system id 1, and only it.
            await link.set_mode(1001, "GUIDED")
            await eventually(lambda: fleet.state(1001).mode == "GUIDED", what="2:1 GUIDED")
            assert fleet.state(1).mode != "GUIDED"
            await link.set_mode(1, "GUIDED")
            await eventually(lambda: fleet.state(1).mode == "GUIDED", what="1 GUIDED")
            # The events name network 2's vehicles by their vehicle id, spelled beside it.
            appeared = {e["system_id"] for e in events.named("vehicle_appeared")}
            assert appeared == {1, 2, 1001, 1002}
        finally:
            fleet.stop()


@run
async def test_a_silent_network_holds_its_vehicles_instead_of_losing_them() -> None:
    """A cut of one network's link (its radio, its cable) is a fleet-wide silence for the
    executor (the show holds), and none of its vehicles is marked lost one by one; the
    other network is heard throughout."""
    events = EventList()
    link = FleetLink([("127.0.0.1", 0), ("127.0.0.1", 0)], clock=ScaledClock(),
                     events=events, heartbeat_period=0.1, timesync_period=0.1, tick=0.01,
                     lost_timeout=0.5, fleet_silence=0.3)
    async with link:
        fleet = SimFleet(_two_networks(link), ScaledClock(1.0))
        try:
            fleet.start()
            await link.wait_for_vehicles([1, 2, 1001, 1002], timeout=5.0)
            for vid in (1001, 1002):
                fleet.set_link_faults(LinkFaults(loss=1.0), vid)
            await eventually(lambda: link.fleet_silent, timeout=3.0, what="fleet silent")
            lost = await _after(link, 1.5)
            assert not lost and not any(v.lost for v in link.vehicles.values())
            for vid in (1001, 1002):
                fleet.set_link_faults(LinkFaults(), vid)
            await eventually(lambda: not link.fleet_silent, timeout=3.0, what="heard again")
            assert [e for e, _ in events.items if e in ("fleet_silent", "fleet_heard")] \
                == ["fleet_silent", "fleet_heard"]
        finally:
            fleet.stop()


async def _after(link: FleetLink, seconds: float) -> list[int]:
    """Every vehicle newly marked lost over ``seconds`` (the link's own periodic checks)."""
    import asyncio

    lost: list[int] = []
    end = link.clock.now() + seconds
    while link.clock.now() < end:
        lost += link.check_lost(link.clock.now())
        await asyncio.sleep(0.02)
    return lost



def test_sim_spreads_its_fleet_over_one_network_per_gcs() -> None:
    from groundctl.cli import build_parser
    from groundctl.commands.sim import build_config

    def config(*argv: str) -> SimConfig:
        return build_config(build_parser().parse_args(["sim", *argv]))

    two = config("--count", "6", "--gcs", "127.0.0.1:14550", "--gcs", "127.0.0.1:14560")
    assert two.networks == [1, 1, 1, 2, 2, 2] and two.local_ids() == [1, 2, 3, 1, 2, 3]
    assert two.sysids() == [1, 2, 3, 1001, 1002, 1003]
    assert [two.gcs_of(i)[1] for i in range(6)] == [14550] * 3 + [14560] * 3
    assert config("--count", "254").networks is None  # one network: as it always was
    for argv, message in [
            (("--count", "300"), "2 networks need 2 --gcs"),
            (("--count", "4", "--networks", "3", "--gcs", "h:1", "--gcs", "h:2"),
             "3 networks need 3 --gcs"),
            (("--count", "4", "--gcs", "h:1", "--gcs", "h:2", "--sysid-base", "5"),
             "--sysid-base is for one network")]:
        with pytest.raises(SimulatorError, match=message):
            config(*argv)


@run
async def test_each_network_has_its_own_signing_key() -> None:
    """Network 1 signs with the simulator's key, network 2 with another: network 1's
    vehicles are heard, network 2's packets are refused and counted, none believed."""
    key, other = bytes(range(32)), bytes(range(1, 33))
    link = FleetLink([("127.0.0.1", 0), ("127.0.0.1", 0)], clock=ScaledClock(),
                     signing_keys=[key, other], heartbeat_period=0.1, timesync_period=0.1,
                     tick=0.01)
    async with link:
        fleet = SimFleet(_two_networks(link, signing_key=key), ScaledClock(4.0))
        try:
            fleet.start()
            await link.wait_for_vehicles([1, 2], timeout=5.0)
            await eventually(lambda: link.stats.bad_signatures >= 4, timeout=3.0,
                             what="network 2's packets refused")
            assert not {1001, 1002} & set(link.vehicles)
        finally:
            fleet.stop()


def test_a_thousand_vehicles_are_one_short_line() -> None:
    from groundctl.vehicleid import spell_many

    fleet = [vehicle_id(n, s) for n in (1, 2, 3, 4) for s in range(1, 251)]
    assert spell_many(fleet) == "1-250, 2:1-2:250, 3:1-3:250, 4:1-4:250"
    assert spell_many([1, 2, 4, 1007]) == "1, 2, 4, 2:7"
    assert spell_many(range(1, 60, 2), most=3) == "1, 3, 5, ... and 27 more"
    assert spell_many([]) == ""


# -- pre-flight exchanges windowed per network ------------------------------------------
def test_pre_flight_work_runs_a_few_vehicles_per_network_at_a_time() -> None:
    import asyncio

    from groundctl.link.window import per_network

    ids = [*range(1, 11), *(vehicle_id(2, s) for s in range(1, 6)),
           *(vehicle_id(3, s) for s in range(1, 4))]
    busy: dict[int, int] = {}
    most: dict[int, int] = {}
    started: list[int] = []

    async def work(vid: int) -> str:
        net = network_of(vid)
        busy[net] = busy.get(net, 0) + 1
        most[net] = max(most.get(net, 0), busy[net])
        started.append(vid)
        await asyncio.sleep(0.001 * (vid % 3))
        busy[net] -= 1
        return spell(vid)

    out = asyncio.run(per_network(ids, work, limit=2))
    assert out == [spell(v) for v in ids]  # in the order asked, whatever finished first
    assert most == {1: 2, 2: 2, 3: 2}  # two at a time on each network, side by side
    assert sorted(started) == sorted(ids)

    async def fails(vid: int) -> int:
        await asyncio.sleep(0.001)
        if vid == 3:
            raise SimulatorError("vehicle 3 went away")
        return vid

    with pytest.raises(SimulatorError, match="vehicle 3 went away"):
        asyncio.run(per_network(ids, fails, limit=2))
    with pytest.raises(ValueError, match="at least 1"):
        asyncio.run(per_network(ids, fails, limit=0))
