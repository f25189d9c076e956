"""A spare's way into a failed drone's track, planned on the spot (issue 29).

When a show drone leaves its track (a way out, a fall, a lost link), a spare waiting
beside the show (:mod:`groundctl.plan.spares`) can fly its part from the next moment
it can reach: :func:`plan_join` looks, earliest first, for the show time ``until`` at
which the spare, starting at rest where it waits, can be on the track's plan in the
track's own state there -- at a formation's slot while it rests (its arrival and hold),
or in motion on the way into it (position, velocity and the acceleration of its last
step: :func:`join_windows`) -- and plans the path there with the show's own SCP planner
among every drone that keeps flying (:func:`~groundctl.plan.scp_quad.plan_among`: the
others on their plans, on their ways out, or on their own joins, and the points where
drones hover or lie).  From ``until`` on the spare flies the track's plan, its
setpoints without a jump.

Nothing is taken on trust: the path, and the track's plan from ``until`` on while the
failed drone is still on its way out, are checked against every obstacle exactly in
continuous time -- both sides are cubic between knots, so on the union of their knots
the distance's minimum is found by the verifier's branch and bound
(:func:`~groundctl.plan.verify.closest_on_segment`).  A window where planning fails
or the check finds less than the limit is skipped for the next; no window left is a
:class:`~groundctl.errors.PlanningError` giving every window's reason.  A drone coming
down its landing column is somewhere on the column, not at a point: the column counts
by a certified lower bound of its distance (:attr:`Moving.spacing`).  Pure: the driver
decides when and which spare, runs this in a worker with a deadline, and flies it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import GroundctlError, PlanningError
from groundctl.execute.leaving import Join, Leave, climb_time, return_duration
from groundctl.flight.returning import (
    COLUMN_STEP_M,
    DESCENT_MARGIN_S,
    DESCENT_SPEED_MPS,
    TRACKING_MARGIN_M,
    column,
)
from groundctl.plan.plan import Plan
from groundctl.plan.scp_quad import plan_among
from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import (
    DIST_TOL,
    bounding_spheres,
    hermite_power,
    kinematics,
    limit_violations,
    nearest_in_order,
)
from groundctl.show.model import PlannerSettings

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)

#: The least a join is planned to last, s: time for the spare's autopilot to settle
#: from its hover onto the path.
MIN_JOIN_S = 4.0
#: Chances to join a track in motion, per transition (before its formation's rest) ...
MOVING_WINDOWS = 3
#: ... this far apart in show time, s (the first on a grid of MOVING_GRID_S).
MOVING_STEP_S = 2.0
MOVING_GRID_S = 0.5
#: A join in motion is given this many SCP iterations (one into a crowd in motion that
#: does not converge in these does not in 30 either: 1,000 drones, 0.2-1.6 m of slack
#: left after 30) ...
MOVING_ITERATIONS = 12
#: ... and windows in motion are tried only while planning has taken less than this, s
#: (each is a full SCP among every drone: about 0.3 s at 1,000 drones).
MOVING_BUDGET_S = 1.0
#: A track slower than this, m/s, is at rest there (a formation's hold): the formation's
#: own window covers it.
MOVING_MIN_SPEED = 1e-3

@dataclass(frozen=True)
class Moving:
    """One drone that is not on its plan for part of the time: on ``trajectory`` (one
    row, time 0 at show time ``offset``) from show time ``start`` to ``end``, clamped."""

    trajectory: Trajectories
    offset: float
    start: float
    end: float
    spacing: float = 0.0
    """Non-zero: it is one of a column's points this far apart, standing for the column's
    stretch around it (a descending drone is somewhere on the column, not at a point)."""

    def position(self, show_times: FloatArray) -> FloatArray:
        tau = np.clip(np.asarray(show_times, dtype=float) - self.offset, 0.0,
                      self.trajectory.end)
        return self.trajectory.evaluate(tau)[0][0]


def _still(point: FloatArray, start: float, end: float, spacing: float = 0.0) -> Moving:
    """A drone that does not move over show times [start, end] (``spacing``: anywhere on
    the column stretch around ``point``, see :attr:`Moving.spacing`)."""
    pos = np.repeat(np.asarray(point, dtype=float)[None, None, :], 2, axis=1)
    return Moving(Trajectories(np.array([0.0, 1.0]), pos, np.zeros_like(pos)), start, start,
                  end, spacing)


def _leave_pieces(plan: Plan, track: int, leave: Leave, t0: float, t1: float
                  ) -> list[Moving]:
    """Where ``track``'s drone is over [t0, t1] while it leaves: on its plan until its way
    out begins (hovering at the way out's start if it was heard again off its plan), then
    on the way out; then anywhere on the column down to its landing spot for as long as a
    descent takes (:data:`~groundctl.flight.returning.DESCENT_SPEED_MPS`, with margin),
    then on the ground there."""
    pieces: list[Moving] = []
    row = Trajectories(plan.trajectories.times, plan.trajectories.pos[track:track + 1],
                       plan.trajectories.vel[track:track + 1])
    if t0 < leave.at and not leave.held:
        pieces.append(Moving(row, 0.0, t0, min(leave.at, t1)))
    began = t0 if leave.held else max(leave.at, t0)
    if min(leave.until, t1) > began:
        pieces.append(Moving(leave.trajectory, leave.at, began, min(leave.until, t1)))
    top = leave.state(leave.until)[0]
    down = leave.until + float(top[2]) / DESCENT_SPEED_MPS + DESCENT_MARGIN_S
    if t1 > leave.until:
        for point in column(top):
            pieces.append(_still(point, max(leave.until, t0), min(down, t1), COLUMN_STEP_M))
    if t1 > down:
        pieces.append(_still(column(top)[-1], max(down, t0), t1))
    return pieces


def closest_approach(path: Moving, plan: Plan, tracks: NDArray[np.intp],
                     moving: Sequence[Moving], static: FloatArray,
                     t0: float, t1: float) -> tuple[float, str]:
    """The closest ``path`` comes over show times [t0, t1] to the plan's ``tracks``, to
    each of ``moving`` over its own stretch, and to the ``static`` points, exact in
    continuous time; and to what, in words.

    Every side is piecewise cubic; refined to the union of their knots it is still
    exactly itself (a cubic restricted to part of its segment is a cubic), so each pair
    is a relative cubic per segment, bounded by its Bezier hull and measured by the
    verifier's branch and bound where the hull reaches under the best found.  A piece
    that stands for a column's stretch (:attr:`Moving.spacing`) counts by the nearest
    the column itself can be: a certified lower bound, not the exact distance."""
    best, what = math.inf, "nothing"
    if t1 <= t0:
        return best, what
    p_knots = path.trajectory.times + path.offset
    sides: list[tuple[str, FloatArray, float, float, Moving | None]] = []
    if len(tracks):
        sides.append(("plan", plan.trajectories.times, t0, t1, None))
    for k, m in enumerate(moving):
        lo, hi = max(m.start, t0), min(m.end, t1)
        if hi > lo:
            sides.append((f"moving {k}", m.trajectory.times + m.offset, lo, hi, m))
    for name, knots, lo, hi, piece in sides:
        t = np.unique(np.concatenate([[lo, hi], p_knots[(p_knots > lo) & (p_knots < hi)],
                                      knots[(knots > lo) & (knots < hi)]]))
        h = np.diff(t)
        tau = np.clip(t - path.offset, 0.0, path.trajectory.end)
        pp, pv, _ = path.trajectory.evaluate(tau)
        pp, pv = pp[0], pv[0]
        # Clamped before its start or after its end, the path holds still there.
        pv = np.where(((t - path.offset < 0) | (t - path.offset > path.trajectory.end))
                      [:, None], 0.0, pv)
        if piece is None:
            op, ov, _ = plan.trajectories.evaluate(np.clip(t, 0.0, plan.duration), tracks)
            labels = [f"drone {int(j) + 1}" for j in tracks]
        else:
            mt = t - piece.offset
            op, ov, _ = piece.trajectory.evaluate(np.clip(mt, 0.0, piece.trajectory.end))
            ov = np.where(((mt < 0) | (mt > piece.trajectory.end))[None, :, None], 0.0, ov)
            labels = [name]
        a = hermite_power(pp[:-1], pp[1:], pv[:-1] * h[:, None], pv[1:] * h[:, None])
        b = hermite_power(op[:, :-1].reshape(-1, 3), op[:, 1:].reshape(-1, 3),
                          (ov[:, :-1] * h[None, :, None]).reshape(-1, 3),
                          (ov[:, 1:] * h[None, :, None]).reshape(-1, 3))
        d = np.tile(a, (len(op), 1, 1)) - b  # row i * segments + k
        near, row, at = _closest_rows(d)
        if row < 0:
            continue
        half = 0.0 if piece is None else piece.spacing / 2
        # A point standing for a stretch of column: the column is no nearer than this.
        near = math.sqrt(max(near * near - half * half, 0.0))
        if near < best:
            i, k = divmod(row, len(h))
            best, what = near, f"{labels[i]} at show time {t[k] + at * h[k]:.1f} s"
    if len(static):
        t = np.unique(np.concatenate([[t0, t1], p_knots[(p_knots > t0) & (p_knots < t1)]]))
        h = np.diff(t)
        tau = np.clip(t - path.offset, 0.0, path.trajectory.end)
        pp, pv, _ = path.trajectory.evaluate(tau)
        pv = np.where(((t - path.offset < 0) | (t - path.offset > path.trajectory.end))
                      [None, :, None], 0.0, pv)
        a = hermite_power(pp[0, :-1], pp[0, 1:], pv[0, :-1] * h[:, None],
                          pv[0, 1:] * h[:, None])
        # Every point against every segment at once (row point * segments + k), pruned by
        # the segments' hulls like the moving sides.
        points = np.asarray(static, dtype=float).reshape(-1, 3)
        d = np.tile(a, (len(points), 1, 1))
        d[:, 0] -= np.repeat(points, len(h), axis=0)
        near, row, at = _closest_rows(d)
        if row >= 0 and near < best:
            i, k = divmod(row, len(h))
            where = ", ".join(f"{c:.1f}" for c in points[i])
            best, what = near, f"the drone at ({where}) at show time {t[k] + at * h[k]:.1f} s"
    return best, what


def _closest_rows(d: FloatArray) -> tuple[float, int, float]:
    """(distance, row, s in [0, 1]) of the smallest minimum over relative cubics ``d``
    (m, 4, 3), exact to the verifier's tolerance; (inf, -1, 0) for none.  The nearer end
    of the nearest segment bounds it from above, each segment's Bezier hull from below
    (a segment whose hull only touches the bound -- one at rest -- is measured too)."""
    if not len(d):
        return math.inf, -1, 0.0
    centre, radius = bounding_spheres(d)
    lower = np.linalg.norm(centre, axis=1) - radius
    upper = float(min(np.linalg.norm(d[:, 0], axis=1).min(),
                      np.linalg.norm(d.sum(axis=1), axis=1).min()))
    rows = np.flatnonzero(lower <= upper)
    rows = rows[np.argsort(lower[rows], kind="stable")]
    best, k, s = nearest_in_order(lower[rows], lambda blk: d[rows[blk]])
    return best, int(rows[k]) if k >= 0 else -1, s


class JoinWindow(NamedTuple):
    """One chance to take a track over: leave where it waits at show time ``leave``,
    be on the track's plan from ``arrive``, at ``slot`` with the plan's velocity
    ``vel`` and acceleration ``acc`` there (zero at a formation's rest)."""

    leave: float
    arrive: float
    slot: FloatArray
    vel: FloatArray
    acc: FloatArray


def join_windows(plan: Plan, track: int, start: FloatArray, earliest: float,
                 vacating: Leave | None = None) -> list[JoinWindow]:
    """Each chance to join ``track`` from ``start`` (at rest) no sooner than ``earliest``,
    earliest arrival first.  Per formation, the earliest arrival at the track's slot
    while it rests there (its arrival to the end of its hold); before it, in the
    transition the track flies to it, up to :data:`MOVING_WINDOWS` instants
    :data:`MOVING_STEP_S` apart at which the spare arrives on the track in motion.  Each
    is given the time a way home of that length would be
    (:func:`~groundctl.execute.leaving.return_duration`), at least :data:`MIN_JOIN_S`;
    the spare waits where it is until it must leave.  ``vacating``: the failed drone's
    own way out; no moving window comes before it leaves, and a formation it leaves
    during its hold also offers the moment its slot is clear again (the limit plus the
    join's margin away)."""
    out: list[JoinWindow] = []
    clear = plan.limits.min_separation + TRACKING_MARGIN_M
    still = np.zeros(3)

    def need(goal: FloatArray) -> float:
        return max(return_duration(plan, start[None, :], goal[None, :]), MIN_JOIN_S)

    moved_from = 0.0  # where the transition into the next formation begins
    last = plan.formations[-1].index if plan.formations else None
    for w in plan.formations:
        goal = w.goals[track]
        # In motion, on the way into this formation (not into the landing: the fleet is
        # coming down, and the failed drone may be down on the track's spot).
        times = np.arange(moved_from + MOVING_GRID_S, w.arrive - MOVING_STEP_S / 2,
                          MOVING_GRID_S) if w.index != last else np.zeros(0)
        if len(times):
            pos, vel, acc = plan.trajectories.evaluate(times, np.array([track]))
            taken, previous = 0, -math.inf
            for k, t in enumerate(times):
                if taken == MOVING_WINDOWS or t >= plan.duration:
                    break
                if t < previous + MOVING_STEP_S - 1e-9:
                    continue
                if np.linalg.norm(vel[0, k]) < MOVING_MIN_SPEED:
                    continue  # at rest: the formation's window covers it
                if vacating is not None and t <= vacating.at:
                    continue  # the failed drone is still on the track there
                lead = need(pos[0, k])
                if t - lead >= earliest:
                    out.append(JoinWindow(float(t) - lead, float(t), pos[0, k], vel[0, k],
                                          acc[0, k]))
                    taken, previous = taken + 1, float(t)
        moved_from = w.end
        need_w = need(goal)
        arrivals = [max(earliest + need_w, w.arrive)]
        if vacating is not None and vacating.at < w.end:
            t = np.arange(max(vacating.at, w.arrive), w.end + 1e-9, 0.05)
            gone = np.linalg.norm(vacating.position(t) - goal, axis=1) >= clear
            if gone.any():
                arrivals.append(max(float(t[int(np.argmax(gone))]), arrivals[0]))
        for arrive in sorted(set(arrivals)):
            if vacating is not None and not vacating.held and arrive < vacating.at:
                continue  # the failed drone is still on the slot then
            if arrive <= w.end + 1e-9 and arrive < plan.duration:
                out.append(JoinWindow(arrive - need_w, arrive, goal, still, still))
    return sorted(out, key=lambda j: j.arrive)


def plan_join(plan: Plan, track: int, start: FloatArray, earliest: float, *,
              absent: Collection[int] = (), leaves: Mapping[int, Leave] | None = None,
              joins: Mapping[int, Join] | None = None,
              static: FloatArray | None = None, climb: float = 0.0,
              climb_s: float | None = None,
              replaced: Sequence[tuple[int, Leave]] = ()) -> Join:
    """The spare waiting at rest at ``start`` takes over ``track`` at the earliest window
    it can (module docstring), leaving no sooner than show time ``earliest``.

    ``climb`` > 0: it waits on the ground at ``start`` and first climbs that many metres
    straight up (:func:`climb_time`; its column is checked against everyone while it
    climbs, each of its points standing for the column around it), its path starting at
    the top; ``climb_s`` (if longer than :func:`climb_time`): how long it is given to arm
    and climb (what the fleet's own takeoffs took).

    ``absent`` tracks fly no plan (their drones left, fell or are down: where they are
    goes in ``static``, (k, 3) points that do not move, like waiting spares); ``leaves``
    (track -> Leave) are ways out being flown -- the failed ``track``'s own among them;
    ``joins`` (track -> Join) other spares on their way in (their tracks count as flown
    from each one's ``until``); ``replaced`` (track, Leave) drones a spare replaced, still
    on their way out (the track itself flown by the spare).  PlanningError if no window
    works."""
    import time

    t_start = time.perf_counter()
    leaves = dict(leaves or {})
    joins = dict(joins or {})
    static = np.zeros((0, 3)) if static is None else np.asarray(static, dtype=float)
    pad = np.asarray(start, dtype=float)
    start = pad + np.array([0.0, 0.0, climb])
    climb_s = climb_time(plan, climb) if climb_s is None or climb <= 0 \
        else max(climb_s, climb_time(plan, climb))
    gone = set(absent) | {track} | set(leaves) | set(joins)
    flown = np.array([j for j in range(plan.drones) if j not in gone], dtype=np.intp)
    limit = plan.limits.min_separation
    reasons: list[str] = []
    said = 0
    vacating = leaves.get(track) or max(
        (lv for j, lv in replaced if j == track), key=lambda lv: lv.at, default=None)
    for leave_at, arrive, goal, goal_vel, goal_acc in join_windows(
            plan, track, start, earliest + climb_s, vacating):
        if len(reasons) > said:
            said = len(reasons)
            log.debug("join of track %d: %s (%.0f ms so far)", track + 1, reasons[-1],
                      (time.perf_counter() - t_start) * 1000.0)
        moving_end = bool(np.any(goal_vel))
        if moving_end and time.perf_counter() - t_start > MOVING_BUDGET_S:
            continue  # tried long enough in motion: the formations' rests are left
        moving: list[Moving] = []
        for j, lv in [*leaves.items(), *replaced]:
            moving += _leave_pieces(plan, j, lv, leave_at - climb_s, plan.duration)
        for j, jn in joins.items():
            moving.append(Moving(jn.trajectory, jn.at, leave_at - climb_s, jn.until))
            moving.append(_plan_row(plan, j, jn.until, plan.duration))
        if climb_s > 0:
            closest, what = _climb_clearance(plan, flown, moving, static, pad, start,
                                             leave_at - climb_s, leave_at)
            if closest < limit - DIST_TOL:
                reasons.append(f"arriving at {arrive:.1f} s its climb from the pad would "
                               f"come {closest:.2f} m from {what}")
                continue

        def others_at(times: FloatArray, moving: list[Moving] = moving,
                      leave_at: float = leave_at) -> FloatArray:
            show_t = leave_at + times
            pos = plan.trajectories.evaluate(np.clip(show_t, 0.0, plan.duration), flown)[0]
            extra = [np.where(((show_t >= m.start) & (show_t <= m.end))[:, None],
                              m.position(show_t), np.nan) for m in moving]
            # A piece outside its stretch is elsewhere: far away, not in the way.
            rows = [np.nan_to_num(e, nan=1e6) for e in extra]
            still = np.repeat(static[:, None, :], len(times), axis=1)
            return np.concatenate([pos, *(r[None] for r in rows), still])

        try:
            result = plan_among(0, f"join of track {track}", start[None, :], goal[None, :],
                                arrive - leave_at, plan.limits,
                                PlannerSettings(tracking_margin=TRACKING_MARGIN_M,
                                                max_iterations=MOVING_ITERATIONS)
                                if moving_end else
                                PlannerSettings(tracking_margin=TRACKING_MARGIN_M), others_at,
                                goal_vel=goal_vel[None, :] if moving_end else None,
                                goal_acc=goal_acc[None, :] if moving_end else None)
        except GroundctlError as exc:
            reasons.append(f"arriving at {arrive:.1f} s: {exc}")
            continue
        # The QP's norm limits are tangent planes, exact only at convergence (and a
        # window in motion is given fewer iterations): checked as the verifier does.
        beyond = limit_violations(kinematics(result.trajectories, plan.limits), plan.limits)
        if beyond:
            reasons.append(f"arriving at {arrive:.1f} s on its way in {beyond[0]}")
            continue
        path = Moving(result.trajectories, leave_at, leave_at, arrive)
        closest, what = closest_approach(path, plan, flown, moving, static, leave_at, arrive)
        if closest < limit - DIST_TOL:
            reasons.append(f"arriving at {arrive:.1f} s it would come {closest:.2f} m from "
                           f"{what}")
            continue
        # Then on the track's plan, while drones off their plans are still about.
        after = _plan_row(plan, track, arrive, plan.duration)
        later = [m for m in moving if m.end > arrive]
        closest, what = closest_approach(after, plan, np.zeros(0, dtype=np.intp), later,
                                         static, arrive, plan.duration)
        if closest < limit - DIST_TOL:
            reasons.append(f"arriving at {arrive:.1f} s the track's plan would then come "
                           f"{closest:.2f} m from {what}")
            continue
        return Join(track, leave_at, result.trajectories,
                    plan_ms=(time.perf_counter() - t_start) * 1000.0, climb_s=climb_s)
    raise PlanningError(0, "no join", f"track {track + 1}: " + (
        "; ".join(reasons) if reasons else "no formation left to join before the show ends"))


def _climb_clearance(plan: Plan, flown: NDArray[np.intp], moving: Sequence[Moving],
                     static: FloatArray, pad: FloatArray, top: FloatArray, t0: float,
                     t1: float) -> tuple[float, str]:
    """The closest anyone comes over [t0, t1] to the column from ``pad`` up to ``top``
    (the spare somewhere on it while it arms and climbs): each of the column's points,
    COLUMN_STEP_M apart at most, counts by the nearest the stretch around it can be."""
    best, what = math.inf, "nothing"
    count = max(2, int(np.ceil(float(top[2] - pad[2]) / COLUMN_STEP_M)) + 1)
    step = float(top[2] - pad[2]) / (count - 1)
    for z in np.linspace(float(pad[2]), float(top[2]), count):
        point = np.array([pad[0], pad[1], z])
        d, near = closest_approach(_still(point, t0, t1), plan, flown, moving, static, t0, t1)
        d = math.sqrt(max(d * d - (step / 2) ** 2, 0.0)) if math.isfinite(d) else d
        if d < best:
            best, what = d, near
    return best, what


def _plan_row(plan: Plan, track: int, start: float, end: float) -> Moving:
    """``track`` on its plan over show times [start, end]."""
    tr = plan.trajectories
    row = Trajectories(tr.times, tr.pos[track:track + 1], tr.vel[track:track + 1])
    return Moving(row, 0.0, start, end)
