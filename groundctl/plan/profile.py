"""The minimum-effort rest-to-rest profile along a straight line.

With no neighbours and no active limits, the quadrotor QP is linear in its
boundary data, so every drone's optimum is the same scalar profile s(t) from
0 to 1 scaled onto its own line: p_k = start + s_k (goal - start).  We solve
that tiny problem once per (N, dt) and use it as the reference trajectory and
straight-line initial guess of the SCP; drones that never come near another
drone and stay within the limits on it need no QP at all.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

#: Weight of squared jerk against squared acceleration in the effort cost, s^2.
JERK_WEIGHT = 0.1


@dataclass(frozen=True)
class Profile:
    """Scalar rest-to-rest profile on N steps of a double integrator."""

    s: NDArray[np.float64]
    """(N+1,) progress from 0 to 1."""
    ds: NDArray[np.float64]
    """(N+1,) d s / dt, 1/s (zero at both ends)."""
    dds: NDArray[np.float64]
    """(N,) d2 s / dt2 held constant over each step, 1/s^2."""


def effort_hessian(steps: int, dt: float) -> NDArray[np.float64]:
    """Hessian of sum(a^2 dt) + JERK_WEIGHT sum(((a_{k+1} - a_k)/dt)^2 dt) in a (N,)."""
    diff = np.diff(np.eye(steps), axis=0)
    return 2.0 * (dt * np.eye(steps) + (JERK_WEIGHT / dt) * diff.T @ diff)


@lru_cache(maxsize=64)
def rest_to_rest(steps: int, dt: float) -> Profile:
    """Minimum-effort profile: s0 = 0, v0 = 0, sN = 1, vN = 0, acceleration piecewise constant."""
    if steps < 2:
        raise ValueError("`steps` must be at least 2")
    k = np.arange(steps)
    # Final velocity and position as linear functions of the accelerations.
    c_v = np.full(steps, dt)
    c_s = dt * dt * (0.5 + (steps - 1 - k))
    c = np.vstack([c_s, c_v])
    hess = effort_hessian(steps, dt)
    hinv_ct = np.linalg.solve(hess, c.T)
    a = hinv_ct @ np.linalg.solve(c @ hinv_ct, np.array([1.0, 0.0]))
    v = np.concatenate([[0.0], np.cumsum(a * dt)])
    s = np.concatenate([[0.0], np.cumsum(v[:-1] * dt + 0.5 * a * dt * dt)])
    v[-1] = 0.0  # exact zero, not 1e-17
    s[-1] = 1.0
    return Profile(s=s, ds=v, dds=a)
