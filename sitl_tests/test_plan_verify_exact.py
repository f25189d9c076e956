"""The verifier at scale: exact closest approaches per segment, figures per segment, the
same verdict as brute force; a transition left in conflict names its drones (issue 14)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from groundctl.errors import PlanningError, SeparationConflict
from groundctl.plan.feasibility import min_transition_time
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.scp_quad import plan_quad_transition
from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import SAMPLES, _dense_pass, close_pairs, inside_polygon, verify
from groundctl.show.model import GeoOrigin, Limits, PlannerSettings, QuadrotorModel

LIMITS = Limits()


def _random_fleet(seed: int, n: int = 40, knots: int = 7) -> Trajectories:
    """Drones wandering through a small box: many close passes, a few near misses."""
    rng = np.random.default_rng(seed)
    times = np.cumsum(np.r_[0.0, rng.uniform(0.3, 0.8, knots - 1)])
    pos = rng.uniform([0, 0, 2], [12, 12, 8], (n, knots, 3))
    vel = rng.normal(0.0, 2.0, (n, knots, 3))
    return Trajectories(times, pos, vel)


def _brute(tr: Trajectories, per_segment: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """Per segment, the min over every pair of sampled distances (an upper bound on the
    true minimum, within a few micrometres of it at this density)."""
    out = np.empty(len(tr.times) - 1)
    for k in range(len(tr.times) - 1):
        t = np.linspace(tr.times[k], tr.times[k + 1], per_segment + 1)
        pos, _, _ = tr.evaluate(t)
        i, j = np.triu_indices(tr.drones, 1)
        out[k] = np.linalg.norm(pos[i] - pos[j], axis=2).min()
    return out, out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_each_segments_closest_pair_is_exact(seed: int) -> None:
    tr = _random_fleet(seed)
    dense = _dense_pass(tr)
    brute, _ = _brute(tr)
    # Never above what sampling finds (it is the minimum), and within sampling's error.
    assert np.all(dense.seg_sep <= brute + 1e-9)
    assert np.allclose(dense.seg_sep, brute, atol=2e-4)
    # The pair named is the pair at that distance, at that time.
    for k in range(len(tr.times) - 1):
        i, j = dense.seg_pair[k] - 1
        pi, _, _ = tr.evaluate(dense.seg_time[k], np.array([i, j]))
        assert np.linalg.norm(pi[0] - pi[1]) == pytest.approx(dense.seg_sep[k], abs=1e-9)
        assert tr.times[k] <= dense.seg_time[k] <= tr.times[k + 1]


def test_the_figures_per_segment_are_those_of_the_dense_samples() -> None:
    tr = _random_fleet(5, n=300)  # more than one drone chunk
    fence = np.array([[1.0, 1.0], [11.0, 1.0], [11.0, 11.0], [1.0, 11.0]])
    dense = _dense_pass(tr, fence)
    pos, vel, acc = tr.evaluate(tr.dense_times(SAMPLES))
    assert dense.seg_speed_h.max() == pytest.approx(np.hypot(vel[..., 0], vel[..., 1]).max())
    assert dense.seg_up.max() == pytest.approx(vel[..., 2].max())
    assert dense.seg_down.max() == pytest.approx(-vel[..., 2].min())
    # Acceleration is exact: its largest norm at either end of a segment's own cubic
    # (the samples at a knot read the next segment's).
    assert dense.seg_accel.max() >= np.linalg.norm(acc, axis=2).max() - 1e-9
    h = np.diff(tr.times)[None, :, None]
    c2 = 3 * (tr.pos[:, 1:] - tr.pos[:, :-1]) - 2 * tr.vel[:, :-1] * h - tr.vel[:, 1:] * h
    c3 = 2 * (tr.pos[:, :-1] - tr.pos[:, 1:]) + (tr.vel[:, :-1] + tr.vel[:, 1:]) * h
    ends = np.maximum(np.linalg.norm(2 * c2, axis=2), np.linalg.norm(2 * c2 + 6 * c3, axis=2))
    assert np.allclose(dense.seg_accel, (ends / h[..., 0] ** 2).max(axis=0))
    assert dense.seg_min_alt.min() == pytest.approx(pos[..., 2].min())
    assert dense.seg_max_alt.max() == pytest.approx(pos[..., 2].max())
    path = np.linalg.norm(np.diff(pos, axis=1), axis=2).sum()
    assert dense.seg_path.sum() == pytest.approx(path)
    assert dense.seg_outside.sum() == (~inside_polygon(fence, pos[..., :2])).sum() > 0
    # Segment 2 alone: its own samples, both knots included.
    seg = slice(2 * SAMPLES, 3 * SAMPLES + 1)
    assert dense.seg_speed_h[2] == pytest.approx(
        np.hypot(vel[:, seg, 0], vel[:, seg, 1]).max())


def test_two_dips_in_one_segment_the_deeper_one_is_found() -> None:
    # The relative path crosses near the other drone twice in one long segment; the
    # shallower dip is the better one on a coarse grid (a review's counterexample).
    times = np.array([0.0, 4.0])
    pos = np.array([[[0.0, 0.0, 5.0], [0.0, 0.0, 5.0]],
                    [[-20.0, 0.5138, 5.0], [20.0, 0.5138, 5.0]]])
    vel = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
                    [[30.0, 0.0, 0.0], [30.0, -0.5, 0.0]]])
    tr = Trajectories(times, pos, vel)
    brute, _ = _brute(tr, 200_000)
    dense = _dense_pass(tr)
    assert dense.seg_sep[0] <= brute[0] + 1e-9
    assert dense.seg_sep[0] == pytest.approx(brute[0], abs=2e-6)
    found = close_pairs(tr, float(brute[0]) + 1e-4)
    assert [p[:2] for p in found] == [(1, 2)]


def test_close_pairs_lists_every_pair_under_the_limit() -> None:
    tr = _random_fleet(9, n=25)
    limit = 1.0
    t = tr.dense_times(2000)
    pos, _, _ = tr.evaluate(t)
    i, j = np.triu_indices(tr.drones, 1)
    d = np.linalg.norm(pos[i] - pos[j], axis=2).min(axis=1)
    expected = {(int(a) + 1, int(b) + 1) for a, b, x in zip(i, j, d, strict=True) if x < limit}
    found = close_pairs(tr, limit)
    assert expected and {(a, b) for a, b, _, _ in found} == expected
    dists = [x for _, _, x, _ in found]
    assert dists == sorted(dists)


def test_a_fleet_in_a_plan_is_verified_like_before() -> None:
    # A plan that passes very close once: verify() names that pair, at that time.
    times = np.array([0.0, 2.0, 4.0])
    pos = np.array([[[0, 0, 5], [2, 0, 5], [4, 0, 5]],
                    [[4, 1.2, 5], [2, 1.2, 5], [0, 1.2, 5]],
                    [[0, 9, 5], [0, 9, 5], [0, 9, 5]]], dtype=float)
    vel = np.zeros_like(pos)
    vel[0, 1], vel[1, 1] = [1.5, 0, 0], [-1.5, 0, 0]
    tr = Trajectories(times, pos, vel)
    plan = Plan(show_name="x", origin=GeoOrigin(47.0, 8.0, 400.0), limits=LIMITS,
                model="quadrotor", home=np.c_[pos[:, 0, :2], np.zeros(3)], takeoff_altitude=3.0,
                trajectories=tr, color_times=np.array([0.0]), colors=np.ones((3, 1, 3)),
                formations=(FormationWindow(1, "f", 0.0, 4.0, 4.0, pos[:, -1]),))
    ver = verify(plan)
    assert ver.overall.min_separation == pytest.approx(1.2)
    assert ver.overall.min_separation_pair == (1, 2)
    assert ver.overall.min_separation_time == pytest.approx(2.0)
    assert "drones 1 and 2 come 1.200 m apart at t = 2.00 s" in ver.violations[0]


def test_a_swap_with_no_time_to_go_around_is_refused_naming_the_pair() -> None:
    # Two drones 3 m apart swapping places head on, with 2 % more time than the straight
    # line needs: going round each other is longer than that allows.
    start = np.array([[0.0, 0.0, 10.0], [3.0, 0.0, 10.0]])
    goal = start[::-1].copy()
    duration = 1.02 * min_transition_time(start, goal, LIMITS, QuadrotorModel()).seconds
    t0 = time.perf_counter()
    with pytest.raises(SeparationConflict) as err:
        plan_quad_transition(4, "swap", start, goal, duration, LIMITS, PlannerSettings())
    assert time.perf_counter() - t0 < 60.0  # fails, and does not hang (generous bound)
    e = err.value
    assert isinstance(e, PlanningError) and e.transition == 4 and e.name == "swap"
    assert [p[:2] for p in e.pairs] == [(1, 2)] and e.conflicts == 1
    assert e.spacing == pytest.approx(3.0) and e.safe_spacing == pytest.approx(2.1213, abs=1e-4)
    msg = str(e)
    assert msg.startswith("transition 4: planner failed: no separation-feasible solution (slack ")
    assert "SCP iterations: drones 1 and 2 " in msg
    assert ("its slots are 3.00 m apart, so the straight lines of the planner's own "
            "assignment would be conflict-free") in msg
    assert "\n" not in msg


def test_the_budget_stops_the_search_and_names_the_drones() -> None:
    # Rows of drones crossing through each other at 1.05 x the limit's spacing: real
    # avoidance.  With a clock that has already run out, the search stops at once.
    row = np.c_[np.arange(6) * 1.05 * LIMITS.min_separation, np.zeros(6), np.full(6, 10.0)]
    start = np.concatenate([row, row + np.array([0.0, 6.0, 0.0])])
    goal = np.concatenate([row + np.array([0.0, 6.0, 0.0]), row])
    duration = 1.5 * min_transition_time(start, goal, LIMITS, QuadrotorModel()).seconds
    ticks = iter(np.arange(0.0, 1e6, 10.0))
    with pytest.raises(SeparationConflict) as err:
        plan_quad_transition(2, "cross", start, goal, duration, LIMITS, PlannerSettings(),
                             budget_s=15.0, clock=lambda: float(next(ticks)))
    assert PlannerSettings().budget_s == 40.0
    e = err.value
    assert e.reason == "no plan within the 15 s budget (1 SCP iterations)"
    assert e.conflicts >= 6 and len(e.pairs) == 4
    assert e.spacing == pytest.approx(1.575)
    assert "space them at least 2.12 m (sqrt 2 x min_separation" in str(e)
    # The same transition with its budget plans safely.
    result = plan_quad_transition(2, "cross", start, goal, duration, LIMITS,
                                  PlannerSettings())
    assert not result.straight and result.qp_drones > 0
    assert _dense_pass(result.trajectories).seg_sep.min() >= LIMITS.min_separation - 1e-9


def test_a_conflict_error_survives_a_worker_process() -> None:
    import pickle
    e = SeparationConflict(3, "wall", "slack 0.2 m after 30 SCP iterations",
                           [(4, 9, 1.1, 2.5)], 7, 1.53, 2.12)
    back = pickle.loads(pickle.dumps(e))
    assert type(back) is SeparationConflict and str(back) == str(e)
    assert back.pairs == [(4, 9, 1.1, 2.5)] and back.conflicts == 7


@pytest.mark.parametrize("seed", [3, 4])
def test_the_pruned_straight_line_check_is_the_full_one(seed: int,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    from groundctl.plan import straight
    rng = np.random.default_rng(seed)
    start = rng.uniform(0, 25, (400, 3))
    goal = rng.uniform(0, 25, (400, 3))
    for limit, margin in ((1.5, 0.2), (2.5, 0.0), (0.3, 0.1)):
        full = straight.check_straight_lines(start, goal, limit, margin)
        monkeypatch.setattr(straight, "PRUNE_ABOVE", 10)
        assert straight.check_straight_lines(start, goal, limit, margin) == full
        monkeypatch.setattr(straight, "PRUNE_ABOVE", 10**9)


def test_the_budget_is_a_show_file_setting(tmp_path: object) -> None:
    from pathlib import Path

    from groundctl.errors import ShowFileError
    from groundctl.show.loader import load_show
    src = (Path(__file__).resolve().parent.parent / "shows" / "quick.toml").read_text()
    assert "\n[planner]\n" in src
    base = Path(str(tmp_path))
    (base / "ok.toml").write_text(src.replace("\n[planner]\n", "\n[planner]\nbudget = 90\n"))
    assert load_show(base / "ok.toml").planner.budget_s == 90.0
    (base / "bad.toml").write_text(src.replace("\n[planner]\n", "\n[planner]\nbudget = 0.1\n"))
    with pytest.raises(ShowFileError, match="budget"):
        load_show(base / "bad.toml")
