"""Land-all in the middle of a show: a collision-free way home, planned on the spot.

Straight lines from wherever the show was interrupted to the landing points
cross each other (a vertical ring flying home to a flat grid, say): the
first end-to-end hold/land-all test flew two drones 1.37 m apart that way.
So land-all first freezes the show clock (every drone hovers on its plan
point, which the plan keeps separated), then plans one more quadrotor
transition with the same SCP planner and limits as the show itself (with a
tracking margin, whatever the show file says), from those points to the
landing points, and the fleet flies it.  Planning takes
well under a second for a hundred drones; they hover meanwhile.

Land-one in the middle of a show is different: the others fly on, and the
drone's way out is planned around them (:func:`plan_leave`; when it leaves is
:mod:`groundctl.execute.leaving`'s business).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from groundctl.errors import PlanningError
from groundctl.execute.authority import scaled_limits
from groundctl.execute.leaving import (
    Join,
    Leave,
    free_spots,
    landing_candidates,
    leave_duration,
    return_duration,
)
from groundctl.execute.preflight import segment_distance
from groundctl.plan.plan import Plan
from groundctl.plan.scp_quad import plan_among, plan_quad_transition
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import PlannerSettings

#: Extra separation the return is planned with, m: it is flown at once, with
#: whatever tracking error the moment has, and unlike the show it was never
#: rehearsed (the first land-all test flew a pair 1.497 m apart at a 1.5 m limit).
TRACKING_MARGIN_M = 0.25


def plan_return(plan: Plan, tracks: list[int], start: NDArray[np.float64],
                static: NDArray[np.float64] | None = None,
                goals: NDArray[np.float64] | None = None,
                authority: float = 1.0) -> Trajectories:
    """Trajectories (one row per entry of ``tracks``) from ``start`` to their landing points
    (``goals``, (n, 3), when a return re-assigned them; else the plan's), around the
    fixed points ``static`` (k, 3): drones that are down or descending.

    ``authority`` in (0, 1] is the weakest returning vehicle's (a weak motor, a tired
    battery: :mod:`groundctl.execute.authority`): the whole return is planned within the
    limits scaled by it, and given the time that takes, so every vehicle can fly it as
    planned.  A return the weak vehicle cannot keep up with is a near miss: its
    neighbours fly on while it lags, and the MPC that would catch it is itself late on a
    ground station busy enough to be landing its show (1.38 m at a 1.5 m limit, seen).

    Raises the planner's InfeasibleTransition / PlanningError if it cannot.
    """
    if not 0.0 < authority <= 1.0:
        raise ValueError(f"authority must be in (0, 1], got {authority!r}")
    start = np.asarray(start, dtype=float)
    goal = plan.landing_hover[tracks] if goals is None else np.asarray(goals, dtype=float)
    limits = plan.limits if authority >= 1.0 else scaled_limits(plan.limits, authority)
    duration = return_duration(plan, start, goal, limits)
    # The planner's own tracking margin: per pair, as far as its two ends allow.
    settings = PlannerSettings(tracking_margin=TRACKING_MARGIN_M)
    if static is not None and len(static):
        points = np.asarray(static, dtype=float)

        def still(times: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.repeat(points[:, None, :], len(times), axis=1)

        return plan_among(0, "return", start, goal, duration, limits, settings,
                          still).trajectories
    # Flown unrehearsed: lines that keep only the bare limit are no return (the show's
    # own path home is kept instead, return_failed).
    result = plan_quad_transition(0, "return", start, goal, duration, limits, settings,
                                  lines_at_limit=False)
    return result.trajectories


def assign_landing(plan: Plan, tracks: list[int], start: NDArray[np.float64],
                   down: NDArray[np.float64], reserved: NDArray[np.float64] | None = None
                   ) -> NDArray[np.float64]:
    """Landing points (n, 3) for returning ``tracks`` from ``start``: each keeps its own
    spot when every one of them is free (and no two share a track); otherwise all of them
    are re-assigned among the
    free spots (the plan's landing spots, then its takeoff slots; least squared
    distance), so nobody lands on a drone that came down early.  ``down`` are drones
    down or descending off their spots, ``reserved`` the points others are landing on.
    Raises PlanningError if there are fewer free spots than drones."""
    own = plan.landing_hover[np.asarray(tracks, dtype=np.intp)]
    fallen = np.asarray(down, dtype=float).reshape(-1, 3)
    blocked = np.zeros((0, 3)) if reserved is None \
        else np.asarray(reserved, dtype=float).reshape(-1, 3)
    # Two drones of one track (one replaced by a spare) never keep the same spot.
    if len(set(tracks)) == len(tracks) \
            and len(free_spots(plan, own, blocked, fallen)) == len(own):
        return own
    candidates = landing_candidates(plan)
    free = free_spots(plan, candidates, blocked, fallen)
    if len(free) < len(own):
        raise PlanningError(0, "no landing spots",
                            f"{len(own)} drones to land but only {len(free)} landing spots "
                            "are clear of the drones already down")
    cost = ((start[:, None, :] - candidates[free][None, :, :]) ** 2).sum(axis=2)
    rows, cols = linear_sum_assignment(cost)
    goals = np.empty((len(own), 3))
    goals[rows] = candidates[free[cols]]
    return goals


# -- one drone leaving a show in progress ------------------------------------------------

#: Descent speed assumed for the landing column check, m/s (ArduCopter's LAND_SPEED
#: is 0.5 m/s, PX4's MPC_LAND_SPEED 0.7 m/s), plus a few seconds' margin.
DESCENT_SPEED_MPS = 0.5
DESCENT_MARGIN_S = 5.0
#: Spacing of the points that stand for a vertical column (a drone descending or
#: landed where it was), m: with obstacle rows of the separation limit (>= 1.5 m
#: around each point) 1 m leaves no gap along the column.
COLUMN_STEP_M = 1.0


def column(top: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points (k, 3) from ``top`` straight down to the ground, COLUMN_STEP_M apart."""
    count = max(2, int(np.ceil(max(float(top[2]), 0.0) / COLUMN_STEP_M)) + 1)
    points = np.repeat(np.asarray(top, dtype=float)[None, :], count, axis=0)
    points[:, 2] = np.linspace(max(float(top[2]), 0.0), 0.0, count)
    return points


