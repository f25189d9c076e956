"""Rounding the corners of a Skybrush show (``--smooth TOL``): that is this module's one job.

A show drawn as straight segments (Skybrush Viewer's own demo: 0.5 s pieces)
changes velocity at once at its knots -- a corner, unbounded acceleration,
which no vehicle flies (Skybrush's drones round them in the air).
:func:`smooth_show` replaces each corner at time ``t`` by a *blend* over
``[t - tau, t + tau]``: the cubic Hermite curve from the show's own state
(position and velocity) at ``t - tau`` to its state at ``t + tau``.  Between
straight pieces with velocities ``v1``, ``v2`` that curve is constant
acceleration ``(v2 - v1) / (2 tau)`` and strays ``|v2 - v1| tau / 4`` from the
corner; for curved neighbours the same is evaluated on the Bezier pieces
themselves.  The rest of the show is kept exactly (its pieces split, which
changes nothing), and so is its clock: no drone is early or late anywhere
but inside a blend, by at most the tolerance.

What a blend is allowed is certified, not sampled:

* its distance from the show's path at the same instant: on each half of
  the window the difference between blend and show is one cubic, bounded by
  its Bezier control points (a curve lies in their convex hull), which is
  exact for straight neighbours;
* its acceleration: linear along a cubic, so largest at one of its ends;
* its speeds: a cubic's velocity is a quadratic Bezier, bounded by its three
  control points; a blend may exceed a speed limit only where the show's own
  curve there already does, and not by more.

``tau`` comes from a grid (8 steps per halving) within the two segments next
to the corner, one value for every drone cornering at that instant where it
can be (groundctl's trajectories share one knot grid: a window per drone would
multiply the knots), as large as the tolerance allows up to half of a segment
shared with another corner: the gentlest acceleration.  A corner that needs
more borrows from its neighbours (they shrink to the least they need).  A
corner that still cannot be rounded within the tolerance, the acceleration
limit and the room it has is reported, with the reason, and left as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import Limits
from groundctl.show.ranges import above_zero
from groundctl.skybrush.model import BezierTrack, SkyShow, hermite_to_bezier

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]

#: ``--smooth``'s allowed values, m: more than a few metres is another show.
TOLERANCE = above_zero(10.0)
#: A velocity change at a knot larger than this is a corner, m/s.
CORNER_EPS = 1e-6
#: Candidate half-widths: the room next to the corner times 2^(-k/8), k < 8 x 12.
STEPS_PER_HALVING = 8
HALVINGS = 12
FACTORS = 2.0 ** (-np.arange(STEPS_PER_HALVING * HALVINGS) / STEPS_PER_HALVING)
#: Times closer than this are one instant, s.
TIME_EPS = 1e-9
#: Corners assessed per block (bounds the temporaries: block x 96 candidates).
BLOCK = 2048
#: Most knots one blend may span (corners too close together for a blend each).
MAX_RUN = 4
#: Unrounded corners listed one line each; the rest are counted in one more line.
LISTED = 50


@dataclass(frozen=True)
class Unrounded:
    """A corner left as it is."""

    drone: int
    """0-based drone index."""
    name: str
    """The drone's name in the show."""
    time: float
    """Skybrush show time of the corner, s."""
    jump: float
    """How much the velocity changes there, m/s."""
    reason: str
    """Why it cannot be rounded (the rule and the figures)."""

    def line(self, tolerance: float, max_accel: float) -> str:
        return (f"drone {self.drone + 1} ({self.name}) changes velocity by {self.jump:.2f} "
                f"m/s at once at show time {self.time:.2f} s, a corner not rounded within "
                f"{tolerance:g} m at {max_accel:g} m/s^2: {self.reason}")


@dataclass(frozen=True)
class DroneSmoothing:
    """What smoothing did to one drone."""

    drone: int
    """0-based drone index."""
    name: str
    """The drone's name in the show."""
    corners: int
    """Corners rounded."""
    unrounded: int
    """Corners left as they are (each an :class:`Unrounded`)."""
    max_deviation: float
    """Largest distance from the show's path at the same instant, m (certified bound)."""
    max_accel: float = math.nan
    """Largest acceleration of the drone's plan, m/s^2 (NaN until :meth:`Smoothing.measured`)."""


