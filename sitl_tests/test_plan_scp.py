"""The SCP separates drones whose straight lines collide, within the limits."""

from __future__ import annotations

import numpy as np
import osqp
import pytest

from groundctl.errors import InfeasibleTransition
from groundctl.plan.assign import assign
from groundctl.plan.conflicts import close_pair_segments
from groundctl.plan.profile import rest_to_rest
from groundctl.plan.scp_quad import plan_quad_transition
from groundctl.plan.scp_unicycle import (
    UnicycleQP,
    pattern_half_width,
    plan_unicycle_transition,
    rollout,
    within,
)
from groundctl.show.model import Limits, PlannerSettings, UnicycleModel

LIM = Limits(min_separation=1.5, min_alt=0.0, max_alt=100.0)


def min_pair_distance(tr) -> float:  # type: ignore[no-untyped-def]
    pos, _, _ = tr.evaluate(tr.dense_times(40))
    i, j = np.triu_indices(tr.drones, 1)
    return float(np.linalg.norm(pos[i] - pos[j], axis=2).min())


def test_head_on_swap_is_separated_in_continuous_time() -> None:
    start = np.array([[-5.0, 0, 10], [5.0, 0, 10]])
    res = plan_quad_transition(1, "swap", start, start[::-1].copy(), 10.0, LIM, PlannerSettings())
    tr = res.trajectories
    # Straight lines would meet at the centre; the plan keeps 1.5 m everywhere.
    assert min_pair_distance(tr) >= 1.5 - 1e-3
    assert np.allclose(tr.pos[:, 0], start) and np.allclose(tr.pos[:, -1], start[::-1])
    assert np.allclose(tr.vel[:, [0, -1]], 0.0)
    _, vel, acc = tr.evaluate(tr.dense_times(20))
    assert np.linalg.norm(vel[..., :2], axis=2).max() <= LIM.max_speed_h * 1.005
    assert np.linalg.norm(acc, axis=2).max() <= LIM.max_accel * 1.005
    assert res.qp_drones == 2


def test_eight_drones_crossing_through_the_centre() -> None:
    ang = np.arange(8) * np.pi / 4
    start = np.column_stack([8 * np.cos(ang), 8 * np.sin(ang), np.full(8, 10.0)])
    goal = start.copy()
    goal[:, :2] *= -1
    res = plan_quad_transition(1, "cross", start, goal, 12.0, LIM, PlannerSettings())
    assert min_pair_distance(res.trajectories) >= 1.5 - 1e-3
    assert res.max_slack < 5e-3


def test_far_apart_drones_need_no_qp_and_fly_the_reference() -> None:
    start = np.array([[0.0, 0, 10], [20.0, 0, 10]])
    goal = start + np.array([0.0, 10, 0])
    res = plan_quad_transition(1, "apart", start, goal, 10.0, LIM, PlannerSettings())
    assert res.qp_drones == 0
    prof = rest_to_rest(res.steps, 10.0 / res.steps)
    expected = start[:, None] + prof.s[None, :, None] * (goal - start)[:, None]
    assert np.allclose(res.trajectories.pos, expected)


def test_too_short_transition_names_the_minimum_time() -> None:
    start = np.array([[0.0, 0, 10]])
    with pytest.raises(InfeasibleTransition) as err:
        far = start + np.array([100.0, 0, 0])
        plan_quad_transition(2, "far", start, far, 5.0, LIM, PlannerSettings())
    assert err.value.needed_time == pytest.approx(100 / 5 + 5 / 3)
    assert "transition 2 into 'far'" in str(err.value)
    assert "needs at least 21.7 s but has 5.0 s" in str(err.value)


def test_assignment_minimises_squared_distance() -> None:
    start = np.array([[0.0, 0], [10.0, 0]])
    slots = np.array([[11.0, 0], [1.0, 0], [50.0, 50]])
    assert assign(start, slots).tolist() == [1, 0]
    with pytest.raises(ValueError, match="`slots` has 1 points for 2 drones"):
        assign(start, slots[:1])


