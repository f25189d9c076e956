"""Sequential convex programming for one quadrotor transition.

The paper's loop, at scale:

1. straight-line initial guess: every drone on its own line with the
   minimum-effort rest-to-rest profile (which is also its reference);
2. find the pair-segments that come near (KD-tree per step, within the
   tightened separation + NEED_MARGIN) and evaluate their linearised
   separation rows at the current iterate.  Only *tight* pairs (row clearance
   below LINK_MARGIN: violated, or held up against another drone) join their
   two drones into a group; groups are the connected components of the tight
   pairs, and links accumulate over the iterations.  Drones that break a limit
   on their straight line form a group of one.  Drones in no group keep their
   current trajectory: on the straight line that is their own optimum, and it
   satisfies every row it is part of;
3. per group, linearise the separation and norm limits around the previous
   iterate and solve the QP with OSQP (built once per group, updated in place,
   warm-started).  Close pairs inside the group get the paper's coupled rows;
   close pairs with a drone outside the group get *obstacle rows* on the
   group's drone only, against where the other drone is now (Gauss-Seidel:
   groups solved earlier in the same iteration have already moved).  Each row
   keeps its pair safe against the other drone's final trajectory of the
   iteration whichever of the two groups is solved last, so every iterate with
   zero slack is safe, and the KKT system of a group never couples it to its
   neighbours: the QPs stay as small as the conflicts instead of growing into
   one fleet-sized mesh.  A group pressed against an obstacle row makes that
   pair tight, so the two groups merge and are optimised jointly next time;
4. repeat per group until no sample moves more than the tolerance with every
   slack zero.  Once a group's iterate is feasible its trust region halves at
   every iteration: the separation rows are a convex restriction, so every
   feasible iterate is already safe and the rest only polishes (without this,
   large groups cycle on the tangent-plane linearisation of the norm limits).
   A converged group is not solved again unless it merges with another or a
   new close pair needs rows.

On the straight-line guess of a 1000-drone grid-to-sphere transition, 13,000
pair-segments come within NEED_MARGIN and chain 541 drones into one component,
but only ~350 rows are violated, in clusters of two or three drones: grouping
by tight pairs solves ~130 drones in groups of a few, instead of one QP whose
LDL factorisation fills in over a pairs-by-time mesh.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.errors import InfeasibleTransition, PlanningError, SeparationConflict
from groundctl.plan.conflicts import (
    close_pair_segments,
    groups,
    segment_keys,
    segments_with,
    unique_segments,
    widen,
    within,
)
from groundctl.plan.feasibility import line_speed_limits, min_transition_time
from groundctl.plan.groupsolve import Failed, GroupSolvers, GroupSpec, SolveJob, colour_classes
from groundctl.plan.profile import capped_profile, rest_to_rest
from groundctl.plan.qp_build import (
    BUILD_MARGIN,
    BUILD_WIDEN,
    MAX_TOLERANCE,
    NEED_MARGIN,
    SLACK_TOL,
    chord_clearance,
)
from groundctl.plan.quad_qp import (
    SEPARATION_BUFFER,
    GroupQP,
    ObstacleSegments,
    PairSegments,
    chord_separation,
)
from groundctl.plan.straight import StraightCheck, check_straight_lines
from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import LIMIT_TOL, close_pairs
from groundctl.show.model import Limits, PlannerSettings, QuadrotorModel

FloatArray = NDArray[np.float64]

#: SCP trust region on positions, m per iteration.
TRUST_RADIUS = 1.0
#: A close pair-segment whose separation row has less than this much clearance at
#: the current iterate (violated, or held up against an obstacle row) joins its two
#: drones into one group, m.
LINK_MARGIN = 0.05
#: Drones in one QP at most: a larger component of tight pairs is cut into breadth-first
#: pieces solved one after another against each other (Gauss-Seidel), as separate
#: groups are: the KKT factorisation of a 100-drone group takes minutes.
MAX_GROUP = 4
#: Default of ``[planner] budget``: wall time one transition may spend looking for a
#: plan that keeps every pair apart (both attempts, with and without the tracking
#: margin), s.  Past it the transition fails with the drones still in conflict named:
#: 1000 drones refused inside a minute.
BUDGET_S = PlannerSettings().budget_s
#: Times OSQP may give up on one group before the transition fails.
GROUP_FAILURES = 3


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
    straight_min_separation: float = float("nan")
    """Closest approach of any pair on the synchronised straight lines, exact, m (nan:
    not checked)."""
    straight: bool = False
    """The straight lines were flown as they are (they keep every pair apart, or the
    optimiser found nothing better that keeps the limit)."""
    converged: bool = True
    """The SCP converged.  False: the budget ran out on an iterate that already keeps
    every pair apart and every drone within its limits, which is the plan (safe, not
    yet the least effort)."""


@dataclass
class _Group:
    """One group's QP and where its SCP stands."""

    spec: GroupSpec
    """What its QP is built from."""
    gid: int
    """Its id in the transition's :class:`GroupSolvers`."""
    keys: NDArray[np.int64]
    """Pair-segment keys the QP has rows for."""
    rows: NDArray[np.int64]
    """(m, 3) the pair-segments (i, j, k) themselves, global drone indices."""
    obs_other: NDArray[np.intp]
    """(m_o,) global index of the drone outside the group, per obstacle row."""
    trust: float = TRUST_RADIUS
    """Trust region on positions for the next solve, m."""
    slack: float = np.inf
    """Largest separation slack of the last solve, m."""
    converged: bool = False
    failures: int = 0
    """Solves OSQP did not finish."""


