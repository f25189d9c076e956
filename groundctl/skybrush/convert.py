"""A Skybrush show to a groundctl plan, and a plan to a Skybrush show.

**Skybrush to plan.**  A Skybrush trajectory starts on the ground at home and
ends on the ground; a groundctl plan starts at each home raised to the takeoff
altitude (groundctl's executor takes off and lands the vehicles itself).  So:

* the plan begins at ``T0``, the first instant at which every drone is at
  least :data:`LIFTED` above its home and at rest, and ends at ``T_end``, the
  last such instant before the landing; before ``T0`` and after ``T_end`` every
  drone must move vertically only (within :data:`VERTICAL_TOL`), as groundctl's
  takeoff and landing do;
* the takeoff altitude is the lowest height above home at ``T0`` (or the one
  asked for); a drone that is higher (or lower) there gets a rest-to-rest
  vertical stretch at the start of the plan from its takeoff altitude to where
  the show has it, and the same at the end down to its landing point raised to
  the takeoff altitude -- its own climb and descent, re-timed;
* between them the trajectories are the show's own curves, exactly: every
  drone's cubic Bezier segments are split at the union of all drones' knots,
  and a cubic on a sub-interval is exactly the cubic Hermite curve of its end
  positions and velocities, which is groundctl's trajectory representation.
  Where a drone's velocity jumps at one of its knots (a corner: unbounded
  acceleration, which no vehicle flies) that is reported as a violation, and
  the plan carries the mean of the two velocities there;
* colours: every drone's keys (linear in between, a step shown 1 ms wide),
  evaluated at the union of all drones' key times, so exact at every key.

**Plan to Skybrush.**  Each drone climbs from its home to its first plan point
with a rest-to-rest cubic (within the plan's limits), flies the plan -- every
cubic Hermite segment written as its cubic Bezier control points -- and
descends from its last plan point to the ground; lights are the plan's colour
keys as 20 ms bytecode.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.plan.plan import Cue, FormationWindow, Plan
from groundctl.plan.planfile import MAX_COLOR_KEYS, MAX_DRONE_KNOTS, MAX_DURATION, MAX_KNOTS
from groundctl.plan.trajectory import Trajectories, concatenate
from groundctl.show.model import GeoOrigin, Limits, MpcSettings
from groundctl.skybrush.lights import UNIT_S, LightKey
from groundctl.skybrush.model import (
    BezierTrack,
    SkyDrone,
    SkyLocation,
    SkyShow,
    hermite_to_bezier,
    orientation_of,
)
from groundctl.skybrush.reader import MAX_SHOW_SECONDS

FloatArray = NDArray[np.float64]

#: Height above home from which a drone counts as taken off, m.
LIFTED = 0.5
#: Speed under which a drone counts as at rest, m/s.
REST_SPEED = 0.02
#: How far a drone may drift sideways while taking off or landing, m.
VERTICAL_TOL = 0.05
#: A velocity jump at a knot larger than this is reported, m/s.
JUMP_TOL = 0.1
#: Width given to a colour step, s.
COLOR_STEP = 1e-3
#: Offsets below this need no re-timed climb or descent, m.
SAME_POINT = 1e-3


class ConversionError(ValueError):
    """A show that cannot become a plan; the message says which drone and why."""


@dataclass(frozen=True)
class Imported:
    """A Skybrush show as a plan, and how it was mapped."""

    plan: Plan
    """The plan (show time 0 = the Skybrush show's ``t0``, less ``climb_s``)."""
    t0: float
    """Skybrush time at which the plan begins (every drone up and at rest), s."""
    t_end: float
    """Skybrush time at which the plan ends, s."""
    climb_s: float
    """Length of the re-timed climb at the plan's start (0: none needed), s."""
    descent_s: float
    """Length of the re-timed descent at its end, s."""
    jumps: tuple[str, ...]
    """One line per velocity jump (a corner) found in the trajectories."""

    def skyc_time(self, plan_time: float) -> float:
        """The Skybrush show's time of plan time ``plan_time``."""
        return plan_time - self.climb_s + self.t0

    @property
    def fits_plan_file(self) -> str | None:
        """Why the plan cannot be saved as a plan file that groundctl reads back, or None."""
        p = self.plan
        if len(p.trajectories.times) > MAX_KNOTS or p.drones * len(p.trajectories.times) \
                > MAX_DRONE_KNOTS:
            return f"{len(p.trajectories.times)} knots for {p.drones} drones, more than a " \
                   "plan file holds"
        if len(p.color_times) > MAX_COLOR_KEYS:
            return f"{len(p.color_times)} colour keys, more than the {MAX_COLOR_KEYS} a " \
                   "plan file holds"
        return None


def limits_for(show: SkyShow, base: Limits) -> Limits:
    """``base`` with what the show's ``settings.validation`` says instead."""
    values: dict[str, float | tuple[tuple[float, float], ...]] = {}
    if show.min_distance is not None:
        values["min_separation"] = show.min_distance
    if show.max_altitude is not None and show.max_altitude > base.min_alt:
        values["max_alt"] = show.max_altitude
    if show.max_velocity_xy is not None:
        values["max_speed_h"] = show.max_velocity_xy
    if show.max_velocity_z is not None:
        values["max_speed_up"] = values["max_speed_down"] = show.max_velocity_z
    if show.max_velocity_z_up is not None:
        values["max_speed_up"] = show.max_velocity_z_up
    if show.geofence is not None:
        values["geofence"] = show.geofence
    from dataclasses import replace
    return replace(base, **values)  # type: ignore[arg-type]


def _rest_to_rest_time(delta: FloatArray, limits: Limits) -> float:
    """Shortest duration of the cubic rest-to-rest move ``delta`` (n, 3) for everyone
    (peak speed 1.5 d / T, peak acceleration 6 d / T^2), rounded up to 0.1 s."""
    dz = delta[:, 2]
    need = [1.5 * float(np.linalg.norm(delta[:, :2], axis=1).max()) / limits.max_speed_h,
            1.5 * float(max(dz.max(), 0.0)) / limits.max_speed_up,
            1.5 * float(max(-dz.min(), 0.0)) / limits.max_speed_down,
            math.sqrt(6 * float(np.linalg.norm(delta, axis=1).max()) / limits.max_accel)]
    return max(0.1, math.ceil(max(need) * 1.02 * 10 - 1e-9) / 10)


def _hermite_time(a: FloatArray, va: FloatArray, b: FloatArray, vb: FloatArray,
                  limits: Limits) -> float:
    """Shortest duration (0.1 s steps) of the cubic Hermite moves ``a, va -> b, vb``
    (n, 3) that keeps the speed and acceleration limits (checked on 64 samples)."""
    T = _rest_to_rest_time(b - a, limits)
    s = np.linspace(0.0, 1.0, 65)[None, :, None]
    for _ in range(200):
        tr = Trajectories(np.array([0.0, T]), np.stack([a, b], 1), np.stack([va, vb], 1))
        _, v, acc = tr.evaluate(s[0, :, 0] * T)
        ok = (np.linalg.norm(v[..., :2], axis=2).max() <= limits.max_speed_h
              and v[..., 2].max() <= limits.max_speed_up
              and -v[..., 2].min() <= limits.max_speed_down
              and np.linalg.norm(acc, axis=2).max() <= limits.max_accel)
        if ok:
            return T
        T = round(T + 0.1, 6)
    return T


def _union_knots(tracks: list[BezierTrack]) -> FloatArray:
    t = np.unique(np.concatenate([tr.times for tr in tracks]))
    keep = np.concatenate([[True], np.diff(t) > 1e-9])
    return t[keep]


def _evaluate_all(tracks: list[BezierTrack], t: FloatArray, side: str
                  ) -> tuple[FloatArray, FloatArray]:
    pos = np.empty((len(tracks), len(t), 3))
    vel = np.empty_like(pos)
    for i, tr in enumerate(tracks):
        pos[i], vel[i] = tr.evaluate(t, side)
    # Before its own start (a later takeoffTime) or after its end a drone stands still.
    for i, tr in enumerate(tracks):
        if side == "right":
            vel[i, (t < tr.start) | (t >= tr.end)] = 0.0
        else:
            vel[i, (t <= tr.start) | (t > tr.end)] = 0.0
    return pos, vel


def sky_to_plan(show: SkyShow, origin: GeoOrigin, limits: Limits,
                takeoff_altitude: float | None = None) -> Imported:
    """``show`` as a groundctl plan (see the module's docstring); ConversionError if its
    takeoff or landing is not one groundctl can fly."""
    tracks = [d.track for d in show.drones]
    n = len(tracks)
    home = np.stack([d.home for d in show.drones])
    knots = _union_knots(tracks)
    if n * len(knots) > MAX_DRONE_KNOTS:
        raise ConversionError(f"{n} drones x {len(knots)} distinct knot times is more than "
                              f"the {MAX_DRONE_KNOTS} groundctl plans hold")
    pos_r, vel_r = _evaluate_all(tracks, knots, "right")
    pos_l, vel_l = _evaluate_all(tracks, knots, "left")
    height = pos_r[:, :, 2] - home[:, None, 2]
    up: NDArray[np.bool_] = np.asarray((height > LIFTED).all(axis=0), dtype=bool)
    rest_r = np.asarray((np.linalg.norm(vel_r, axis=2) <= REST_SPEED).all(axis=0), dtype=bool)
    rest_l = np.asarray((np.linalg.norm(vel_l, axis=2) <= REST_SPEED).all(axis=0), dtype=bool)
    # The show starts at the first instant every drone is up and at rest, or, if some
    # drone moves sideways before any such instant (a show sampled too coarsely to see
    # its rest, one that flies off from the climb), at the last knot before that.
    side_home = np.linalg.norm(pos_r[:, :, :2] - home[:, None, :2], axis=2)
    away = np.flatnonzero((side_home > VERTICAL_TOL).any(axis=0))
    first_away = int(away[0]) if len(away) else len(knots)
    starts = np.flatnonzero(up & rest_r)
    starts = starts[starts < first_away]
    if len(starts):
        i0 = int(starts[0])
    elif 0 < first_away < len(knots) and up[first_away - 1]:
        i0 = first_away - 1
    elif first_away == len(knots):
        raise ConversionError(f"no instant at which all {n} drones are up (more than "
                              f"{LIFTED} m above home) and at rest after taking off, and "
                              "none flies off sideways: not a show groundctl can start")
    else:
        k = first_away
        i = int(np.argmax(side_home[:, k]))
        raise ConversionError(
            f"drone {i + 1} ({show.drones[i].name}) is {side_home[i, k]:.2f} m sideways from "
            f"its home at t = {knots[k]:.2f} s, before every drone is up (more than {LIFTED} "
            "m above home): groundctl takes off straight up")
    final = pos_l[:, -1:, :2]
    side_end = np.linalg.norm(pos_l[:, :, :2] - final, axis=2)
    moving = np.flatnonzero((side_end > VERTICAL_TOL).any(axis=0))
    last_move = int(moving[-1]) if len(moving) else -1
    ends = np.flatnonzero(up & rest_l)
    ends = ends[ends > last_move]
    if len(ends):
        i1 = int(ends[-1])
    elif last_move + 1 < len(knots) and up[last_move + 1]:
        i1 = last_move + 1
    else:
        raise ConversionError(f"no instant at which all {n} drones are up and at rest before "
                              "they land (once none moves sideways any more): groundctl lands "
                              "straight down from rest")
    if i1 <= i0:
        raise ConversionError("the show never moves between taking off and landing")
    t0, t_end = float(knots[i0]), float(knots[i1])
    h = float(height[:, i0].min()) if takeoff_altitude is None else float(takeoff_altitude)

    # The show's own curves between t0 and t_end on the union of knots.
    mid_t = knots[i0:i1 + 1]
    mid_p = pos_r[:, i0:i1 + 1].copy()
    vr, vl = vel_r[:, i0:i1 + 1], vel_l[:, i0:i1 + 1]
    mid_v = 0.5 * (vr + vl)
    mid_v[:, 0], mid_v[:, -1] = vr[:, 0], vl[:, -1]
    mid_p[:, -1] = pos_l[:, i1]
    jump = np.linalg.norm(vr - vl, axis=2)
    jump[:, [0, -1]] = 0.0
    jumps = []
    for i, k in np.argwhere(jump > JUMP_TOL)[:50]:
        jumps.append(f"drone {i + 1} ({show.drones[i].name}) changes velocity by "
                     f"{jump[i, k]:.2f} m/s at once at t = {mid_t[k]:.2f} s (a corner: "
                     "unbounded acceleration)")
    extra = int((jump > JUMP_TOL).sum()) - len(jumps)
    if extra > 0:
        jumps.append(f"and {extra} more velocity jumps")

    parts: list[Trajectories] = []
    top = home + np.array([0.0, 0.0, h])
    climb = mid_p[:, 0] - top
    climb_s = 0.0
    if np.abs(climb).max() > SAME_POINT:
        climb_s = _hermite_time(top, np.zeros_like(top), mid_p[:, 0], mid_v[:, 0], limits)
        parts.append(Trajectories(np.array([0.0, climb_s]), np.stack([top, mid_p[:, 0]], 1),
                                  np.stack([np.zeros_like(top), mid_v[:, 0]], 1)))
    else:
        mid_p[:, 0] = top
    parts.append(Trajectories(mid_t - t0 + climb_s, mid_p, mid_v))
    bottom = np.column_stack([mid_p[:, -1, :2], home[:, 2] + h])
    descent = bottom - mid_p[:, -1]
    descent_s = 0.0
    if np.abs(descent).max() > SAME_POINT:
        descent_s = _hermite_time(mid_p[:, -1], mid_v[:, -1], bottom, np.zeros_like(bottom),
                                  limits)
        end = parts[-1].end
        parts.append(Trajectories(np.array([end, end + descent_s]),
                                  np.stack([mid_p[:, -1], bottom], 1),
                                  np.stack([mid_v[:, -1], np.zeros_like(bottom)], 1)))
    else:
        parts[-1].pos[:, -1] = bottom
    traj = concatenate(parts)
    duration = traj.end

    color_times, colors = _colors(show.drones, lambda t: t - t0 + climb_s, duration)
    goals = traj.pos[:, -1].copy()
    window = FormationWindow(index=1, name=show.title[:100], start=0.0, arrive=duration,
                             end=duration, goals=goals)
    plan = Plan(show_name=show.title, origin=origin, limits=limits, model="quadrotor",
                home=home.copy(), takeoff_altitude=h, trajectories=traj,
                color_times=color_times, colors=colors, formations=(window,),
                mpc=MpcSettings(), show_digest="", names=tuple(d.name for d in show.drones),
                cues=tuple(Cue(min(max(t - t0 + climb_s, -MAX_DURATION), MAX_DURATION), name)
                           for t, name in show.cues))
    return Imported(plan=plan, t0=t0, t_end=t_end, climb_s=climb_s, descent_s=descent_s,
                    jumps=tuple(jumps))


def _drone_keys(keys: tuple[LightKey, ...]) -> tuple[FloatArray, FloatArray]:
    """Strictly increasing (times, colours 0..1) of one drone, a step 1 ms wide."""
    if not keys:
        return np.array([0.0]), np.zeros((1, 3))
    ts: list[float] = []
    cs: list[tuple[int, int, int]] = []
    for k in keys:
        if ts and k.t <= ts[-1]:
            # A step: the colour before it holds until COLOR_STEP earlier.
            if len(ts) >= 2 and k.t - COLOR_STEP > ts[-2]:
                ts[-1] = k.t - COLOR_STEP
            else:
                ts.pop()
                cs.pop()
        ts.append(k.t)
        cs.append(k.rgb)
    return np.array(ts), np.array(cs, dtype=float) / 255.0


def _colors(drones: tuple[SkyDrone, ...], shift: Callable[[FloatArray], FloatArray],
            duration: float) -> tuple[FloatArray, FloatArray]:
    """Shared colour keys on the plan's clock (``shift``: Skybrush time to plan time)."""
    per = [_drone_keys(d.lights) for d in drones]
    times = np.unique(np.concatenate([shift(t) for t, _ in per] + [np.array([0.0, duration])]))
    times = times[(times >= 0.0) & (times <= duration)]
    keep = np.concatenate([[True], np.diff(times) > 1e-9])
    times = times[keep]
    colors = np.empty((len(drones), len(times), 3))
    for i, (t, c) in enumerate(per):
        tp = shift(t)
        for ch in range(3):
            colors[i, :, ch] = np.interp(times, tp, c[:, ch])
    return times, np.clip(colors, 0.0, 1.0)


# -- plan to Skybrush ----------------------------------------------------------------------


#: Largest distance between a merged segment and the segments it replaces, m (positions
#: are written to 0.1 mm).
MERGE_TOL = 1e-5


def _hermite_at(p0: FloatArray, v0: FloatArray, p1: FloatArray, v1: FloatArray,
                h: FloatArray, s: FloatArray) -> FloatArray:
    """Positions (..., 3) of cubic Hermite segments (..., 3) lasting ``h`` (..., 1) at the
    fractions ``s`` (..., 1) of their durations."""
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0
            + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * v1)


