"""End to end: the security issue's measured attacks against a flying dry-run.

Raw UDP with a vehicle's own address and port as source (a raw socket: these
tests skip where one cannot be opened), sent only to 127.0.0.1: one HEARTBEAT
saying LOITER for vehicle 5 mid-show, "disarmed" HEARTBEATs for all nine in the
air, a forged EKF origin for all nine before take-off, and, with signing, a
packet with a wrong signature and a fresh timestamp.  Plus a stray system id
during a pre-flight with no fleet file.  The simulator's truth decides.
"""

from __future__ import annotations

import asyncio
import socket
import time
from pathlib import Path
from typing import Any

import pymap3d
import pytest
from flight_fixtures import FAST, dry_run, quick_plan, show_time, until
from hostile_mavlink import FLEET_KEY, RawUdp
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import ScaledClock
from groundctl.flight.dryrun import LOOPBACK, DryRunOptions, sim_config
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.link.flavours import COPTER_MODES
from groundctl.link.fleet import FleetLink
from groundctl.link.signing import signing_timestamp
from groundctl.record.events import read_events
from groundctl.sim.process import SimProcess


@pytest.fixture
def raw() -> Any:
    sock = RawUdp.open()
    if sock is None:
        pytest.skip("no raw socket (needs CAP_NET_RAW): cannot forge source addresses")
    yield sock
    sock.close()


class Forger:
    """Packets under the fleet's ids, from the vehicles' own addresses."""

    def __init__(self, raw: RawUdp, runner: ShowRunner) -> None:
        self.raw, self.link = raw, runner.link
        self.codecs: dict[int, mavlink.MAVLink] = {}

    def send(self, sysid: int, msg: mavlink.MAVLink_message, *, key: bytes | None = None,
             ahead_s: float = 0.0) -> None:
        mav = self.codecs.setdefault(sysid, mavlink.MAVLink(None, srcSystem=sysid,
                                                            srcComponent=1))
        if key is not None:
            mav.signing.secret_key, mav.signing.sign_outgoing = key, True
            mav.signing.timestamp = signing_timestamp(time.time() + ahead_s)
        data = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 7) % 256  # a numbering of its own
        src, dst = self.link.address_of(sysid), self.link.local_address
        assert src is not None and dst is not None
        self.raw.send(data, src, dst)


def _heartbeat(mode: str, armed: bool) -> mavlink.MAVLink_message:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
        COPTER_MODES[mode], mavlink.MAV_STATE_ACTIVE, 3)


def _events(record: Path, name: str) -> list[dict[str, Any]]:
    return [e for e in read_events(record / "events.jsonl") if e["event"] == name]


def _assert_flown_as_planned(report: dict[str, Any]) -> None:
    why = (report["unsafe_reasons"], [(v["system_id"], v["phase"], v["reason"])
                                      for v in report["vehicles"]])
    assert report["safe"] and report["landed"], why
    assert [(v["phase"], v["reason"]) for v in report["vehicles"]] == [("landed", None)] * 9
    assert report["simulator"]["crashed"] == []
    assert report["simulator"]["down_and_disarmed"] == 9
    assert report["true_min_separation_m"] >= report["separation_limit_m"]


