"""Trajectories checked and made without the QP: the exact rollout, the straight stop,
the continuous-time verifier, which neighbours get a slot, a convex fence's rows, the
limits a start state already breaks and the escape's raised limits."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from groundctl.execute.mpc.types import (
    FloatArray,
    IntArray,
    MpcRequest,
    TrajectoryCheck,
    _array,
)
from groundctl.plan.verify import inside_polygon
from groundctl.show.model import Limits
from groundctl.vehicleid import spell

#: Absolute tolerance on separation and altitude in the verifier, m.
DIST_TOL = 1e-3
#: Below this a direction (speed, acceleration) is taken as undefined.
_TINY = 1e-6


def rollout(p0: FloatArray, v0: FloatArray, acc: FloatArray,
            dt: float) -> tuple[FloatArray, FloatArray]:
    """Exact double-integrator states (N+1, 3) from (p0, v0) under ``acc`` (N, 3)."""
    dv = dt * acc
    vel = np.concatenate([v0[None], v0[None] + np.cumsum(dv, axis=0)])
    dp = dt * vel[:-1] + 0.5 * dt * dt * acc
    pos = np.concatenate([p0[None], p0[None] + np.cumsum(dp, axis=0)])
    return pos, vel


def brake_trajectory(p0: ArrayLike, v0: ArrayLike, dt: float, steps: int,
                     max_accel: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A straight stop at ``max_accel`` from (p0, v0), then a hold: (pos, vel, acc).

    The step in which the vehicle comes to rest brakes just enough to end it at
    zero velocity, so the trajectory is the same piecewise-constant-acceleration
    kind as the MPC's and ends exactly at rest.
    """
    p = _array("p0", p0, (3,))
    v = _array("v0", v0, (3,))
    if not max_accel > 0:
        raise ValueError(f"`max_accel` must be positive, got {max_accel}")
    speed = float(np.linalg.norm(v))
    direction = v / speed if speed > _TINY else np.zeros(3)
    s = np.maximum(speed - max_accel * dt * np.arange(steps + 1), 0.0)
    acc = np.diff(s)[:, None] / dt * direction[None]
    pos, vel = rollout(p, v, acc, dt)
    return pos, vel, acc


