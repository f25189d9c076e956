"""The paper's unicycle experiments reach the paper's pattern error (issue 14).

Outcome tests, not timed: the verifier (cubic Hermite trajectories, dense
separation check) judges the plans of the bundled paper shows.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from groundctl.plan.planner import plan_show
from groundctl.plan.scp_unicycle import (
    AIM_MARGIN,
    pattern_half_width,
    plan_unicycle_transition,
)
from groundctl.show.loader import load_show
from groundctl.show.model import Limits, PlannerSettings, UnicycleModel

SHOWS = Path(__file__).resolve().parent.parent / "shows"
#: The source paper's pattern error on its star, m.
PAPER_PATTERN_ERROR = 0.05


@pytest.mark.parametrize("name", ["paper_star", "paper_transitions"])
def test_paper_show_reaches_the_papers_pattern_error(name: str) -> None:
    show = load_show(SHOWS / f"{name}.toml")
    ver = plan_show(show, workers=1).verification
    assert ver.safe, ver.violations
    assert len(ver.pattern_errors) == len(show.formations)
    assert max(ver.pattern_errors) <= PAPER_PATTERN_ERROR
    # Collision-free in continuous time, not only at the QP's samples.
    assert ver.overall.min_separation >= show.limits.min_separation


def test_pattern_box_corners_lie_on_half_the_tolerance() -> None:
    # The QP's pattern rows are a box per drone: its corner, not its side, must be
    # within eps/2, or the cost parks the end point in the corner (eps/2 sqrt(2)).
    for eps in (0.1, 0.25, 0.5):
        half = pattern_half_width(eps)
        assert np.hypot(half, half) == pytest.approx(eps / 2 - AIM_MARGIN)


def test_unicycle_swap_ends_within_half_the_tolerance() -> None:
    start = np.array([[-15.0, 0.0, 0], [15.0, 0.0, 0], [0.0, -15.0, 0]])
    goal = np.array([[12.0, 0.5, 0], [-12.0, -0.5, 0], [0.0, 12.0, 0]])
    res, _ = plan_unicycle_transition(
        1, "swap", start, goal, np.array([0.0, np.pi, np.pi / 2]), 15.0, 10.0,
        Limits(min_separation=1.0, min_alt=0.0), UnicycleModel(speed=2.0, r_min=1.5),
        PlannerSettings(steps=80, pattern_tolerance=0.2))
    end = res.trajectories.pos[:, -1, :2]
    assert np.linalg.norm(end - goal[:, :2], axis=1).max() <= 0.1
