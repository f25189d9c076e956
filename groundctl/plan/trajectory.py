"""Piecewise-cubic trajectories for a whole fleet on shared knot times.

Every drone's trajectory is the cubic Hermite interpolant of its knot
positions and velocities.  For the quadrotor model (a double integrator with
acceleration held constant between knots) the flown path between two knots is
a quadratic, which a cubic Hermite interpolant reproduces exactly: what we
verify here is what the optimiser planned, not an approximation of it.  For
the unicycle model it is the paper's cubic-spline smoothing of the samples.

All drones share one knot vector, so evaluation at time t is one
``searchsorted`` and a few vectorised multiply-adds over the fleet.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Trajectories:
    """Fleet trajectories: cubic Hermite segments between shared knots."""

    times: FloatArray
    """(K,) strictly increasing knot times, s."""
    pos: FloatArray
    """(n, K, 3) positions at the knots, show-frame metres."""
    vel: FloatArray
    """(n, K, 3) velocities at the knots, m/s."""

    def __post_init__(self) -> None:
        if self.times.ndim != 1 or len(self.times) < 2:
            raise ValueError("`times` must hold at least two knots")
        if np.any(np.diff(self.times) <= 0):
            raise ValueError("`times` must be strictly increasing")
        if self.pos.shape != self.vel.shape or self.pos.shape[1] != len(self.times):
            raise ValueError("`pos` and `vel` must both be (n, K, 3) with K knots")

    @property
    def drones(self) -> int:
        return int(self.pos.shape[0])

    @property
    def start(self) -> float:
        return float(self.times[0])

    @property
    def end(self) -> float:
        return float(self.times[-1])

    def _coefficients(self, t: FloatArray) -> tuple[NDArray[np.intp], FloatArray, FloatArray]:
        t = np.clip(np.asarray(t, dtype=float), self.times[0], self.times[-1])
        seg = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2)
        h = self.times[seg + 1] - self.times[seg]
        s = (t - self.times[seg]) / h
        return seg, s, h

    def evaluate(self, t: FloatArray | float, drones: NDArray[np.intp] | None = None
                 ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, velocity, acceleration of every drone (or of ``drones``) at times ``t``.

        ``t`` scalar gives (n, 3) arrays; ``t`` of shape (T,) gives (n, T, 3).
        Times outside the knots are clamped (the fleet holds its end states).
        """
        scalar = np.ndim(t) == 0
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        seg, s, h = self._coefficients(tt)
        pos_k = self.pos if drones is None else self.pos[drones]
        vel_k = self.vel if drones is None else self.vel[drones]
        p0, p1 = pos_k[:, seg], pos_k[:, seg + 1]
        m0, m1 = vel_k[:, seg] * h[None, :, None], vel_k[:, seg + 1] * h[None, :, None]
        s = s[None, :, None]
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        pos = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
        d00, d10, d01, d11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
        hh = h[None, :, None]
        vel = (d00 * p0 + d10 * m0 + d01 * p1 + d11 * m1) / hh
        e00, e10, e01, e11 = 12 * s - 6, 6 * s - 4, -12 * s + 6, 6 * s - 2
        acc = (e00 * p0 + e10 * m0 + e01 * p1 + e11 * m1) / (hh * hh)
        if scalar:
            return pos[:, 0], vel[:, 0], acc[:, 0]
        return pos, vel, acc

    def evaluate_each(self, t: FloatArray, drones: NDArray[np.intp]
                      ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, velocity, acceleration (m, 3) of ``drones[k]`` at its own time ``t[k]``
        (clamped to the knots, like :meth:`evaluate`)."""
        tt = np.asarray(t, dtype=float)
        rows = np.asarray(drones, dtype=np.intp)
        if tt.shape != rows.shape or tt.ndim != 1:
            raise ValueError("`t` and `drones` must be 1-D arrays of the same length")
        seg, s, h = self._coefficients(tt)
        p0, p1 = self.pos[rows, seg], self.pos[rows, seg + 1]
        hh = h[:, None]
        m0, m1 = self.vel[rows, seg] * hh, self.vel[rows, seg + 1] * hh
        s = s[:, None]
        s2, s3 = s * s, s * s * s
        pos = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 \
            + (s3 - s2) * m1
        vel = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * m0 + (-6 * s2 + 6 * s) * p1
               + (3 * s2 - 2 * s) * m1) / hh
        acc = ((12 * s - 6) * p0 + (6 * s - 4) * m0 + (-12 * s + 6) * p1
               + (6 * s - 2) * m1) / (hh * hh)
        return pos, vel, acc

    def dense_times(self, per_segment: int) -> FloatArray:
        """Knot times with ``per_segment - 1`` evenly spaced times between each pair."""
        frac = np.arange(per_segment) / per_segment
        inner = self.times[:-1, None] + np.diff(self.times)[:, None] * frac[None, :]
        return np.concatenate([inner.ravel(), self.times[-1:]])

    def path_lengths(self, per_segment: int = 16) -> FloatArray:
        """(n,) arc length of every drone's path, m."""
        pos, _, _ = self.evaluate(self.dense_times(per_segment))
        return np.linalg.norm(np.diff(pos, axis=1), axis=2).sum(axis=1)

    def shifted(self, offset: float) -> Trajectories:
        """The same trajectories with every time moved by ``offset`` seconds."""
        return Trajectories(self.times + offset, self.pos, self.vel)


def hold(positions: FloatArray, start: float, duration: float) -> Trajectories:
    """Every drone motionless at ``positions`` (n, 3) from ``start`` for ``duration``."""
    if duration <= 0:
        raise ValueError("`duration` must be positive")
    pos = np.repeat(np.asarray(positions, dtype=float)[:, None, :], 2, axis=1)
    return Trajectories(np.array([start, start + duration]), pos, np.zeros_like(pos))


def concatenate(parts: list[Trajectories]) -> Trajectories:
    """Join consecutive trajectories end to start (shared boundary knots merged)."""
    if not parts:
        raise ValueError("`parts` must not be empty")
    times = [parts[0].times]
    pos = [parts[0].pos]
    vel = [parts[0].vel]
    for prev, part in itertools.pairwise(parts):
        if abs(part.start - prev.end) > 1e-9:
            raise ValueError(f"trajectories do not meet: {prev.end} s then {part.start} s")
        times.append(part.times[1:])
        pos.append(part.pos[:, 1:])
        vel.append(part.vel[:, 1:])
    return Trajectories(np.concatenate(times), np.concatenate(pos, axis=1),
                        np.concatenate(vel, axis=1))
