"""Continuous-time verification of a plan: what the drones will fly, not the QP samples.

Separation is checked on the cubic trajectories between knots: per knot
segment, a KD-tree at the segment start finds every pair that could come
within the limit during the segment (radius = limit + the most two drones can
close in it), those pairs are sampled densely, and the pairs that come near
the limit are refined on a much finer grid.  Speeds, accelerations, altitude
and the geofence are checked on a dense sampling of every segment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.plan.plan import Plan
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import Limits

FloatArray = NDArray[np.float64]

#: Dense samples per knot segment for every check.
SAMPLES = 12
#: Finer samples per segment for the pairs near the separation limit.
REFINE = 400
#: Relative slack on speed and acceleration limits (solver tolerance), 0.5 %.
LIMIT_TOL = 5e-3
#: Max distance from its slot a drone may be when its formation is due, m.  The
#: unicycle model's pattern tolerance (the paper's eps) is at most this in practice.
PATTERN_TOL = 0.15
#: Absolute slack on separation and altitude (solver tolerance), m.
DIST_TOL = 1e-3


@dataclass(frozen=True)
class WindowMetrics:
    """Measured figures over one time window (a transition, or the whole show)."""

    min_separation: float
    """Smallest distance between any two drones, m."""
    min_separation_pair: tuple[int, int]
    """The 1-based drone numbers of that pair (0, 0 if fewer than two drones)."""
    min_separation_time: float
    """Show time of it, s."""
    max_speed_h: float
    """Largest horizontal speed, m/s."""
    max_speed_up: float
    """Largest climb rate, m/s."""
    max_speed_down: float
    """Largest descent rate, m/s."""
    max_accel: float
    """Largest acceleration, m/s^2."""
    min_alt: float
    """Lowest altitude, m."""
    max_alt: float
    """Highest altitude, m."""
    path_length_mean: float
    """Mean path length per drone, m."""
    outside_fence: int
    """Number of dense samples outside the geofence."""


@dataclass(frozen=True)
class Verification:
    """The verifier's verdict on a plan."""

    overall: WindowMetrics
    """Figures over the whole show."""
    windows: tuple[WindowMetrics, ...]
    """Figures over each transition, in show order."""
    pattern_errors: tuple[float, ...]
    """Max distance from the assigned slot when each formation is due, m."""
    separation_limit: float
    """The min separation the plan was checked against, m."""
    violations: tuple[str, ...] = field(default=())
    """One line per violated limit; empty when the plan is safe."""

    @property
    def safe(self) -> bool:
        return not self.violations

    @property
    def worst_violation(self) -> float:
        """How far below the separation limit the plan goes, m (0 if it never does)."""
        return max(0.0, self.separation_limit - self.overall.min_separation)


