"""Continuous-time verification of a plan: what the drones will fly, not the QP samples.

Everything is evaluated once, densely, over the whole show (see
:func:`_dense_pass`); per-transition and whole-show figures are read off that
one pass.  Separation is checked on the cubic trajectories between knots, not
only at the knots.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.plan.feasibility import airborne_time
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


def inside_polygon(poly: NDArray[np.float64], xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Even-odd rule, vectorised over points (any shape (..., 2))."""
    x, y = xy[..., 0], xy[..., 1]
    inside = np.zeros(x.shape, dtype=bool)
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < xint)
    return inside


@dataclass(frozen=True)
class _DensePass:
    """Everything the checks need, evaluated once over the whole show."""

    tr: Trajectories
    ts: FloatArray
    """(T,) dense times: SAMPLES per knot segment, segment k is ts[k*S : (k+1)*S + 1]."""
    pos: FloatArray
    vel: FloatArray
    acc: FloatArray
    seg_sep: FloatArray
    """(K-1,) min distance between any two drones in each segment (inf: nobody near)."""
    seg_pair: NDArray[np.intp]
    """(K-1, 2) 1-based drone numbers of that pair."""
    seg_time: FloatArray
    """(K-1,) when it happens."""


def _dense_pass(tr: Trajectories, limit: float) -> _DensePass:
    """Sample every segment densely once; find each segment's closest pair.

    Per knot segment, a KD-tree at the segment start finds every pair that could
    come within the limit during it (radius = limit + the most two drones can
    close in it, from the segment's top speed); those pairs are read off the
    dense samples, and the ones near the limit are refined on a much finer grid
    of their own two trajectories only.
    """
    S = SAMPLES
    ts = tr.dense_times(S)
    pos, vel, acc = tr.evaluate(ts)
    nseg = len(tr.times) - 1
    seg_sep = np.full(nseg, np.inf)
    seg_pair = np.zeros((nseg, 2), dtype=np.intp)
    seg_time = tr.times[:-1].copy()
    if tr.drones < 2:
        return _DensePass(tr, ts, pos, vel, acc, seg_sep, seg_pair, seg_time)
    speed = np.linalg.norm(vel, axis=2).max(axis=0)  # (T,) fastest drone at each sample
    fine_frac = np.linspace(0.0, 1.0, REFINE + 1)
    for k in range(nseg):
        window = slice(k * S, (k + 1) * S + 1)
        h = tr.times[k + 1] - tr.times[k]
        radius = limit + 0.5 + 2 * float(speed[window].max()) * h
        pairs = cKDTree(tr.pos[:, k]).query_pairs(radius, output_type="ndarray")
        if not len(pairs):
            continue
        d = np.linalg.norm(pos[pairs[:, 0], window] - pos[pairs[:, 1], window], axis=2)
        dmin = d.min(axis=1)
        at = ts[window][np.argmin(d, axis=1)]
        near = np.flatnonzero(dmin < limit + 0.25)
        if len(near):
            fine = tr.times[k] + fine_frac * h
            pi, _, _ = tr.evaluate(fine, pairs[near, 0])
            pj, _, _ = tr.evaluate(fine, pairs[near, 1])
            dn = np.linalg.norm(pi - pj, axis=2)
            dmin[near] = dn.min(axis=1)
            at[near] = fine[np.argmin(dn, axis=1)]
        q = int(np.argmin(dmin))
        seg_sep[k] = dmin[q]
        seg_pair[k] = pairs[q] + 1
        seg_time[k] = at[q]
    return _DensePass(tr, ts, pos, vel, acc, seg_sep, seg_pair, seg_time)


def _window(dp: _DensePass, limits: Limits, t0: float, t1: float) -> WindowMetrics:
    """Figures over show times [t0, t1] (knot-aligned), read off the dense pass."""
    tr, S = dp.tr, SAMPLES
    k0 = int(np.searchsorted(tr.times, t0 - 1e-9))
    k1 = int(np.searchsorted(tr.times, t1 + 1e-9)) - 1  # last knot inside
    k1 = max(k1, k0 + 1)
    dense = slice(k0 * S, k1 * S + 1)
    pos, vel, acc = dp.pos[:, dense], dp.vel[:, dense], dp.acc[:, dense]
    segs = slice(k0, k1)
    if np.isfinite(dp.seg_sep[segs]).any():
        q = k0 + int(np.argmin(dp.seg_sep[segs]))
        sep, pair, tsep = float(dp.seg_sep[q]), (int(dp.seg_pair[q, 0]),
                                                 int(dp.seg_pair[q, 1])), float(dp.seg_time[q])
    elif tr.drones >= 2:
        # Nobody came near anybody: report the closest pair at the window's start.
        dist, idx = cKDTree(tr.pos[:, k0]).query(tr.pos[:, k0], k=2)
        q = int(np.argmin(dist[:, 1]))
        sep, pair, tsep = float(dist[q, 1]), (q + 1, int(idx[q, 1]) + 1), float(tr.times[k0])
    else:
        sep, pair, tsep = np.inf, (0, 0), t0
    outside = 0
    if limits.geofence:
        poly = np.asarray(limits.geofence, dtype=float)
        outside = int((~inside_polygon(poly, pos[..., :2])).sum())
    return WindowMetrics(
        min_separation=sep, min_separation_pair=pair, min_separation_time=tsep,
        max_speed_h=float(np.linalg.norm(vel[..., :2], axis=2).max()),
        max_speed_up=float(max(vel[..., 2].max(), 0.0)),
        max_speed_down=float(max(-vel[..., 2].min(), 0.0)),
        max_accel=float(np.linalg.norm(acc, axis=2).max()),
        min_alt=float(pos[..., 2].min()), max_alt=float(pos[..., 2].max()),
        path_length_mean=float(np.linalg.norm(np.diff(pos, axis=1), axis=2).sum(axis=1).mean()),
        outside_fence=outside)


def verify(plan: Plan) -> Verification:
    """Check every limit of ``plan.limits`` on the continuous trajectories."""
    lim = plan.limits
    tr = plan.trajectories
    dense = _dense_pass(tr, lim.min_separation)
    windows = tuple(_window(dense, lim, f.start, f.arrive) for f in plan.formations)
    overall = _window(dense, lim, tr.start, tr.end)
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
    airborne = airborne_time(tr.end - tr.start, plan.takeoff_altitude, lim)
    if airborne > lim.max_flight_time * (1 + LIMIT_TOL):
        v.append(f"drones are airborne {airborne:.0f} s with the climb and descent "
                 f"(max_flight_time {lim.max_flight_time:g} s)")
    return Verification(overall=overall, windows=windows, pattern_errors=tuple(errors),
                        separation_limit=lim.min_separation, violations=tuple(v))