@dataclass(frozen=True)
class Smoothing:
    """A show with its corners rounded, and what was done."""

    show: SkyShow
    """The show with every rounded corner replaced by its blend."""
    tolerance: float
    """The tolerance asked for, m."""
    max_accel: float
    """The acceleration limit the blends keep, m/s^2."""
    drones: tuple[DroneSmoothing, ...]
    """One entry per drone, in show order."""
    unrounded: tuple[Unrounded, ...]
    """Every corner that could not be rounded, in time order."""

    def problems(self) -> tuple[str, ...]:
        """One line per corner not rounded (the first :data:`LISTED`, then a count)."""
        out = [u.line(self.tolerance, self.max_accel) for u in self.unrounded[:LISTED]]
        if len(self.unrounded) > LISTED:
            out.append(f"and {len(self.unrounded) - LISTED} more corners not rounded")
        return tuple(out)

    def lines(self) -> list[str]:
        """One ``smoothed:`` line per drone with a corner."""
        out = []
        for d in self.drones:
            if d.corners or d.unrounded:
                left = f", {d.unrounded} not rounded" if d.unrounded else ""
                out.append(f"smoothed: drone {d.drone + 1} ({d.name}): {d.corners} corners "
                           f"rounded{left}, at most {d.max_deviation:.3f} m from the show's "
                           f"path, max accel {d.max_accel:.2f} m/s^2")
        return out

    def measured(self, traj: Trajectories) -> Smoothing:
        """These figures with every drone's largest acceleration read off ``traj``."""
        acc = drone_max_accel(traj)
        return replace(self, drones=tuple(replace(d, max_accel=float(acc[d.drone]))
                                          for d in self.drones))

    def report(self) -> dict[str, object]:
        """The ``smoothed`` object of ``plan --json``."""
        return {
            "tolerance_m": self.tolerance,
            "drones": [{"drone": d.drone + 1, "name": d.name, "corners": d.corners,
                        "unrounded": d.unrounded, "max_deviation_m": d.max_deviation,
                        "max_accel_mps2": d.max_accel} for d in self.drones],
            "unrounded": [{"drone": u.drone + 1, "name": u.name, "show_time_s": u.time,
                           "jump_mps": u.jump, "reason": u.reason} for u in self.unrounded],
        }


def drone_max_accel(traj: Trajectories) -> FloatArray:
    """(n,) every drone's largest acceleration, exactly: along a cubic it is linear, so it
    is largest at one end of a segment."""
    p, v = traj.pos, traj.vel
    h = np.diff(traj.times)[None, :, None]
    dp = p[:, 1:] - p[:, :-1]
    a0 = (6 * dp - h * (4 * v[:, :-1] + 2 * v[:, 1:])) / (h * h)
    a1 = (-6 * dp + h * (2 * v[:, :-1] + 4 * v[:, 1:])) / (h * h)
    return np.asarray(np.maximum(np.linalg.norm(a0, axis=2).max(axis=1),
                                 np.linalg.norm(a1, axis=2).max(axis=1)), dtype=float)


# -- corners -------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Corners:
    """Every corner of every drone inside the flown window, flattened (C,)."""

    drone: IntArray
    knot: IntArray
    """Index of the corner's knot in its drone's track."""
    time: FloatArray
    jump: FloatArray
    h_a: FloatArray
    """Length of the segment ending at the corner, s."""
    h_b: FloatArray
    """Length of the segment starting there, s."""
    a: FloatArray
    """(C, 4, 3) that segment's control points."""
    b: FloatArray
    prev: IntArray
    """Index of the same drone's corner at the knot before (-1: that knot is no corner)."""
    next: IntArray
    room: FloatArray
    """Largest half-width inside both segments and the flown window, s."""

    def __len__(self) -> int:
        return len(self.time)


def _find_corners(show: SkyShow, start: float, end: float) -> _Corners:
    parts: list[tuple[int, IntArray, FloatArray, FloatArray, FloatArray]] = []
    for i, d in enumerate(show.drones):
        t, c = d.track.times, d.track.ctrl
        if len(t) < 3:
            continue
        h = np.diff(t)
        vl = 3 * (c[:-1, 3] - c[:-1, 2]) / h[:-1, None]
        vr = 3 * (c[1:, 1] - c[1:, 0]) / h[1:, None]
        jump = np.linalg.norm(vr - vl, axis=1)
        inner = t[1:-1]
        keep = (jump > CORNER_EPS) & (inner > start + TIME_EPS) & (inner < end - TIME_EPS)
        j = np.flatnonzero(keep) + 1
        parts.append((i, j, t, h, jump[keep]))
    drone = np.concatenate([np.full(len(j), i, dtype=np.intp) for i, j, *_ in parts]
                           + [np.zeros(0, dtype=np.intp)])
    knot = np.concatenate([j for _, j, *_ in parts] + [np.zeros(0, dtype=np.intp)])
    time = np.concatenate([t[j] for _, j, t, *_ in parts] + [np.zeros(0)])
    jump = np.concatenate([jp for *_, jp in parts] + [np.zeros(0)])
    h_a = np.concatenate([h[j - 1] for _, j, _, h, _ in parts] + [np.zeros(0)])
    h_b = np.concatenate([h[j] for _, j, _, h, _ in parts] + [np.zeros(0)])
    ctrl = [show.drones[i].track.ctrl for i, *_ in parts]
    a = np.concatenate([c[j - 1] for c, (_, j, *_) in zip(ctrl, parts, strict=True)]
                       + [np.zeros((0, 4, 3))])
    b = np.concatenate([c[j] for c, (_, j, *_) in zip(ctrl, parts, strict=True)]
                       + [np.zeros((0, 4, 3))])
    idx = np.arange(len(time))
    same = (np.diff(drone) == 0) & (np.diff(knot) == 1)
    prev = np.full(len(time), -1, dtype=np.intp)
    nxt = np.full(len(time), -1, dtype=np.intp)
    prev[1:][same] = idx[:-1][same]
    nxt[:-1][same] = idx[1:][same]
    room = np.minimum.reduce([h_a, h_b, time - start, end - time])
    return _Corners(drone, knot, time, jump, h_a, h_b, a, b, prev, nxt, room)