def test_forged_loiter_disarms_and_origins_from_the_vehicles_addresses_change_nothing(
        raw: RawUdp, tmp_path: Path) -> None:
    plan = quick_plan()
    seen: dict[str, Any] = {}

    async def attack(runner: ShowRunner, sim: SimProcess) -> None:
        forger = Forger(raw, runner)
        link = runner.link
        ids = list(range(1, plan.drones + 1))
        await until(runner, lambda: all(link.address_of(s) is not None for s in ids))
        while runner.sequence is None:  # pre-flight: an EKF origin 60 m off, for all nine
            for sysid in ids:
                state = link.vehicles.get(sysid)
                if state is None or state.ekf_origin is None:
                    continue
                o = state.ekf_origin
                lat, lon, alt = pymap3d.ned2geodetic(60.0, -20.0, -4.0, o.lat_deg,
                                                     o.lon_deg, o.alt_m)
                forger.send(sysid, mavlink.MAVLink_gps_global_origin_message(
                    round(float(lat) * 1e7), round(float(lon) * 1e7),
                    round(float(alt) * 1000), 0))
            await asyncio.sleep(runner.clock.wall_interval(0.3))
        await until(runner, lambda: show_time(runner) > 6.0)
        forger.send(5, _heartbeat("LOITER", armed=True))  # vehicle 5 out of the show?
        for _ in range(10):  # "disarmed" for all nine, in the air, for 5 s
            for sysid in ids:
                forger.send(sysid, _heartbeat("GUIDED", armed=False))
            await asyncio.sleep(runner.clock.wall_interval(0.5))
        seen["conflicts"] = {s: link.vehicles[s].link_conflicts for s in ids}

    result = dry_run(tmp_path, during=attack)
    _assert_flown_as_planned(result.report)
    assert all(n >= 1 for n in seen["conflicts"].values()), seen
    assert _events(tmp_path, "preflight_passed")
    assert [e for e in _events(tmp_path, "mode_changed") if e["new"] == "LOITER"] == []
    assert len(_events(tmp_path, "disarmed")) == 9  # each once: on the ground, at the end
    assert len(_events(tmp_path, "ekf_origin")) == 9
    assert _events(tmp_path, "link_conflict")


def test_a_badly_signed_packet_with_a_fresh_timestamp_loses_no_vehicle(
        raw: RawUdp, tmp_path: Path) -> None:
    async def attack(runner: ShowRunner, sim: SimProcess) -> None:
        forger = Forger(raw, runner)
        await until(runner, lambda: show_time(runner) > 3.0)
        for sysid in range(1, 10):  # a wrong key, an hour ahead, from each vehicle's address
            forger.send(sysid, _heartbeat("LAND", armed=False), key=bytes(32), ahead_s=3600)

    result = dry_run(tmp_path, during=attack, signing_key=FLEET_KEY)
    _assert_flown_as_planned(result.report)
    assert _events(tmp_path, "vehicle_lost") == []
    assert result.report["link"]["bad_signatures"] == 9
    assert {e["system_id"] for e in _events(tmp_path, "bad_signature")} == set(range(1, 10))


def test_a_stray_heartbeat_does_not_block_the_preflight_of_a_fleet_without_a_file() -> None:
    """``groundctl fly`` without a fleet file accepts any system id: one HEARTBEAT from
    id 77, not in the show, used to make pre-flight refuse ('vehicle 77: NOT READY')."""
    plan = quick_plan()

    async def main() -> Any:
        clock = ScaledClock(FAST["speed"])
        link = FleetLink((LOOPBACK, 0), clock=clock)  # no expected ids, as `fly` has it
        stray = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        stray.bind((LOOPBACK, 0))
        mav = mavlink.MAVLink(None, srcSystem=77, srcComponent=1)
        fleet: SimProcess | None = None
        try:
            await link.start()
            assert link.local_address is not None
            stray.sendto(bytes(_heartbeat("STABILIZE", False).pack(mav)), link.local_address)
            options = DryRunOptions(ekf_origin_delay_s=FAST["ekf_origin_delay_s"],
                                    ready_delay_s=FAST["ready_delay_s"])
            fleet = await asyncio.to_thread(SimProcess,
                                            sim_config(plan, options, link.local_address),
                                            clock)
            runner = ShowRunner(plan, link, clock, RunnerConfig(preflight_timeout_s=60.0))
            await runner.connect()
            return await runner.preflight(), set(link.vehicles)
        finally:
            stray.close()
            if fleet is not None:
                fleet.stop()
            await link.close()

    report, heard = asyncio.run(main())
    assert 77 in heard and 77 not in report.results
    assert report.extra[77].startswith("not in the show")
    assert report.summary() == "9/9 ready; 1 not in the show, ignored: 77"
