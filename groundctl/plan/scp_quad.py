"""Sequential convex programming for one quadrotor transition.

The paper's loop, at scale:

1. straight-line initial guess: every drone on its own line with the
   minimum-effort rest-to-rest profile (which is also its reference);
2. find the pair-segments that can come close (KD-tree per step, radius =
   separation + what two trust regions can add) and group the drones they
   join into connected components; drones in no group keep their straight
   line, which is already their optimum;
3. per group, linearise the separation and norm limits around the previous
   iterate and solve the QP with OSQP (built once per group, updated in place,
   warm-started); drones that break a limit on their straight line form a
   group of one;
4. repeat until no sample moves more than the tolerance, every slack is zero
   and the samples keep the separation; a group whose pair set grows is
   rebuilt, all others are updated in place.

The groups are independent QPs: the full problem is block-separable once the
pairs that cannot come close are left out, so this is the exact problem, not
a heuristic split.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import InfeasibleTransition, PlanningError
from groundctl.plan.conflicts import close_pair_segments, groups, segment_keys, widen
from groundctl.plan.feasibility import min_transition_time
from groundctl.plan.profile import rest_to_rest
from groundctl.plan.qp_build import BUILD_MARGIN, BUILD_WIDEN, MAX_TOLERANCE, NEED_MARGIN
from groundctl.plan.quad_qp import GroupQP, PairSegments
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import Limits, PlannerSettings, QuadrotorModel

FloatArray = NDArray[np.float64]

OSQP_SETTINGS: dict[str, float | int | bool] = {
    "verbose": False,
    "eps_abs": 1e-3,
    "eps_rel": 1e-3,
    "max_iter": 4000,
    "polishing": True,
    "adaptive_rho": True,
    "rho": 1.0,
}
#: SCP trust region on positions, m per iteration.
TRUST_RADIUS = 1.0
#: Max slack (m) still counted as "separation holds" at convergence.
SLACK_TOL = 5e-3


@dataclass(frozen=True)
class TransitionResult:
    """One planned transition and how the planner got there."""

    index: int
    """1-based formation index this transition leads into."""
    name: str
    """Formation name."""
    trajectories: Trajectories
    """Knot-sampled trajectories from t = 0 to the transition's duration."""
    steps: int
    """QP steps N."""
    iterations: int
    """SCP iterations run."""
    seconds: float
    """Wall time spent planning this transition, s."""
    qp_drones: int
    """Drones that needed a QP (the others flew straight lines)."""
    groups: int
    """Number of independent QP groups in the last iteration."""
    max_slack: float
    """Largest separation slack at the end, m (0 when converged)."""
    straight_length: float
    """Mean straight-line distance start to goal, m (a lower bound on path length)."""


def _steps(duration: float, settings: PlannerSettings) -> tuple[int, float]:
    steps = settings.steps or max(4, math.ceil(duration / settings.dt - 1e-9))
    return steps, duration / steps


def _limit_violators(V: FloatArray, A: FloatArray, lim: Limits) -> NDArray[np.intp]:
    tol = 1e-6
    vh = np.linalg.norm(V[:, :, :2], axis=2).max(axis=1)
    up = V[:, :, 2].max(axis=1)
    down = -V[:, :, 2].min(axis=1)
    acc = np.linalg.norm(A, axis=2).max(axis=1)
    bad = ((vh > lim.max_speed_h + tol) | (up > lim.max_speed_up + tol)
           | (down > lim.max_speed_down + tol) | (acc > lim.max_accel + tol))
    return np.flatnonzero(bad)