def _inside(poly: NDArray[np.float64], xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Even-odd rule, vectorised over points (any shape (..., 2))."""
    x, y = xy[..., 0], xy[..., 1]
    inside = np.zeros(x.shape, dtype=bool)
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < xint)
    return inside


def _separation(tr: Trajectories, limit: float, vmax: float, t0: float,
                t1: float) -> tuple[float, tuple[int, int], float]:
    """Min distance between any two drones over [t0, t1] on the continuous trajectories."""
    n = tr.drones
    if n < 2:
        return np.inf, (0, 0), t0
    kk = np.flatnonzero((tr.times[:-1] < t1 - 1e-12) & (tr.times[1:] > t0 + 1e-12))
    best = (np.inf, (0, 0), t0)
    frac = np.linspace(0.0, 1.0, SAMPLES + 1)
    for k in kk:
        a, b = tr.times[k], tr.times[k + 1]
        h = b - a
        # Two drones at most vmax each can close 2 vmax h during the segment.
        radius = limit + 0.5 + 2 * vmax * h
        pairs = cKDTree(tr.pos[:, k]).query_pairs(radius, output_type="ndarray")
        if not len(pairs):
            continue
        ts = a + frac * h
        pos, _, _ = tr.evaluate(ts)
        d = np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=2)
        dmin = d.min(axis=1)
        near = np.flatnonzero(dmin < limit + 0.25)
        if len(near):
            fine = a + np.linspace(0.0, 1.0, REFINE + 1) * h
            pf, _, _ = tr.evaluate(fine)
            dn = np.linalg.norm(pf[pairs[near, 0]] - pf[pairs[near, 1]], axis=2)
            dmin[near] = dn.min(axis=1)
        q = int(np.argmin(dmin))
        if dmin[q] < best[0]:
            tq = float(ts[int(np.argmin(d[q]))])
            best = (float(dmin[q]), (int(pairs[q, 0]) + 1, int(pairs[q, 1]) + 1), tq)
    return best


def window_metrics(tr: Trajectories, limits: Limits, t0: float, t1: float) -> WindowMetrics:
    """Figures of the trajectories over show times [t0, t1]."""
    mask = (tr.times >= t0 - 1e-9) & (tr.times <= t1 + 1e-9)
    sub = Trajectories(tr.times[mask], tr.pos[:, mask], tr.vel[:, mask])
    ts = sub.dense_times(SAMPLES)
    pos, vel, acc = sub.evaluate(ts)
    speed_h = np.linalg.norm(vel[..., :2], axis=2)
    vmax = float(np.linalg.norm(vel, axis=2).max())
    sep, pair, tsep = _separation(sub, limits.min_separation, vmax, t0, t1)
    if not np.isfinite(sep) and sub.drones >= 2:
        # Nobody came near anybody: report the closest pair at the window's start.
        dist, idx = cKDTree(sub.pos[:, 0]).query(sub.pos[:, 0], k=2)
        q = int(np.argmin(dist[:, 1]))
        sep, pair, tsep = float(dist[q, 1]), (q + 1, int(idx[q, 1]) + 1), float(sub.times[0])
    outside = 0
    if limits.geofence:
        poly = np.asarray(limits.geofence, dtype=float)
        outside = int((~_inside(poly, pos[..., :2])).sum())
    return WindowMetrics(
        min_separation=float(sep), min_separation_pair=pair, min_separation_time=tsep,
        max_speed_h=float(speed_h.max()), max_speed_up=float(max(vel[..., 2].max(), 0.0)),
        max_speed_down=float(max(-vel[..., 2].min(), 0.0)),
        max_accel=float(np.linalg.norm(acc, axis=2).max()),
        min_alt=float(pos[..., 2].min()), max_alt=float(pos[..., 2].max()),
        path_length_mean=float(np.linalg.norm(np.diff(pos, axis=1), axis=2).sum(axis=1).mean()),
        outside_fence=outside)


def verify(plan: Plan) -> Verification:
    """Check every limit of ``plan.limits`` on the continuous trajectories."""
    lim = plan.limits
    tr = plan.trajectories
    windows = tuple(window_metrics(tr, lim, f.start, f.arrive) for f in plan.formations)
    overall = window_metrics(tr, lim, tr.start, tr.end)
    errors = []
    for f in plan.formations:
        pos, _, _ = tr.evaluate(f.arrive)
        errors.append(float(np.linalg.norm(pos - f.goals, axis=1).max()))
    v: list[str] = []
    o = overall
    if o.min_separation < lim.min_separation - DIST_TOL:
        v.append(f"drones {o.min_separation_pair[0]} and {o.min_separation_pair[1]} come "
                 f"{o.min_separation:.3f} m apart at t = {o.min_separation_time:.2f} s "
                 f"(min_separation {lim.min_separation} m)")
    if plan.model == "quadrotor":
        checks = [("horizontal speed", o.max_speed_h, lim.max_speed_h, "m/s"),
                  ("climb rate", o.max_speed_up, lim.max_speed_up, "m/s"),
                  ("descent rate", o.max_speed_down, lim.max_speed_down, "m/s"),
                  ("acceleration", o.max_accel, lim.max_accel, "m/s^2")]
        for what, got, limit, unit in checks:
            if got > limit * (1 + LIMIT_TOL):
                v.append(f"{what} reaches {got:.2f} {unit} (limit {limit} {unit})")
    if o.min_alt < lim.min_alt - DIST_TOL:
        v.append(f"altitude goes down to {o.min_alt:.2f} m (min_altitude {lim.min_alt} m)")
    if o.max_alt > lim.max_alt + DIST_TOL:
        v.append(f"altitude goes up to {o.max_alt:.2f} m (max_altitude {lim.max_alt} m)")
    for f, err in zip(plan.formations, errors, strict=True):
        if err > PATTERN_TOL:
            v.append(f"formation {f.index} '{f.name}': a drone is {err:.3f} m from its slot "
                     f"when the formation is due (tolerance {PATTERN_TOL} m)")
    if o.outside_fence:
        v.append(f"{o.outside_fence} trajectory samples lie outside the geofence")
    return Verification(overall=overall, windows=windows, pattern_errors=tuple(errors),
                        separation_limit=lim.min_separation, violations=tuple(v))
