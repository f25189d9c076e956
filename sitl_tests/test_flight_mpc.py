"""End to end: MPC replanning against the simulator over real UDP (quick show, x8).

A vehicle pushed off its path mid-show (the simulator carries it 3 m up over a
second, as a gust would) is replanned with MPC back onto its path, clear of its
neighbours, and stays in the show; a weak vehicle (60 % of its speed and
acceleration) that falls behind is flown safely too.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from flight_fixtures import dry_run, flavours, show_time, until, vehicle

from groundctl.flight.dryrun import Push
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.link.flavours import Flavour
from groundctl.record.events import read_events
from groundctl.sim.process import SimProcess


def _events(record: Path, name: str) -> list[dict]:
    return [e for e in read_events(record / "events.jsonl") if e["event"] == name]


def _safe(report: dict) -> None:
    why = (report["unsafe_reasons"], [(v["system_id"], v["phase"], v["reason"])
                                      for v in report["vehicles"]])
    assert report["safe"], why
    assert [v["phase"] for v in report["vehicles"]] == ["landed"] * 9, why
    assert report["true_min_separation_m"] >= report["separation_limit_m"]
    assert report["simulator"]["crashed"] == []


@pytest.mark.parametrize("flavour", flavours(Flavour.ARDUPILOT))
def test_a_push_mid_show_is_corrected_by_mpc_and_the_vehicle_stays_in_the_show(
        flavour: Flavour, tmp_path: Path) -> None:
    result = dry_run(tmp_path, flavour=flavour, pushes=(Push(5, 12.0, (0.0, 0.0, 3.0)),))
    report = result.report
    assert result.error is None, result.error
    _safe(report)
    mpc = report["mpc"]
    assert mpc["activations"] >= 1 and 5 in mpc["vehicles"], mpc
    assert mpc["solve_ms"]["solves"] > 0
    started = _events(tmp_path, "mpc_started")
    assert started and started[0]["system_id"] == 5
    assert [e["system_id"] for e in _events(tmp_path, "mpc_ended")].count(5) >= 1
    assert vehicle(report, 5)["reason"] is None  # back on its path, not taken out
    # Pushed 3 m up: one excursion beyond 0.5 m, timed until it was back within it.
    back = vehicle(report, 5)["recovery_s"]
    assert back and all(t is not None and t > 0 for t in back), back
    assert report["recovery"]["excursions"] >= len(back) and report["recovery"]["never"] == 0


def test_without_mpc_the_same_push_is_flown_by_the_autopilot_alone(tmp_path: Path) -> None:
    result = dry_run(tmp_path, pushes=(Push(5, 12.0, (0.0, 0.0, 3.0)),),
                     runner=RunnerConfig(mpc=False))
    report = result.report
    assert report["mpc"] == {**report["mpc"], "enabled": False, "activations": 0}
    assert _events(tmp_path, "mpc_started") == []
    assert _events(tmp_path, "push")[0]["system_id"] == 5


def test_a_weak_vehicle_is_seen_by_its_throttle_and_flown_safely(tmp_path: Path) -> None:
    # Vehicle 1 hovers at 0.35 / 0.6 of full throttle against its fleet's 0.35: its
    # authority is known before the show starts, and the MPC flies it while its path
    # ahead asks more than 60 % of the limits (its first climb, 2.0 m/s: it manages 1.5).
    result = dry_run(weak=((1, 0.6),), record_dir=tmp_path)
    assert result.error is None, result.error
    _safe(result.report)
    mpc = result.report["mpc"]
    assert mpc["weak"] == {"1": pytest.approx(0.6, abs=0.03)}
    started = _events(tmp_path, "mpc_started")
    assert started and started[0]["system_id"] == 1, started
    assert "asks more than it can fly" in started[0]["why"]
    # Anyone else put under MPC is there to keep clear of the weak one (its re-timed
    # trajectory predicted within the limit of a neighbour's path: both are replanned,
    # seen in CI on a busy machine), never for a deviation or a demand of its own.
    others = [e for e in started if e["system_id"] != 1]
    assert all(e["why"].startswith("predicted within") and e["why"].endswith("of vehicle 1")
               for e in others), others


def test_a_land_all_with_a_weak_vehicle_returns_within_what_the_weak_one_can_fly(
        tmp_path: Path) -> None:
    # Land-all mid-transition with vehicle 1 at 60 %: the return is planned within 60 % of
    # the limits for everyone (and given the time that takes), so vehicle 1 flies it as
    # planned (test_plan_leave checks the plan itself); a return at the full limits left it
    # lagging next to vehicle 7 (1.38 m) on a ground station too busy to keep the show.
    async def operate(runner: ShowRunner, sim: SimProcess) -> None:
        await until(runner, lambda: show_time(runner) > 11.0)
        runner.land_all()

    result = dry_run(weak=((1, 0.6),), record_dir=tmp_path, during=operate)
    assert result.error is None, result.error
    _safe(result.report)
    planning = _events(tmp_path, "return_planning")
    # The authority is measured from hover throttles averaged over seconds: within 0.05 of
    # the truth even on a busy machine (0.63 seen in CI); the return flown safely is the
    # claim, checked above.
    assert planning and planning[0]["authority"] == pytest.approx(0.6, abs=0.05)
    assert "of the limits: vehicle 1 is weak)" in planning[0]["text"]
    assert any(e["text"].startswith("flying the") for e in _events(tmp_path, "sequence"))
