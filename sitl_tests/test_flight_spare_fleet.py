"""Spares on the ground (issue 29), end to end: the dry-run's fleet has one more vehicle
per spare, standing on its pad; the ground station checks them before the show, knows
them for spares (never a track), and starts without the ones not ready."""

from __future__ import annotations

import asyncio
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
from flight_fixtures import FAST, dry_run, quick_plan

from groundctl.errors import NoGo
from groundctl.execute.frames import show_to_enu
from groundctl.execute.preflight import PreflightReport
from groundctl.flight.dryrun import DryRunOptions, fleet_stands, fly_dry_run, sim_config
from groundctl.flight.runner import ShowRunner
from groundctl.plan.plan import Plan
from groundctl.plan.spares import place_spares
from groundctl.record.events import read_events
from groundctl.show.model import SpareSettings
from groundctl.sim.group import split_config
from groundctl.sim.process import SimProcess

#: The quick show's 9 drones are vehicles 1-9; its two spares come after them.
SPARES = [10, 11]


@cache
def spare_plan() -> Plan:
    """The quick show with two spares waiting on the ground, on laid-out pads."""
    plan = quick_plan()
    return replace(plan, spares=place_spares(SpareSettings(count=2, standby="ground"), plan))


def test_the_simulated_fleet_stands_the_spares_on_their_pads() -> None:
    plan = spare_plan()
    assert plan.spares is not None
    config = sim_config(plan, DryRunOptions(), [("127.0.0.1", 14550), ("127.0.0.1", 14560)])
    assert config.count == 11 and config.sysids() == [1, 2, 3, 4, 5, 6, 1001, 1002, 1003,
                                                      1004, 1005]
    homes = config.homes_enu()
    assert np.allclose(homes[9:], show_to_enu(plan.origin, plan.spares.pads))
    assert np.allclose(homes[:9], show_to_enu(plan.origin, plan.home))
    assert len(fleet_stands(plan)) == 11
    # Split over two simulator processes, every vehicle keeps its place and its id.
    parts = split_config(config, 2)
    assert [p.count for p in parts] == [6, 5]
    assert [s for p in parts for s in p.sysids()] == config.sysids()
    assert np.allclose(np.vstack([p.homes_enu() for p in parts]), homes)


def test_spares_stand_disarmed_on_their_pads_through_the_show(tmp_path: Path) -> None:
    plan = spare_plan()
    assert plan.spares is not None
    pads = show_to_enu(plan.origin, plan.spares.pads)
    armed: set[int] = set()
    moved = [0.0]

    async def watch(runner: ShowRunner, sim: SimProcess) -> None:
        # The simulator's truth, through the whole flight: armed, or off the pad.
        while True:
            for s in sim.call("snapshot"):
                if s.sysid in SPARES:
                    armed.update([s.sysid] if s.armed else [])
                    off = float(np.linalg.norm(np.subtract(s.position,
                                                           pads[SPARES.index(s.sysid)])))
                    moved[0] = max(moved[0], off)
            await asyncio.sleep(0.1)

    result = dry_run(tmp_path, plan=plan, during=watch)
    assert result.error is None and result.flown
    report = result.report
    assert report["safe"] and report["landed"], report["unsafe_reasons"]
    show = [v for v in report["vehicles"] if v["system_id"] not in SPARES]
    assert [v["phase"] for v in show] == ["landed"] * 9
    assert report["simulator"]["crashed"] == []
    assert report["simulator"]["down_and_disarmed"] == 11
    # The simulator's truth: no spare ever armed or left its pad (none was needed).
    assert armed == set() and moved[0] < 0.5
    events = read_events(tmp_path / "events.jsonl")
    (ready,) = [e for e in events if e["event"] == "spares_ready"]
    assert ready["ready"] == SPARES and ready["asked"] == 2
    assert ready["text"] == "spares: 2 of 2 ready"
    assert not [e for e in events if e["event"] == "spare_not_ready"]
    (passed,) = [e for e in events if e["event"] == "preflight_passed"]
    assert sorted(passed["tracks"]) == [str(s) for s in range(1, 10)]
    assert "vehicle 10 (spare 1): ready" in passed["lines"]
    (started,) = [e for e in events if e["event"] == "dry_run"]
    assert started["vehicles"] == 9 and started["spares"] == 2


def test_a_spare_not_ready_does_not_hold_the_show(tmp_path: Path) -> None:
    # Spare 2's battery is low from the start: the show's vehicles pass and the show may
    # start (stopped here at the operator's go, before anything arms), a spare fewer.
    async def drain(runner: ShowRunner, sim: SimProcess) -> None:
        sim.call("low_battery", 0.3, 11)

    async def no_go(report: PreflightReport) -> bool:
        return False

    def gate(runner: ShowRunner) -> None:
        runner.confirm_go = no_go

    options = DryRunOptions(**{**FAST, "record_dir": tmp_path})
    result = asyncio.run(fly_dry_run(spare_plan(), options, during=drain, on_runner=gate))
    assert isinstance(result.error, NoGo) and not result.flown
    events = read_events(tmp_path / "events.jsonl")
    (passed,) = [e for e in events if e["event"] == "preflight_passed"]
    assert "vehicle 11 (spare 2): NOT READY: battery: 30 % (minimum 60 %)" in passed["lines"]
    (warned,) = [e for e in events if e["event"] == "spare_not_ready"]
    assert warned["system_id"] == 11 and warned["spare"] == 1
    assert warned["text"] == ("vehicle 11 (spare 2) not ready: battery: 30 % (minimum 60 %); "
                              "the show starts without this spare")
    (ready,) = [e for e in events if e["event"] == "spares_ready"]
    assert ready["ready"] == [10] and ready["asked"] == 2
    assert ready["text"] == "spares: 1 of 2 ready"
