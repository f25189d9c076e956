"""The planner's floor: synchronised straight lines checked exactly, and flown when safe;
a planning worker that dies."""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import threading
from pathlib import Path

import numpy as np
import pytest

from groundctl.cli import main
from groundctl.plan.feasibility import min_transition_time
from groundctl.plan.planner import plan_show
from groundctl.plan.scp_quad import plan_quad_transition
from groundctl.plan.straight import check_straight_lines, segment_closest
from groundctl.plan.verify import _dense_pass
from groundctl.show.loader import load_show
from groundctl.show.model import Limits, PlannerSettings, QuadrotorModel

LIMITS = Limits()


def _grid(side: int, spacing: float, z: float) -> np.ndarray:
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2) * spacing
    return np.c_[g, np.full(len(g), z)]


def test_the_closed_form_closest_approach_matches_dense_sampling() -> None:
    rng = np.random.default_rng(7)
    r0, r1 = rng.normal(0.0, 3.0, (500, 3)), rng.normal(0.0, 3.0, (500, 3))
    s = np.linspace(0.0, 1.0, 20001)
    dense = np.linalg.norm(r0[:, None] + s[None, :, None] * (r1 - r0)[:, None], axis=2)
    exact = segment_closest(r0, r1)
    assert np.all(exact <= dense.min(axis=1) + 1e-12)
    assert np.allclose(exact, dense.min(axis=1), atol=1e-6)
    assert segment_closest(np.array([2.0, 0, 0]), np.array([2.0, 0, 0])) == 2.0  # at rest


def test_every_pair_is_checked_whatever_the_block() -> None:
    rng = np.random.default_rng(11)
    start, goal = rng.uniform(0, 20, (300, 3)), rng.uniform(0, 20, (300, 3))
    whole = check_straight_lines(start, goal, 1.5, 0.2, block=1000)
    for block in (1, 7, 64):
        assert check_straight_lines(start, goal, 1.5, 0.2, block=block) == whole
    i, j = whole.pair  # type: ignore[misc]
    assert whole.min_separation_m == pytest.approx(
        float(segment_closest(start[i] - start[j], goal[i] - goal[j])))
    brute = [float(segment_closest(start[a] - start[b], goal[a] - goal[b]))
             for a in range(300) for b in range(a + 1, 300)]
    assert whole.min_separation_m == pytest.approx(min(brute))
    assert whole.below_limit == sum(d < 1.5 for d in brute)
    assert whole.below_target >= whole.below_limit
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        check_straight_lines(start[:, :2], goal[:, :2], 1.5)


def test_a_tight_grid_whose_straight_lines_keep_the_limit_is_planned_in_one_pass() -> None:
    # The case: 100 drones 1.526 m apart at a 1.5 m limit, flown parallel to a
    # higher grid at 1.3 times the minimum time.  The optimiser alone refused it after
    # 30 SCP iterations (24 s): "no separation-feasible solution (slack 0.021 m)".
    start = _grid(10, 1.526, 10.0)
    goal = start + np.array([4.0, 3.0, 4.0])
    duration = 1.3 * min_transition_time(start, goal, LIMITS, QuadrotorModel()).seconds
    result = plan_quad_transition(1, "wall", start, goal, duration, LIMITS, PlannerSettings())
    assert result.straight and result.iterations == 0 and result.qp_drones == 0
    assert result.straight_min_separation == pytest.approx(1.526)
    # The continuous-time verifier agrees: the limit is kept between the knots too.
    dense = _dense_pass(result.trajectories)
    assert dense.seg_sep.min() >= LIMITS.min_separation - 1e-9


def test_crossing_drones_still_get_real_avoidance() -> None:
    # Two rows swapping places at 1.05 x the spacing of the limit: straight lines collide.
    row = np.c_[np.arange(6) * 1.05 * LIMITS.min_separation, np.zeros(6), np.full(6, 10.0)]
    start = np.concatenate([row, row + np.array([0.0, 6.0, 0.0])])
    goal = np.concatenate([row + np.array([0.0, 6.0, 0.0]), row])
    lines = check_straight_lines(start, goal, LIMITS.min_separation)
    assert not lines.keeps_limit and lines.min_separation_m < 0.01
    duration = 1.5 * min_transition_time(start, goal, LIMITS, QuadrotorModel()).seconds
    result = plan_quad_transition(1, "swap", start, goal, duration, LIMITS,
                                  PlannerSettings())
    assert not result.straight and result.iterations >= 1 and result.qp_drones > 0
    dense = _dense_pass(result.trajectories)
    assert dense.seg_sep.min() >= LIMITS.min_separation - 1e-9


