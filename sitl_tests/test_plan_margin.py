"""The quadrotor planner's tracking margin: planned separation beyond the limit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from groundctl.errors import ShowFileError
from groundctl.plan.scp_quad import plan_quad_transition
from groundctl.plan.trajectory import Trajectories
from groundctl.show.loader import load_show
from groundctl.show.model import Limits, PlannerSettings

LIM = Limits(min_separation=1.5, min_alt=0.0, max_alt=100.0)
SHOWS = Path(__file__).resolve().parents[1] / "shows"


def _min_distance(tr: Trajectories) -> float:
    pos, _, _ = tr.evaluate(tr.dense_times(40))
    i, j = np.triu_indices(tr.drones, 1)
    return float(np.linalg.norm(pos[i] - pos[j], axis=2).min())


@pytest.mark.parametrize("margin", [0.0, 0.2, 0.4])
def test_a_head_on_swap_keeps_the_margin_beyond_the_limit(margin: float) -> None:
    start = np.array([[-5.0, 0, 10], [5.0, 0, 10]])
    res = plan_quad_transition(1, "swap", start, start[::-1].copy(), 10.0, LIM,
                               PlannerSettings(tracking_margin=margin))
    # The rows ask for limit + margin + the chord-bulge and buffer terms (~0.08 m here).
    assert 1.5 + margin - 1e-3 <= _min_distance(res.trajectories) <= 1.5 + margin + 0.12


def test_the_margin_shrinks_to_what_close_formation_slots_allow() -> None:
    # Two drones 1.6 m apart at both ends swap sides of a third: the pair's own
    # slots leave no room for a margin, yet the plan still keeps the limit.
    start = np.array([[0.0, 0.0, 10.0], [1.6, 0.0, 10.0], [0.8, -6.0, 10.0]])
    goal = np.array([[0.0, 0.0, 14.0], [1.6, 0.0, 14.0], [0.8, 6.0, 10.0]])
    res = plan_quad_transition(1, "squeeze", start, goal, 12.0, LIM,
                               PlannerSettings(tracking_margin=0.3))
    assert _min_distance(res.trajectories) >= 1.5 - 1e-3


def test_bundled_flying_shows_set_a_margin_and_the_loader_bounds_it(tmp_path: Path) -> None:
    assert load_show(SHOWS / "demo.toml").planner.tracking_margin == 0.2
    assert load_show(SHOWS / "quick.toml").planner.tracking_margin == 0.2
    bad = tmp_path / "bad.toml"
    bad.write_text((SHOWS / "quick.toml").read_text().replace("tracking_margin = 0.2",
                                                              "tracking_margin = 3.0"))
    with pytest.raises(ShowFileError, match="tracking_margin"):
        load_show(bad)