def _dense(pos: FloatArray, vel: FloatArray, acc: FloatArray, dt: float,
           substeps: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Samples of the piecewise-quadratic trajectory: (T, 3) positions and velocities at
    T = N substeps + 1 instants, and the (T,) time offsets."""
    tau = dt * np.arange(substeps) / substeps
    t = tau[None, :, None]
    p = pos[:-1, None] + vel[:-1, None] * t + 0.5 * acc[:, None] * t * t
    v = vel[:-1, None] + acc[:, None] * t
    offs = dt * np.arange(len(acc))[:, None] + tau[None]
    return (np.concatenate([p.reshape(-1, 3), pos[-1:]]),
            np.concatenate([v.reshape(-1, 3), vel[-1:]]),
            np.concatenate([offs.ravel(), [dt * len(acc)]]))


def _dense_linear(q: FloatArray, substeps: int) -> FloatArray:
    """(m, N+1, 3) samples interpolated linearly to (m, N substeps + 1, 3)."""
    frac = (np.arange(substeps) / substeps)[None, None, :, None]
    d = q[:, :-1, None] + (q[:, 1:, None] - q[:, :-1, None]) * frac
    return np.concatenate([d.reshape(len(q), -1, 3), q[:, -1:]], axis=1)


def speed_envelope(limit: float, start: float, brake: float, steps: int,
                   dt: float) -> FloatArray:
    """A speed limit as an envelope from a start above it, at the steps 0..``steps``:
    ``max(limit, start - brake t_k)`` (module docstring, "Envelope"); ``limit`` at every
    step when the start is within it."""
    return np.maximum(limit, start - brake * dt * np.arange(steps + 1))


def verify(pos: FloatArray, vel: FloatArray, acc: FloatArray, dt: float, limits: Limits,
           neighbours: FloatArray | None = None, neighbour_ids: ArrayLike | None = None, *,
           substeps: int = 10, limit_tol: float = 0.01, baseline: bool = False,
           brake: float | None = None) -> TrajectoryCheck:
    """Check a trajectory (pos, vel (N+1, 3), acc (N, 3)) in continuous time.

    ``substeps`` samples per step of the piecewise-quadratic trajectory against the
    neighbours' predictions (m, N+1, 3) interpolated linearly; speeds and
    accelerations within ``limit_tol`` (relative), separation and altitude within
    :data:`DIST_TOL`, the geofence (any polygon, even-odd rule).  ``baseline``:
    every limit already broken at the first sample is relaxed to its value there
    ("no worse than now", for a stop from a bad state; a fence already left is not
    checked).  ``brake`` (m/s^2): a speed limit the first sample is above is the
    envelope closing from it at that rate (:func:`speed_envelope` at the steps, linear
    between them).  Time offsets in the messages are from the first sample.
    """
    ps, vs, offs = _dense(pos, vel, acc, dt, substeps)
    out: list[str] = []
    vh = np.linalg.norm(vs[:, :2], axis=1)
    an = np.linalg.norm(acc, axis=1)
    checks = [("horizontal speed", vh, limits.max_speed_h, "m/s", "max_speed_h"),
              ("climb rate", vs[:, 2], limits.max_speed_up, "m/s", "max_speed_up"),
              ("descent rate", -vs[:, 2], limits.max_speed_down, "m/s", "max_speed_down")]
    for what, values, limit, unit, name in checks:
        start = float(values[0])
        allowed: float | FloatArray = limit
        closing = ""
        if brake is not None and start > limit:
            # The envelope before ``baseline``: it starts at the measured speed too, and
            # closes (a vehicle recovering a neighbour's separation is not let fly on
            # over its limit).
            steps = len(acc)
            allowed = np.interp(offs, dt * np.arange(steps + 1),
                                speed_envelope(limit, start, brake, steps, dt))
            closing = f", closing from {start:.2f} {unit}"
        elif baseline:
            allowed = max(limit, start)
        over = values - np.asarray(allowed) * (1 + limit_tol) - 1e-9
        worst = int(np.argmax(over))
        if over[worst] > 0:
            out.append(f"{what} {values[worst]:.2f} {unit} at +{offs[worst]:.2f} s "
                       f"({name} {limit} {unit}{closing})")
    if len(an) and an.max() > limits.max_accel * (1 + limit_tol):
        k = int(np.argmax(an))
        out.append(f"acceleration {an[k]:.2f} m/s^2 at +{dt * k:.2f} s "
                   f"(max_accel {limits.max_accel} m/s^2)")
    z = ps[:, 2]
    lo = min(limits.min_alt, float(z[0])) if baseline else limits.min_alt
    hi = max(limits.max_alt, float(z[0])) if baseline else limits.max_alt
    if z.min() < lo - DIST_TOL:
        k = int(np.argmin(z))
        out.append(f"altitude {z[k]:.2f} m at +{offs[k]:.2f} s (min_alt {limits.min_alt} m)")
    if z.max() > hi + DIST_TOL:
        k = int(np.argmax(z))
        out.append(f"altitude {z[k]:.2f} m at +{offs[k]:.2f} s (max_alt {limits.max_alt} m)")
    if limits.geofence:
        poly = np.asarray(limits.geofence, dtype=float)
        inside = inside_polygon(poly, ps[:, :2])
        if not inside.all() and not (baseline and not inside[0]):
            k = int(np.argmin(inside))
            out.append(f"outside the geofence at +{offs[k]:.2f} s "
                       f"({ps[k, 0]:.2f}, {ps[k, 1]:.2f})")
    min_sep, closest = math.inf, None
    if neighbours is not None and len(neighbours):
        ids = (np.arange(len(neighbours)) if neighbour_ids is None
               else np.asarray(neighbour_ids))
        d = np.linalg.norm(ps[None] - _dense_linear(neighbours, substeps), axis=2)  # (m, T)
        per = d.min(axis=1)
        j = int(np.argmin(per))
        min_sep, closest = float(per[j]), int(ids[j])
        need = np.full(len(per), limits.min_separation)
        if baseline:
            need = np.minimum(need, d[:, 0])
        bad = np.flatnonzero(per < need - DIST_TOL)
        if len(bad):
            b = bad[int(np.argmin(per[bad]))]
            k = int(np.argmin(d[b]))
            more = f" (and {len(bad) - 1} more vehicles)" if len(bad) > 1 else ""
            out.append(f"separation from vehicle {spell(int(ids[b]))} {per[b]:.2f} m at "
                       f"+{offs[k]:.2f} s (min_separation {limits.min_separation} m){more}")
    return TrajectoryCheck(tuple(out), min_sep, closest)


def select_neighbours(guess: FloatArray, neighbours: FloatArray, max_count: int,
                      reach: float) -> IntArray:
    """Indices of the (at most ``max_count``) neighbours that come within ``reach`` of
    ``guess`` (N+1, 3) over the horizon, nearest first (distance at the samples)."""
    if not len(neighbours) or max_count == 0:
        return np.empty(0, dtype=np.intp)
    d = np.linalg.norm(neighbours - guess[None], axis=2).min(axis=1)
    near = np.flatnonzero(d <= reach)
    return near[np.argsort(d[near], kind="stable")][:max_count].astype(np.intp)


@lru_cache(maxsize=16)
def convex_fence(polygon: tuple[tuple[float, float], ...]) -> tuple[FloatArray, FloatArray] | None:
    """Inward unit normals (E, 2) and offsets (E,) of a convex polygon (inside:
    ``n . xy >= offset`` for every edge), or None if it is not convex (or degenerate)."""
    poly = np.asarray(polygon, dtype=float)
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
        return None
    edges = np.roll(poly, -1, axis=0) - poly
    keep = np.linalg.norm(edges, axis=1) > _TINY  # repeated vertices
    poly, edges = poly[keep], edges[keep]
    if len(poly) < 3:
        return None
    nxt = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]
    turn = np.arctan2(cross, np.einsum("ij,ij->i", edges, nxt))
    # Convex and simple: every turn the same way, and once round in all (a pentagram
    # turns the same way throughout but twice round).
    if not (np.all(cross >= -1e-9) or np.all(cross <= 1e-9)) or \
            abs(abs(turn.sum()) - 2 * math.pi) > 1e-6:
        return None
    sign = 1.0 if turn.sum() > 0 else -1.0  # counter-clockwise: inside is on the left
    normals = sign * np.stack([-edges[:, 1], edges[:, 0]], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = np.einsum("ij,ij->i", normals, poly)
    normals.setflags(write=False)
    offsets.setflags(write=False)
    return normals, offsets


def speed_violations(v: FloatArray, lim: Limits, limit_tol: float = 0.01) -> list[str]:
    """Speed limits velocity ``v`` (3,) breaks (by more than ``limit_tol``, a fraction)."""
    out: list[str] = []
    vh = float(np.linalg.norm(v[:2]))
    tol = 1.0 + limit_tol
    if vh > lim.max_speed_h * tol:
        out.append(f"horizontal speed {vh:.2f} m/s above max_speed_h {lim.max_speed_h} m/s")
    if v[2] > lim.max_speed_up * tol:
        out.append(f"climb rate {v[2]:.2f} m/s above max_speed_up {lim.max_speed_up} m/s")
    if -v[2] > lim.max_speed_down * tol:
        out.append(f"descent rate {-v[2]:.2f} m/s above max_speed_down "
                   f"{lim.max_speed_down} m/s")
    return out


def start_violations(request: MpcRequest, limit_tol: float = 0.01) -> list[str]:
    """Limits the measured state already breaks at ``t0``: its speeds (a state to recover
    from, within the envelope), then its position (:func:`position_violations`)."""
    return speed_violations(request.v0, request.limits, limit_tol) + \
        position_violations(request)


def position_violations(request: MpcRequest, *, with_neighbours: bool = True) -> list[str]:
    """Limits the measured position already breaks at ``t0``: its altitude, the geofence,
    a neighbour's separation (of these the MPC recovers only the separation; leave it
    out with ``with_neighbours=False``)."""
    lim, p = request.limits, request.p0
    out: list[str] = []
    if p[2] < lim.min_alt - DIST_TOL or p[2] > lim.max_alt + DIST_TOL:
        out.append(f"altitude {p[2]:.2f} m outside [{lim.min_alt}, {lim.max_alt}] m")
    if lim.geofence and not inside_polygon(np.asarray(lim.geofence, dtype=float), p[None, :2])[0]:
        out.append(f"position ({p[0]:.2f}, {p[1]:.2f}) outside the geofence")
    nb = request.others
    if with_neighbours and len(nb):
        d = np.linalg.norm(nb[:, 0] - p[None], axis=1)
        j = int(np.argmin(d))
        if d[j] < lim.min_separation - DIST_TOL:
            out.append(f"{d[j]:.2f} m from vehicle {spell(int(request.other_ids[j]))} "
                       f"(min_separation {lim.min_separation} m)")
    return out


#: Speed limits (horizontal, climb, descent) an escape may exceed by this fraction
#: (module docstring, "Escape"); accelerations and everything else stay.
ESCAPE_SPEED_MARGIN = 0.2


def escape_limits(limits: Limits) -> Limits:
    """``limits`` with the speeds raised by :data:`ESCAPE_SPEED_MARGIN`."""
    return limits.scaled(1.0 + ESCAPE_SPEED_MARGIN)


def _only_separation(check: TrajectoryCheck) -> bool:
    """Whether ``check`` found a separation shortfall and nothing else."""
    return bool(check.violations) and all(v.startswith("separation") for v in check.violations)