def _steps(duration: float, settings: PlannerSettings) -> tuple[int, float]:
    steps = settings.steps_for(duration)
    return steps, duration / steps


def _limit_violators(V: FloatArray, A: FloatArray, lim: Limits, rel: float = 0.0
                     ) -> NDArray[np.intp]:
    """Drones over a speed or acceleration limit at a knot by more than 1e-6 plus ``rel``
    of the limit."""
    tol = 1e-6
    f = 1.0 + rel
    vh = np.linalg.norm(V[:, :, :2], axis=2).max(axis=1)
    up = V[:, :, 2].max(axis=1)
    down = -V[:, :, 2].min(axis=1)
    acc = np.linalg.norm(A, axis=2).max(axis=1)
    bad = ((vh > lim.max_speed_h * f + tol) | (up > lim.max_speed_up * f + tol)
           | (down > lim.max_speed_down * f + tol) | (acc > lim.max_accel * f + tol))
    return np.flatnonzero(bad)


def _pair_margin(start: FloatArray, goal: FloatArray, d_row: float, wanted: float
                 ) -> Callable[[NDArray[np.int64], NDArray[np.int64]], FloatArray]:
    """Per pair (i, j): the tracking margin their rows ask for on top of ``d_row``.

    ``wanted``, except where the pair's fixed start or goal are closer than
    that allows (formation slots near the minimum separation): there the
    margin shrinks, to zero at worst, never below the limit.  It leaves two
    LINK_MARGINs of room, so a pair flying parallel at its end distance is not
    "tight" and does not pull its drones into a QP.
    """
    def margin(i: NDArray[np.int64], j: NDArray[np.int64]) -> FloatArray:
        if wanted <= 0:
            return np.zeros(len(i))
        ends = np.minimum(np.linalg.norm(start[i] - start[j], axis=1),
                          np.linalg.norm(goal[i] - goal[j], axis=1))
        return np.clip(ends - d_row - 2 * LINK_MARGIN, 0.0, wanted)
    return margin


