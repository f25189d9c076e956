"""Conflict groups solved in worker processes: the same plan as in one process, and
nothing lost when a worker dies."""

from __future__ import annotations

import itertools
import logging
import os
import signal

import numpy as np
import pytest
from plan_fixtures import points_show

from groundctl.errors import SeparationConflict
from groundctl.plan.assign import assign
from groundctl.plan.conflicts import groups
from groundctl.plan.feasibility import min_transition_time
from groundctl.plan.groupsolve import (
    Failed,
    GroupSolvers,
    GroupSpec,
    Solved,
    SolveJob,
    colour_classes,
)
from groundctl.plan.planner import plan_show
from groundctl.plan.profile import capped_profile, rest_to_rest
from groundctl.plan.quad_qp import ObstacleSegments, PairSegments
from groundctl.plan.scp_quad import plan_quad_transition
from groundctl.plan.verify import close_pairs
from groundctl.show.model import Limits, PlannerSettings, QuadrotorModel

LIM = Limits(min_separation=1.5, min_alt=1.0, max_alt=60.0)


def grid_to_wall(side: int = 5, spacing: float = 1.6) -> tuple[np.ndarray, np.ndarray, float]:
    """A takeoff grid into a vertical wall in front of it, slots ``spacing`` apart (just
    above the 1.5 m limit), in 1.3 x the minimum time: many small conflict groups."""
    u = (np.arange(side) - (side - 1) / 2) * spacing
    gx, gy = np.meshgrid(u, u, indexing="ij")
    start = np.column_stack([gx.ravel(), gy.ravel(), np.full(side * side, 3.0)])
    goal = np.column_stack([gx.ravel(), np.full(side * side, u.max() + 8.0),
                            gy.ravel() + u.max() + 8.0])
    goal = goal[assign(start, goal)]
    duration = 1.3 * min_transition_time(start, goal, LIM, QuadrotorModel()).seconds
    return start, goal, duration


def test_colour_classes_never_batch_groups_that_see_each_other() -> None:
    rng = np.random.default_rng(7)
    n = 60
    members = np.array_split(rng.permutation(n), 15)
    obstacles = [rng.choice(n, size=rng.integers(0, 6), replace=False) for _ in members]
    batches = colour_classes(members, obstacles, n)
    owner = np.empty(n, dtype=int)
    for g, m in enumerate(members):
        owner[m] = g
    assert sorted(g for b in batches for g in b) == list(range(len(members)))
    for batch in batches:
        assert batch == sorted(batch)  # in the given order within a batch
        for g in batch:
            seen = set(owner[obstacles[g]].tolist()) - {g}
            assert not seen & set(batch), f"group {g} reads a group of its own batch"
            for h in batch:
                assert g not in owner[obstacles[h]].tolist() or g == h


def test_the_plan_is_the_same_with_worker_processes() -> None:
    start, goal, duration = grid_to_wall()
    here = plan_quad_transition(1, "wall", start, goal, duration, LIM, PlannerSettings())
    spread = plan_quad_transition(1, "wall", start, goal, duration, LIM, PlannerSettings(),
                                  workers=3)
    assert here.groups >= 3 and not here.straight
    assert np.array_equal(here.trajectories.pos, spread.trajectories.pos)
    assert np.array_equal(here.trajectories.vel, spread.trajectories.vel)
    assert here.iterations == spread.iterations


def test_a_show_of_one_transition_gives_its_spare_workers_to_the_groups() -> None:
    start, goal, duration = grid_to_wall(side=4)
    home = start.copy()
    home[:, 2] = 0.0
    show = points_show(home, [goal], transition=duration, limits=LIM, takeoff_altitude=3.0)
    one = plan_show(show, workers=1)
    two = plan_show(show, workers=2)
    assert np.array_equal(one.plan.trajectories.pos, two.plan.trajectories.pos)
    assert two.verification.safe


def _specs(count: int) -> list[tuple[GroupSpec, SolveJob]]:
    """Independent two-drone head-on swaps (one QP each) and their first solves."""
    steps, dt = 40, 0.25
    prof = rest_to_rest(steps, dt)
    out = []
    for g in range(count):
        start = np.array([[-5.0, 10.0 * g, 10.0], [5.0, 10.0 * g, 10.0]])
        goal = start[::-1].copy()
        delta = goal - start
        ref = start[:, None, :] + prof.s[None, :, None] * delta[:, None, :]
        vel = prof.ds[None, :, None] * delta[:, None, :]
        acc = prof.dds[None, :, None] * delta[:, None, :]
        k = np.arange(steps)
        pairs = PairSegments(np.zeros(steps, dtype=np.intp), np.ones(steps, dtype=np.intp), k)
        spec = GroupSpec(start, goal, ref, steps, dt, LIM, pairs, ObstacleSegments.empty(),
                         PlannerSettings().alpha, PlannerSettings().beta)
        out.append((spec, SolveJob(g, ref.copy(), vel, acc, 1.0, np.empty((0, 2, 3)),
                                   np.empty((0, 3)), 0.0)))
    return out


