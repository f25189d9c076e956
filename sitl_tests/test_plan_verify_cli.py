"""Verifier, plan file, and the plan / check commands' exit codes and JSON."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from plan_fixtures import points_show

from groundctl.cli import main
from groundctl.errors import PlanFileError
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.planner import plan_show
from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import verify
from groundctl.show.model import GeoOrigin, Limits

SHOW_TOML = """
[show]
name = "tiny"
drones = 4
takeoff_altitude = 3.0
[origin]
lat = 47.0
lon = 8.0
alt = 400.0
[limits]
min_separation = 1.5
[takeoff]
layout = "grid"
spacing = 3.0
columns = 2
[[formation]]
name = "line"
shape = "line"
center = [0.0, 0.0, 10.0]
size = 9.0
transition = {transition}
hold = 1.0
color = "#ff0000"
"""


def straight_plan(speed_scale: float = 1.0) -> Plan:
    """Two drones flying straight through each other: unsafe on purpose."""
    times = np.array([0.0, 5.0, 10.0])
    pos = np.array([[[-5, 0, 10], [0, 0, 10], [5, 0, 10]],
                    [[5, 0, 10], [0, 0.5, 10], [-5, 0, 10]]], dtype=float)
    vel = np.zeros_like(pos)
    vel[:, 1, 0] = [1.0 * speed_scale, -1.0 * speed_scale]
    goals = pos[:, -1]
    return Plan(show_name="bad", origin=GeoOrigin(47, 8, 400), limits=Limits(min_alt=1.0),
                model="quadrotor", home=pos[:, 0] - [0, 0, 10], takeoff_altitude=10.0,
                trajectories=Trajectories(times, pos, vel), color_times=np.array([0.0]),
                colors=np.ones((2, 1, 3)),
                formations=(FormationWindow(1, "x", 0.0, 10.0, 10.0, goals),))


def test_verifier_catches_a_hand_made_collision() -> None:
    ver = verify(straight_plan())
    assert not ver.safe
    assert ver.overall.min_separation == pytest.approx(0.5, abs=1e-3)
    assert ver.worst_violation == pytest.approx(1.0, abs=1e-3)
    assert ver.violations[0] == ("drones 1 and 2 come 0.500 m apart at t = 5.00 s "
                                 "(min_separation 1.5 m)")


def test_verifier_catches_speed_between_knots() -> None:
    ver = verify(straight_plan(speed_scale=8.0))
    assert any(v.startswith("horizontal speed reaches") for v in ver.violations)


def test_planned_show_is_safe_and_round_trips_through_a_file(tmp_path: Path) -> None:
    home = np.array([[0.0, 0, 0], [3.0, 0, 0], [6.0, 0, 0]])
    targets = [np.array([[6.0, 0, 8], [3.0, 0, 8], [0.0, 0, 8]])]
    result = plan_show(points_show(home, targets), workers=1)
    assert result.verification.safe, result.verification.violations
    plan = result.plan
    st = plan.state_at(plan.formations[0].arrive)
    assert np.allclose(st.pos, plan.formations[0].goals, atol=1e-3)
    assert np.allclose(st.rgb, [1.0, 0.0, 0.0])
    path = plan.save(tmp_path / "p.plan.npz")
    again = Plan.load(path)
    assert np.array_equal(again.trajectories.pos, plan.trajectories.pos)
    assert again.formations[0].name == "f1" and again.limits == plan.limits
    assert again.mpc == plan.mpc  # the show's [mpc] settings fly with the plan
    mid = plan.duration / 2
    assert np.allclose(again.state_at(mid).pos, plan.state_at(mid).pos)


def test_loading_a_non_plan_says_so(tmp_path: Path) -> None:
    bad = tmp_path / "x.plan.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(PlanFileError, match="not a groundctl plan"):
        Plan.load(bad)
    with pytest.raises(PlanFileError, match="no such file"):
        Plan.load(tmp_path / "missing.npz")


def test_plan_command_json_and_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    show = tmp_path / "tiny.toml"
    show.write_text(SHOW_TOML.format(transition=10.0))
    out = tmp_path / "tiny.plan.npz"
    assert main(["plan", str(show), "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("drones", "transitions", "min_separation_m", "max_speed_mps", "max_accel_mps2",
                "pattern_error_m", "plan_seconds", "safe"):
        assert key in report
    assert report["drones"] == 4 and report["safe"] is True
    assert report["min_separation_m"] >= 1.5 - 1e-3
    assert report["transitions"][0]["name"] == "line"
    assert main(["check", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["safe"] is True


def test_infeasible_show_exits_3_with_the_minimum_time(tmp_path: Path) -> None:
    show = tmp_path / "tiny.toml"
    show.write_text(SHOW_TOML.format(transition=1.0))
    proc = subprocess.run([sys.executable, "-m", "groundctl", "plan", str(show), "-o",
                           str(tmp_path / "x.npz")], capture_output=True, text=True, timeout=60)
    assert proc.returncode in (2, 3)
    assert "too short" in proc.stderr or "needs at least" in proc.stderr
    assert proc.stderr.count("\n") == 1  # one clear line, no traceback


def test_check_of_an_unsafe_plan_exits_1(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    path = straight_plan().save(tmp_path / "bad.plan.npz")
    assert main(["check", str(path)]) == 1
    assert "UNSAFE" in capsys.readouterr().out


def test_check_of_garbage_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.npz"
    bad.write_text("hello")
    assert main(["check", str(bad)]) == 2
    assert "not a groundctl plan" in capsys.readouterr().err
