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
shared with another corner: the gentlest acceleration.  Then, in order:

* a corner that needs more borrows from its neighbours (they shrink to the
  least they need);
* one that the grid missed gets the least ``tau`` that keeps the acceleration
  limit (bisection), if that fits;
* corners too close together for a blend each (a sharp turn drawn as two or
  three short segments) get one blend across up to :data:`MAX_RUN` knots,
  evaluated piece by piece on the show's own segments; next to the plan's
  first or last instant such a blend may begin or end there.

A corner still not rounded within the tolerance, the acceleration limit and
the room it has is left as it is and reported with the reason and the
figures (what turning it takes); the show then stays refused.  The corners
are taken between the instants the plan begins and ends, which stay where
they were.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from groundctl.show.model import Limits
from groundctl.show.ranges import above_zero
from groundctl.skybrush.blend import (
    TIME_EPS,
    Corners,
    Window,
    assess,
    assess_run,
    curve_max_accel,
    find_corners,
    rebuild,
)
from groundctl.skybrush.model import SkyShow

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]

#: ``--smooth``'s allowed values, m: more than a few metres is another show.
TOLERANCE = above_zero(10.0)
#: Candidate half-widths: the room next to the corner times 2^(-k/8), k < 8 x 12.
STEPS_PER_HALVING = 8
HALVINGS = 12
FACTORS = 2.0 ** (-np.arange(STEPS_PER_HALVING * HALVINGS) / STEPS_PER_HALVING)
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
    max_accel: float
    """Largest acceleration of its curve as flown (the plan between its first and last
    instants), m/s^2, exact; not counting the velocity jumps at corners not rounded."""


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
                left = f"; {d.unrounded} not rounded (velocity jumps)" if d.unrounded else ""
                out.append(f"smoothed: drone {d.drone + 1} ({d.name}): {d.corners} corners "
                           f"rounded, at most {d.max_deviation:.3f} m from the show's path, "
                           f"max accel {d.max_accel:.2f} m/s^2{left}")
        return out

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


# -- the candidates --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Grid:
    """Every corner assessed at every candidate half-width."""

    tau: FloatArray
    """(C, K) the candidates, largest first (the same for every corner at one instant)."""
    ok: BoolArray
    """(C, K) within the tolerance, the acceleration limit and the speeds."""


def _grid(cs: Corners, width: FloatArray, tolerance: float, limits: Limits) -> _Grid:
    n, k = len(cs), len(FACTORS)
    tau = width[:, None] * FACTORS[None, :]
    ok = np.zeros((n, k), dtype=bool)
    for lo in range(0, n, BLOCK):
        rows = np.arange(lo, min(n, lo + BLOCK))
        acc, dev, speeds = assess(cs, np.repeat(rows, k), tau[rows].ravel(), limits)
        ok[rows] = ((acc <= limits.max_accel) & (dev <= tolerance) & speeds).reshape(-1, k)
    return _Grid(tau, ok)


def _least_turn(cs: Corners, idx: IntArray, width: FloatArray, limits: Limits
                ) -> tuple[FloatArray, BoolArray]:
    """The least half-width (to 2^-40 of ``width``) that keeps the acceleration limit, for
    the corners ``idx``, and whether ``width`` itself does."""
    hi = width.copy()
    acc, _, _ = assess(cs, idx, hi, limits)
    can = acc <= limits.max_accel
    lo = np.zeros_like(hi)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        acc, _, _ = assess(cs, idx, mid, limits)
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

    def __init__(self, cs: Corners, grid: _Grid) -> None:
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