def own_segments(times: FloatArray, pos: FloatArray, vel: FloatArray,
                 max_accel: float = math.inf) -> NDArray[np.intp]:
    """The knots of one drone's trajectory (``times`` (K+1,), ``pos``/``vel`` (K+1, 3) on
    the fleet's shared time grid) that are its own: indices of the knots where its
    polynomial changes, first and last included.

    Two cubic pieces meeting at a knot with the same position, velocity, acceleration
    and jerk are one polynomial split at a knot another drone needed.  Acceleration and
    jerk are compared within what rounding of the positions and velocities makes of them
    on pieces that short (a millisecond piece's jerk carries 1e-4 m/s^3 of it); each run
    so joined is then checked against the pieces it replaces, at every inner knot and
    every piece's middle, within :data:`MERGE_TOL`, and kept split where it is not one.
    """
    h = np.diff(times)[:, None]
    p0, p1, v0, v1 = pos[:-1], pos[1:], vel[:-1], vel[1:]
    d = p1 - p0
    a0 = (6.0 * d - h * (4.0 * v0 + 2.0 * v1)) / h**2
    a1 = (-6.0 * d + h * (2.0 * v0 + 4.0 * v1)) / h**2
    jerk = (a1 - a0) / h
    # What float rounding of this piece's numbers can make of its acceleration and jerk.
    size = np.abs(np.concatenate([p0, p1], axis=1)).max(axis=1, keepdims=True) \
        + h * np.abs(np.concatenate([v0, v1], axis=1)).max(axis=1, keepdims=True)
    eps = 64.0 * np.finfo(float).eps * size
    err_a, err_j = (eps / h**2)[:, 0], (eps / h**3)[:, 0]
    same = (np.abs(a1[:-1] - a0[1:]).max(axis=1) <= 1e-9 + err_a[:-1] + err_a[1:]) \
        & (np.abs(jerk[:-1] - jerk[1:]).max(axis=1) <= 1e-9 + 2 * (err_j[:-1] + err_j[1:]))
    cuts = np.concatenate([[0], np.flatnonzero(~same) + 1, [len(times) - 1]])
    starts, ends = cuts[:-1], cuts[1:]
    # Each run's one cubic, against the pieces it replaces (all runs at once).
    piece = np.arange(len(times) - 1)
    run = np.searchsorted(ends, piece, side="right")
    i0, i1 = starts[run], ends[run]
    hh = (times[i1] - times[i0])[:, None]
    off = np.zeros(len(piece))
    for s_frac in (0.0, 0.5):
        t = times[piece] + s_frac * h[:, 0]
        mine = _hermite_at(p0, v0, p1, v1, h, np.full((len(piece), 1), s_frac))
        theirs = _hermite_at(pos[i0], vel[i0], pos[i1], vel[i1], hh,
                             ((t - times[i0]) / hh[:, 0])[:, None])
        off = np.maximum(off, np.abs(mine - theirs).max(axis=1))
    bad_runs = np.unique(run[off > MERGE_TOL])
    keep = set(cuts.tolist())
    for r in bad_runs:
        keep.update(range(int(starts[r]) + 1, int(ends[r])))
    return _without_slivers(times, pos, vel, sorted(keep), max_accel)


