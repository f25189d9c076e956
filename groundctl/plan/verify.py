"""Continuous-time verification of a plan: what the drones will fly, not the QP samples.

One pass over the show (:func:`_dense_pass`) reduces everything to one row per knot
segment; per-transition and whole-show figures are read off those rows.  Separation
is exact in continuous time: per segment a KD-tree over each drone's Bezier bounding
sphere finds the pairs that can come close, and their closest approach is solved on
their relative cubic (time grows with drones x segments, not drones^2 or the fleet's
dense samples held at once).  Speeds, accelerations, altitudes and the geofence are
read off SAMPLES points per segment, drone-chunk by drone-chunk.
"""

from __future__ import annotations

import math
from collections.abc import Callable
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
#: A close pair's closest approach is certified to within this, m (10 micrometres).
CLOSEST_TOL = 1e-5
#: Pieces each close pair's segment starts in, and halvings at most (2^-40 of a segment).
SEED_PIECES = 8
MAX_HALVINGS = 40
#: Powers of the coarse samples that bound a segment's minimum from above.
_COARSE_POWERS = np.linspace(0.0, 1.0, 9)[None, :] ** np.arange(4)[:, None]
#: Close pairs measured per block (bounds the temporaries).
PAIR_BLOCK = 20_000
#: Drones evaluated per block for the kinematic figures (bounds the temporaries).
DRONE_CHUNK = 256
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
    """Everything the checks need, reduced to one row per knot segment.

    Built drone-chunk by drone-chunk and segment by segment, so memory stays bounded
    and time grows with drones x segments (plus the close pairs), whatever the fleet size.
    """

    tr: Trajectories
    seg_sep: FloatArray
    """(K-1,) min distance between any two drones in each segment (inf: nobody near)."""
    seg_pair: NDArray[np.intp]
    """(K-1, 2) 1-based drone numbers of that pair."""
    seg_time: FloatArray
    """(K-1,) when it happens."""
    seg_speed_h: FloatArray
    """(K-1,) largest horizontal speed in each segment (dense samples), m/s."""
    seg_up: FloatArray
    seg_down: FloatArray
    seg_accel: FloatArray
    seg_min_alt: FloatArray
    seg_max_alt: FloatArray
    seg_path: FloatArray
    """(K-1,) path length flown in each segment, summed over the fleet, m."""
    seg_outside: NDArray[np.intp]
    """(K-1,) dense samples outside the geofence (each knot counted in the segment before it,
    the first knot in the first segment)."""


def _power_basis(tr: Trajectories, k: int, rows: NDArray[np.intp] | slice = slice(None)
                 ) -> FloatArray:
    """(m, 4, 3) coefficients c0..c3 of p(s) = sum c_q s^q, s in [0, 1], on knot segment k."""
    h = tr.times[k + 1] - tr.times[k]
    return hermite_power(tr.pos[rows, k], tr.pos[rows, k + 1], tr.vel[rows, k] * h,
                          tr.vel[rows, k + 1] * h)


def hermite_power(p0: FloatArray, p1: FloatArray, m0: FloatArray, m1: FloatArray
                   ) -> FloatArray:
    """Power-basis coefficients (stacked on axis 1) of the cubic Hermite curves from p0 to
    p1 with end tangents m0, m1 (velocities times the segment's length)."""
    return np.stack([p0, m0, 3 * (p1 - p0) - 2 * m0 - m1, 2 * (p0 - p1) + m0 + m1], axis=1)