def _build_group(members: NDArray[np.intp], inside: NDArray[np.bool_],
                 near_build: NDArray[np.int64], had_rows: Sequence[NDArray[np.int64]],
                 start: FloatArray, goal: FloatArray, ref: FloatArray, steps: int, dt: float,
                 limits: Limits, settings: PlannerSettings, trust: float,
                 margin: Callable[[NDArray[np.int64], NDArray[np.int64]], FloatArray],
                 gid: int = 0) -> _Group:
    """A group's QP spec with rows for every pair-segment of its drones within BUILD_MARGIN.

    Pairs inside the group get coupled rows, pairs with a drone outside it obstacle
    rows on the group's drone.  Rows only ever grow: a pair-segment that had rows
    keeps them, so a rebuild happens only for pairs that are really new.
    """
    n = len(inside)
    touch = near_build[inside[near_build[:, 0]] | inside[near_build[:, 1]]]
    glob = widen(touch, steps, BUILD_WIDEN)
    mine = [h[inside[h[:, 0]] | inside[h[:, 1]]] for h in had_rows]
    glob = unique_segments(np.concatenate([glob, *mine]), n, steps)
    local = np.full(n, -1, dtype=np.intp)
    local[members] = np.arange(len(members))
    both = inside[glob[:, 0]] & inside[glob[:, 1]]
    internal, external = glob[both], glob[~both]
    pairs = PairSegments(local[internal[:, 0]], local[internal[:, 1]],
                         internal[:, 2].astype(np.intp), margin(internal[:, 0], internal[:, 1]))
    first_in = inside[external[:, 0]]
    mine_drone = np.where(first_in, external[:, 0], external[:, 1])
    other = np.where(first_in, external[:, 1], external[:, 0]).astype(np.intp)
    obstacles = ObstacleSegments(local[mine_drone], external[:, 2].astype(np.intp),
                                 margin(mine_drone, other))
    spec = GroupSpec(start[members], goal[members], ref[members], steps, dt, limits, pairs,
                     obstacles, settings.alpha, settings.beta)
    return _Group(spec, gid, segment_keys(glob, n, steps), rows=glob, obs_other=other,
                  trust=trust)


def plan_quad_transition(index: int, name: str, start: FloatArray, goal: FloatArray,
                         duration: float, limits: Limits,
                         settings: PlannerSettings, lines_at_limit: bool = True,
                         budget_s: float | None = None,
                         clock: Callable[[], float] = time.perf_counter,
                         workers: int = 1, ray: bool = False) -> TransitionResult:
    """Plan one quadrotor transition from ``start`` to ``goal`` (n, 3) in ``duration`` s.

    With the tracking margin first; if that cannot be met, without it (the
    plan then keeps the limit only, and its minimum separation says so).
    Straight lines that keep every pair at its target are flown as they are; if
    the optimiser fails, lines that keep only the limit are flown unless
    ``lines_at_limit`` is False (a return flown unrehearsed wants its margin).
    Past ``budget_s`` (default ``settings.budget_s``) of ``clock`` the search stops with a
    SeparationConflict.  ``workers`` > 1 solves the conflict groups in that many worker
    processes (:mod:`groundctl.plan.groupsolve`; the same plan as with one), ``ray``:
    this process and actors on the Ray cluster it is connected to.
    """
    t0 = time.perf_counter()
    budget_s = settings.budget_s if budget_s is None else budget_s
    deadline = clock() + budget_s
    guess = _straight_lines(index, name, start, goal, duration, limits, settings)
    steps, P, V, A = guess.steps, guess.ref, guess.V, guess.A
    lines = check_straight_lines(start, goal, limits.min_separation, settings.tracking_margin)
    # The floor (plan.straight): lines that keep every pair at its target need nothing
    # more; lines that keep the limit are what is flown if the optimiser finds nothing.
    # Both only on the shared profile: lines on the slower, capped one of a long mover
    # are not synchronised and the exact check says nothing of them.
    usable = (guess.synchronised and lines.keeps_limit
              and len(_limit_violators(V, A, limits)) == 0)
    if usable and lines.keeps_target:
        return _straight_result(index, name, start, goal, duration, steps, P, V, lines, t0)
    try:
        try:
            result = _plan(index, name, start, goal, guess, duration, limits, settings, t0,
                           deadline, clock, budget_s, workers, ray)
        except PlanningError:
            if settings.tracking_margin <= 0 or clock() >= deadline:
                raise
            result = _plan(index, name, start, goal, guess, duration, limits,
                           replace(settings, tracking_margin=0.0), t0, deadline, clock,
                           budget_s, workers, ray)
    except PlanningError:
        if not (usable and lines_at_limit):
            raise
        return _straight_result(index, name, start, goal, duration, steps, P, V, lines, t0)
    return replace(result, straight_min_separation=lines.min_separation_m)


