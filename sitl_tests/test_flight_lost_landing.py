"""End to end: a vehicle that goes silent while landing is counted down once it is.

A real ArduCopter frozen for 8 s while its LAND was pending came back in LAND,
touched down and disarmed, and used to stay "lost".  Here the simulator cuts one
vehicle's link both ways for 8 s the moment the executor starts landing it:
whether the LAND got through before the cut (it lands in the silence) or was
lost in it (it is heard again hovering and the LAND is sent again), the flight
ends with every vehicle landed and the report safe.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from flight_fixtures import dry_run, flavours, quick_plan, show_time, until, vehicle

from groundctl.execute.sequence import VehiclePhase
from groundctl.flight.runner import ShowRunner
from groundctl.link.flavours import Flavour
from groundctl.record.events import read_events
from groundctl.sim.process import SimProcess

SILENT = 5


def test_a_vehicle_silent_while_landing_is_counted_landed(tmp_path: Path) -> None:
    async def cut_while_landing(runner: ShowRunner, sim: SimProcess) -> None:
        def landing() -> bool:
            seq = runner.sequence
            return seq is not None and seq.vehicles[SILENT].phase is VehiclePhase.LANDING
        await until(runner, landing, timeout_s=300.0)
        sim.call("cut_link", SILENT, None, float(sim.get("time")) + 8.0)

    result = dry_run(tmp_path, during=cut_while_landing)
    report = result.report
    assert result.error is None, result.error
    events = list(read_events(tmp_path / "events.jsonl"))
    assert any(e["event"] == "vehicle_lost" and e.get("system_id") == SILENT for e in events)
    assert vehicle(report, SILENT)["phase"] == "landed", vehicle(report, SILENT)
    assert [v["phase"] for v in report["vehicles"]] == ["landed"] * 9
    assert report["simulator"]["down_and_disarmed"] == 9
    assert report["simulator"]["crashed"] == []
    assert report["safe"], report["unsafe_reasons"]


@pytest.mark.parametrize("flavour", flavours(Flavour.ARDUPILOT))
def test_a_vehicle_silent_across_the_end_of_the_show_lands_when_heard_again(
        flavour: Flavour, tmp_path: Path) -> None:
    """Silent from 2 s before the end for 8 s: its LAND is sent into the silence (or it
    is still returning); heard again hovering in its flight mode, it is landed."""
    async def cut_before_the_end(runner: ShowRunner, sim: SimProcess) -> None:
        end = quick_plan().duration
        await until(runner, lambda: show_time(runner) > end - 2.0, timeout_s=300.0)
        sim.call("cut_link", SILENT, None, float(sim.get("time")) + 8.0)

    result = dry_run(tmp_path, flavour=flavour, during=cut_before_the_end)
    report = result.report
    assert result.error is None, result.error
    events = list(read_events(tmp_path / "events.jsonl"))
    assert any(e["event"] == "vehicle_lost" and e.get("system_id") == SILENT for e in events)
    assert [v["phase"] for v in report["vehicles"]] == ["landed"] * 9, vehicle(report, SILENT)
    assert report["simulator"]["down_and_disarmed"] == 9
    assert report["safe"], report["unsafe_reasons"]
