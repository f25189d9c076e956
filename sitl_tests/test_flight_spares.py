"""Spares in flight (issue 29), end to end through the dry-run: a drone leaves the show
(it falls, its battery, the operator's ``replace``), a spare on its pad is planned in
around everyone, arms, climbs, flies its way in dark and takes the track over; the
formations after it are whole again, and every drone comes down where nobody is."""

from __future__ import annotations

import asyncio
from functools import cache
from pathlib import Path
from typing import Any

from flight_fixtures import dry_run, vehicle

from groundctl.commands.flying import operator_line
from groundctl.flight.dryrun import Failure
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.plan.plan import Plan
from groundctl.record.events import read_events
from groundctl.sim.process import SimProcess

#: Nine show drones (1-9) and two spares on the ground (10, 11), five formations held
#: 5 s each (sitl_tests/data/spares.toml).
SPARES_SHOW = Path(__file__).parent / "data" / "spares.toml"
SPARES = (10, 11)


@cache
def spares_plan() -> Plan:
    from groundctl.plan.planner import plan_show
    from groundctl.show.loader import load_show

    result = plan_show(load_show(SPARES_SHOW), workers=1)
    assert result.verification.safe and result.plan.spares is not None
    return result.plan


def _events(record: Path, name: str) -> list[dict[str, Any]]:
    return [e for e in read_events(record / "events.jsonl") if e["event"] == name]


def _after_join_complete(report: dict[str, Any], plan: Plan, joined_at: float) -> None:
    """Every formation whose hold begins after the join has all its slots held, each
    drone within the rejoin tolerance of its slot (1 m; 0.06-0.13 m measured idle)."""
    for w, f in zip(plan.formations, report["pattern_error_m"], strict=True):
        if w.arrive >= joined_at - 1e-6:
            assert f["complete"], (f, joined_at)
            assert f["max_m"] < 1.0, f


def test_a_spare_takes_over_the_track_of_a_drone_that_fell(tmp_path: Path) -> None:
    plan = spares_plan()
    result = dry_run(tmp_path, plan=plan, failures=(Failure(5, 2.0, "motor"),))
    report = result.report
    assert result.error is None, result.error
    spares = report["spares"]
    assert spares["asked"] == 2 and spares["ready"] == 2 and spares["used"] == 1, spares
    (r,) = spares["replacements"]
    assert r["track"] == 4 and r["failed"] == 5 and r["spare"] in SPARES, r
    assert r["outcome"] == "joined" and r["joined_at"] is not None
    assert abs(r["dark_s"] - (r["joined_at"] - r["left_at"])) <= 0.011 and r["dark_s"] > 0
    assert r["plan_ms"] > 0
    # Only the crash is unsafe: nobody came near anybody, the spare and the rest landed.
    assert report["unsafe_reasons"] == ["vehicle(s) [5] did not land under control",
                                        "vehicle(s) [5] crashed"], report["unsafe_reasons"]
    assert report["true_min_separation_m"] >= plan.limits.min_separation
    assert vehicle(report, r["spare"])["phase"] == "landed"
    assert vehicle(report, r["spare"])["track"] == 4
    other = SPARES[1] if r["spare"] == SPARES[0] else SPARES[0]
    assert vehicle(report, other)["phase"] == "not flown"
    assert report["simulator"]["down_and_disarmed"] == 11
    _after_join_complete(report, plan, r["joined_at"])
    # Before the join a formation had a hole.
    assert not report["pattern_error_m"][0]["complete"]
    planned = _events(tmp_path, "spare_planned")
    joined = _events(tmp_path, "spare_joined")
    assert [e["system_id"] for e in planned] == [r["spare"]]
    assert [e["system_id"] for e in joined] == [r["spare"]]


@cache
def air_spares_plan() -> Plan:
    """The same show, its two spares waiting in the air over their pads."""
    from dataclasses import replace

    from groundctl.plan.spares import place_spares
    from groundctl.show.model import SpareSettings

    plan = spares_plan()
    return replace(plan, spares=place_spares(SpareSettings(count=2, standby="air"), plan))


def test_a_spare_waiting_in_the_air_takes_over_and_the_other_lands_with_the_fleet(
        tmp_path: Path) -> None:
    plan = air_spares_plan()
    assert plan.spares is not None
    result = dry_run(tmp_path, plan=plan, failures=(Failure(5, 2.0, "motor"),))
    report = result.report
    assert result.error is None, result.error
    (r,) = report["spares"]["replacements"]
    assert r["track"] == 4 and r["failed"] == 5 and r["outcome"] == "joined", r
    assert report["unsafe_reasons"] == ["vehicle(s) [5] did not land under control",
                                        "vehicle(s) [5] crashed"], report["unsafe_reasons"]
    assert report["true_min_separation_m"] >= plan.limits.min_separation
    other = SPARES[1] if r["spare"] == SPARES[0] else SPARES[0]
    # Both flew: one took the track over, the other hovered at its point and came down
    # on its pad with the fleet.
    assert vehicle(report, r["spare"])["phase"] == "landed"
    assert vehicle(report, r["spare"])["track"] == 4
    assert vehicle(report, other)["phase"] == "landed"
    assert vehicle(report, other)["track"] is None
    assert report["simulator"]["down_and_disarmed"] == 11
    _after_join_complete(report, plan, r["joined_at"])
    # From the air a spare is there sooner than from its pad (no arming, no climb).
    assert [e["system_id"] for e in _events(tmp_path, "spare_joined")] == [r["spare"]]