def _same(a: list, b: list) -> bool:  # type: ignore[type-arg]
    return all(isinstance(x, Solved) and isinstance(y, Solved) and np.array_equal(x.P, y.P)
               for x, y in zip(a, b, strict=True))


def test_groups_spread_over_the_workers_solve_as_they_do_here() -> None:
    cases = _specs(6)
    with GroupSolvers(1, workers=1) as here:
        for spec, job in cases:
            here.build(job.group, spec)
        alone = here.solve([job for _, job in cases])
    with GroupSolvers(1, workers=3) as spread:
        for spec, job in cases:
            spread.build(job.group, spec)
        assert sorted(spread._where.values()) == [-1, -1, 0, 0, 1, 1]
        together = spread.solve([job for _, job in cases])
    assert _same(alone, together)


def test_a_killed_worker_loses_only_time(caplog: pytest.LogCaptureFixture) -> None:
    cases = _specs(4)
    with GroupSolvers(1, workers=2) as solvers:
        for spec, job in cases:
            solvers.build(job.group, spec)
        victim = solvers._slots[0].process  # type: ignore[union-attr]
        assert victim.pid is not None
        os.kill(victim.pid, signal.SIGKILL)
        victim.join(10)
        with caplog.at_level(logging.WARNING):
            outcomes = solvers.solve([job for _, job in cases])
        assert "a group solver process died" in caplog.text
        assert set(solvers._where.values()) == {-1}
        again = solvers.solve([job for _, job in cases])  # no worker left: all here
    with GroupSolvers(1) as here:
        for spec, job in cases:
            here.build(job.group, spec)
        alone = here.solve([job for _, job in cases])
    assert _same(alone, outcomes)
    assert all(isinstance(o, Solved) for o in again)


def test_a_bug_in_a_worker_is_raised_as_itself() -> None:
    (spec, job), = _specs(1)
    with GroupSolvers(1, workers=2) as solvers:
        solvers.build(5, spec)
        solvers.build(6, spec)  # the worker's
        assert solvers._where[6] == 0
        wrong = SolveJob(6, job.P[:, :5], job.V, job.A, 1.0, job.others, job.others_acc, 0.0)
        with pytest.raises(IndexError, match="out of bounds"):
            solvers.solve([wrong])
        # Its worker is still there and serves the next batch.
        ok = solvers.solve([SolveJob(6, job.P, job.V, job.A, 1.0, job.others, job.others_acc,
                                     0.0)])
        assert isinstance(ok[0], Solved)


def test_an_osqp_failure_is_an_outcome_not_an_error() -> None:
    (spec, job), = _specs(1)
    with GroupSolvers(1, workers=2) as solvers:
        solvers.build(1, spec)
        solvers.build(2, spec)
        # Iterates at 0.05 m from where the goal is pinned: a 1 mm trust region leaves
        # no way to meet both.
        moved = job.P.copy()
        moved[:, -2] += 5.0
        outcomes = solvers.solve([SolveJob(g, moved, job.V, job.A, 1e-3, job.others,
                                           job.others_acc, 0.0) for g in (1, 2)])
    assert all(isinstance(o, Failed) for o in outcomes)
    assert outcomes[0] == outcomes[1]


def test_a_solver_needs_a_worker() -> None:
    with pytest.raises(ValueError, match="`workers` must be at least 1"):
        GroupSolvers(1, workers=0)


# -- long movers given less than 1.5 x the minimum time ------------------------------------

def test_the_capped_profile_keeps_its_caps_and_rests_at_both_ends() -> None:
    steps, dt = 158, 0.2
    free = rest_to_rest(steps, dt)
    cap = 0.9 * free.ds.max()
    prof = capped_profile(steps, dt, cap, 0.01)
    assert prof is not None
    assert prof.ds.max() <= cap and np.abs(prof.dds).max() <= 0.01
    assert prof.s[0] == 0.0 and prof.s[-1] == 1.0 and prof.ds[0] == prof.ds[-1] == 0.0
    # Its knots follow the double integrator exactly, as the QP's dynamics rows ask.
    step = prof.s[:-1] + dt * prof.ds[:-1] + 0.5 * dt * dt * prof.dds
    assert np.allclose(step, prof.s[1:], atol=1e-6)
    # Slower than 1 / (steps dt) on average it cannot arrive: None.
    assert capped_profile(steps, dt, 0.9 / (steps * dt), 0.01) is None
    with pytest.raises(ValueError, match="must be positive"):
        capped_profile(steps, dt, 0.0, 0.01)