#: Shortest segment an export keeps where it can, s: Skybrush counts durations in whole
#: milliseconds (its server rounds each to the millisecond, and refuses one that rounds
#: to none), and on a piece of a few milliseconds the written decimals of its control
#: points become acceleration.
SLIVER_S = 0.005
#: How far joining a sliver to its neighbour may move the trajectory, m.
SLIVER_TOL = 1e-3


def _without_slivers(times: FloatArray, pos: FloatArray, vel: FloatArray,
                     keep: list[int], max_accel: float = math.inf) -> NDArray[np.intp]:
    """``keep`` without the knots that end segments shorter than :data:`SLIVER_S` (where
    two blends, or a drone's own knots and another's, fall a few milliseconds apart): the
    sliver and a neighbour (the shorter first) become one cubic Hermite segment between
    their outer knots where that stays within :data:`SLIVER_TOL` of both (at the joint
    and both pieces' midpoints) and accelerates no harder than they do or than
    ``max_accel`` (a cubic's acceleration is largest at an end); otherwise the sliver
    stays (one under a millisecond is then refused in one line on export)."""
    k = list(keep)

    def joined(drop: int) -> bool:
        a, m, b = k[drop - 1], k[drop], k[drop + 1]
        whole = Trajectories(np.array([times[a], times[b]]), np.stack([pos[a], pos[b]])[None],
                             np.stack([vel[a], vel[b]])[None])
        parts = Trajectories(times[a:b + 1], pos[None, a:b + 1], vel[None, a:b + 1])
        at = np.array([times[m], 0.5 * (times[a] + times[m]), 0.5 * (times[m] + times[b])])
        off = float(np.abs(whole.evaluate(at)[0] - parts.evaluate(at)[0]).max())
        acc_whole = float(np.linalg.norm(
            whole.evaluate(np.array([times[a], times[b]]))[2][0], axis=1).max())
        ends = np.array([times[a], times[m] - 1e-9, times[m], times[b]])
        acc_parts = float(np.linalg.norm(parts.evaluate(ends)[2][0], axis=1).max())
        return off <= SLIVER_TOL and acc_whole <= max(acc_parts + 1e-6, max_accel)

    i = 0
    while i < len(k) - 1 and len(k) > 2:
        if times[k[i + 1]] - times[k[i]] >= SLIVER_S:
            i += 1
            continue
        left = times[k[i]] - times[k[i - 1]] if i > 0 else math.inf
        right = times[k[i + 2]] - times[k[i + 1]] if i + 2 < len(k) else math.inf
        sides = [i, i + 1] if left <= right else [i + 1, i]
        for drop in sides:
            if 0 < drop < len(k) - 1 and joined(drop):
                del k[drop]
                i = max(drop - 2, 0)
                break
        else:
            i += 1
    return np.array(k, dtype=np.intp)