def test_replace_from_the_command_line_sends_a_spare_in(tmp_path: Path) -> None:
    plan = spares_plan()
    said: list[str] = []

    async def replace_three(runner: ShowRunner, sim: SimProcess) -> None:
        while runner.sequence is None or runner.sequence.started_at is None \
                or runner.sequence.show_time(runner.clock.now()) < 1.0:
            await asyncio.sleep(0.05)
        operator_line(runner, "replace 3", said.append)

    result = dry_run(tmp_path, plan=plan, during=replace_three)
    report = result.report
    assert result.error is None, result.error
    assert report["safe"] and report["landed"], report["unsafe_reasons"]
    (r,) = report["spares"]["replacements"]
    assert r["failed"] == 3 and r["track"] == vehicle(report, 3)["track"]
    assert r["outcome"] == "joined", r
    assert vehicle(report, 3)["phase"] == "landed"
    assert vehicle(report, r["spare"])["phase"] == "landed"
    assert report["true_min_separation_m"] >= plan.limits.min_separation
    assert report["simulator"]["down_and_disarmed"] == 11
    _after_join_complete(report, plan, r["joined_at"])
    texts = [e.get("text", "") for e in _events(tmp_path, "sequence")]
    assert any("a spare takes its track" in t for t in texts), texts


def test_a_spare_that_fails_on_its_way_in_is_followed_by_the_next(tmp_path: Path) -> None:
    plan = spares_plan()
    first: list[int] = []

    async def fail_the_first_spare(runner: ShowRunner, sim: SimProcess) -> None:
        # The first spare sent in loses its motors once it is up and flying its way in.
        while True:
            seq = runner.sequence
            going = [v for v in seq.vehicles.values() if v.join is not None
                     and str(v.phase) == "joining"] if seq is not None else []
            if going:
                first.append(going[0].sysid)
                sim.call("motor_failure", going[0].sysid)
                return
            await asyncio.sleep(0.05)

    result = dry_run(tmp_path, plan=plan, failures=(Failure(5, 2.0, "motor"),),
                     during=fail_the_first_spare)
    report = result.report
    assert result.error is None, result.error
    assert len(first) == 1
    by_spare = {r["spare"]: r for r in report["spares"]["replacements"]}
    assert by_spare[first[0]]["outcome"].startswith("failed"), by_spare
    (second,) = set(SPARES) - {first[0]}
    assert second in by_spare, by_spare
    assert by_spare[second]["failed"] == first[0]  # it took over from the spare that fell
    assert by_spare[second]["outcome"] == "joined", by_spare
    assert vehicle(report, second)["phase"] == "landed"
    _after_join_complete(report, plan, by_spare[second]["joined_at"])
    assert report["true_min_separation_m"] >= plan.limits.min_separation
    assert _events(tmp_path, "spare_failed")


def test_no_spares_leaves_the_track_dark_and_refuses_replace(tmp_path: Path) -> None:
    """`--no-spares`: a drone that falls leaves its track dark (said once), and the
    operator's `replace` is refused with nothing changed (the drone flies on)."""
    plan = spares_plan()
    said: list[str] = []

    async def replace_two(runner: ShowRunner, sim: SimProcess) -> None:
        while runner.sequence is None or runner.sequence.started_at is None:
            await asyncio.sleep(0.05)
        operator_line(runner, "replace 2", said.append)

    result = dry_run(tmp_path, plan=plan, failures=(Failure(6, 1.0, "motor"),),
                     during=replace_two, runner=RunnerConfig(use_spares=False))
    report = result.report
    assert report["unsafe_reasons"] == ["vehicle(s) [6] did not land under control",
                                        "vehicle(s) [6] crashed"], report["unsafe_reasons"]
    assert report["spares"] == {"asked": 2, "ready": 2, "used": 0, "replacements": []}
    assert [vehicle(report, s)["phase"] for s in SPARES] == ["not flown"] * 2
    assert not any(f["complete"] for f in report["pattern_error_m"][1:])
    assert vehicle(report, 2)["phase"] == "landed" and vehicle(report, 2)["reason"] is None
    texts = [e.get("text", "") for e in _events(tmp_path, "sequence")]
    assert any("stays dark" in t and "--no-spares" in t for t in texts), texts
    assert any("replace 2: spares are off for this flight" in t for t in texts), texts