def _bezier(c: FloatArray, s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Position and derivative by the parameter of the cubics ``c`` (M, 4, 3) at ``s`` (M,)."""
    s = s[:, None]
    u = 1.0 - s
    pos = u**3 * c[:, 0] + 3 * u * u * s * c[:, 1] + 3 * u * s * s * c[:, 2] + s**3 * c[:, 3]
    der = 3 * (u * u * (c[:, 1] - c[:, 0]) + 2 * u * s * (c[:, 2] - c[:, 1])
               + s * s * (c[:, 3] - c[:, 2]))
    return pos, der


def _split_matrix(parts: int) -> FloatArray:
    """(4 parts, 4): a cubic's Bezier control points to those of its ``parts`` equal pieces
    (each the blossom at the piece's ends, by de Casteljau)."""
    rows = []
    for k in range(parts):
        a, b = k / parts, (k + 1) / parts
        for us in ((a, a, a), (a, a, b), (a, b, b), (b, b, b)):
            m = np.eye(4)
            for u in us:
                m = (1 - u) * m[:-1] + u * m[1:]
            rows.append(m[0])
    return np.array(rows)


#: A blend across knots is checked on the control points of 4 pieces of each difference
#: cubic: within a few per cent of its largest value, and never below it.
_SPLIT = _split_matrix(4)


def _hull(d: FloatArray, split: FloatArray | None = None) -> FloatArray:
    """An upper bound of the length of the cubics with control points ``d`` (..., 4, 3):
    the longest of their control points (or of their pieces' by ``split``)."""
    if split is not None:
        d = np.einsum("rk,...kd->...rd", split, d)
    return np.asarray(np.linalg.norm(d, axis=-1).max(axis=-1), dtype=float)


def _envelope(v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Largest horizontal speed, climb and descent rate over control velocities (M, k, 3)."""
    return (np.linalg.norm(v[..., :2], axis=-1).max(axis=-1), v[..., 2].max(axis=-1),
            (-v[..., 2]).max(axis=-1))


def _assess(cs: _Corners, idx: IntArray, tau: FloatArray, limits: Limits
            ) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Acceleration, deviation bound and whether the speeds are kept, of the blends of the
    corners ``idx`` (M,) with half-widths ``tau`` (M,) (see the module's docstring)."""
    A, B = cs.a[idx], cs.b[idx]
    ha, hb = cs.h_a[idx][:, None], cs.h_b[idx][:, None]
    p0, d0 = _bezier(A, 1.0 - tau / ha[:, 0])
    p1, d1 = _bezier(B, tau / hb[:, 0])
    v0, v1 = d0 / ha, d1 / hb
    corner = A[:, 3]
    vl, vr = 3 * (A[:, 3] - A[:, 2]) / ha, 3 * (B[:, 1] - B[:, 0]) / hb
    tt = tau[:, None]
    T = 2 * tt
    dp = p1 - p0
    acc = np.maximum(np.linalg.norm(6 * dp - T * (4 * v0 + 2 * v1), axis=1),
                     np.linalg.norm(-6 * dp + T * (2 * v0 + 4 * v1), axis=1)) / (T[:, 0] ** 2)
    # The blend's state half way (at the corner's time); on each half, show minus blend
    # is the cubic with control points (0, 0, e - (vl - vm) tau / 3, e) before the
    # corner and (e, e + (vr - vm) tau / 3, 0, 0) after it.
    mid = 0.5 * (p0 + p1) + T * (v0 - v1) / 8
    vm = 1.5 * dp / T - 0.25 * (v0 + v1)
    e = corner - mid
    zero = np.zeros_like(e)
    dev = np.maximum(_hull(np.stack([zero, zero, e - (vl - vm) * tt / 3, e], axis=1)),
                     _hull(np.stack([e, e + (vr - vm) * tt / 3, zero, zero], axis=1)))
    blend = np.stack([v0, 3 * dp / T - v0 - v1, v1], axis=1)
    show = np.stack([v0, 3 * (corner - p0) / tt - v0 - vl, vl,
                     vr, 3 * (p1 - corner) / tt - vr - v1, v1], axis=1)
    bh, bu, bd = _envelope(blend)
    sh, su, sd = _envelope(show)
    slack = 1e-9
    speeds = ((bh <= np.maximum(limits.max_speed_h, sh) + slack)
              & (bu <= np.maximum(limits.max_speed_up, su) + slack)
              & (bd <= np.maximum(limits.max_speed_down, sd) + slack))
    return acc, dev, speeds


@dataclass(frozen=True)
class _Grid:
    """Every corner assessed at every candidate half-width."""

    tau: FloatArray
    """(C, K) the candidates, largest first (the same for every corner at one instant)."""
    ok: BoolArray
    """(C, K) within the tolerance, the acceleration limit and the speeds."""


def _grid(cs: _Corners, width: FloatArray, tolerance: float, limits: Limits) -> _Grid:
    n, k = len(cs), len(FACTORS)
    tau = width[:, None] * FACTORS[None, :]
    ok = np.zeros((n, k), dtype=bool)
    for lo in range(0, n, BLOCK):
        rows = np.arange(lo, min(n, lo + BLOCK))
        acc, dev, speeds = _assess(cs, np.repeat(rows, k), tau[rows].ravel(), limits)
        ok[rows] = ((acc <= limits.max_accel) & (dev <= tolerance) & speeds).reshape(-1, k)
    return _Grid(tau, ok)


def _least_turn(cs: _Corners, idx: IntArray, width: FloatArray, limits: Limits
                ) -> tuple[FloatArray, BoolArray]:
    """The least half-width (to 2^-40 of ``width``) that keeps the acceleration limit, for
    the corners ``idx``, and whether ``width`` itself does."""
    hi = width.copy()
    acc, _, _ = _assess(cs, idx, hi, limits)
    can = acc <= limits.max_accel
    lo = np.zeros_like(hi)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        acc, _, _ = _assess(cs, idx, mid, limits)
        fine = acc <= limits.max_accel
        hi = np.where(fine, mid, hi)
        lo = np.where(fine, lo, mid)
    return hi, can


# -- choosing the half-widths --------------------------------------------------------------


def _instants(time: FloatArray) -> tuple[IntArray, IntArray, IntArray]:
    """Corners grouped by instant: (group of each corner, corners sorted by group, where
    each group starts in that order)."""
    order = np.argsort(time, kind="stable").astype(np.intp)
    new = np.concatenate([[True], np.diff(time[order]) > TIME_EPS])
    group = np.empty(len(time), dtype=np.intp)
    group[order] = np.cumsum(new) - 1
    return group, order, np.flatnonzero(new).astype(np.intp)


class _Chooser:
    """The half-width of every corner (an index into its candidates; -1: not rounded)."""

    def __init__(self, cs: _Corners, grid: _Grid) -> None:
        self.cs, self.grid = cs, grid
        self.group, self.order, self.starts = _instants(cs.time)
        self.k = np.full(len(cs), -1, dtype=np.intp)

    def members(self, c: int) -> IntArray:
        """The corners at ``c``'s instant that share its half-width."""
        g = int(self.group[c])
        lo = int(self.starts[g])
        hi = int(self.starts[g + 1]) if g + 1 < len(self.starts) else len(self.order)
        rows = self.order[lo:hi]
        return rows[self.k[rows] == self.k[c]]

    def tau(self, c: int) -> float:
        return 0.0 if c < 0 or self.k[c] < 0 else float(self.grid.tau[c, self.k[c]])

    def least(self, c: int) -> float:
        """The least half-width ``c``'s sharers can all do with (0: not rounded)."""
        if c < 0 or self.k[c] < 0:
            return 0.0
        rows = self.members(c)
        common = np.flatnonzero(self.grid.ok[rows].all(axis=0))
        return float(self.grid.tau[c, common[-1]])

    def shrink(self, c: int, bound: float) -> None:
        """``c`` and its sharers down to the widest half-width within ``bound``."""
        if c < 0 or self.k[c] < 0 or self.tau(c) <= bound:
            return
        rows = self.members(c)
        fits = self.grid.ok[rows].all(axis=0) & (self.grid.tau[c] <= bound)
        self.k[rows] = int(np.flatnonzero(fits)[0])

    def easy(self, preferred: FloatArray) -> BoolArray:
        """Every corner that can be rounded within ``preferred``: the widest half-width that
        all of them at one instant can take, or (where they disagree) the fewest."""
        cand: BoolArray = self.grid.ok & (self.grid.tau <= preferred[:, None] * (1 + 1e-12))
        easy: BoolArray = np.asarray(cand.any(axis=1), dtype=bool)
        rows = cand[self.order].copy()
        rows[~easy[self.order]] = True  # neutral for the instant's AND
        common = np.logical_and.reduceat(rows, self.starts, axis=0)
        agreed: BoolArray = np.asarray(common.any(axis=1), dtype=bool)
        first = np.argmax(common, axis=1)
        chosen = easy & agreed[self.group]
        self.k[chosen] = first[self.group[chosen]]
        for g in np.flatnonzero(~agreed):
            lo = int(self.starts[g])
            hi = int(self.starts[g + 1]) if g + 1 < len(self.starts) else len(self.order)
            rows_g = self.order[lo:hi]
            left = rows_g[easy[rows_g]]
            while len(left):
                counts = cand[left].sum(axis=0)
                best = int(np.argmax(counts))  # the most corners; ties: the widest
                hit = cand[left, best]
                self.k[left[hit]] = best
                left = left[~hit]
        return easy

    def borrow(self, c: int) -> bool:
        """Round ``c`` with the least half-width it needs, shrinking its neighbours if it
        must; False if even that does not fit."""
        cs, ok, tau = self.cs, self.grid.ok[c], self.grid.tau[c]
        p, q = int(cs.prev[c]), int(cs.next[c])
        room = min(cs.h_a[c] - self.tau(p), cs.h_b[c] - self.tau(q))
        fits = np.flatnonzero(ok & (tau <= room + TIME_EPS))
        if not len(fits):
            room = min(cs.h_a[c] - self.least(p), cs.h_b[c] - self.least(q))
            fits = np.flatnonzero(ok & (tau <= room + TIME_EPS))
        if not len(fits):
            return False
        self.k[c] = int(fits[-1])
        width = float(tau[fits[-1]])
        self.shrink(p, float(cs.h_a[c]) - width)
        self.shrink(q, float(cs.h_b[c]) - width)
        return True


@dataclass(frozen=True)
class _Turn:
    """The gentlest blend of a corner left over: what it would take."""

    width: float
    """The most half-width it has within its segments and the flown window, s."""
    tau: float
    """The least half-width that keeps the acceleration limit (inf: none does), s."""
    acc: float
    """The acceleration of the widest blend, m/s^2."""
    dev: float
    """The deviation of the blend of half-width ``tau``, m."""
    speeds: bool
    """That blend keeps the speeds."""
    room: float
    """The half-width its neighbouring corners leave, s."""


def _reason(cs: _Corners, c: int, turn: _Turn, limits: Limits, tolerance: float,
            window: tuple[float, float]) -> str:
    """Why corner ``c`` is not rounded, with the figures."""
    w = turn.width
    if not math.isfinite(turn.tau):
        t, (start, end) = float(cs.time[c]), window
        if t - start <= w + TIME_EPS:
            why = f"the plan begins {t - start:.2f} s before it, at show time {start:.2f} s, " \
                  "the first instant every drone is up and at rest"
        elif end - t <= w + TIME_EPS:
            why = f"the plan ends {end - t:.2f} s after it, at show time {end:.2f} s, the " \
                  "last instant every drone is up and at rest"
        elif cs.room[c] > w + TIME_EPS:
            why = "another drone's corner at the same instant has no more room"
        else:
            why = "its neighbouring segments leave no more"
        return (f"turning in the {2 * w:.2f} s it has takes {turn.acc:.1f} m/s^2 ({why})")
    need = f"turning it at {limits.max_accel:g} m/s^2 takes {2 * turn.tau:.2f} s"
    if turn.dev > tolerance:
        return f"{need} and strays {turn.dev:.3f} m from the show's path"
    if not turn.speeds:
        return f"{need} and exceeds a speed limit by more than the show itself does there"
    return f"{need} and its neighbouring corners leave {2 * max(turn.room, 0.0):.2f} s"


def _leftovers(cs: _Corners, left: IntArray, width: FloatArray, taus: FloatArray,
               tolerance: float, limits: Limits) -> dict[int, _Turn]:
    """Round what the grid missed of the corners ``left`` (each with the least half-width
    that keeps the acceleration limit, where that fits, into ``taus``); the rest, and
    what they would take."""
    tau, can = _least_turn(cs, left, width[left], limits)
    acc_w, _, _ = _assess(cs, left, width[left], limits)
    _, dev, speeds = _assess(cs, left, tau, limits)
    out = {}
    for m, c in enumerate(left):
        p, q = int(cs.prev[c]), int(cs.next[c])
        room = min(cs.h_a[c] - (taus[p] if p >= 0 else 0.0),
                   cs.h_b[c] - (taus[q] if q >= 0 else 0.0), width[c])
        if can[m] and dev[m] <= tolerance and speeds[m] and tau[m] <= room:
            taus[c] = tau[m]
        else:
            out[int(c)] = _Turn(float(width[c]), float(tau[m]) if can[m] else math.inf,
                                float(acc_w[m]), float(dev[m]), bool(speeds[m]), float(room))
    return out


# -- blends across several knots --------------------------------------------------------


@dataclass(frozen=True)
class _Window:
    """One blend of one drone: it flies the Hermite curve from ``lo`` to ``hi``."""

    first: int
    """The first knot inside it."""
    last: int
    """The last knot inside it (``first`` for the blend of one corner)."""
    lo: float
    hi: float
    dev: float
    """Its deviation bound, m."""


def _hermite_state(p0: FloatArray, v0: FloatArray, p1: FloatArray, v1: FloatArray,
                   T: FloatArray, s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Position and velocity of the Hermite curves (M, 3) lasting ``T`` (M, 1) at the
    parameters ``s`` (M, P): (M, P, 3) each."""
    p0, v0, p1, v1 = (x[:, None] for x in (p0, v0, p1, v1))
    TT = T[:, None]
    s = s[..., None]
    s2, s3 = s * s, s * s * s
    pos = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * TT * v0 \
        + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * TT * v1
    vel = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * TT * v0
           + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * TT * v1) / TT
    return pos, vel


def _assess_run(track: BezierTrack, first: int, last: int, lo: FloatArray, hi: FloatArray,
                limits: Limits) -> tuple[FloatArray, FloatArray, BoolArray]:
    """As :func:`_assess`, for candidate blends ``[lo, hi]`` (M,) of one drone across its
    knots ``first`` to ``last``: the show is a cubic on each piece between them."""
    t, c = track.times, track.ctrl
    h = np.diff(t)
    M = len(lo)
    pa, da = _bezier(np.repeat(c[first - 1][None], M, 0), (lo - t[first - 1]) / h[first - 1])
    pb, db = _bezier(np.repeat(c[last][None], M, 0), (hi - t[last]) / h[last])
    va, vb = da / h[first - 1], db / h[last]
    T = (hi - lo)[:, None]
    dp = pb - pa
    acc = np.maximum(np.linalg.norm(6 * dp - T * (4 * va + 2 * vb), axis=1),
                     np.linalg.norm(-6 * dp + T * (2 * va + 4 * vb), axis=1)) / T[:, 0] ** 2
    segs, hs = c[first - 1:last + 1], h[first - 1:last + 1]
    m = last - first + 1
    at = np.broadcast_to(segs[1:, 0], (M, m, 3))
    v_in = np.broadcast_to(3 * (segs[:-1, 3] - segs[:-1, 2]) / hs[:-1, None], (M, m, 3))
    v_out = np.broadcast_to(3 * (segs[1:, 1] - segs[1:, 0]) / hs[1:, None], (M, m, 3))
    bounds = np.concatenate([lo[:, None], np.broadcast_to(t[first:last + 1], (M, m)),
                             hi[:, None]], axis=1)
    dur = np.diff(bounds, axis=1)
    show = hermite_to_bezier(np.concatenate([pa[:, None], at], 1),
                             np.concatenate([va[:, None], v_out], 1),
                             np.concatenate([at, pb[:, None]], 1),
                             np.concatenate([v_in, vb[:, None]], 1), dur)
    bp, bv = _hermite_state(pa, va, pb, vb, T, (bounds - lo[:, None]) / T)
    blend = hermite_to_bezier(bp[:, :-1], bv[:, :-1], bp[:, 1:], bv[:, 1:], dur)
    dev = _hull(show - blend, _SPLIT).max(axis=1)
    bh, bu, bd = _envelope(np.stack([va, 3 * dp / T - va - vb, vb], axis=1))
    sh, su, sd = _envelope((3 * np.diff(show, axis=2) / dur[..., None, None]).reshape(M, -1, 3))
    slack = 1e-9
    speeds = ((bh <= np.maximum(limits.max_speed_h, sh) + slack)
              & (bu <= np.maximum(limits.max_speed_up, su) + slack)
              & (bd <= np.maximum(limits.max_speed_down, sd) + slack))
    return acc, dev, speeds


def _merge(show: SkyShow, cs: _Corners, grid: _Grid, windows: dict[int, list[_Window]],
           left: list[int], window: tuple[float, float], tolerance: float, limits: Limits
           ) -> set[int]:
    """Round each corner of ``left`` that no blend of its own can with one blend across it
    and the knots next to it (up to :data:`MAX_RUN`, the fewest first), replacing the blends
    inside and shrinking a corner's blend on either side to the least it needs if it must;
    the corners so rounded."""
    start, end = window
    corner = {(int(d), int(j)): c for c, (d, j) in enumerate(zip(cs.drone, cs.knot,
                                                                  strict=True))}
    done: set[int] = set()

    def halves(i: int, w: _Window | None, t: FloatArray) -> tuple[float, float, int]:
        """How far the blend ``w`` reaches from its knot now and at the least (its own
        half-width for a blend across knots or off the grid), and its corner (-1: none)."""
        if w is None:
            return 0.0, 0.0, -1
        if w.first != w.last:
            return math.inf, math.inf, -1
        now = w.hi - float(t[w.first])
        c = corner.get((i, w.first), -1)
        if c < 0:
            return now, now, -1
        ok = np.flatnonzero(grid.ok[c] & (grid.tau[c] <= now + TIME_EPS))
        return (now, float(grid.tau[c, ok[-1]]), c) if len(ok) else (now, now, -1)

    for c in left:
        if c in done:
            continue
        i, j = int(cs.drone[c]), int(cs.knot[c])
        t = show.drones[i].track.times
        wins = windows.setdefault(i, [])
        runs = [(f, f + n - 1) for n in range(2, MAX_RUN + 1) for f in range(j - n + 1, j + 1)]
        for first, last in runs:
            if first < 1 or last > len(t) - 2 or t[first] <= start or t[last] >= end:
                continue
            inner = [w for w in wins if w.last >= first and w.first <= last]
            if any(w.first < first or w.last > last for w in inner):
                continue
            before = next((w for w in wins if w.last == first - 1), None)
            after = next((w for w in wins if w.first == last + 1), None)
            _, least_b, _ = halves(i, before, t)
            _, least_a, _ = halves(i, after, t)
            lo_min = max(float(t[first - 1]) + least_b if math.isfinite(least_b)
                         else before.hi if before else -math.inf, start)
            hi_max = min(float(t[last + 1]) - least_a if math.isfinite(least_a)
                         else after.lo if after else math.inf, end)
            room_lo, room_hi = t[first] - lo_min, hi_max - t[last]
            if min(room_lo, room_hi) <= TIME_EPS:
                continue
            # Each side as far as the other, or as far as it can (the plan's first instant
            # just before a corner: the blend starts there, at rest).
            tau = max(room_lo, room_hi) * FACTORS
            lo, hi = t[first] - np.minimum(tau, room_lo), t[last] + np.minimum(tau, room_hi)
            acc, dev, speeds = _assess_run(show.drones[i].track, first, last, lo, hi, limits)
            ok = np.flatnonzero((acc <= limits.max_accel) & (dev <= tolerance) & speeds)
            if not len(ok):
                continue
            k = int(ok[0])
            new = _Window(first, last, float(lo[k]), float(hi[k]), float(dev[k]))
            keep = [w for w in wins if w not in inner and w is not before and w is not after]
            for w, room in ((before, new.lo - float(t[first - 1])),
                            (after, float(t[last + 1]) - new.hi)):
                if w is None:
                    continue
                now, _, cw = halves(i, w, t)
                if cw >= 0 and now > room + TIME_EPS:
                    # The widest half-width that fits beside the new blend.
                    half = float(grid.tau[cw, np.flatnonzero(
                        grid.ok[cw] & (grid.tau[cw] <= room + TIME_EPS))[0]])
                    _, d, _ = _assess(cs, np.array([cw]), np.array([half]), limits)
                    w = _Window(w.first, w.last, float(t[w.first] - half),
                                float(t[w.first] + half), float(d[0]))
                keep.append(w)
            wins[:] = [*keep, new]
            mine = np.flatnonzero(cs.drone == i)
            done.update(int(x) for x in mine[(cs.knot[mine] >= first)
                                             & (cs.knot[mine] <= last)])
            break
    return done


# -- the smoothed tracks -------------------------------------------------------------------


def _rebuild(track: BezierTrack, windows: list[_Window]) -> BezierTrack:
    """``track`` flying each of ``windows``' blends instead of the show inside it."""
    t, c = track.times, track.ctrl
    K = len(t) - 1
    first = np.array([w.first for w in windows], dtype=np.intp)
    last = np.array([w.last for w in windows], dtype=np.intp)
    wlo = np.array([w.lo for w in windows])
    whi = np.array([w.hi for w in windows])
    seg_lo, seg_hi = t[:-1].copy(), t[1:].copy()
    seg_hi[first - 1] = wlo
    seg_lo[last] = whi
    covered = np.zeros(K, dtype=bool)
    for w in windows:
        covered[w.first:w.last] = True
    segs = np.flatnonzero(~covered & (seg_hi - seg_lo > TIME_EPS))
    lo = np.concatenate([seg_lo[segs], wlo])
    hi = np.concatenate([seg_hi[segs], whi])
    key = np.concatenate([2 * segs + 1, 2 * first])
    on_lo = np.concatenate([segs, first - 1])  # the segment each end lies on
    on_hi = np.concatenate([segs, last])
    blend = np.concatenate([np.zeros(len(segs), dtype=bool), np.ones(len(first), dtype=bool)])
    order = np.argsort(key, kind="stable")
    lo, hi, on_lo, on_hi, blend = (x[order] for x in (lo, hi, on_lo, on_hi, blend))
    # Where a segment between two blends is used up, they meet: one instant.
    if np.abs(lo[1:] - hi[:-1]).max(initial=0.0) > 1e-6:
        raise AssertionError("blends overlap")  # the chooser keeps them apart
    lo[1:] = hi[:-1]
    h = np.diff(t)
    p0, d0 = _bezier(c[on_lo], (lo - t[on_lo]) / h[on_lo])
    p1, d1 = _bezier(c[on_hi], (hi - t[on_hi]) / h[on_hi])
    ctrl = hermite_to_bezier(p0, d0 / h[on_lo, None], p1, d1 / h[on_hi, None], hi - lo)
    whole = ~blend & (lo == t[on_lo]) & (hi == t[on_lo + 1])
    ctrl[whole] = c[on_lo[whole]]  # untouched segments stay exactly as read
    return BezierTrack(np.concatenate([lo, hi[-1:]]), ctrl)


def smooth_show(show: SkyShow, limits: Limits, tolerance: float, start: float,
                end: float) -> Smoothing:
    """``show`` with every corner between ``start`` and ``end`` (Skybrush times of the
    flown window: the plan's first and last instants) rounded within ``tolerance`` m and
    ``limits``; see the module's docstring."""
    problem = TOLERANCE.problem("tolerance", tolerance)
    if problem:
        raise ValueError(problem)
    cs = _find_corners(show, start, end)
    if not len(cs):
        return Smoothing(show=show, tolerance=tolerance, max_accel=limits.max_accel,
                         drones=tuple(DroneSmoothing(i, d.name, 0, 0, 0.0)
                                      for i, d in enumerate(show.drones)), unrounded=())
    group, order, starts = _instants(cs.time)
    width = np.minimum.reduceat(cs.room[order], starts)[group]
    grid = _grid(cs, width, tolerance, limits)
    chooser = _Chooser(cs, grid)
    # At most half of a segment shared with another corner: windows never overlap.
    preferred = np.minimum.reduce([np.where(cs.prev >= 0, cs.h_a / 2, cs.h_a),
                                   np.where(cs.next >= 0, cs.h_b / 2, cs.h_b), cs.room])
    easy = chooser.easy(preferred)
    for c in np.flatnonzero(~easy)[np.argsort(cs.time[~easy], kind="stable")]:
        if grid.ok[c].any():
            chooser.borrow(int(c))
    k = chooser.k
    done = np.flatnonzero(k >= 0)
    taus = np.zeros(len(cs))
    taus[done] = grid.tau[done, k[done]]
    left = np.flatnonzero(k < 0)
    left = left[np.argsort(cs.time[left], kind="stable")]
    turns = _leftovers(cs, left, width, taus, tolerance, limits)
    rounded = np.flatnonzero(taus > 0)
    _, dev, _ = _assess(cs, rounded, taus[rounded], limits)
    windows: dict[int, list[_Window]] = {}
    for c, d in zip(rounded, dev, strict=True):
        windows.setdefault(int(cs.drone[c]), []).append(
            _Window(int(cs.knot[c]), int(cs.knot[c]), float(cs.time[c] - taus[c]),
                    float(cs.time[c] + taus[c]), float(d)))
    for c in _merge(show, cs, grid, windows, list(turns), (start, end), tolerance,
                    limits):
        turns.pop(c, None)

    drones = []
    summary = []
    for i, d in enumerate(show.drones):
        wins = windows.get(i, [])
        mine = cs.knot[cs.drone == i]
        inside = sum(int(((mine >= w.first) & (mine <= w.last)).sum()) for w in wins)
        drones.append(replace(d, track=_rebuild(d.track, wins)) if wins else d)
        summary.append(DroneSmoothing(
            drone=i, name=d.name, corners=inside,
            unrounded=sum(int(cs.drone[c]) == i for c in turns),
            max_deviation=max([w.dev for w in wins], default=0.0)))
    unrounded = tuple(
        Unrounded(drone=int(cs.drone[c]), name=show.drones[int(cs.drone[c])].name,
                  time=float(cs.time[c]), jump=float(cs.jump[c]),
                  reason=_reason(cs, c, turn, limits, tolerance, (start, end))
                  + f"; nor does one blend across up to {MAX_RUN} knots around it")
        for c, turn in sorted(turns.items(), key=lambda ct: (cs.time[ct[0]], cs.drone[ct[0]])))
    return Smoothing(show=replace(show, drones=tuple(drones)), tolerance=tolerance,
                     max_accel=limits.max_accel, drones=tuple(summary), unrounded=unrounded)
