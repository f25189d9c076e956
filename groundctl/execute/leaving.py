"""One drone leaving a show in progress: when it can, and the way out it flies.

Land-one in the middle of a show must not cut through the formation, and the
others fly on.  The drone keeps flying its own plan until it next rests on a
formation (quadrotor transitions are rest to rest, so from a formation's
arrival to the end of its hold), then flies a way out planned around every
other drone (:func:`groundctl.flight.returning.plan_leave`) to the point above
its landing spot, and lands.  Pure: the sequence decides when, the driver
plans, the setpoint stream flies it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.plan.feasibility import min_transition_time
from groundctl.plan.plan import Plan
from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import inside_polygon
from groundctl.show.checks import polygon_edge_distance
from groundctl.show.model import Limits, QuadrotorModel

FloatArray = NDArray[np.float64]

#: A drone leaves at the next instant it rests on a formation at least this far
#: ahead in show time, s: time to plan its way out.
LEAVE_LEAD_S = 2.0
#: The way out takes this many times its straight-line minimum ...
TIME_MARGIN = 1.5
#: ... and at least this long, s.
MIN_DURATION_S = 4.0

#: A spare waiting on the ground first arms and climbs straight up: this long to arm
#: and leave the ground, s, then its climb at the show's climb rate with TIME_MARGIN
#: (5 m: 7 s, what real ArduCopter SITL's NAV_TAKEOFF to 5 m took).
ARM_S = 5.0


@dataclass(frozen=True)
class Leave:
    """A planned way out of the show: ``trajectory`` (one row) flown from show time ``at``."""

    at: float
    trajectory: Trajectories
    held: bool = False
    """It hovers at the way out's start until ``at`` (heard again off its plan), rather
    than flying its plan there."""

    @property
    def until(self) -> float:
        """Show time it reaches the point above its landing spot, s."""
        return self.at + self.trajectory.end

    def state(self, show_time: float) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                NDArray[np.float64]]:
        """Position, velocity, acceleration (3,) at ``show_time`` (clamped to the way out)."""
        tau = min(max(show_time - self.at, 0.0), self.trajectory.end)
        p, v, a = self.trajectory.evaluate(tau)
        return p[0], v[0], a[0]

    def position(self, show_times: NDArray[np.float64]) -> NDArray[np.float64]:
        """(len(show_times), 3) positions along the way out (clamped at both ends)."""
        tau = np.clip(np.asarray(show_times, dtype=float) - self.at, 0.0, self.trajectory.end)
        return self.trajectory.evaluate(tau)[0][0]


@dataclass(frozen=True)
class Join:
    """A spare's way into ``track``: ``trajectory`` (one row, time 0 at show time ``at``)
    from where it waits onto the track's plan, reached at show time :attr:`until` in the
    track's own state there (at rest at a formation's slot, or in motion between two);
    the track's plan after that."""

    track: int
    """The plan track it takes over (0-based)."""
    at: float
    """Show time it leaves where it waits, s."""
    trajectory: Trajectories
    """Its path there, one row, from time 0."""
    plan_ms: float = 0.0
    """Wall time the planning took, ms (said in the report)."""
    climb_s: float = 0.0
    """A spare waiting on the ground: it takes off this long before :attr:`at`, straight
    up from its pad to where the path starts."""

    @property
    def until(self) -> float:
        """Show time it is on the track's plan, s."""
        return self.at + self.trajectory.end

    def state(self, show_time: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, velocity, acceleration (3,) on the path at ``show_time`` (clamped)."""
        tau = min(max(show_time - self.at, 0.0), self.trajectory.end)
        p, v, a = self.trajectory.evaluate(tau)
        return p[0], v[0], a[0]

    def position(self, show_times: FloatArray) -> FloatArray:
        """(len(show_times), 3) positions on the path (clamped at both ends)."""
        tau = np.clip(np.asarray(show_times, dtype=float) - self.at, 0.0,
                      self.trajectory.end)
        return self.trajectory.evaluate(tau)[0][0]


def climb_time(plan: Plan, height: float) -> float:
    """How long a spare on the ground is given to arm and climb ``height`` m, s."""
    return ARM_S + TIME_MARGIN * height / plan.limits.max_speed_up if height > 0 else 0.0


def leave_duration(plan: Plan, track: int, at: float,
                   start: NDArray[np.float64] | None = None) -> float:
    """How long ``track``'s way out takes if it leaves at show time ``at`` (from its plan
    point then, or from ``start``), s."""
    if start is None:
        start = plan.state_at(at).pos[track]
    return return_duration(plan, np.asarray(start, dtype=float)[None, :],
                           plan.landing_hover[track][None, :])


def return_duration(plan: Plan, start: NDArray[np.float64], goal: NDArray[np.float64],
                    limits: Limits | None = None) -> float:
    """How long a planned way home from ``start`` to ``goal`` (n, 3) is given, s: TIME_MARGIN
    times the slowest drone's straight-line minimum within ``limits`` (the plan's by
    default), at least MIN_DURATION_S."""
    bound = min_transition_time(start, goal, plan.limits if limits is None else limits,
                                QuadrotorModel())
    return max(bound.seconds * TIME_MARGIN, MIN_DURATION_S)


def leave_time(plan: Plan, track: int, show_time: float, *,
               after_hold: bool = False) -> float | None:
    """When ``track`` can leave: the first show time >= ``show_time`` + LEAVE_LEAD_S at
    which it rests on a formation and from which its way out ends before the plan
    does.  None if there is none (it lands with the others at the end).
    ``after_hold``: the end of that formation's hold instead (a drone a spare replaces:
    the formation is held whole, and the spare takes the track over on the way to the
    next one).
    """
    if plan.model != "quadrotor":
        return None
    earliest = show_time + LEAVE_LEAD_S
    for w in plan.formations:
        at = w.end if after_hold else max(w.arrive, earliest)
        if earliest <= at + 1e-9 and at <= w.end + 1e-9 \
                and at + leave_duration(plan, track, at) <= plan.duration:
            return at
    return None


def landing_candidates(plan: Plan) -> NDArray[np.float64]:
    """Points a returning drone may descend from (m, 3): the plan's landing spots, then
    every takeoff slot that is not one of them, then the spares' pads (verified clear of
    the show; a pad a spare still stands on is taken, like any spot a drone is down on),
    at the landing altitude."""
    spots = plan.landing_hover
    alt = np.array([0.0, 0.0, float(spots[:, 2].mean())])
    homes = plan.home + alt
    d = np.linalg.norm(homes[:, None, :2] - spots[None, :, :2], axis=2)
    extra = homes[d.min(axis=1) >= plan.limits.min_separation]
    pads = plan.spares.pads + alt if plan.spares is not None else np.empty((0, 3))
    return np.concatenate([spots, extra, pads])


#: Room for a landing drone's own error, m: a spot next to a drone that is down keeps the
#: separation limit plus this.  A drone descends once it is within the sequence's arrive
#: tolerance (0.5 m) of its spot, in practice a few centimetres, and lands where it
#: descends (measured: a spot 1.5 m from a drone that came down by land-here, at a 1.5 m
#: limit, was landed on 1.49 m from it).
LANDING_MARGIN_M = 0.3


#: The last resort's search for a clear spot around a drone: lattice steps of this many
#: separation limits ...
CLEAR_STEP = 0.5
#: ... out to this many separation limits from it ...
CLEAR_REACH = 20.0
#: ... and at least this far inside the geofence, m (the sequence's arrive tolerance: a
#: drone descends once within it of its spot).
CLEAR_FENCE_MARGIN_M = 0.5


def clear_spot_near(plan: Plan, point: FloatArray, blocked: FloatArray | None = None,
                    down: FloatArray | None = None) -> FloatArray | None:
    """The point nearest ``point`` (its altitude kept) on a lattice around it whose column
    keeps what :func:`free_spots` keeps from ``blocked`` and ``down``, CLEAR_FENCE_MARGIN_M
    inside the show's geofence if it has one; None when there is none within CLEAR_REACH
    separation limits.  For a drone with no landing candidate left: landing where it
    hovers could put it on a drone that is down.  (The flight there, at the altitude it
    hovers at, is not planned: as for the plan's own spots, see ``_blocked``.)"""
    sep = plan.limits.min_separation
    steps = np.arange(-CLEAR_REACH, CLEAR_REACH + 1e-9, CLEAR_STEP) * sep
    dx, dy = np.meshgrid(steps, steps)
    offsets = np.column_stack([dx.ravel(), dy.ravel()])
    offsets = offsets[np.argsort(np.hypot(offsets[:, 0], offsets[:, 1]), kind="stable")]
    spots = np.column_stack([offsets + np.asarray(point, dtype=float)[:2],
                             np.full(len(offsets), float(point[2]))])
    if plan.limits.geofence is not None:
        fence = np.asarray(plan.limits.geofence, dtype=float)
        spots = spots[inside_polygon(fence, spots[:, :2])
                      & (polygon_edge_distance(spots, fence) >= CLEAR_FENCE_MARGIN_M)]
    hits = free_spots(plan, spots, blocked, down)
    return spots[hits[0]] if len(hits) else None


def free_spots(plan: Plan, candidates: NDArray[np.float64],
               blocked: NDArray[np.float64] | None = None,
               down: NDArray[np.float64] | None = None) -> NDArray[np.intp]:
    """Indices of ``candidates`` whose column keeps the separation limit from every point
    of ``blocked`` (k, 3), spots others fly to (the plan separates those, and both land the
    same way), and the limit plus LANDING_MARGIN_M from every point of ``down`` (m, 3):
    drones down or descending somewhere the plan did not put them."""
    free = np.ones(len(candidates), dtype=bool)
    for points, keep in ((blocked, plan.limits.min_separation),
                         (down, plan.limits.min_separation + LANDING_MARGIN_M)):
        if points is not None and len(points) and len(candidates):
            d, _ = cKDTree(np.asarray(points, dtype=float)[:, :2]).query(
                np.asarray(candidates, dtype=float)[:, :2])
            free &= d >= keep
    return np.flatnonzero(free)