def test_unicycle_keeps_constant_speed_and_reaches_the_pattern() -> None:
    start = np.array([[-15.0, 0.0, 0], [15.0, 0.0, 0], [0.0, -15.0, 0]])
    goal = np.array([[12.0, 0.5, 0], [-12.0, -0.5, 0], [0.0, 12.0, 0]])
    model = UnicycleModel(speed=2.0, r_min=1.5)
    heading0 = np.array([0.0, np.pi, np.pi / 2])
    lim = Limits(min_separation=1.0, min_alt=0.0)
    settings = PlannerSettings(steps=80, pattern_tolerance=0.1)
    res, _ = plan_unicycle_transition(1, "swap", start, goal, heading0, 15.0, 10.0, lim, model,
                                      settings)
    tr = res.trajectories
    assert np.linalg.norm(tr.pos[:, -1, :2] - goal[:, :2], axis=1).max() <= 0.1
    assert min_pair_distance(tr) >= 1.0
    lengths = tr.path_lengths()
    assert lengths == pytest.approx(np.full(3, 30.0), rel=0.01)
    # The knots lie exactly on the nonlinear constant-speed rollout.
    theta = np.arctan2(np.diff(tr.pos[:, :, 1]), np.diff(tr.pos[:, :, 0]))
    theta = np.concatenate([theta, theta[:, -1:]], axis=1)
    assert np.allclose(rollout(start[:, :2], theta, 2.0, 15.0 / 80), tr.pos[:, :, :2], atol=1e-9)



def test_within_equals_a_spatial_query_at_the_smaller_radius() -> None:
    # The unicycle SCP queries once per iterate at its largest radius and filters.
    rng = np.random.default_rng(3)
    P = rng.uniform(0.0, 6.0, size=(12, 1, 2)) + np.cumsum(
        rng.normal(scale=0.3, size=(12, 30, 2)), axis=1)
    near = close_pair_segments(P, 2.0)
    for radius in (0.5, 1.0, 1.5, 2.0):
        assert np.array_equal(within(P, near, radius), close_pair_segments(P, radius))
    assert within(P, near[:0], 1.0).shape == (0, 3)


def test_unicycle_factorises_once_per_scp_iteration(monkeypatch: pytest.MonkeyPatch) -> None:
    # OSQP factorises the KKT matrix in setup() and again in every update(Ax=...):
    # a (re)built QP is set up with its first linearisation, not updated right after.
    calls = {"setup": 0, "update": 0}
    real_setup, real_update = osqp.OSQP.setup, osqp.OSQP.update

    def setup(self: osqp.OSQP, *args: object, **kwargs: object) -> object:
        calls["setup"] += 1
        return real_setup(self, *args, **kwargs)

    def update(self: osqp.OSQP, *args: object, **kwargs: object) -> object:
        calls["update"] += 1
        return real_update(self, *args, **kwargs)

    monkeypatch.setattr(osqp.OSQP, "setup", setup)
    monkeypatch.setattr(osqp.OSQP, "update", update)
    start = np.array([[-15.0, 0.0, 0], [15.0, 0.0, 0], [0.0, -15.0, 0]])
    goal = np.array([[12.0, 0.5, 0], [-12.0, -0.5, 0], [0.0, 12.0, 0]])
    res, _ = plan_unicycle_transition(
        1, "swap", start, goal, np.array([0.0, np.pi, np.pi / 2]), 15.0, 10.0,
        Limits(min_separation=1.0, min_alt=0.0), UnicycleModel(speed=2.0, r_min=1.5),
        PlannerSettings(steps=80, pattern_tolerance=0.1))
    assert calls["setup"] >= 1
    assert calls["setup"] + calls["update"] == res.iterations

def test_swap_boxed_in_by_neighbours_merges_groups_and_stays_safe() -> None:
    # Two drones swap head-on inside a "tube" of four neighbours flying parallel
    # 1.7 m off their line (left, right, above, below): close enough to get rows but
    # not in conflict, so they start as obstacles of the swapping pair's group.  Any
    # dodge presses the pair against them, so the groups must merge and push the
    # neighbours aside; the plan must stay separated in continuous time all along.
    offsets = np.array([[0.0, 1.7, 0], [0.0, -1.7, 0], [0.0, 0, 1.7], [0.0, 0, -1.7]])
    west, east = np.array([-5.0, 0, 10]), np.array([5.0, 0, 10])
    start = np.vstack([west, east, west + offsets])
    goal = np.vstack([east, west, east + offsets])
    res = plan_quad_transition(1, "tube", start, goal, 12.0, LIM, PlannerSettings())
    assert res.qp_drones > 2
    assert min_pair_distance(res.trajectories) >= 1.5 - 1e-3
    assert res.max_slack < 5e-3
    assert np.allclose(res.trajectories.pos[:, -1], goal)


