"""The geometry of a blend (:mod:`groundctl.skybrush.smooth` chooses them): a show's
corners, what a blend of one or across several knots does (acceleration, a certified
bound of its distance from the show at the same instant, speeds), and a track with its
blends in place of the show.

Every figure is exact or an upper bound: a cubic's acceleration is linear (largest at an
end), a cubic lies in the convex hull of its Bezier control points (of a difference
cubic: its distance), and a cubic's velocity is the quadratic Bezier of its control
points' differences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.show.model import Limits
from groundctl.skybrush.model import BezierTrack, SkyShow, hermite_to_bezier

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]

#: A velocity change at a knot larger than this is a corner, m/s.
CORNER_EPS = 1e-6
#: Times closer than this are one instant, s.
TIME_EPS = 1e-9


@dataclass(frozen=True)
class Corners:
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


def find_corners(show: SkyShow, start: float, end: float) -> Corners:
    """Every knot strictly between ``start`` and ``end`` (Skybrush times) at which a
    drone's velocity changes by more than :data:`CORNER_EPS`, in drone and knot order."""
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
    return Corners(drone, knot, time, jump, h_a, h_b, a, b, prev, nxt, room)


def bezier(c: FloatArray, s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Position and derivative by the parameter of the cubics ``c`` (M, 4, 3) at ``s`` (M,)."""
    s = s[:, None]
    u = 1.0 - s
    pos = u**3 * c[:, 0] + 3 * u * u * s * c[:, 1] + 3 * u * s * s * c[:, 2] + s**3 * c[:, 3]
    der = 3 * (u * u * (c[:, 1] - c[:, 0]) + 2 * u * s * (c[:, 2] - c[:, 1])
               + s * s * (c[:, 3] - c[:, 2]))
    return pos, der


def split_matrix(parts: int) -> FloatArray:
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
SPLIT = split_matrix(4)


def hull(d: FloatArray, split: FloatArray | None = None) -> FloatArray:
    """An upper bound of the length of the cubics with control points ``d`` (..., 4, 3):
    the longest of their control points (or of their pieces' by ``split``)."""
    if split is not None:
        d = np.einsum("rk,...kd->...rd", split, d)
    return np.asarray(np.linalg.norm(d, axis=-1).max(axis=-1), dtype=float)


def envelope(v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Largest horizontal speed, climb and descent rate over control velocities (M, k, 3)."""
    return (np.linalg.norm(v[..., :2], axis=-1).max(axis=-1), v[..., 2].max(axis=-1),
            (-v[..., 2]).max(axis=-1))


def assess(cs: Corners, idx: IntArray, tau: FloatArray, limits: Limits
            ) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Acceleration, deviation bound and whether the speeds are kept, of the blends of the
    corners ``idx`` (M,) with half-widths ``tau`` (M,) (see the module's docstring)."""
    A, B = cs.a[idx], cs.b[idx]
    ha, hb = cs.h_a[idx][:, None], cs.h_b[idx][:, None]
    p0, d0 = bezier(A, 1.0 - tau / ha[:, 0])
    p1, d1 = bezier(B, tau / hb[:, 0])
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
    dev = np.maximum(hull(np.stack([zero, zero, e - (vl - vm) * tt / 3, e], axis=1)),
                     hull(np.stack([e, e + (vr - vm) * tt / 3, zero, zero], axis=1)))
    blend = np.stack([v0, 3 * dp / T - v0 - v1, v1], axis=1)
    show = np.stack([v0, 3 * (corner - p0) / tt - v0 - vl, vl,
                     vr, 3 * (p1 - corner) / tt - vr - v1, v1], axis=1)
    bh, bu, bd = envelope(blend)
    sh, su, sd = envelope(show)
    slack = 1e-9
    speeds = ((bh <= np.maximum(limits.max_speed_h, sh) + slack)
              & (bu <= np.maximum(limits.max_speed_up, su) + slack)
              & (bd <= np.maximum(limits.max_speed_down, sd) + slack))
    return acc, dev, speeds


# -- blends across several knots --------------------------------------------------------


@dataclass(frozen=True)
class Window:
    """One blend of one drone: it flies the Hermite curve from ``lo`` to ``hi``."""

    first: int
    """The first knot inside it."""
    last: int
    """The last knot inside it (``first`` for the blend of one corner)."""
    lo: float
    hi: float
    dev: float
    """Its deviation bound, m."""


def hermite_state(p0: FloatArray, v0: FloatArray, p1: FloatArray, v1: FloatArray,
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


def assess_run(track: BezierTrack, first: int, last: int, lo: FloatArray, hi: FloatArray,
                limits: Limits) -> tuple[FloatArray, FloatArray, BoolArray]:
    """As :func:`assess`, for candidate blends ``[lo, hi]`` (M,) of one drone across its
    knots ``first`` to ``last``: the show is a cubic on each piece between them."""
    t, c = track.times, track.ctrl
    h = np.diff(t)
    M = len(lo)
    pa, da = bezier(np.repeat(c[first - 1][None], M, 0), (lo - t[first - 1]) / h[first - 1])
    pb, db = bezier(np.repeat(c[last][None], M, 0), (hi - t[last]) / h[last])
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
    bp, bv = hermite_state(pa, va, pb, vb, T, (bounds - lo[:, None]) / T)
    blend = hermite_to_bezier(bp[:, :-1], bv[:, :-1], bp[:, 1:], bv[:, 1:], dur)
    dev = hull(show - blend, SPLIT).max(axis=1)
    bh, bu, bd = envelope(np.stack([va, 3 * dp / T - va - vb, vb], axis=1))
    sh, su, sd = envelope((3 * np.diff(show, axis=2) / dur[..., None, None]).reshape(M, -1, 3))
    slack = 1e-9
    speeds = ((bh <= np.maximum(limits.max_speed_h, sh) + slack)
              & (bu <= np.maximum(limits.max_speed_up, su) + slack)
              & (bd <= np.maximum(limits.max_speed_down, sd) + slack))
    return acc, dev, speeds


# -- the smoothed tracks -------------------------------------------------------------------


def rebuild(track: BezierTrack, windows: list[Window]) -> BezierTrack:
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
    p0, d0 = bezier(c[on_lo], (lo - t[on_lo]) / h[on_lo])
    p1, d1 = bezier(c[on_hi], (hi - t[on_hi]) / h[on_hi])
    ctrl = hermite_to_bezier(p0, d0 / h[on_lo, None], p1, d1 / h[on_hi, None], hi - lo)
    whole = ~blend & (lo == t[on_lo]) & (hi == t[on_lo + 1])
    ctrl[whole] = c[on_lo[whole]]  # untouched segments stay exactly as read
    return BezierTrack(np.concatenate([lo, hi[-1:]]), ctrl)


def curve_max_accel(track: BezierTrack, start: float, end: float) -> float:
    """The largest acceleration of ``track`` between ``start`` and ``end``, exactly (along
    a cubic it is linear: largest at an end of a piece), not counting its velocity jumps
    at knots (unbounded)."""
    t, c = track.times, track.ctrl
    h = np.diff(t)
    seg = np.flatnonzero((t[1:] > start) & (t[:-1] < end))
    if not len(seg):
        return 0.0
    s0 = np.clip((start - t[seg]) / h[seg], 0.0, 1.0)[:, None]
    s1 = np.clip((end - t[seg]) / h[seg], 0.0, 1.0)[:, None]
    q0 = c[seg, 0] - 2 * c[seg, 1] + c[seg, 2]
    q1 = c[seg, 1] - 2 * c[seg, 2] + c[seg, 3]
    hh = (h[seg] ** 2)[:, None]
    a0 = 6 * ((1 - s0) * q0 + s0 * q1) / hh
    a1 = 6 * ((1 - s1) * q0 + s1 * q1) / hh
    return float(max(np.linalg.norm(a0, axis=1).max(), np.linalg.norm(a1, axis=1).max()))
