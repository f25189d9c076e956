"""Checks a show must pass before planning: separation, geofence, altitude, time.

Each check returns a message (without the file and place) or None, so the
loader decides where to point and tests can call them directly.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.plan.feasibility import TimeBound
from groundctl.show.model import Limits, Model, UnicycleModel
from groundctl.show.ranges import MAX_COORD
from groundctl.show.reader import fmt

FloatArray = NDArray[np.float64]


def ceil_to(x: float, step: float = 0.1) -> float:
    """``x`` rounded up to a multiple of ``step`` (advice must be enough, not almost)."""
    return math.ceil(x / step - 1e-9) * step


#: Up to this many points :func:`closest_pair` compares every pair (a few numpy calls);
#: beyond it a KD-tree, whose building and querying costs more than that on a small fleet
#: (the flight monitor, guard and replay call it every tick on a few vehicles).
BRUTE_FORCE_PAIRS = 40


def closest_pair(points: FloatArray) -> tuple[float, int, int]:
    """(distance, i, j) of the two closest points, i < j; (inf, -1, -1) for fewer than
    two."""
    pts = np.asarray(points, dtype=float)
    n = len(pts)
    if n < 2:
        return math.inf, -1, -1
    if n <= BRUTE_FORCE_PAIRS:
        diff = pts[:, None, :] - pts[None, :, :]
        d2 = np.add.reduce(diff * diff, axis=-1)
        d2.flat[::n + 1] = np.inf
        i, j = divmod(int(np.argmin(d2)), n)
        return math.sqrt(float(d2[i, j])), min(i, j), max(i, j)
    dist, idx = cKDTree(pts).query(pts, k=2)
    i = int(np.argmin(dist[:, 1]))
    j = int(idx[i, 1])
    return float(dist[i, 1]), min(i, j), max(i, j)


def separation_problem(points: FloatArray, min_separation: float,
                       scale_key: str | None, scale: float) -> str | None:
    """Message if two slots are closer than ``min_separation``.

    Shapes scale linearly with their size key, so the size that fixes it is
    ``scale * min_separation / closest``.
    """
    d, i, j = closest_pair(points)
    if d >= min_separation - 1e-9:
        return None
    dist, lim = fmt(d) if fmt(d) != fmt(min_separation) else f"{d:.3f}", fmt(min_separation)
    if scale_key is None:
        return (f"points {i + 1} and {j + 1} are {dist} m apart but min_separation is {lim} m; "
                "move them apart")
    if d <= 1e-9:
        return f"points {i + 1} and {j + 1} coincide; min_separation is {lim} m"
    need = fmt(ceil_to(scale * min_separation / d))
    return (f"points are {dist} m apart but min_separation is {lim} m; "
            f"increase '{scale_key}' to at least {need}")


def coordinate_problem(points: FloatArray, what: str = "point") -> str | None:
    """Message naming the point farthest out if one lies beyond +-MAX_COORD horizontally.

    The show frame is a flat tangent plane at the origin: 10 km out it is
    already 8 m below the horizon.
    """
    if len(points) == 0:
        return None
    reach = np.abs(np.asarray(points, dtype=float)[:, :2]).max(axis=1)
    far = int(np.argmax(reach))
    if reach[far] <= MAX_COORD:
        return None
    xyz = ", ".join(f"{float(c):.6g}" for c in points[far])
    return (f"{what} {far + 1} at ({xyz}) is more than {MAX_COORD:g} m from the origin; "
            "keep the show within 10 km of [origin]")


def inside_polygon(points: FloatArray, polygon: FloatArray) -> NDArray[np.bool_]:
    """Which (M, 2+) points lie inside (or on) the (K, 2) polygon (even-odd rule)."""
    p = np.asarray(points, dtype=float)[:, :2]
    poly = np.asarray(polygon, dtype=float)
    x, y = p[:, 0:1], p[:, 1:2]
    a, b = poly, np.roll(poly, -1, axis=0)
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    inside = np.count_nonzero(crosses & (x < x_at), axis=1) % 2 == 1
    # Points on an edge count as inside: a fence drawn through a slot is not a breach.
    return inside | (polygon_edge_distance(p, poly) < 1e-6)


def polygon_edge_distance(points: FloatArray, polygon: FloatArray) -> FloatArray:
    """Each (M, 2+) point's distance to the nearest edge of the (K, 2) polygon, m."""
    p = np.asarray(points, dtype=float)[:, :2]
    poly = np.asarray(polygon, dtype=float)
    x, y = p[:, 0:1], p[:, 1:2]
    a = poly
    ab = np.roll(poly, -1, axis=0) - a
    t = np.clip(((x - a[:, 0]) * ab[:, 0] + (y - a[:, 1]) * ab[:, 1])
                / np.maximum((ab**2).sum(axis=1), 1e-12), 0.0, 1.0)
    gap = np.hypot(a[:, 0] + t * ab[:, 0] - x, a[:, 1] + t * ab[:, 1] - y)
    return np.asarray(gap.min(axis=1))


def geofence_problem(points: FloatArray, limits: Limits, what: str = "point") -> str | None:
    """Message naming the point farthest outside the geofence, if any is outside."""
    if limits.geofence is None or len(points) == 0:
        return None
    poly = np.array(limits.geofence, dtype=float)
    out = ~inside_polygon(points, poly)
    if not out.any():
        return None
    centre = poly.mean(axis=0)
    far = np.flatnonzero(out)[np.argmax(np.linalg.norm(points[out, :2] - centre, axis=1))]
    xyz = ", ".join(fmt(float(c)) for c in points[far])
    return (f"{what} {far + 1} at ({xyz}) is outside the geofence "
            f"({np.count_nonzero(out)} of {len(points)} outside)")


def altitude_problem(points: FloatArray, limits: Limits) -> str | None:
    """Message naming the lowest / highest point if it breaks the altitude limits."""
    if len(points) == 0:
        return None
    z = points[:, 2]
    lo, hi = int(np.argmin(z)), int(np.argmax(z))
    if z[lo] < limits.min_alt - 1e-9:
        return (f"lowest point is at z = {fmt(float(z[lo]))} m, below min_altitude "
                f"{fmt(limits.min_alt)} m; raise 'center' by at least "
                f"{fmt(ceil_to(limits.min_alt - float(z[lo])))} m")
    if z[hi] > limits.max_alt + 1e-9:
        return (f"highest point is at z = {fmt(float(z[hi]))} m, above max_altitude "
                f"{fmt(limits.max_alt)} m; lower 'center' by at least "
                f"{fmt(ceil_to(float(z[hi]) - limits.max_alt))} m")
    return None


def transition_problem(bound: TimeBound, given_s: float, model: Model) -> str | None:
    """Message if ``given_s`` is shorter than the lower bound ``bound``."""
    if bound.seconds <= given_s + 1e-9:
        return None
    speed = (f"at {fmt(bound.speed_limit)} m/s (the unicycle's constant speed)"
             if isinstance(model, UnicycleModel) else f"at <= {fmt(bound.speed_limit)} m/s")
    return (f"'transition' {fmt(given_s)} s is too short: a drone must fly "
            f"{bound.distance:.1f} m {speed}; it needs at least {fmt(ceil_to(bound.seconds))} s")