def test_only_conflicting_drones_get_a_qp() -> None:
    # A row of drones 1.7 m apart flying in parallel is close (within the need
    # margin) but never in conflict: it flies the reference with no QP at all.  One
    # head-on swap far from the row is the only group.
    row = np.column_stack([np.arange(8) * 1.7, np.zeros(8), np.full(8, 10.0)])
    swap = np.array([[40.0, -5, 10], [40.0, 5, 10]])
    start = np.vstack([row, swap])
    goal = np.vstack([row + np.array([0.0, 10, 0]), swap[::-1]])
    res = plan_quad_transition(1, "row", start, goal, 10.0, LIM, PlannerSettings())
    assert res.qp_drones == 2
    assert min_pair_distance(res.trajectories) >= 1.5 - 1e-3
    prof = rest_to_rest(res.steps, 10.0 / res.steps)
    expected = row[:, None] + prof.s[None, :, None] * (goal[:8] - row)[:, None]
    assert np.allclose(res.trajectories.pos[:8], expected)


def test_unicycle_polishing_model_passes_through_the_new_rollout() -> None:
    # After the fleet is feasible the QP keeps its Jacobian (no refactorisation) but
    # is shifted to the new rollout: evaluated at the new headings, the kept linear
    # model must predict exactly the positions those headings fly.
    rng = np.random.default_rng(5)
    n, steps, dt, speed = 3, 40, 0.25, 2.0
    model = UnicycleModel(speed=speed, r_min=1.5)
    start = np.array([[0.0, 0.0], [0.0, 4.0], [0.0, 8.0]])
    theta0 = np.cumsum(rng.normal(scale=0.05, size=(n, steps + 1)), axis=1)
    theta0[:, -1] = theta0[:, -2]
    P0 = rollout(start, theta0, speed, dt)
    goal = P0[:, -1] + 0.3
    ref = np.linspace(start, goal, steps + 1, axis=1)
    qp = UnicycleQP(start, goal, theta0[:, 0], ref, model, steps, dt, 0.85, 0.1,
                    np.zeros((0, 3), dtype=np.int64), 1.0, 0.01)
    trust = np.full(n, 0.5)
    qp.linearise(P0, theta0, trust)
    theta1 = theta0 + rng.normal(scale=0.1, size=theta0.shape)
    theta1[:, 0] = theta0[:, 0]
    P1 = rollout(start, theta1, speed, dt)
    qp.linearise(P1, theta1, trust, relinearise=False)
    # The step model at theta1: dp[k] = sum over j < k of dt V perp(theta0[j]) dtheta[j].
    dth = (theta1 - theta0)[:, :steps]
    step = dt * speed * np.stack([-np.sin(theta0[:, :steps]) * dth,
                                  np.cos(theta0[:, :steps]) * dth], axis=2)
    dp_end = step.sum(axis=1)
    # The pattern rows read goal - (base end) +- the half-width, base = what the model
    # puts at dp = 0.
    half = pattern_half_width(0.1)
    lo = qp.l[qp.term_rows]
    base_end = goal - np.column_stack([lo[:n], lo[n:]]) - half
    assert np.allclose(base_end + dp_end, P1[:, -1], atol=1e-9)
    # The trust region is centred on theta1 (in steps from theta0).
    box = qp.l[qp.head_box].reshape(n, steps - 1)[:, 1:]
    assert np.allclose(box + trust[:, None], (theta1 - theta0)[:, 2:steps], atol=1e-9)
    # And the QP solves to headings within the trust region of theta1.
    theta2, _ = qp.solve(1)
    assert np.all(np.abs(theta2 - theta1)[:, 1:steps] <= trust[:, None] + 1e-2)


def test_a_large_assignment_is_solved_once_for_the_loader_and_the_planner(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from groundctl.plan import assign as assign_module

    calls = []
    real = assign_module.linear_sum_assignment

    def counted(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        calls.append(cost.shape)
        return real(cost)
    monkeypatch.setattr(assign_module, "linear_sum_assignment", counted)
    rng = np.random.default_rng(7)
    n = assign_module.REMEMBER_FROM
    start, slots = rng.uniform(-50, 50, (n, 3)), rng.uniform(-50, 50, (n, 3))
    first = assign_module.assign(start, slots)
    first[0] = -1  # the caller's copy: what is remembered is not changed
    again = assign_module.assign(start.copy(), slots.copy())
    assert len(calls) == 1
    assert again[0] != -1 and sorted(again) == list(range(n))
    slots[3, 0] += 1.0  # other points: solved again
    assign_module.assign(start, slots)
    assert len(calls) == 2
    small = assign_module.assign(start[:10], slots[:10])  # small ones are not remembered
    assign_module.assign(start[:10], slots[:10])
    assert len(calls) == 4 and sorted(small) == list(range(10))
