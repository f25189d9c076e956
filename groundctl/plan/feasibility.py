"""Lower bounds on how long a transition must last under the show's limits.

These bounds ignore the other drones: a transition shorter than the bound is
infeasible for certain, one longer may still need more time to let drones
go around each other (the planner then reports it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.show.model import Limits, Model, UnicycleModel


@dataclass(frozen=True)
class TimeBound:
    """The slowest drone of a transition and the time it needs."""

    seconds: float
    """Minimum duration of the transition, s."""
    drone: int
    """Index of the drone that needs it."""
    distance: float
    """Straight-line distance that drone flies, m."""
    speed_limit: float
    """Speed limit along that drone's line, m/s."""


def line_speed_limits(delta: NDArray[np.float64], limits: Limits) -> NDArray[np.float64]:
    """Max speed along each straight line ``delta`` (n, 3) given split h/v limits."""
    horiz = np.linalg.norm(delta[:, :2], axis=1)
    vert = delta[:, 2]
    dist = np.linalg.norm(delta, axis=1)
    safe = np.where(dist > 0, dist, 1.0)
    v_up = np.where(vert > 0, limits.max_speed_up, limits.max_speed_down)
    with np.errstate(divide="ignore"):
        by_h = np.where(horiz > 1e-9, limits.max_speed_h * safe / np.maximum(horiz, 1e-12), np.inf)
        by_v = np.where(np.abs(vert) > 1e-9, v_up * safe / np.maximum(np.abs(vert), 1e-12),
                        np.inf)
    return np.minimum(by_h, by_v)


def rest_to_rest_time(dist: NDArray[np.float64], vmax: NDArray[np.float64] | float,
                      amax: float) -> NDArray[np.float64]:
    """Fastest time to cover ``dist`` from rest to rest (trapezoidal speed profile)."""
    dist = np.asarray(dist, dtype=float)
    vmax = np.broadcast_to(np.asarray(vmax, dtype=float), dist.shape)
    cruise = dist >= vmax**2 / amax
    t_cruise = dist / vmax + vmax / amax
    t_triangle = 2.0 * np.sqrt(dist / amax)
    return np.where(cruise, t_cruise, t_triangle)


def min_transition_time(start: NDArray[np.float64], goal: NDArray[np.float64],
                        limits: Limits, model: Model) -> TimeBound:
    """Lower bound on the duration of a transition from ``start`` to ``goal`` (n, 3).

    Quadrotor: the slowest drone's trapezoidal rest-to-rest time along its
    line.  Unicycle: constant speed V, so the straight-line distance over V.
    """
    delta = np.asarray(goal, dtype=float) - np.asarray(start, dtype=float)
    dist = np.linalg.norm(delta, axis=1)
    if isinstance(model, UnicycleModel):
        vlim = np.full(dist.shape, model.speed)
        times = dist / model.speed
    else:
        vlim = line_speed_limits(delta, limits)
        times = rest_to_rest_time(dist, vlim, limits.max_accel)
    if not len(times):
        return TimeBound(0.0, 0, 0.0, 0.0)
    worst = int(np.argmax(times))
    return TimeBound(float(times[worst]), worst, float(dist[worst]), float(vlim[worst]))


def airborne_time(show_seconds: float, takeoff_altitude: float, limits: Limits) -> float:
    """How long a drone is in the air for a show of ``show_seconds``: the climb to the
    takeoff altitude, the show, the descent (each at its vertical speed limit), s.
    ``limits.max_flight_time`` (the battery's endurance) bounds it."""
    return (takeoff_altitude / limits.max_speed_up + show_seconds
            + takeoff_altitude / limits.max_speed_down)