def _reason(cs: Corners, c: int, turn: _Turn, limits: Limits, tolerance: float,
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


def _leftovers(cs: Corners, left: IntArray, width: FloatArray, taus: FloatArray,
               tolerance: float, limits: Limits) -> dict[int, _Turn]:
    """Round what the grid missed of the corners ``left`` (each with the least half-width
    that keeps the acceleration limit, where that fits, into ``taus``); the rest, and
    what they would take."""
    tau, can = _least_turn(cs, left, width[left], limits)
    acc_w, _, _ = assess(cs, left, width[left], limits)
    _, dev, speeds = assess(cs, left, tau, limits)
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


def _merge(show: SkyShow, cs: Corners, grid: _Grid, windows: dict[int, list[Window]],
           left: list[int], window: tuple[float, float], tolerance: float, limits: Limits
           ) -> set[int]:
    """Round each corner of ``left`` that no blend of its own can with one blend across it
    and the knots next to it (up to :data:`MAX_RUN`, the fewest first), replacing the blends
    inside and shrinking a corner's blend on either side to the least it needs if it must;
    the corners so rounded."""
    start, end = window
    per = np.searchsorted(cs.drone, np.arange(len(show.drones) + 1))
    done: set[int] = set()

    def corner(i: int, knot: int) -> int:
        """Drone ``i``'s corner at ``knot`` (-1: none); corners are in drone, knot order."""
        k = int(per[i] + np.searchsorted(cs.knot[per[i]:per[i + 1]], knot))
        return k if k < per[i + 1] and cs.knot[k] == knot else -1

    def halves(i: int, w: Window | None, t: FloatArray) -> tuple[float, float, int]:
        """How far the blend ``w`` reaches from its knot now and at the least (its own
        half-width for a blend across knots or off the grid), and its corner (-1: none)."""
        if w is None:
            return 0.0, 0.0, -1
        if w.first != w.last:
            return math.inf, math.inf, -1
        now = w.hi - float(t[w.first])
        c = corner(i, w.first)
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
            acc, dev, speeds = assess_run(show.drones[i].track, first, last, lo, hi, limits)
            ok = np.flatnonzero((acc <= limits.max_accel) & (dev <= tolerance) & speeds)
            if not len(ok):
                continue
            k = int(ok[0])
            new = Window(first, last, float(lo[k]), float(hi[k]), float(dev[k]))
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
                    _, d, _ = assess(cs, np.array([cw]), np.array([half]), limits)
                    w = Window(w.first, w.last, float(t[w.first] - half),
                                float(t[w.first] + half), float(d[0]))
                keep.append(w)
            wins[:] = [*keep, new]
            mine = np.arange(per[i], per[i + 1])
            done.update(int(x) for x in mine[(cs.knot[mine] >= first)
                                             & (cs.knot[mine] <= last)])
            break
    return done


def smooth_show(show: SkyShow, limits: Limits, tolerance: float, start: float,
                end: float) -> Smoothing:
    """``show`` with every corner between ``start`` and ``end`` (Skybrush times of the
    flown window: the plan's first and last instants) rounded within ``tolerance`` m and
    ``limits``; see the module's docstring."""
    problem = TOLERANCE.problem("tolerance", tolerance)
    if problem:
        raise ValueError(problem)
    cs = find_corners(show, start, end)
    if not len(cs):
        return Smoothing(show=show, tolerance=tolerance, max_accel=limits.max_accel,
                         drones=tuple(DroneSmoothing(i, d.name, 0, 0, 0.0,
                                                     curve_max_accel(d.track, start, end))
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
    _, dev, _ = assess(cs, rounded, taus[rounded], limits)
    windows: dict[int, list[Window]] = {}
    for c, d in zip(rounded, dev, strict=True):
        windows.setdefault(int(cs.drone[c]), []).append(
            Window(int(cs.knot[c]), int(cs.knot[c]), float(cs.time[c] - taus[c]),
                    float(cs.time[c] + taus[c]), float(d)))
    for c in _merge(show, cs, grid, windows, list(turns), (start, end), tolerance,
                    limits):
        turns.pop(c, None)

    # Corners are in drone order: drone i's are cs[per[i]:per[i + 1]].
    per = np.searchsorted(cs.drone, np.arange(len(show.drones) + 1))
    left_per = np.bincount(cs.drone[list(turns)], minlength=len(show.drones))
    drones = []
    summary = []
    for i, d in enumerate(show.drones):
        wins = sorted(windows.get(i, []), key=lambda w: w.first)
        inside = 0
        if wins:
            mine = cs.knot[per[i]:per[i + 1]]
            at = np.searchsorted([w.first for w in wins], mine, side="right") - 1
            lasts = np.array([w.last for w in wins])
            inside = int(((at >= 0) & (mine <= lasts[np.maximum(at, 0)])).sum())
        drones.append(replace(d, track=rebuild(d.track, wins)) if wins else d)
        summary.append(DroneSmoothing(
            drone=i, name=d.name, corners=inside, unrounded=int(left_per[i]),
            max_deviation=max([w.dev for w in wins], default=0.0),
            max_accel=curve_max_accel(drones[-1].track, start, end)))
    unrounded = tuple(
        Unrounded(drone=int(cs.drone[c]), name=show.drones[int(cs.drone[c])].name,
                  time=float(cs.time[c]), jump=float(cs.jump[c]),
                  reason=_reason(cs, c, turn, limits, tolerance, (start, end))
                  + f"; nor does one blend across up to {MAX_RUN} knots around it")
        for c, turn in sorted(turns.items(), key=lambda ct: (cs.time[ct[0]], cs.drone[ct[0]])))
    return Smoothing(show=replace(show, drones=tuple(drones)), tolerance=tolerance,
                     max_accel=limits.max_accel, drones=tuple(summary), unrounded=unrounded)