TIGHT_SHOW = """
[show]
name = "tight"
drones = 100
takeoff_altitude = 3.0

[origin]
lat = 47.3977
lon = 8.5456
alt = 488.0
heading = 0.0

[limits]
max_speed_h = 4.0
max_speed_up = 2.5
max_speed_down = 1.5
max_accel = 2.5
min_separation = 1.5
min_altitude = 2.0
max_altitude = 40.0

[takeoff]
layout = "grid"
spacing = 1.526
columns = 10
center = [0.0, 0.0]

[[formation]]
name = "low"
shape = "grid"
plane = "horizontal"
columns = 10
spacing = 1.526
center = [0.0, 0.0, 10.0]
transition = 6.0
hold = 2.0
color = "#ffffff"

[[formation]]
name = "shifted"
shape = "grid"
plane = "horizontal"
columns = 10
spacing = 1.526
center = [4.0, 3.0, 14.0]
transition = 6.0
hold = 2.0
color = "#ff0000"

[landing]
transition = 12.0
hold = 1.0
"""


def test_groundctl_plan_flies_a_tight_show_on_its_straight_lines(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """100 drones 1.526 m apart (limit 1.5) from the takeoff grid to two grids and down:
    every transition keeps the limit on its straight lines, so none is optimised (the
    optimiser alone ran for more than 6 minutes on this show without a result)."""
    show = tmp_path / "tight.toml"
    show.write_text(TIGHT_SHOW)
    assert main(["plan", str(show), "-o", str(tmp_path / "tight.plan.npz"), "--json",
                 "--workers", "1"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["safe"] and report["min_separation_m"] >= 1.5 - 1e-9
    assert [(t["name"], t["straight_lines"], t["iterations"]) for t in report["transitions"]
            ] == [("low", True, 0), ("shifted", True, 0), ("landing", True, 0)]
    assert all(t["straight_min_separation_m"] == pytest.approx(1.526)
               for t in report["transitions"])
    assert all(t["converged"] for t in report["transitions"])


def test_a_planning_worker_that_dies_does_not_lose_the_show() -> None:
    """A worker process killed mid-plan (out of memory, say): its transitions are planned
    again in a fresh worker, with the same result (the error, had there been one, would be
    the transition's own, not "a process in the pool was terminated abruptly")."""
    show = load_show(Path(__file__).resolve().parents[1] / "shows" / "demo.toml")
    killed: list[int] = []

    def kill_first_worker() -> None:
        for _ in range(20000):
            children = multiprocessing.active_children()
            if children and children[0].pid is not None:
                os.kill(children[0].pid, signal.SIGKILL)
                killed.append(children[0].pid)
                return
            threading.Event().wait(0.0005)

    killer = threading.Thread(target=kill_first_worker)
    killer.start()
    result = plan_show(show, workers=2)
    killer.join()
    assert killed, "no worker process was seen to kill"
    serial = plan_show(show, workers=1)
    assert result.verification.safe
    assert np.allclose(result.plan.trajectories.pos, serial.plan.trajectories.pos)


def test_a_pair_ending_just_above_the_limit_is_planned_with_its_own_bulge() -> None:
    """Drone 1 flies to where drone 2 was, which side-steps to end 1.53 m from it: their
    straight lines pass at 1.48 m.  The rows tighten each pair-segment by the bulge of the
    pair's own relative motion, not by the largest two drones could have (0.04 m at this
    step), which at the goal, where the slots are fixed 1.53 m apart, could never be
    met: the optimiser refused this after 30 SCP iterations."""
    start = np.array([[0.0, 0.0, 10.0], [0.0, 6.0, 10.0]])
    goal = np.array([[0.0, 6.0, 10.0], [1.53, 6.0, 10.0]])
    lines = check_straight_lines(start, goal, LIMITS.min_separation)
    assert lines.min_separation_m == pytest.approx(1.4826, abs=1e-4)
    duration = 1.5 * min_transition_time(start, goal, LIMITS, QuadrotorModel()).seconds
    result = plan_quad_transition(1, "side", start, goal, duration, LIMITS,
                                  PlannerSettings())
    assert not result.straight and result.iterations <= 5
    dense = _dense_pass(result.trajectories)
    assert dense.seg_sep.min() >= LIMITS.min_separation
