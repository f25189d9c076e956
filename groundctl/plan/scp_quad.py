"""Sequential convex programming for one quadrotor transition.

The paper's loop, at scale:

1. straight-line initial guess: every drone on its own line with the
   minimum-effort rest-to-rest profile (which is also its reference);
2. find the pair-segments that come near (KD-tree per step, within the
   tightened separation + NEED_MARGIN) and group the drones they join into
   connected components; drones in no group keep their straight line, which
   is already their optimum;
3. per group, linearise the separation and norm limits around the previous
   iterate and solve the QP with OSQP (built once per group, updated in place,
   warm-started); drones that break a limit on their straight line form a
   group of one;
4. repeat per group until no sample moves more than the tolerance with every
   slack zero.  Once a group's iterate is feasible its trust region halves at
   every iteration: the separation rows are a convex restriction, so every
   feasible iterate is already safe and the rest only polishes (without this,
   large groups cycle on the tangent-plane linearisation of the norm limits).
   A converged group is not solved again unless it merges with another.

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
from groundctl.plan.qp_build import (
    BUILD_MARGIN,
    BUILD_WIDEN,
    MAX_TOLERANCE,
    NEED_MARGIN,
    OSQP_SETTINGS,
    SLACK_TOL,
)
from groundctl.plan.quad_qp import GroupQP, PairSegments
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import Limits, PlannerSettings, QuadrotorModel

FloatArray = NDArray[np.float64]

#: SCP trust region on positions, m per iteration.
TRUST_RADIUS = 1.0


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


@dataclass
class _Group:
    """One group's QP and where its SCP stands."""

    qp: GroupQP
    keys: NDArray[np.int64]
    """Pair-segment keys the QP has rows for."""
    trust: float = TRUST_RADIUS
    """Trust region on positions for the next solve, m."""
    slack: float = np.inf
    """Largest separation slack of the last solve, m."""
    converged: bool = False


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

    d_sep = limits.min_separation + limits.max_accel * dt * dt / 4
    states: dict[tuple[int, ...], _Group] = {}
    iterations = 0
    qp_drones: set[int] = set()
    need_all = np.empty((0, 3), dtype=np.int64)
    violators_all = np.empty(0, dtype=np.intp)
    had_rows = np.empty((0, 3), dtype=np.int64)
    if settings.tolerance > MAX_TOLERANCE:
        raise ValueError(f"`tolerance` must be at most {MAX_TOLERANCE} m")
    for iterations in range(1, settings.max_iterations + 1):  # noqa: B007 (used after)
        # Only pairs that actually come near join drones into a group; grid neighbours
        # that stay 3 m apart must not weld the whole fleet into one QP.  Needed pairs
        # accumulate, so a group keeps its members (and its QP) until it converges.
        need_all = np.unique(
            np.concatenate([need_all, close_pair_segments(P, d_sep + NEED_MARGIN)]), axis=0)
        violators_all = np.union1d(violators_all, _limit_violators(V, A, limits))
        grouped = groups(n, need_all[:, :2], violators_all)
        # Which group each drone was in, so a grown or merged group inherits the
        # smallest trust region of its parts: resetting it would let a group that
        # keeps picking up neighbours cycle for ever.
        trust_of = np.full(n, TRUST_RADIUS)
        for key, st in states.items():
            trust_of[list(key)] = st.trust
        new_states: dict[tuple[int, ...], _Group] = {}
        for members in grouped:
            key = tuple(int(x) for x in members)
            qp_drones.update(key)
            mine_need = need_all[np.isin(need_all[:, 0], members)]
            state = states.get(key)
            if state is None or not np.all(np.isin(segment_keys(mine_need, n, steps),
                                                   state.keys)):
                # Rows for every pair-segment of the group within BUILD_MARGIN, so the
                # QP (OSQP's factorisation, its warm start) lasts many iterations.
                near = widen(close_pair_segments(P[members], d_sep + BUILD_MARGIN), steps,
                             BUILD_WIDEN)
                glob = np.column_stack([members[near[:, 0]], members[near[:, 1]], near[:, 2]])
                # Rows only ever grow: a pair-segment that had rows keeps them, so a
                # rebuild happens only for pairs that are really new.
                inside = np.isin(had_rows[:, 0], members) & np.isin(had_rows[:, 1], members)
                glob = np.unique(np.concatenate([glob, had_rows[inside]]), axis=0)
                had_rows = np.unique(np.concatenate([had_rows, glob]), axis=0)
                local = np.full(n, -1, dtype=np.intp)
                local[members] = np.arange(len(members))
                pairs = PairSegments(local[glob[:, 0]], local[glob[:, 1]],
                                     glob[:, 2].astype(np.intp))
                qp = GroupQP(start[members], goal[members], ref[members], steps, dt, limits,
                             pairs, settings.alpha, settings.beta, OSQP_SETTINGS)
                state = _Group(qp, segment_keys(glob.astype(np.int64), n, steps),
                               trust=float(trust_of[members].min()))
            new_states[key] = state
            if state.converged:
                continue
            state.qp.linearise(P[members], V[members], A[members], state.trust)
            Pg, Vg, Ag, Sg = state.qp.solve(index)
            change = float(np.abs(Pg - P[members]).max())
            state.slack = float(Sg.max(initial=0.0))
            P[members], V[members], A[members] = Pg, Vg, Ag
            if state.slack < SLACK_TOL:
                state.converged = change < settings.tolerance
                state.trust = max(state.trust * 0.5, settings.tolerance / 4)
        states = new_states
        if all(st.converged for st in states.values()):
            break
    max_slack = max((st.slack for st in states.values()), default=0.0)
    if max_slack >= SLACK_TOL:
        raise PlanningError(
            index, "no separation-feasible solution",
            f"slack {max_slack:.3f} m after {iterations} SCP iterations; give transition "
            f"into '{name}' more time or space the formations further")
    times = np.linspace(0.0, duration, steps + 1)
    return TransitionResult(
        index=index, name=name, trajectories=Trajectories(times, P, V), steps=steps,
        iterations=iterations, seconds=time.perf_counter() - t0, qp_drones=len(qp_drones),
        groups=len(states), max_slack=max_slack,
        straight_length=float(np.linalg.norm(delta, axis=1).mean()))
