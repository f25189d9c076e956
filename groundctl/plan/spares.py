"""Where a show's spare drones wait, and the proof that they wait clear of the show.

A spare waits on its pad (``[spares] standby = "ground"``) or hovering at a point
straight above it (``"air"``).  It takes off from its pad and lands on it with the
fleet, before the show clock starts and after the show ends, so its *column* (from the
pad up to its waiting point) must clear every show drone's takeoff and landing column,
and its waiting point must clear every show drone's path at every instant of the plan,
in continuous time: the verifier's branch and bound on each drone's cubic, as for two
drones (:func:`groundctl.plan.verify.closest_on_segment`).  Spares keep the same
distance from one another.

Without given pads or points the planner lays them out: a block of pads beside the
takeoff grid, on whichever side (+x or -x) is clear at the smaller step out, stepped out
a pad spacing at a time until every spare clears the show by the limit plus
:data:`LAYOUT_MARGIN_M` (a hovering spare wanders, and so do the show's drones) and
stands inside the geofence.  Given pads or points are verified as they are: one that
comes within the limit is refused (:class:`~groundctl.errors.SpareError`), naming the
drone, where and when.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.errors import SpareError
from groundctl.plan.plan import Plan, SparePlan
from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import (
    DIST_TOL,
    bounding_spheres,
    hermite_power,
    nearest_in_order,
)
from groundctl.show.checks import closest_pair, inside_polygon
from groundctl.show.model import SpareSettings
from groundctl.show.ranges import MAX_COORD

FloatArray = NDArray[np.float64]

#: Laid-out spares clear every show drone (and each other) by the limit plus this, m.
LAYOUT_MARGIN_M = 1.0
#: Steps of one pad spacing a laid-out block is moved out at most, each side.
MAX_STEPS_OUT = 200
#: Drones whose every segment is measured against a point at once (bounds temporaries).
DRONE_CHUNK = 256
#: Show columns measured against every spare's at once (bounds temporaries).
COLUMN_CHUNK = 1024


@dataclass(frozen=True)
class Clearance:
    """The closest any spare comes to the show or to another spare."""

    distance: float
    """How close, m (infinite: nothing to come close to)."""
    spare: int
    """Which spare, 0-based (-1: none)."""
    what: str
    """What it comes that close to, in words ("drone 17 at show time 34.2 s")."""


def _vertical_gaps(a_xy: FloatArray, a_lo: FloatArray, a_hi: FloatArray,
                   b_xy: FloatArray, b_lo: FloatArray, b_hi: FloatArray) -> FloatArray:
    """(k, m) distances between k and m vertical segments (x, y, from z lo to z hi)."""
    dxy = np.linalg.norm(a_xy[:, None, :] - b_xy[None, :, :], axis=2)
    dz = np.maximum(0.0, np.maximum(b_lo[None, :] - a_hi[:, None],
                                    a_lo[:, None] - b_hi[None, :]))
    return np.hypot(dxy, dz)


def _closest_column(a_xy: FloatArray, a_lo: FloatArray, a_hi: FloatArray,
                    b_xy: FloatArray, b_lo: FloatArray, b_hi: FloatArray
                    ) -> tuple[float, int, int]:
    """(distance, a's index, b's index) of the closest pair of vertical segments, b in
    chunks (a thousand spares against ten thousand columns at once would be 400 MB)."""
    best, at = math.inf, (-1, -1)
    for c in range(0, len(b_xy), COLUMN_CHUNK):
        gaps = _vertical_gaps(a_xy, a_lo, a_hi, b_xy[c:c + COLUMN_CHUNK],
                              b_lo[c:c + COLUMN_CHUNK], b_hi[c:c + COLUMN_CHUNK])
        j, i = (int(x) for x in np.unravel_index(int(np.argmin(gaps)), gaps.shape))
        if gaps[j, i] < best:
            best, at = float(gaps[j, i]), (j, c + i)
    return best, at[0], at[1]


@dataclass(frozen=True)
class Hulls:
    """Every drone's every knot segment as a sphere holding its Bezier hull, flattened
    drone-major (row ``drone * segments + k``): computed once per plan, then each point
    asked about costs one pass over them."""

    centre: FloatArray
    """(n * segments, 3) sphere centres."""
    radius: FloatArray
    """(n * segments,) sphere radii."""
    segments: int
    """Knot segments per drone."""
    tree: cKDTree
    """A KD-tree on the centres."""

    @classmethod
    def of(cls, tr: Trajectories) -> Hulls:
        h = np.diff(tr.times)[None, :, None]
        segs = len(tr.times) - 1
        centre = np.empty((tr.drones * segs, 3))
        radius = np.empty(tr.drones * segs)
        for a in range(0, tr.drones, DRONE_CHUNK):
            p, v = tr.pos[a:a + DRONE_CHUNK], tr.vel[a:a + DRONE_CHUNK]
            rows = slice(a * segs, (a + len(p)) * segs)
            centre[rows], radius[rows] = bounding_spheres(hermite_power(
                p[:, :-1].reshape(-1, 3), p[:, 1:].reshape(-1, 3),
                (v[:, :-1] * h).reshape(-1, 3), (v[:, 1:] * h).reshape(-1, 3)))
        return cls(centre, radius, segs, cKDTree(centre))

    def near(self, q: FloatArray) -> tuple[NDArray[np.intp], FloatArray]:
        """The segments that can hold the closest approach to ``q``, nearest hull first,
        and each one's lower bound: a few nearest centres bound the distance from above
        (a curve lies within its sphere), one ball query finds every hull under it."""
        d, i = self.tree.query(q, k=min(8, len(self.radius)))
        upper = float(np.min(np.atleast_1d(d) + self.radius[np.atleast_1d(i)]))
        # With slack: at rest (radius 0) the nearest centre is exactly at the radius, and
        # the ball query may round it out.
        reach = upper * (1 + 1e-9) + 1e-12 + float(self.radius.max())
        rows = np.asarray(self.tree.query_ball_point(q, reach), dtype=np.intp)
        lower = np.linalg.norm(self.centre[rows] - q, axis=1) - self.radius[rows]
        keep = lower <= upper  # a hull at rest only touches the bound: measured too
        order = np.argsort(lower[keep], kind="stable")
        return rows[keep][order], lower[keep][order]


def closest_to_point(tr: Trajectories, q: FloatArray, hulls: Hulls | None = None
                     ) -> tuple[float, int, float]:
    """(distance, drone 0-based, show time) of the closest any drone's path comes to the
    fixed point ``q``, exact in continuous time (to the verifier's tolerance).

    A few nearest hulls bound the distance from above, each segment's hull from below;
    only the segments whose hull reaches under the bound are measured, by the verifier's branch
    and bound (:func:`~groundctl.plan.verify.closest_on_segment`)."""
    hulls = hulls if hulls is not None else Hulls.of(tr)
    rows, lower = hulls.near(q)
    segs = hulls.segments
    h = np.diff(tr.times)

    def cubics(blk: slice) -> FloatArray:
        drone, seg = rows[blk] // segs, rows[blk] % segs
        coef = hermite_power(tr.pos[drone, seg], tr.pos[drone, seg + 1],
                             tr.vel[drone, seg] * h[seg, None],
                             tr.vel[drone, seg + 1] * h[seg, None])
        coef[:, 0] -= q
        return coef

    best, k, s = nearest_in_order(lower, cubics)
    if k < 0:
        return best, -1, 0.0
    drone, seg = divmod(int(rows[k]), segs)
    return best, drone, float(tr.times[seg] + s * h[seg])


def clearance(plan: Plan, pads: FloatArray, points: FloatArray,
              hulls: Hulls | None = None) -> Clearance:
    """The closest the spares waiting at ``points`` (each over its pad in ``pads``) come
    to a show drone -- its path in the plan, its takeoff and landing columns -- or to one
    another, exact in continuous time.  ``hulls``: the plan's, if already computed."""
    tr = plan.trajectories
    hulls = hulls if hulls is not None else Hulls.of(tr)
    found = Clearance(math.inf, -1, "nothing")
    for j, q in enumerate(points):
        d, drone, t = closest_to_point(tr, q, hulls)
        if d < found.distance:
            found = Clearance(d, j, f"drone {drone + 1} at show time {t:.1f} s")
    s_xy, s_lo, s_hi = pads[:, :2], pads[:, 2], np.maximum(points[:, 2], pads[:, 2])
    landing = plan.landing
    for kind, ground in (("takeoff", plan.home), ("landing", landing)):
        gap, a, b = _closest_column(s_xy, s_lo, s_hi, ground[:, :2], ground[:, 2],
                                    ground[:, 2] + plan.takeoff_altitude)
        if gap < found.distance:
            found = Clearance(gap, a, f"drone {b + 1}'s {kind} column")
    for a in range(len(pads) - 1):  # each spare against the ones after it
        gap, _, b = _closest_column(s_xy[a:a + 1], s_lo[a:a + 1], s_hi[a:a + 1],
                                    s_xy[a + 1:], s_lo[a + 1:], s_hi[a + 1:])
        if gap < found.distance:
            found = Clearance(gap, a, f"spare {a + b + 2}")
    return found


def _ground(plan: Plan) -> float:
    """The ground's height in the show frame: where the takeoff grid stands."""
    return float(np.median(plan.home[:, 2]))


def _spacing(plan: Plan) -> float:
    """Laid-out pads' spacing: the takeoff grid's, and never under the limit plus margin."""
    floor = plan.limits.min_separation + LAYOUT_MARGIN_M
    if len(plan.home) < 2:
        return floor
    return max(floor, closest_pair(plan.home[:, :2])[0])


def layout(plan: Plan, count: int, side: int, step: int, height: float
           ) -> tuple[FloatArray, FloatArray]:
    """(pads, points) of ``count`` spares in a block beside the takeoff grid and the
    landing spots: columns of pads along y (as many rows as the grid is deep), the first
    ``step`` pad spacings out from its ``side`` (+1: +x, -1: -x); points ``height``
    above the ground (0: the pads)."""
    home = np.vstack([plan.home, plan.landing])
    spacing = _spacing(plan)
    depth = float(home[:, 1].max() - home[:, 1].min())
    rows = min(count, int(depth // spacing) + 1)
    edge = float(home[:, 0].max() if side > 0 else home[:, 0].min())
    middle = float(home[:, 1].max() + home[:, 1].min()) / 2
    k = np.arange(count)
    x = edge + side * spacing * (step + k // rows)
    y = middle + spacing * (k % rows - (rows - 1) / 2)
    ground = _ground(plan)
    pads = np.column_stack([x, y, np.full(count, ground)])
    points = pads + np.array([0.0, 0.0, height])
    return pads, points


def _inside(plan: Plan, pads: FloatArray) -> bool:
    """Every pad within the show frame's range and the geofence (if any)."""
    if np.abs(pads[:, :2]).max() > MAX_COORD:
        return False
    fence = plan.limits.geofence
    return fence is None or bool(inside_polygon(pads, np.array(fence, dtype=float)).all())


def place_spares(settings: SpareSettings, plan: Plan) -> SparePlan:
    """Where ``settings``' spares wait in ``plan``: given pads or points verified, or a
    block laid out beside the takeoff grid (module docstring).  SpareError if given ones
    come within the limit, or no block fits within :data:`MAX_STEPS_OUT` steps."""
    limit = plan.limits.min_separation
    ground = _ground(plan)
    if settings.points is not None or settings.pads is not None:
        if settings.points is not None:
            points = np.asarray(settings.points, dtype=float)
            pads = np.column_stack([points[:, :2], np.full(len(points), ground)])
            what = "standby point"
            low = np.flatnonzero(points[:, 2] <= ground)
            if len(low):
                raise SpareError(
                    f"[spares] standby point {int(low[0]) + 1} is at z = "
                    f"{points[low[0], 2]:g} m, not above the ground ({ground:g} m, where "
                    "the takeoff grid stands): a spare waiting in the air hovers above its "
                    "pad", spare=int(low[0]))
        else:
            xy = np.asarray(settings.pads, dtype=float)
            pads = np.column_stack([xy, np.full(len(xy), ground)])
            points = pads.copy()
            what = "pad"
        found = clearance(plan, pads, points, Hulls.of(plan.trajectories))
        if found.distance < limit - DIST_TOL:
            j = found.spare
            where = ", ".join(f"{c:g}" for c in np.round(points[j], 2))
            raise SpareError(
                f"[spares] {what} {j + 1} at ({where}) comes within {found.distance:.2f} m "
                f"of {found.what} (min_separation {limit:g} m): give it a place outside the "
                "show's volume, or leave the spares' positions out and the planner lays "
                "them out beside the takeoff grid", spare=j, distance=found.distance)
        return SparePlan(settings.standby, pads, points, found.distance, given=True)
    height = 0.0 if settings.standby == "ground" else (
        settings.altitude if settings.altitude is not None else plan.takeoff_altitude)
    if settings.standby == "air" and not height > 0:
        raise SpareError(f"[spares] 'altitude' {height:g} m: a spare waiting in the air "
                         "hovers above its pad; give a height above 0")
    want = limit + LAYOUT_MARGIN_M
    hulls = Hulls.of(plan.trajectories)
    for step in range(1, MAX_STEPS_OUT + 1):
        for side in (1, -1):
            pads, points = layout(plan, settings.count, side, step, height)
            if not _inside(plan, pads):
                continue
            found = clearance(plan, pads, points, hulls)
            if found.distance >= want - DIST_TOL:
                return SparePlan(settings.standby, pads, points, found.distance)
    raise SpareError(
        f"[spares] no room for {settings.count} spares beside the takeoff grid within "
        f"{MAX_STEPS_OUT} pad spacings of it, clear of the show by {want:g} m and inside "
        "the geofence: give their 'pads' or 'points'", spare=None, distance=None)