def plan_leave(plan: Plan, track: int, at: float, leaves: Mapping[int, Leave],
               absent: Collection[int] = (), static: NDArray[np.float64] | None = None,
               start: NDArray[np.float64] | None = None,
               joins: Mapping[int, Join] | None = None,
               replaced: Sequence[tuple[int, Leave]] = ()) -> Leave:
    """A way for ``track`` from its formation point at show time ``at`` (or from
    ``start``, where it hovers) to its landing point, around every other drone as it
    will fly meanwhile.

    The others are obstacles on their plan, or on their own way out from
    ``leaves`` (track -> Leave) once it has begun.  ``absent`` tracks fly no
    plan (excluded, landed, descending, killed); where they really are goes in
    ``static`` (k, 3), points that do not move (see :func:`column`); ``joins`` (track ->
    Join) are spares on their way into those tracks: over their pads' columns' tops until
    they set off, on their ways in, then on the track's plan; ``replaced`` (track, Leave)
    are drones a spare replaced, still on their way out (on the track's plan before it):
    obstacles of their own, the track itself flown by the spare.  Raises the planner's
    InfeasibleTransition / PlanningError.
    """
    origin = plan.state_at(at).pos[track] if start is None else np.asarray(start, dtype=float)
    goal = plan.landing_hover[track][None, :]
    duration = leave_duration(plan, track, at, origin)
    # A track a spare is on its way into is the spare's way in, then the track's plan
    # (``coming`` below), not the plan throughout: the drone it replaces, if still up, is
    # its own way out (``going``).
    gone = set(absent) | {track} | set(joins or {})
    others = np.array([j for j in range(plan.drones) if j not in gone], dtype=np.intp)
    fixed = np.empty((0, 3)) if static is None else np.asarray(static, dtype=float)

    def others_at(times: NDArray[np.float64]) -> NDArray[np.float64]:
        show_t = np.clip(at + times, 0.0, plan.duration)
        pos = plan.trajectories.evaluate(show_t, others)[0].copy()
        for row, j in enumerate(others):
            leave = leaves.get(int(j))
            if leave is not None:
                # On its way out from leave.at; one heard again off its plan hovers at
                # the start until then (Leave.position clamps there).
                left = np.ones(len(times), dtype=bool) if leave.held \
                    else at + times >= leave.at
                pos[row, left] = leave.position(at + times[left])
        still = np.repeat(fixed[:, None, :], len(times), axis=1)
        coming = [np.where((at + times < jn.until)[:, None], jn.position(at + times),
                           plan.trajectories.evaluate(show_t, np.array([j]))[0][0])[None]
                  for j, jn in (joins or {}).items()]
        going = [np.where((lv.held | (at + times >= lv.at))[:, None], lv.position(at + times),
                          plan.trajectories.evaluate(show_t, np.array([j]))[0][0])[None]
                 for j, lv in replaced]
        return np.concatenate([pos, still, *coming, *going])

    result = plan_among(0, f"way out of track {track}", origin[None, :], goal, duration,
                        plan.limits,
                        PlannerSettings(tracking_margin=TRACKING_MARGIN_M), others_at)
    # Then it descends over its landing spot while the show goes on: the column
    # must stay clear of everyone until it is down.
    descent = float(goal[0, 2]) / DESCENT_SPEED_MPS + DESCENT_MARGIN_S
    times = duration + np.arange(0.0, descent + 0.1, 0.1)
    ground = goal[0] * np.array([1.0, 1.0, 0.0])
    closest = segment_distance(others_at(times).reshape(-1, 3), goal, ground[None, :])
    if len(closest) and float(closest.min()) < plan.limits.min_separation:
        raise PlanningError(0, "landing column not clear",
                            f"another drone passes {float(closest.min()):.2f} m from the "
                            f"column above track {track}'s landing spot while it would descend")
    return Leave(at, result.trajectories, held=start is not None)