def _straight_result(index: int, name: str, start: FloatArray, goal: FloatArray,
                     duration: float, steps: int, P: FloatArray, V: FloatArray,
                     lines: StraightCheck, t0: float) -> TransitionResult:
    times = np.linspace(0.0, duration, steps + 1)
    return TransitionResult(
        index=index, name=name, trajectories=Trajectories(times, P, V), steps=steps,
        iterations=0, seconds=time.perf_counter() - t0, qp_drones=0, groups=0,
        max_slack=0.0, straight_length=float(np.linalg.norm(goal - start, axis=1).mean()),
        straight_min_separation=lines.min_separation_m, straight=True)


@dataclass(frozen=True)
class _Lines:
    """The SCP's steps and its initial guess: every drone on its straight line."""

    steps: int
    dt: float
    ref: FloatArray
    """(n, N+1, 3) reference positions, also the guess's positions (read only: the SCP
    works on a copy)."""
    V: FloatArray
    A: FloatArray
    synchronised: bool
    """Every drone on the shared rest-to-rest profile (:mod:`groundctl.plan.straight`'s
    exact check holds only then)."""


def _straight_lines(index: int, name: str, start: FloatArray, goal: FloatArray,
                    duration: float, limits: Limits, settings: PlannerSettings) -> _Lines:
    """Steps, dt, and the initial guess: reference positions and the (P, V, A) of every
    drone on its straight line with the rest-to-rest profile, or where that breaks the
    drone's limits the one that keeps them.  InfeasibleTransition if ``duration`` is
    shorter than the limits allow."""
    bound = min_transition_time(start, goal, limits, QuadrotorModel())
    if bound.seconds > duration + 1e-9:
        raise InfeasibleTransition(
            index, name, bound.seconds, duration,
            f"drone {bound.drone + 1} must fly {bound.distance:.1f} m at "
            f"<= {bound.speed_limit:.1f} m/s")
    steps, dt = _steps(duration, settings)
    prof = rest_to_rest(steps, dt)
    delta = goal - start
    s = np.tile(prof.s, (len(start), 1))
    ds = np.tile(prof.ds, (len(start), 1))
    dds = np.tile(prof.dds, (len(start), 1))
    # The shared profile peaks at 1.5 x the mean speed: with less than 1.5 x the minimum
    # time a long mover breaks its speed limit on it (and its QP, held near it by the
    # trust region, could not get back within it).  Such drones fly their line on the
    # profile that keeps their limits instead.
    dist = np.linalg.norm(delta, axis=1)
    moving = dist > 1e-9
    cap_v = np.full(len(start), np.inf)
    cap_a = np.full(len(start), np.inf)
    cap_v[moving] = line_speed_limits(delta[moving], limits) / dist[moving]
    cap_a[moving] = limits.max_accel / dist[moving]
    fast = np.flatnonzero((prof.ds.max() > cap_v) | (np.abs(prof.dds).max() > cap_a))
    for i in fast:
        capped = capped_profile(steps, dt, float(cap_v[i]), float(cap_a[i]))
        if capped is not None:
            s[i], ds[i], dds[i] = capped.s, capped.ds, capped.dds

    ref = start[:, None, :] + s[:, :, None] * delta[:, None, :]
    V = ds[:, :, None] * delta[:, None, :]
    A = dds[:, :, None] * delta[:, None, :]
    return _Lines(steps, dt, ref, V, A, synchronised=len(fast) == 0)


