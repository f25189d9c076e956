"""The shows shipped in shows/ load, and their numbers are physically consistent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from groundctl.plan.feasibility import min_transition_time
from groundctl.show.loader import assigned_goals, load_show
from groundctl.show.model import QuadrotorModel, UnicycleModel

SHOWS = Path(__file__).resolve().parent.parent / "shows"


def dubins_to_point(start: np.ndarray, heading: np.ndarray, goal: np.ndarray,
                    r: float) -> np.ndarray:
    """Shortest turn-limited path length from a pose to a point (free final heading).

    Turn left or right on a circle of radius ``r``, then fly straight along the
    tangent: the shorter of the two (the goal is never inside either circle here).
    """
    best = np.full(len(start), np.inf)
    for side in (1.0, -1.0):
        c = start + side * r * np.column_stack([-np.sin(heading), np.cos(heading)])
        v = goal - c
        d = np.linalg.norm(v, axis=1)
        straight = np.sqrt(np.maximum(d**2 - r**2, 0.0))
        a_start = np.arctan2(start[:, 1] - c[:, 1], start[:, 0] - c[:, 0])
        a_tangent = np.arctan2(v[:, 1], v[:, 0]) - side * np.arccos(np.clip(r / d, -1, 1))
        arc = r * np.mod(side * (a_tangent - a_start), 2 * np.pi)
        best = np.minimum(best, np.where(d >= r, arc + straight, np.inf))
    return best


@pytest.mark.parametrize("name", sorted(p.name for p in SHOWS.glob("*.toml")))
def test_bundled_show_loads(name):
    show = load_show(SHOWS / name)
    assert show.drones > 0 and show.formations
    for f in show.formations:
        assert len(f.points) >= show.drones
        assert np.all((f.colors >= 0) & (f.colors <= 1))


def test_paper_star_is_the_papers_setting_and_flyable_at_constant_speed():
    show = load_show(SHOWS / "paper_star.toml")
    model = show.model
    assert isinstance(model, UnicycleModel)
    assert (show.drones, model.speed, model.r_min, model.turn_rate_limit) == (25, 2.0, 1.5, 1.0)
    assert show.limits.min_separation == 0.8
    assert (show.planner.steps, show.planner.pattern_tolerance) == (100, 0.1)
    (star,) = show.formations
    assert star.shape == "star" and star.transition_s == 20.0
    assert np.all(np.abs(show.home[:, :2]) <= 50.0)  # inside the 100 m x 100 m field
    start = show.start_positions
    goal = assigned_goals(show)[0]
    dist = np.linalg.norm(goal - start, axis=1)
    path = model.speed * star.transition_s  # every path is exactly 40 m
    assert dist.max() <= path - 2.0
    assert dist.min() >= 0.7 * path
    assert dist.mean() == pytest.approx(32.4, abs=0.1)  # the paper's average path
    assert show.start_headings is not None
    shortest = dubins_to_point(start[:, :2], show.start_headings, goal[:, :2], model.r_min)
    assert shortest.max() <= path


def test_paper_transitions_times_cover_every_drone_at_constant_speed():
    show = load_show(SHOWS / "paper_transitions.toml")
    model = show.model
    assert isinstance(model, UnicycleModel)
    assert [f.shape for f in show.formations] == ["square", "spiral", "circle"]
    # The drones start on the first circle, 25 evenly spaced on 12 m.
    r = np.linalg.norm(show.home[:, :2], axis=1)
    np.testing.assert_allclose(r, 6.0, atol=1e-3)
    prev = show.start_positions
    for f, goal in zip(show.formations, assigned_goals(show), strict=True):
        dist = np.linalg.norm(goal - prev, axis=1)
        path = model.speed * f.transition_s
        assert dist.max() <= path - 1.5, f.name  # room for the turn at the start
        assert dist.min() >= 0.7 * path, f.name  # nobody has to loiter for long
        assert f.hold_s == 0
        prev = goal


def test_demo_is_a_comfortable_64_drone_quadrotor_show():
    show = load_show(SHOWS / "demo.toml")
    assert isinstance(show.model, QuadrotorModel)
    assert show.drones == 64 and show.takeoff_altitude == 3.0
    assert show.limits.geofence is not None
    names = [f.name for f in show.formations]
    assert names == ["ring", "star", "hello", "globe", "landing"]
    total = sum(f.transition_s + f.hold_s for f in show.formations)
    assert 120 <= total <= 180
    prev = show.start_positions
    for f, goal in zip(show.formations, assigned_goals(show), strict=True):
        need = min_transition_time(prev, goal, show.limits, show.model).seconds
        assert f.transition_s >= 1.5 * need, f.name
        prev = goal
    for f in show.formations[:-1]:
        assert 3.0 <= f.hold_s <= 5.0