def plan_quad_transition(index: int, name: str, start: FloatArray, goal: FloatArray,
                         duration: float, limits: Limits,
                         settings: PlannerSettings) -> TransitionResult:
    """Plan one quadrotor transition from ``start`` to ``goal`` (n, 3) in ``duration`` s."""
    t0 = time.perf_counter()
    bound = min_transition_time(start, goal, limits, QuadrotorModel())
    if bound.seconds > duration + 1e-9:
        raise InfeasibleTransition(
            index, name, bound.seconds, duration,
            f"drone {bound.drone + 1} must fly {bound.distance:.1f} m at "
            f"<= {bound.speed_limit:.1f} m/s")
    n = start.shape[0]
    steps, dt = _steps(duration, settings)
    prof = rest_to_rest(steps, dt)
    delta = goal - start
    ref = start[:, None, :] + prof.s[None, :, None] * delta[:, None, :]
    P = ref.copy()
    V = prof.ds[None, :, None] * delta[:, None, :]
    A = prof.dds[None, :, None] * delta[:, None, :]

    trust = TRUST_RADIUS
    d_sep = limits.min_separation + limits.max_accel * dt * dt / 4
    qps: dict[tuple[int, ...], tuple[GroupQP, NDArray[np.int64]]] = {}
    iterations = 0
    max_slack = 0.0
    n_groups = 0
    qp_drones: set[int] = set()
    need_all = np.empty((0, 3), dtype=np.int64)
    violators_all = np.empty(0, dtype=np.intp)
    if settings.tolerance > MAX_TOLERANCE:
        raise ValueError(f"`tolerance` must be at most {MAX_TOLERANCE} m")
    for iterations in range(1, settings.max_iterations + 1):  # noqa: B007 (used after)
        # Only pairs that actually come near join drones into a group; grid neighbours
        # that stay 3 m apart must not weld the whole fleet into one QP.
        # Needed pairs accumulate: a group keeps iterating (and keeps its QP) until it
        # has converged, even once its drones have moved apart.
        need = np.unique(np.concatenate([need_all, close_pair_segments(P, d_sep + NEED_MARGIN)]),
                         axis=0)
        need_all = need
        violators = np.union1d(violators_all, _limit_violators(V, A, limits))
        violators_all = violators
        grouped = groups(n, need[:, :2], violators)
        n_groups = len(grouped)
        if not grouped:
            break
        change = 0.0
        max_slack = 0.0
        new_qps: dict[tuple[int, ...], tuple[GroupQP, NDArray[np.int64]]] = {}
        for members in grouped:
            key = tuple(int(x) for x in members)
            qp_drones.update(key)
            mine_need = need[np.isin(need[:, 0], members)]
            cached = qps.get(key)
            if cached is None or not np.all(np.isin(segment_keys(mine_need, n, steps),
                                                    cached[1])):
                # Rows for every pair-segment of the group that is anywhere near, so the
                # QP (OSQP's factorisation, its warm start) lasts many iterations.
                near = close_pair_segments(P[members], d_sep + BUILD_MARGIN)
                near = widen(near, steps, BUILD_WIDEN)
                glob = np.column_stack([members[near[:, 0]], members[near[:, 1]], near[:, 2]])
                pairs = PairSegments(near[:, 0].astype(np.intp), near[:, 1].astype(np.intp),
                                     near[:, 2].astype(np.intp))
                qp = GroupQP(start[members], goal[members], ref[members], steps, dt, limits,
                             pairs, settings.alpha, settings.beta, trust, OSQP_SETTINGS)
                cached = (qp, segment_keys(glob.astype(np.int64), n, steps))
            new_qps[key] = cached
            qp = cached[0]
            qp.linearise(P[members], V[members], A[members])
            Pg, Vg, Ag, Sg = qp.solve(index)
            change = max(change, float(np.abs(Pg - P[members]).max()))
            max_slack = max(max_slack, float(Sg.max(initial=0.0)))
            P[members], V[members], A[members] = Pg, Vg, Ag
        qps = new_qps
        if change < settings.tolerance and max_slack < SLACK_TOL:
            break
    else:
        if max_slack >= SLACK_TOL:
            raise PlanningError(
                index, "no separation-feasible solution",
                f"slack {max_slack:.3f} m after {settings.max_iterations} SCP iterations; "
                f"give transition into '{name}' more time or space the formations further")
    times = np.linspace(0.0, duration, steps + 1)
    return TransitionResult(
        index=index, name=name, trajectories=Trajectories(times, P, V), steps=steps,
        iterations=iterations, seconds=time.perf_counter() - t0, qp_drones=len(qp_drones),
        groups=n_groups, max_slack=max_slack,
        straight_length=float(np.linalg.norm(delta, axis=1).mean()))