def _own_keys(times: FloatArray, rgb: NDArray[np.int_]) -> NDArray[np.intp]:
    """Indices of one drone's colour keys (``rgb`` (F, 3) bytes at ``times``) that say
    something: a key whose colour is the straight fade between its neighbours (a colour
    held while another drone's changes) is left out, which the light program plays the
    same."""
    if len(times) <= 2:
        return np.arange(len(times))
    c = rgb.astype(float)
    w = ((times[1:-1] - times[:-2]) / (times[2:] - times[:-2]))[:, None]
    between = c[:-2] + w * (c[2:] - c[:-2])
    inner = np.flatnonzero(np.abs(c[1:-1] - between).max(axis=1) > 1e-9) + 1
    keep = np.concatenate([[0], inner, [len(times) - 1]])
    # Leaving out a key changes its neighbours' neighbours: check the kept keys again
    # until every one left out lies on the fade between the two kept around it.
    while True:
        k = np.arange(len(times))
        right = np.searchsorted(keep, k, side="left")
        right = np.clip(right, 1, len(keep) - 1)
        lo, hi = keep[right - 1], keep[right]
        ww = np.where(hi > lo, (times[k] - times[lo]) / np.maximum(times[hi] - times[lo],
                                                                  1e-12), 0.0)[:, None]
        off = np.abs(c[k] - (c[lo] + ww * (c[hi] - c[lo]))).max(axis=1)
        missing = np.setdiff1d(np.flatnonzero(off > 0.5), keep)
        if not len(missing):
            return keep
        keep = np.union1d(keep, missing)