def bounding_spheres(coef: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centre (m, 3) and radius (m,) of a sphere holding each cubic on [0, 1].

    The curve lies in the convex hull of its four Bezier control points."""
    c0, c1, c2, c3 = coef[:, 0], coef[:, 1], coef[:, 2], coef[:, 3]
    b = np.stack([c0, c0 + c1 / 3, c0 + 2 * c1 / 3 + c2 / 3, c0 + c1 + c2 + c3], axis=1)
    centre = b.mean(axis=1)
    return centre, np.linalg.norm(b - centre[:, None], axis=2).max(axis=1)


def closest_on_segment(d: FloatArray, shared: bool = False, below: float = np.inf,
                        tol: float = CLOSEST_TOL, groups: NDArray[np.intp] | None = None
                        ) -> tuple[FloatArray, FloatArray]:
    """Min over s in [0, 1] of |d(s)| for relative cubics d (m, 4, 3), and where, to
    within ``tol`` (branch and bound: certified, whatever the number of dips).

    ``shared``: only the smallest of all m minima is wanted (pieces that cannot beat
    the best of any pair are dropped; the others' values are then upper bounds).
    ``below``: only minima under it are wanted (pieces that cannot go under it are
    dropped; a pair that never does gets an upper bound at or above it).
    ``groups`` (m,) 0..G-1: ``shared`` within each group (only each group's smallest
    minimum is wanted: many segments' candidate pairs measured in one call).

    Each piece [a, a + w] of a pair's curve lies in the convex hull of its four Bezier
    control points, so no point of it is closer than |centre| - radius of their
    bounding sphere (a lower bound); the curve's values at the piece's ends and middle
    are upper bounds.  Pieces whose lower bound cannot beat the pair's best upper bound
    by CLOSEST_TOL are dropped, the others halved, until none is left."""
    m = len(d)
    seeds = np.arange(SEED_PIECES) / SEED_PIECES
    pair = np.repeat(np.arange(m), SEED_PIECES)
    a = np.tile(seeds, m)
    w = np.full(len(a), 1.0 / SEED_PIECES)
    best = np.full(m, np.inf)
    best_s = np.zeros(m)
    for _ in range(MAX_HALVINGS):
        c = d[pair]
        # The piece's own power basis: p(a + w u) for u in [0, 1].
        aa, ww = a[:, None], w[:, None]
        c0 = c[:, 0] + aa * (c[:, 1] + aa * (c[:, 2] + aa * c[:, 3]))
        c1 = ww * (c[:, 1] + aa * (2 * c[:, 2] + 3 * aa * c[:, 3]))
        c2 = ww * ww * (c[:, 2] + 3 * aa * c[:, 3])
        c3 = ww * ww * ww * c[:, 3]
        centre, radius = bounding_spheres(np.stack([c0, c1, c2, c3], axis=1))
        lower = np.linalg.norm(centre, axis=1) - radius
        mid = c0 + c1 / 2 + c2 / 4 + c3 / 8
        ends = np.stack([np.linalg.norm(c0, axis=1), np.linalg.norm(mid, axis=1),
                         np.linalg.norm(c0 + c1 + c2 + c3, axis=1)], axis=1)
        where = np.argmin(ends, axis=1)
        upper = ends[np.arange(len(a)), where]
        at = a + w * where / 2.0
        order = np.lexsort((upper, pair))  # per pair, its best piece first
        first = order[np.r_[True, pair[order][1:] != pair[order][:-1]]]
        improve = upper[first] < best[pair[first]]
        best[pair[first[improve]]] = upper[first[improve]]
        best_s[pair[first[improve]]] = at[first[improve]]
        if groups is not None:
            group_best = np.full(int(groups.max()) + 1, np.inf)
            np.minimum.at(group_best, groups, best)
            bar = group_best[groups[pair]]
        else:
            bar = np.full(len(a), best.min()) if shared else best[pair]
        keep = (lower < bar - tol) & (lower < below)
        if not keep.any():
            break
        pair, a, w = np.repeat(pair[keep], 2), np.repeat(a[keep], 2), np.repeat(w[keep], 2) / 2
        a[1::2] += w[1::2]
    return best, best_s


def nearest_in_order(lower: FloatArray,
                     cubics: Callable[[slice], FloatArray]) -> tuple[float, int, float]:
    """(distance, index, s in [0, 1]) of the smallest minimum of |d(s)| over relative
    cubics visited in the order of their lower bounds ``lower`` (ascending): ``cubics(k)``
    gives those of the slice ``k`` (m, 4, 3), built as they are needed, PAIR_BLOCK at a
    time, until the next lower bound cannot beat the best found.  (inf, -1, 0) for none."""
    best, best_k, best_s = math.inf, -1, 0.0
    for c in range(0, len(lower), PAIR_BLOCK):
        if lower[c] >= best:
            break
        dmin, at = closest_on_segment(cubics(slice(c, c + PAIR_BLOCK)), shared=True,
                                      below=best)
        q = int(np.argmin(dmin))
        if dmin[q] < best:
            best, best_k, best_s = float(dmin[q]), c + q, float(at[q])
    return best, best_k, best_s


def _pairs_within(coef: FloatArray, reach: float) -> NDArray[np.intp]:
    """(m, 2) the pairs whose segments (power bases ``coef``) can come within ``reach``:
    their Bezier bounding spheres do (a KD-tree on the centres, then each pair's radii)."""
    centre, radius = bounding_spheres(coef)
    pairs = cKDTree(centre).query_pairs(reach + 2 * float(radius.max()), output_type="ndarray")
    gap = (np.linalg.norm(centre[pairs[:, 0]] - centre[pairs[:, 1]], axis=1)
           - radius[pairs[:, 0]] - radius[pairs[:, 1]])
    return np.asarray(pairs[gap <= reach], dtype=np.intp)


def _separation(tr: Trajectories
                ) -> tuple[FloatArray, NDArray[np.intp], FloatArray]:
    """Per knot segment: the closest pair, how close, and when, in continuous time.

    Each drone's segment is a cubic inside a bounding sphere (its Bezier hull).  The
    closest pair at the segment's first knot bounds the segment's minimum from above
    (``bound``); a KD-tree on the sphere centres gives the few pairs whose spheres come
    within ``bound`` of each other -- the only pairs that can hold the minimum -- and
    their exact closest approach is found on their relative cubic.  A spatial index per
    segment: drones x segments, not drones^2.
    """
    nseg = len(tr.times) - 1
    seg_sep = np.full(nseg, np.inf)
    seg_pair = np.zeros((nseg, 2), dtype=np.intp)
    seg_time = tr.times[:-1].copy()
    if tr.drones < 2:
        return seg_sep, seg_pair, seg_time
    # The few candidate pairs of many segments are measured in one batch (a call per
    # segment was most of a small show's verification: 100 calls, 0.1 s for 25 drones).
    batch: list[tuple[int, NDArray[np.intp], FloatArray]] = []
    rows = 0

    def flush() -> None:
        d = np.concatenate([b[2] for b in batch])
        groups = np.repeat(np.arange(len(batch)), [len(b[2]) for b in batch])
        dmin, at = closest_on_segment(d, groups=groups)
        start = 0
        for k, pairs, dk in batch:
            q = start + int(np.argmin(dmin[start:start + len(dk)]))
            if dmin[q] < seg_sep[k]:
                seg_sep[k] = float(dmin[q])
                seg_pair[k] = pairs[q - start] + 1
                seg_time[k] = tr.times[k] + float(at[q]) * (tr.times[k + 1] - tr.times[k])
            start += len(dk)
        batch.clear()

    for k in range(nseg):
        coef = _power_basis(tr, k)
        knot_gap, _ = cKDTree(tr.pos[:, k]).query(tr.pos[:, k], k=2)
        bound = float(knot_gap[:, 1].min()) * (1 + 1e-9) + 1e-12
        pairs = _pairs_within(coef, bound)
        # Coarse samples bound the segment's minimum from above again, much tighter;
        # each pair's relative Bezier hull bounds its own minimum from below.  Only the
        # pairs whose lower bound reaches under it can hold the minimum.
        d = coef[pairs[:, 0]] - coef[pairs[:, 1]]
        coarse = np.linalg.norm(np.einsum("mqx,qf->mfx", d, _COARSE_POWERS), axis=2)
        centre_d, radius_d = bounding_spheres(d)
        lower = np.linalg.norm(centre_d, axis=1) - radius_d
        keep = lower <= coarse.min() * (1 + 1e-9) + 1e-12  # never none: a pair at 0 m
        pairs, d = pairs[keep], d[keep]
        if len(pairs) > PAIR_BLOCK:  # a crowded segment on its own, sharing its bound
            for b in range(0, len(pairs), PAIR_BLOCK):
                dmin, at = closest_on_segment(d[b:b + PAIR_BLOCK], shared=True)
                q = int(np.argmin(dmin))
                if dmin[q] < seg_sep[k]:
                    seg_sep[k] = float(dmin[q])
                    seg_pair[k] = pairs[b + q] + 1
                    seg_time[k] = tr.times[k] + float(at[q]) * (tr.times[k + 1] - tr.times[k])
            continue
        if rows + len(pairs) > PAIR_BLOCK:
            flush()
            rows = 0
        batch.append((k, pairs, d))
        rows += len(pairs)
    if batch:
        flush()
    return seg_sep, seg_pair, seg_time


def close_segments(tr: Trajectories, limit: float
                   ) -> tuple[NDArray[np.intp], FloatArray, FloatArray]:
    """Every (pair, knot segment) closer than ``limit``: rows (i, j, k) 0-based, and each
    one's closest approach and its time, exact in continuous time (as
    :func:`_separation`), in segment order."""
    rows: list[NDArray[np.intp]] = []
    dists: list[FloatArray] = []
    times: list[FloatArray] = []
    for k in range(len(tr.times) - 1 if tr.drones >= 2 else 0):
        coef = _power_basis(tr, k)
        pairs = _pairs_within(coef, limit)
        h = tr.times[k + 1] - tr.times[k]
        for b in range(0, len(pairs), PAIR_BLOCK):
            blk = pairs[b:b + PAIR_BLOCK]
            dmin, at = closest_on_segment(coef[blk[:, 0]] - coef[blk[:, 1]], below=limit,
                                           tol=1e-4)
            hit = dmin < limit
            rows.append(np.column_stack([blk[hit], np.full(int(hit.sum()), k)]))
            dists.append(dmin[hit])
            times.append(tr.times[k] + at[hit] * h)
    if not rows:
        return np.empty((0, 3), dtype=np.intp), np.empty(0), np.empty(0)
    return (np.concatenate(rows).astype(np.intp), np.concatenate(dists),
            np.concatenate(times))


def close_pairs(tr: Trajectories, limit: float) -> list[tuple[int, int, float, float]]:
    """Every pair that comes closer than ``limit``, worst first: (i, j, distance, time)
    with 1-based drone numbers, exact in continuous time (as :func:`_separation`)."""
    rows, dist, at = close_segments(tr, limit)
    best: dict[tuple[int, int], tuple[float, float]] = {}
    for (i, j, _), d, t in zip(rows, dist, at, strict=True):
        key = (int(i) + 1, int(j) + 1)
        if key not in best or d < best[key][0]:
            best[key] = (float(d), float(t))
    return sorted(((i, j, d, t) for (i, j), (d, t) in best.items()), key=lambda r: r[2])


def _dense_pass(tr: Trajectories, geofence: NDArray[np.float64] | None = None) -> _DensePass:
    """Separation per segment in continuous time; kinematics on SAMPLES points per segment.

    The kinematic figures are read drone-chunk by drone-chunk off the dense samples and
    reduced to one row per segment at once, so no (drones x samples) array of the whole
    fleet is ever held.
    """
    S = SAMPLES
    nseg = len(tr.times) - 1
    seg_sep, seg_pair, seg_time = _separation(tr)
    ts = tr.dense_times(S)
    speed_h = np.zeros(nseg)
    up, down, accel = np.zeros(nseg), np.zeros(nseg), np.zeros(nseg)
    lo, hi = np.full(nseg, np.inf), np.full(nseg, -np.inf)
    path = np.zeros(nseg)
    outside = np.zeros(nseg, dtype=np.intp)

    def per_seg_max(q: FloatArray) -> FloatArray:
        # q (m, T) -> (nseg,) max over drones and the segment's samples, both ends included.
        body = q[:, :-1].reshape(len(q), nseg, S).max(axis=(0, 2))
        return np.maximum(body, q[:, S::S].max(axis=0))

    for c in range(0, tr.drones, DRONE_CHUNK):
        rows = np.arange(c, min(c + DRONE_CHUNK, tr.drones))
        pos, vel, _ = tr.evaluate(ts, rows)
        speed_h = np.maximum(speed_h, per_seg_max(np.hypot(vel[..., 0], vel[..., 1])))
        up = np.maximum(up, per_seg_max(vel[..., 2]))
        down = np.maximum(down, per_seg_max(-vel[..., 2]))
        # Acceleration is linear within a segment: its largest norm is at one of the two
        # ends, each from the segment's own cubic (a sample at a knot would read the next
        # segment's).
        h = np.diff(tr.times)[None, :, None]
        coef = hermite_power(tr.pos[rows, :-1], tr.pos[rows, 1:], tr.vel[rows, :-1] * h,
                              tr.vel[rows, 1:] * h)  # (m, 4, segments, 3)
        c2, c3 = coef[:, 2], coef[:, 3]
        a_ends = np.maximum(np.linalg.norm(2 * c2, axis=2),
                            np.linalg.norm(2 * c2 + 6 * c3, axis=2)) / h[..., 0] ** 2
        accel = np.maximum(accel, a_ends.max(axis=0))
        hi = np.maximum(hi, per_seg_max(pos[..., 2]))
        lo = np.minimum(lo, -per_seg_max(-pos[..., 2]))
        step = np.linalg.norm(np.diff(pos, axis=1), axis=2)  # (m, T-1)
        path += step.reshape(len(rows), nseg, S).sum(axis=(0, 2))
        if geofence is not None:
            out = ~inside_polygon(geofence, pos[..., :2])  # (m, T)
            counts = out[:, 1:].reshape(len(rows), nseg, S).sum(axis=(0, 2))
            counts[0] += int(out[:, 0].sum())
            outside += counts
    return _DensePass(tr, seg_sep, seg_pair, seg_time, speed_h, np.maximum(up, 0.0),
                      np.maximum(down, 0.0), accel, lo, hi, path, outside)


def _window(dp: _DensePass, limits: Limits, t0: float, t1: float) -> WindowMetrics:
    """Figures over show times [t0, t1] (knot-aligned), read off the per-segment rows."""
    tr = dp.tr
    k0 = int(np.searchsorted(tr.times, t0 - 1e-9))
    k1 = int(np.searchsorted(tr.times, t1 + 1e-9)) - 1  # last knot inside
    k1 = max(k1, k0 + 1)
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
    return WindowMetrics(
        min_separation=sep, min_separation_pair=pair, min_separation_time=tsep,
        max_speed_h=float(dp.seg_speed_h[segs].max()),
        max_speed_up=float(dp.seg_up[segs].max()),
        max_speed_down=float(dp.seg_down[segs].max()),
        max_accel=float(dp.seg_accel[segs].max()),
        min_alt=float(dp.seg_min_alt[segs].min()), max_alt=float(dp.seg_max_alt[segs].max()),
        path_length_mean=float(dp.seg_path[segs].sum() / max(tr.drones, 1)),
        outside_fence=int(dp.seg_outside[segs].sum()))


def limit_violations(o: WindowMetrics, lim: Limits, *, quadrotor: bool = True) -> list[str]:
    """The speed (a quadrotor's), acceleration and altitude limits ``o`` breaks, in words."""
    v: list[str] = []
    if quadrotor:
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
    return v


def kinematics(tr: Trajectories, limits: Limits) -> WindowMetrics:
    """``tr``'s figures over its whole time, as :func:`verify` reads them."""
    return _window(_dense_pass(tr), limits, tr.start, tr.end)


def verify(plan: Plan) -> Verification:
    """Check every limit of ``plan.limits`` on the continuous trajectories."""
    lim = plan.limits
    tr = plan.trajectories
    fence = np.asarray(lim.geofence, dtype=float) if lim.geofence else None
    dense = _dense_pass(tr, fence)
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
    v += limit_violations(o, lim, quadrotor=plan.model == "quadrotor")
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
    if plan.spares is not None:
        from groundctl.plan.spares import clearance
        from groundctl.show.checks import inside_polygon as inside_fence

        near = clearance(plan, plan.spares.pads, plan.spares.points)
        if near.distance < lim.min_separation - DIST_TOL:
            v.append(f"spare {near.spare + 1} comes {near.distance:.3f} m from {near.what} "
                     f"(min_separation {lim.min_separation} m)")
        if fence is not None and not inside_fence(plan.spares.points, fence).all():
            v.append("a spare waits outside the geofence")
        z = plan.spares.points[:, 2]
        low, high = z.min() < lim.min_alt - DIST_TOL, z.max() > lim.max_alt + DIST_TOL
        if plan.spares.standby == "air" and (low or high):
            v.append(f"a spare waits at {float(z.min() if low else z.max()):.2f} m, outside "
                     f"min_altitude {lim.min_alt} .. max_altitude {lim.max_alt} m")
    return Verification(overall=overall, windows=windows, pattern_errors=tuple(errors),
                        separation_limit=lim.min_separation, violations=tuple(v))