def _hermite_guess(start: FloatArray, goal: FloatArray, goal_vel: FloatArray,
                   duration: float, steps: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Positions, velocities (g, N+1, 3) and step accelerations (g, N, 3) on the cubic
    from rest at ``start`` to ``goal`` with ``goal_vel`` in ``duration``: the guess (and
    reference) of a transition that ends in motion."""
    s = np.linspace(0.0, 1.0, steps + 1)[None, :, None]
    p0, p1 = start[:, None, :], goal[:, None, :]
    m1 = goal_vel[:, None, :] * duration
    P = (2 * s**3 - 3 * s**2 + 1) * p0 + (-2 * s**3 + 3 * s**2) * p1 + (s**3 - s**2) * m1
    V = ((6 * s**2 - 6 * s) * p0 + (-6 * s**2 + 6 * s) * p1 + (3 * s**2 - 2 * s) * m1) \
        / duration
    A = np.diff(V, axis=1) / (duration / steps)
    return P, V, A


def _conflict(index: int, name: str, start: FloatArray, goal: FloatArray, duration: float,
              P: FloatArray, V: FloatArray, limits: Limits, reason: str
              ) -> SeparationConflict:
    """The error for a transition left in conflict: who, how close and when, on the
    last iterate ``P``, ``V`` (knots), and a spacing that is sure to work.

    Synchronised straight lines under the assignment that minimises the sum of squared
    distances (the planner's) never bring two drones closer than min_separation if
    every start and every goal are at least sqrt 2 x min_separation apart (Turpin,
    Michael, Kumar, CAPT, 2014)."""
    times = np.linspace(0.0, duration, P.shape[1])
    found = close_pairs(Trajectories(times, P, V), limits.min_separation - 1e-3)
    spacing = min(_closest_slots(start), _closest_slots(goal))
    return SeparationConflict(index, name, reason, found[:4], len(found), spacing,
                              float(np.sqrt(2.0) * limits.min_separation))


def _closest_slots(points: FloatArray) -> float:
    if len(points) < 2:
        return float("inf")
    d, _ = cKDTree(points).query(points, k=2)
    return float(d[:, 1].min())


def _plan(index: int, name: str, start: FloatArray, goal: FloatArray, guess: _Lines,
          duration: float, limits: Limits, settings: PlannerSettings, t0: float,
          deadline: float = np.inf, clock: Callable[[], float] = time.perf_counter,
          budget_s: float = BUDGET_S, workers: int = 1, ray: bool = False
          ) -> TransitionResult:
    with GroupSolvers(index, workers, ray=ray) as solvers:
        return _scp(index, name, start, goal, guess, duration, limits, settings, t0,
                    deadline, clock, budget_s, solvers)


def _scp(index: int, name: str, start: FloatArray, goal: FloatArray, guess: _Lines,
         duration: float, limits: Limits, settings: PlannerSettings, t0: float,
         deadline: float, clock: Callable[[], float], budget_s: float,
         solvers: GroupSolvers) -> TransitionResult:
    """The SCP from ``guess`` (left as it is: the iterate is a copy)."""
    n = start.shape[0]
    steps, dt, ref = guess.steps, guess.dt, guess.ref
    P, V, A = ref.copy(), guess.V.copy(), guess.A.copy()
    delta = goal - start
    d_sep = chord_separation(limits, dt)  # the widest bulge: for the searches' radii
    d_row = limits.min_separation + SEPARATION_BUFFER  # what the rows ask, bulge apart
    margin = _pair_margin(start, goal, d_row, settings.tracking_margin)
    d_far = d_sep + settings.tracking_margin  # pairs beyond this plus a margin are left out
    states: dict[tuple[int, ...], _Group] = {}
    iterations = 0
    qp_drones: set[int] = set()
    links = np.empty((0, 3), dtype=np.int64)
    violators_all = np.empty(0, dtype=np.intp)
    had_rows = np.empty((0, 3), dtype=np.int64)
    built = 0
    out_of_time = False
    if settings.tolerance > MAX_TOLERANCE:
        raise ValueError(f"`tolerance` must be at most {MAX_TOLERANCE} m")
    for iterations in range(1, settings.max_iterations + 1):
        # One spatial query per iterate, at the largest radius; the others filter it.
        near_build = close_pair_segments(P, d_far + BUILD_MARGIN)
        need = within(P, near_build, d_far + NEED_MARGIN)
        # Only pairs whose row is violated or nearly active join drones into a group;
        # the other close pairs become obstacle rows.  Links accumulate, so a group
        # keeps its members (and its QP) until it converges.
        tight = need[chord_clearance(P, need, A, dt) < d_row + margin(need[:, 0], need[:, 1])
                     + LINK_MARGIN]
        links = unique_segments(np.concatenate([links, tight]), n, steps)
        violators_all = np.union1d(violators_all, _limit_violators(V, A, limits))
        grouped = groups(n, links[:, :2], violators_all, MAX_GROUP, keep=states)
        # Which group each drone was in, so a grown or merged group inherits the
        # smallest trust region of its parts: resetting it would let a group that
        # keeps picking up neighbours cycle for ever.
        trust_of = np.full(n, TRUST_RADIUS)
        for key, st in states.items():
            trust_of[list(key)] = st.trust
        new_states: dict[tuple[int, ...], _Group] = {}
        fresh: list[NDArray[np.int64]] = []
        for members in grouped:
            key = tuple(int(x) for x in members)
            qp_drones.update(key)
            inside = np.zeros(n, dtype=bool)
            inside[members] = True
            mine_need = need[inside[need[:, 0]] | inside[need[:, 1]]]
            state = states.get(key)
            if state is None or not np.all(np.isin(segment_keys(mine_need, n, steps),
                                                   state.keys)):
                built += 1
                state = _build_group(members, inside, near_build, [had_rows, *fresh], start,
                                     goal, ref, steps, dt, limits, settings,
                                     trust=float(trust_of[members].min()), margin=margin,
                                     gid=built)
                solvers.build(state.gid, state.spec)
                fresh.append(state.rows)
            new_states[key] = state
        # Every row a group was ever built with, once per iteration (per build, the
        # growing set's unique pass was most of a 1000-drone transition's time).
        had_rows = unique_segments(np.concatenate([had_rows, *fresh]), n, steps)
        kept = {st.gid for st in new_states.values()}
        solvers.forget([st.gid for st in states.values() if st.gid not in kept])
        # Gauss-Seidel, one colour at a time: obstacles are where the other drones are
        # now, including groups solved in earlier batches of this iteration.  Every group
        # keeps the rows against them, so each pair is safe after whichever of its two
        # groups was solved last, and a group's current iterate is always feasible.
        # Groups of one batch never read each other's drones: solved in any order, or
        # at the same time, they give the same iterate.
        todo = [(key, st) for key, st in new_states.items() if not st.converged]
        for batch in colour_classes([np.asarray(k, dtype=np.intp) for k, _ in todo],
                                    [st.obs_other for _, st in todo], n):
            if clock() >= deadline:
                out_of_time = True
                break
            jobs = []
            for b in batch:
                key, state = todo[b]
                members = np.asarray(key, dtype=np.intp)
                ks = state.spec.obstacles.k
                jobs.append(SolveJob(state.gid, P[members], V[members], A[members],
                                     state.trust,
                                     np.stack([P[state.obs_other, ks],
                                               P[state.obs_other, ks + 1]], axis=1),
                                     A[state.obs_other, ks], max(deadline - clock(), 1e-3)))
            for b, outcome in zip(batch, solvers.solve(jobs), strict=True):
                key, state = todo[b]
                members = np.asarray(key, dtype=np.intp)
                if isinstance(outcome, Failed):
                    if clock() >= deadline:
                        out_of_time = True  # it keeps the iterate of its last solve
                        continue
                    # OSQP gave up on this group (it can call a badly scaled QP
                    # infeasible): the group keeps its trajectory, which every neighbour
                    # solved since was kept clear of, and tries again with a smaller
                    # trust region.
                    state.failures += 1
                    if state.failures > GROUP_FAILURES:
                        raise _conflict(index, name, start, goal, duration, P, V, limits,
                                        f"{outcome.status} for a group of {len(members)} "
                                        f"drones after {iterations} SCP iterations")
                    state.slack = np.inf
                    state.trust = max(state.trust * 0.5, settings.tolerance / 4)
                    continue
                change = float(np.abs(outcome.P - P[members]).max())
                state.slack = float(outcome.S.max(initial=0.0))
                P[members], V[members], A[members] = outcome.P, outcome.V, outcome.A
                if state.slack < SLACK_TOL:
                    state.converged = change < settings.tolerance
                    state.trust = max(state.trust * 0.5, settings.tolerance / 4)
        states = new_states
        if out_of_time or all(st.converged for st in states.values()):
            break
    max_slack = max((st.slack for st in states.values()), default=0.0)
    times = np.linspace(0.0, duration, steps + 1)
    if out_of_time:
        # Every solve keeps its group clear of everybody where they are, so an iterate
        # with no slack left is a plan -- not yet the optimum, the budget stopped the
        # polishing.  It is kept only if it is certainly safe: no pair closer than the
        # limit in continuous time (rows exist only for close pairs, and a group moves
        # up to its trust region per solve) and no drone over its limits.
        if (max_slack >= SLACK_TOL or len(_limit_violators(V, A, limits, LIMIT_TOL / 2))
                or close_pairs(Trajectories(times, P, V), limits.min_separation)):
            raise _conflict(index, name, start, goal, duration, P, V, limits,
                            f"no plan within the {budget_s:g} s budget "
                            f"({iterations} SCP iterations)")
    elif max_slack >= SLACK_TOL:
        raise _conflict(index, name, start, goal, duration, P, V, limits,
                        f"slack {max_slack:.3f} m after {iterations} SCP iterations")
    return TransitionResult(
        index=index, name=name, trajectories=Trajectories(times, P, V), steps=steps,
        iterations=iterations, seconds=time.perf_counter() - t0, qp_drones=len(qp_drones),
        groups=len(states), max_slack=max_slack,
        straight_length=float(np.linalg.norm(delta, axis=1).mean()),
        converged=not out_of_time)


def plan_among(index: int, name: str, start: FloatArray, goal: FloatArray, duration: float,
               limits: Limits, settings: PlannerSettings,
               others_at: Callable[[FloatArray], FloatArray], *,
               goal_vel: FloatArray | None = None,
               goal_acc: FloatArray | None = None) -> TransitionResult:
    """Plan ``start`` -> ``goal`` (g, 3) in ``duration`` s among drones that keep flying.

    ``others_at(times)`` gives the other drones' positions (m, len(times), 3) at the
    transition's knot times (0 = this transition's start).  They are obstacles:
    their trajectories never change, every close pair-segment with them becomes an
    obstacle row on the moving drone, and the moving drones form one group.  A
    drone leaving a show in progress is planned this way (see
    :mod:`groundctl.flight.returning`).  The rows tighten the limit by the chord
    bulge of *both* drones, so they hold between the knots as long as the others'
    trajectories keep the acceleration limit, as planned ones do.

    ``goal_vel`` (g, 3): arrive with these velocities, not at rest (and ``goal_acc``,
    the last step's accelerations): handed over onto a trajectory in motion.  The guess
    is then the cubic from rest at the start to that state at the goal.
    """
    t0 = time.perf_counter()
    g = start.shape[0]
    guess = _straight_lines(index, name, start, goal, duration, limits, settings)
    steps, dt, ref, V, A = guess.steps, guess.dt, guess.ref, guess.V, guess.A
    moving_end = goal_vel is not None and bool(np.any(goal_vel))
    if moving_end:
        assert goal_vel is not None
        ref, V, A = _hermite_guess(start, goal, np.asarray(goal_vel, dtype=float),
                                   duration, steps)
        # Within the altitude limits (never tighter than the ends themselves): the QP's
        # trust region is around the guess, and a guess below the floor would empty it.
        low = np.minimum(limits.min_alt, np.minimum(start[:, 2], goal[:, 2]))[:, None]
        high = np.maximum(limits.max_alt, np.maximum(start[:, 2], goal[:, 2]))[:, None]
        ref[:, :, 2] = np.clip(ref[:, :, 2], low, high)
    P = ref.copy()
    delta = goal - start
    times = np.linspace(0.0, duration, steps + 1)
    others = np.asarray(others_at(times), dtype=float).reshape(-1, steps + 1, 3)
    n = g + len(others)
    d_sep = chord_separation(limits, dt)
    d_row = limits.min_separation + SEPARATION_BUFFER
    start_all = np.concatenate([start, others[:, 0]])
    goal_all = np.concatenate([goal, others[:, -1]])
    ref_all = np.concatenate([ref, others])
    margin = _pair_margin(start_all, goal_all, d_row, settings.tracking_margin)
    d_far = d_sep + settings.tracking_margin
    members = np.arange(g, dtype=np.intp)
    inside = np.zeros(n, dtype=bool)
    inside[:g] = True
    state: _Group | None = None
    qp: GroupQP | None = None
    fixed = np.empty((0, 2, 3))
    iterations, slack = 0, np.inf
    for iterations in range(1, settings.max_iterations + 1):  # noqa: B007 (used after)
        # Only pairs with a moving drone, from one query at the largest radius.
        every = np.concatenate([P, others])
        near_build = segments_with(every, g, d_far + BUILD_MARGIN)
        need = within(every, near_build, d_far + NEED_MARGIN)
        if state is None or not np.all(np.isin(segment_keys(need, n, steps), state.keys)):
            # A rebuilt group keeps every row it had (_build_group carries state.rows).
            state = _build_group(members, inside, near_build,
                                 [] if state is None else [state.rows], start_all, goal_all,
                                 ref_all, steps, dt,
                                 limits, settings,
                                 trust=TRUST_RADIUS if state is None else state.trust,
                                 margin=margin)
            qp = state.spec.build()
            if moving_end:
                assert goal_vel is not None
                qp.end_on_the_move(goal_vel, goal_acc)
            # The obstacles never move: their rows' positions are set once per build.
            fixed = np.stack([every[state.obs_other, qp.obstacles.k],
                              every[state.obs_other, qp.obstacles.k + 1]], axis=1)
        assert qp is not None
        qp.linearise(P, V, A, state.trust, fixed)
        Pg, Vg, Ag, Sg = qp.solve(index)
        change = float(np.abs(Pg - P).max())
        slack = float(Sg.max(initial=0.0))
        P, V, A = Pg, Vg, Ag
        if slack < SLACK_TOL:
            if change < settings.tolerance:
                break
            state.trust = max(state.trust * 0.5, settings.tolerance / 4)
    if slack >= SLACK_TOL:
        raise PlanningError(
            index, "no separation-feasible solution",
            f"slack {slack:.3f} m after {iterations} SCP iterations among {len(others)} "
            "drones that keep flying")
    return TransitionResult(
        index=index, name=name, trajectories=Trajectories(times, P, V), steps=steps,
        iterations=iterations, seconds=time.perf_counter() - t0, qp_drones=g, groups=1,
        max_slack=slack, straight_length=float(np.linalg.norm(delta, axis=1).mean()))