def plan_to_sky(plan: Plan, placed: bool = True, altitude: bool = True
                ) -> tuple[SkyShow, float]:
    """``plan`` as a Skybrush show, and the climb's length (plan time 0 is that Skybrush
    time).  Its origin and heading are written as ``environment.location`` when
    ``placed`` (not for an imported show groundctl anchored at its stand-in field), with
    the altitude when ``altitude`` (not a stand-in either)."""
    tr = plan.trajectories
    start, end = tr.pos[:, 0], tr.pos[:, -1]
    climb = start - plan.home
    descent = plan.landing - end
    lim = plan.limits
    climb_s = math.ceil(_rest_to_rest_time(climb, lim) / UNIT_S - 1e-9) * UNIT_S
    descent_s = math.ceil(_rest_to_rest_time(descent, lim) / UNIT_S - 1e-9) * UNIT_S
    zero = np.zeros_like(start)
    up = hermite_to_bezier(plan.home, zero, start, zero, np.array(climb_s))
    down = hermite_to_bezier(end, zero, plan.landing, zero, np.array(descent_s))
    drones = []
    rgb = np.clip(np.round(plan.colors * 255.0), 0, 255).astype(int)
    for i in range(plan.drones):
        # Each drone with its own knots: the plan's grid is every drone's knots together,
        # which would make each drone's trajectory as long as the whole fleet's.
        k = own_segments(tr.times, tr.pos[i], tr.vel[i], lim.max_accel)
        t = tr.times[k]
        body = hermite_to_bezier(tr.pos[i, k[:-1]], tr.vel[i, k[:-1]], tr.pos[i, k[1:]],
                                 tr.vel[i, k[1:]], np.diff(t))
        times = np.concatenate([[0.0], t + climb_s, [tr.end + climb_s + descent_s]])
        ctrl = np.concatenate([up[i][None], body, down[i][None]])
        # Its own colour keys: the plan's are every drone's together.
        own = _own_keys(plan.color_times, rgb[i])
        keys = tuple(LightKey(float(plan.color_times[k] + climb_s),
                              (int(rgb[i, k, 0]), int(rgb[i, k, 1]), int(rgb[i, k, 2])))
                     for k in own)
        drones.append(SkyDrone(name=plan.name_of(i) or f"drone_{i + 1}", home=plan.home[i].copy(),
                               track=BezierTrack(times, ctrl), lights=keys))
    sky = SkyShow(title=plan.show_name, drones=tuple(drones),
                  min_distance=lim.min_separation, max_altitude=lim.max_alt,
                  max_velocity_xy=lim.max_speed_h, max_velocity_z=lim.max_speed_down,
                  max_velocity_z_up=lim.max_speed_up, geofence=lim.geofence,
                  cues=tuple((min(max(c.time + climb_s, 0.0), MAX_SHOW_SECONDS), c.name)
                             for c in plan.cues),
                  location=SkyLocation(lat=plan.origin.lat, lon=plan.origin.lon,
                                       amsl=plan.origin.alt if altitude else None,
                                       orientation_deg=orientation_of(plan.origin.heading_deg))
                  if placed else None)
    return sky, climb_s
