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


def _ends(steps: int, dt: float) -> NDArray[np.float64]:
    """(2, N): the final position and velocity of a rest-to-rest profile as linear
    functions of its accelerations."""
    k = np.arange(steps)
    return np.vstack([dt * dt * (0.5 + (steps - 1 - k)), np.full(steps, dt)])


def _integrate(a: NDArray[np.float64], dt: float) -> Profile:
    """The profile of accelerations ``a`` from rest at 0, its end set exactly to rest at 1
    (the caller has checked it gets there)."""
    v = np.concatenate([[0.0], np.cumsum(a * dt)])
    s = np.concatenate([[0.0], np.cumsum(v[:-1] * dt + 0.5 * a * dt * dt)])
    v[-1] = 0.0  # exact zero, not 1e-17
    s[-1] = 1.0
    return Profile(s=s, ds=v, dds=a)


@lru_cache(maxsize=64)
def rest_to_rest(steps: int, dt: float) -> Profile:
    """Minimum-effort profile: s0 = 0, v0 = 0, sN = 1, vN = 0, acceleration piecewise constant."""
    if steps < 2:
        raise ValueError("`steps` must be at least 2")
    c = _ends(steps, dt)
    hess = effort_hessian(steps, dt)
    hinv_ct = np.linalg.solve(hess, c.T)
    a = hinv_ct @ np.linalg.solve(c @ hinv_ct, np.array([1.0, 0.0]))
    return _integrate(np.asarray(a, dtype=np.float64), dt)


#: Caps of :func:`capped_profile` are rounded down onto a geometric grid of this ratio,
#: so drones with nearly the same caps share one solve (and stay within their own).
CAP_GRID = 1.002


def _grid_down(x: float) -> float:
    return float(CAP_GRID ** np.floor(np.log(x) / np.log(CAP_GRID)))


def capped_profile(steps: int, dt: float, ds_max: float, dds_max: float) -> Profile | None:
    """The minimum-effort rest-to-rest profile with ``|ds| <= ds_max`` (1/s) and
    ``|dds| <= dds_max`` (1/s^2), or None if no profile of ``steps`` steps keeps them.

    The unconstrained profile (:func:`rest_to_rest`) peaks at 1.5 times the mean speed;
    a transition given less than 1.5 times the time a trapezoidal speed profile needs
    (:func:`~groundctl.plan.feasibility.min_transition_time`) breaks the speed limit of
    its longest movers on it.  Their straight line with this profile keeps the limits.
    The caps are rounded down a little (:data:`CAP_GRID`), so the result keeps them
    exactly although OSQP's equalities only hold to its tolerance."""
    if ds_max <= 0 or dds_max <= 0:
        raise ValueError("`ds_max` and `dds_max` must be positive")
    return _capped(steps, dt, _grid_down(ds_max), _grid_down(dds_max))


@lru_cache(maxsize=4096)
def _capped(steps: int, dt: float, ds_max: float, dds_max: float) -> Profile | None:
    import osqp
    import scipy.sparse as sp

    # s_N = 1, v_N = 0, then v_k = dt sum_{i<k} a_i (k = 1..N-1) and a itself, boxed.
    tril = np.tril(np.ones((steps - 1, steps)) * dt, 0)
    a_mat = sp.csc_matrix(np.vstack([_ends(steps, dt), tril, np.eye(steps)]))
    # A little inside the caps: what ADMM leaves over stays within them.
    v_cap, a_cap = ds_max * (1 - 1e-3), dds_max * (1 - 1e-3)
    lo = np.concatenate([[1.0, 0.0], np.full(steps - 1, -v_cap), np.full(steps, -a_cap)])
    hi = np.concatenate([[1.0, 0.0], np.full(steps - 1, v_cap), np.full(steps, a_cap)])
    solver = osqp.OSQP()
    solver.setup(P=sp.triu(sp.csc_matrix(effort_hessian(steps, dt)), format="csc"),
                 q=np.zeros(steps), A=a_mat, l=lo, u=hi, verbose=False, eps_abs=1e-6,
                 eps_rel=1e-6, max_iter=20000, polishing=True, polish_refine_iter=10)
    res = solver.solve(raise_error=False)
    if res.info.status not in ("solved", "solved inaccurate"):
        return None
    a = np.asarray(res.x, dtype=float)
    end_s, end_v = _ends(steps, dt) @ a
    v = np.cumsum(a * dt)
    if (abs(end_s - 1.0) > 1e-6 or abs(end_v) > 1e-6 or np.abs(v).max() > ds_max
            or np.abs(a).max() > dds_max):
        return None
    return _integrate(a, dt)