def test_a_wall_climbing_far_at_1_2_times_the_minimum_time_is_planned() -> None:
    # A tall wall's top rows climb 40 m: the shared profile, 1.5 x their mean speed,
    # breaks the 2.5 m/s climb limit at 1.2 x the (trapezoidal) minimum time.  Those
    # drones were groups of one whose QP, held near that profile by its trust region,
    # was infeasible four times: 1000 drones refused after minutes ("OSQP primal
    # infeasible for a group of 1 drones").
    side, spacing = 5, 1.6
    u = (np.arange(side) - (side - 1) / 2) * spacing
    gx, gy = np.meshgrid(u, u, indexing="ij")
    start = np.column_stack([gx.ravel(), gy.ravel(), np.full(side * side, 3.0)])
    goal = np.column_stack([gx.ravel(), np.full(side * side, u.max() + 8.0),
                            gy.ravel() * 8.0 + 25.0])
    goal = goal[assign(start, goal)]
    duration = 1.2 * min_transition_time(start, goal, LIM, QuadrotorModel()).seconds
    steps = PlannerSettings().steps_for(duration)
    free = rest_to_rest(steps, duration / steps)
    climb = (goal - start)[:, 2].max()
    assert free.ds.max() * climb > LIM.max_speed_up  # the shared profile would break it
    res = plan_quad_transition(1, "tall", start, goal, duration, LIM, PlannerSettings())
    _, vel, acc = res.trajectories.evaluate(res.trajectories.dense_times(10))
    assert vel[..., 2].max() <= LIM.max_speed_up * 1.005
    assert np.linalg.norm(acc, axis=2).max() <= LIM.max_accel * 1.005
    assert close_pairs(res.trajectories, LIM.min_separation - 1e-3) == []


def test_a_batch_past_its_time_fails_its_solves_wherever_they_run() -> None:
    cases = _specs(4)
    with GroupSolvers(1, workers=2) as solvers:
        for spec, job in cases:
            solvers.build(job.group, spec)
        late = [SolveJob(job.group, job.P, job.V, job.A, job.trust, job.others,
                         job.others_acc, 1e-9) for _, job in cases]
        outcomes = solvers.solve(late)
    assert [type(o) for o in outcomes] == [Failed] * 4
    assert all(isinstance(o, Failed) and "time limit" in o.status for o in outcomes)


def test_a_budget_that_runs_out_on_a_safe_iterate_keeps_it_as_the_plan() -> None:
    # The budget is counted on the clock the planner is given: here one tick per look.
    # Whatever it is, the transition is a safe plan or a SeparationConflict; where it
    # runs out after the iterate became safe but before the SCP converged, that iterate
    # is the plan (it was refused before: 1000 drones planned nothing in 40 s).
    start, goal, duration = grid_to_wall()
    full = plan_quad_transition(1, "wall", start, goal, duration, LIM, PlannerSettings())
    assert full.converged
    outcomes = []
    for budget in range(5, 45, 5):
        ticks = itertools.count()
        try:
            res = plan_quad_transition(1, "wall", start, goal, duration, LIM,
                                       PlannerSettings(), budget_s=float(budget),
                                       clock=lambda ticks=ticks: float(next(ticks)))
        except SeparationConflict as exc:
            assert exc.pairs, "a refusal names the drones in conflict"
            outcomes.append("refused")
            continue
        tr = res.trajectories
        assert close_pairs(tr, LIM.min_separation) == []
        _, vel, acc = tr.evaluate(tr.dense_times(10))
        assert np.linalg.norm(vel[..., :2], axis=2).max() <= LIM.max_speed_h * 1.005
        assert np.linalg.norm(acc, axis=2).max() <= LIM.max_accel * 1.005
        outcomes.append("converged" if res.converged else "safe, not converged")
        if res.converged:
            assert np.array_equal(tr.pos, full.trajectories.pos)
    assert outcomes[0] == "refused"
    assert "safe, not converged" in outcomes and outcomes[-1] == "converged"


def test_a_large_components_cut_keeps_its_pieces_when_a_link_is_added() -> None:
    # A chain of 12 drones cut into pieces of 4; a new link at one end used to reshuffle
    # every piece (each a new QP).  The pieces of the last cut that still fit stay.
    chain = np.array([[i, i + 1] for i in range(11)], dtype=np.int64)
    first = groups(13, chain, np.empty(0, dtype=np.intp), 4)
    assert sorted(len(p) for p in first) == [4, 4, 4]
    grown = np.concatenate([chain, [[0, 12]]])  # at the start of the breadth-first walk
    fresh = groups(13, grown, np.empty(0, dtype=np.intp), 4)
    kept = groups(13, grown, np.empty(0, dtype=np.intp), 4, keep=first)
    as_sets = {frozenset(p.tolist()) for p in kept}
    assert all(frozenset(p.tolist()) in as_sets for p in first)
    assert sorted(np.concatenate(kept).tolist()) == list(range(13))
    # Cut afresh, every piece would have moved.
    assert not any(frozenset(p.tolist()) in {frozenset(q.tolist()) for q in fresh}
                   for p in first)
    # A kept piece that now straddles two components is not kept.
    split = groups(13, chain[:5], np.empty(0, dtype=np.intp), 4, keep=[np.array([4, 5, 6, 7])])
    assert all(not {4, 5, 6, 7} <= set(p.tolist()) for p in split)
