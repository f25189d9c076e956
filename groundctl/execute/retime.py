"""A weak vehicle's path, re-timed to what it can fly: the MPC's long view.  Pure.

A vehicle that cannot fly as fast as its path (a weak motor, a tired battery, a
headwind: :mod:`groundctl.execute.authority` measures its speed ceilings) falls
behind wherever the path is faster than it can go, and the lag only grows
until the path slows down.  The MPC's 3 s horizon cannot help: no correction
within 3 s makes it faster.  What can is to start earlier: a vehicle that sets
off before its path does is ahead at first and behind at the end, and the
largest error can be about half the lag that simply following gives.  That
needs a view of the whole fast stretch, tens of seconds.

:class:`Retimer` solves that view as one QP over ``steps`` steps of ``dt``
(20 s in 0.25 s steps by default), a double integrator from the vehicle's state::

    minimise   W s + sum_k dt |q_k - p_k|^2 + w_a sum_k dt |a_k|^2
    subject to |q_k - p_k|_inf <= s            (the largest error, per axis)
               -down <= v_z <= up,  f . v_xy <= speed_h cos(pi/F)   (F faces)
               |a_k|_inf <= a_max
               q_0 = p0, v_0 = v0, dynamics

where p is the path and the limits are the vehicle's ceilings.  The min-max term
is what makes it set off early (a quadratic cost alone also leads, but less);
the quadratic term picks, among the min-max solutions, the one closest to the
path everywhere else.  The result is a *reference* for the MPC, not a
trajectory flown as it is: the MPC tracks it over its own horizon with its own
limits and its neighbours' predictions, and verifies what it sends.

Built once per vehicle (fixed sparsity); each solve changes only ``q``, ``l``
and ``u`` and warm-starts from the last solution shifted to the new start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from groundctl.show.model import Limits

FloatArray = NDArray[np.float64]

#: OSQP settings: the reference only needs centimetres.
RETIME_OSQP: dict[str, float | int | bool] = {
    "verbose": False, "eps_abs": 1e-3, "eps_rel": 1e-3, "max_iter": 4000, "time_limit": 0.05,
    "polishing": False, "adaptive_rho": True, "warm_starting": True,
}
_ACCEPTED = ("solved", "solved inaccurate")


@dataclass(frozen=True)
class Retimed:
    """A re-timed reference: positions, velocities and accelerations at ``t0 + k dt``."""

    t0: float
    dt: float
    pos: FloatArray
    """(L+1, 3)."""
    vel: FloatArray
    """(L+1, 3)."""
    acc: FloatArray
    """(L, 3), held over each step."""
    max_error_m: float
    """The largest per-axis distance from the path it accepts (the min-max value)."""

    @property
    def end(self) -> float:
        return self.t0 + self.dt * (len(self.pos) - 1)

    def sample(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(T, 3) position, velocity, acceleration at show times ``t`` (T,), exact on the
        piecewise-quadratic reference; held at its ends outside it."""
        t = np.asarray(t, dtype=float)
        u = np.clip((t - self.t0) / self.dt, 0.0, len(self.acc) - 1e-9)
        k = np.minimum(u.astype(np.intp), len(self.acc) - 1)
        tau = ((u - k) * self.dt)[:, None]
        a = self.acc[k]
        pos = self.pos[k] + self.vel[k] * tau + 0.5 * a * tau * tau
        vel = self.vel[k] + a * tau
        past = (t > self.end)[:, None]
        return (np.where(past, self.pos[-1] + self.vel[-1] * (t - self.end)[:, None], pos),
                np.where(past, self.vel[-1], vel), np.where(past, 0.0, a))


def clip_speed(vel: ArrayLike, limits: Limits, h_scale: float = 1.0) -> FloatArray:
    """``vel`` (3,) with its horizontal speed within ``h_scale`` times the limit and its
    vertical rate within the climb and descent limits."""
    out = np.array(vel, dtype=float)
    vh_max = limits.max_speed_h * h_scale
    vh = float(np.hypot(out[0], out[1]))
    if vh > vh_max:
        out[:2] *= vh_max / vh
    out[2] = min(max(out[2], -limits.max_speed_down), limits.max_speed_up)
    return out


class Retimer:
    """One vehicle's re-timing QP, built once (see the module docstring)."""

    def __init__(self, steps: int = 80, dt: float = 0.25, faces: int = 8,
                 minmax_weight: float = 200.0, accel_weight: float = 0.05,
                 osqp_settings: dict[str, float | int | bool] | None = None) -> None:
        if steps < 2 or not dt > 0 or faces < 4:
            raise ValueError("`steps` must be at least 2, `dt` positive, `faces` at least 4")
        self.steps, self.dt, self.faces = steps, dt, faces
        L = steps
        # x = [Q (L+1,3) | V (L+1,3) | A (L,3) | s]
        self.oV, self.oA, self.oS = 3 * (L + 1), 6 * (L + 1), 6 * (L + 1) + 3 * L
        self.nx = self.oS + 1
        eye3 = sp.identity(3, format="csc")
        shift = sp.eye(L, L + 1, 1, format="csc") - sp.eye(L, L + 1, 0, format="csc")
        head = sp.eye(L, L + 1, 0, format="csc")
        # Dynamics: q[k+1] - q[k] - dt v[k] - dt^2/2 a[k] = 0;  v[k+1] - v[k] - dt a[k] = 0.
        dyn_q = sp.hstack([sp.kron(shift, eye3), -dt * sp.kron(head, eye3),
                           -0.5 * dt * dt * sp.kron(sp.identity(L), eye3),
                           sp.csc_matrix((3 * L, 1))])
        dyn_v = sp.hstack([sp.csc_matrix((3 * L, 3 * (L + 1))), sp.kron(shift, eye3),
                           -dt * sp.kron(sp.identity(L), eye3), sp.csc_matrix((3 * L, 1))])
        pick = np.zeros((6, self.nx))
        pick[0:3, 0:3] = np.eye(3)
        pick[3:6, self.oV:self.oV + 3] = np.eye(3)
        start_rows = sp.csc_matrix(pick)
        # |q_k - p_k| <= s per axis: q - s <= p and q + s >= p.
        qsel = sp.hstack([sp.identity(3 * (L + 1)), sp.csc_matrix((3 * (L + 1), self.nx
                                                                      - 3 * (L + 1)))])
        s_col = sp.lil_matrix((3 * (L + 1), self.nx))
        s_col[:, self.oS] = 1.0
        dev_hi = (qsel - s_col).tocsc()
        dev_lo = (qsel + s_col).tocsc()
        # Vertical speed rows, horizontal speed faces, acceleration boxes, s >= 0.
        vz = sp.lil_matrix((L + 1, self.nx))
        for k in range(L + 1):
            vz[k, self.oV + 3 * k + 2] = 1.0
        ang = 2 * math.pi * np.arange(faces) / faces
        face = sp.lil_matrix((faces * (L + 1), self.nx))
        for k in range(L + 1):
            for f in range(faces):
                face[faces * k + f, self.oV + 3 * k] = math.cos(ang[f])
                face[faces * k + f, self.oV + 3 * k + 1] = math.sin(ang[f])
        abox = sp.hstack([sp.csc_matrix((3 * L, self.oA)), sp.identity(3 * L),
                          sp.csc_matrix((3 * L, 1))])
        sbox = sp.lil_matrix((1, self.nx))
        sbox[0, self.oS] = 1.0
        self.A = sp.vstack([dyn_q, dyn_v, start_rows, dev_hi, dev_lo, vz.tocsc(), face.tocsc(),
                            abox, sbox.tocsc()], format="csc")
        n = self.A.shape[0]
        self.r_dyn = slice(0, 6 * L)
        self.r_start = slice(6 * L, 6 * L + 6)
        o = 6 * L + 6
        self.r_hi = slice(o, o + 3 * (L + 1))
        self.r_lo = slice(self.r_hi.stop, self.r_hi.stop + 3 * (L + 1))
        self.r_vz = slice(self.r_lo.stop, self.r_lo.stop + L + 1)
        self.r_face = slice(self.r_vz.stop, self.r_vz.stop + faces * (L + 1))
        self.r_acc = slice(self.r_face.stop, self.r_face.stop + 3 * L)
        self.r_s = slice(self.r_acc.stop, n)
        assert self.r_s.stop - self.r_s.start == 1
        self.l = np.full(n, -np.inf)
        self.u = np.full(n, np.inf)
        self.l[self.r_dyn] = self.u[self.r_dyn] = 0.0
        self.l[self.r_s] = 0.0
        # Cost: sum dt |q - p|^2 + w_a dt |a|^2 + W s (the linear term carries -2 dt p).
        diag = np.zeros(self.nx)
        diag[: self.oV] = 2.0 * dt
        diag[self.oA: self.oS] = 2.0 * accel_weight * dt
        diag[self.oS] = 1e-6
        self.P = sp.diags(diag, format="csc")
        self.q = np.zeros(self.nx)
        self.q[self.oS] = minmax_weight
        self.solver = osqp.OSQP()
        settings = RETIME_OSQP if osqp_settings is None else osqp_settings
        self.solver.setup(self.P, self.q, self.A, self.l, self.u, **settings)
        self._last: Retimed | None = None

    def solve(self, t0: float, path_pos: FloatArray, p0: FloatArray, v0: FloatArray,
              limits: Limits) -> Retimed | None:
        """The re-timed reference from (p0, v0) at show time ``t0`` given the path's
        positions ``path_pos`` (L+1, 3) at ``t0 + k dt``; None if OSQP did not solve it
        (the caller keeps the path as the reference)."""
        L, dt = self.steps, self.dt
        path = np.asarray(path_pos, dtype=float)
        if path.shape != (L + 1, 3):
            raise ValueError(f"`path_pos` must have shape ({L + 1}, 3), got {path.shape}")
        base = np.asarray(p0, dtype=float)
        rel = path - base  # around zero: OSQP scales better
        self.q[: self.oV] = -2.0 * dt * rel.ravel()
        # Start within the limits (a start beyond them has no solution at all): the
        # horizontal speed inside the face polygon, the vertical rate inside its bounds.
        start_v = clip_speed(v0, limits, math.cos(math.pi / self.faces))
        self.l[self.r_start] = self.u[self.r_start] = np.concatenate([np.zeros(3), start_v])
        self.u[self.r_hi] = rel.ravel()
        self.l[self.r_lo] = rel.ravel()
        # The start is where the vehicle is: its distance is no choice of the QP's (and
        # pinning s to it leaves ADMM a flat optimum to crawl along).
        self.u[self.r_hi.start: self.r_hi.start + 3] = np.inf
        self.l[self.r_lo.start: self.r_lo.start + 3] = -np.inf
        self.l[self.r_vz] = -limits.max_speed_down
        self.u[self.r_vz] = limits.max_speed_up
        self.u[self.r_face] = limits.max_speed_h * math.cos(math.pi / self.faces)
        a_box = limits.max_accel  # per axis: the MPC that tracks it keeps the norm
        self.l[self.r_acc], self.u[self.r_acc] = -a_box, a_box
        self.solver.update(q=self.q, l=self.l, u=self.u)
        last = self._last
        if last is not None and t0 < last.end:
            lp, lv, la = last.sample(t0 + dt * np.arange(L + 1))
            x0 = np.concatenate([(lp - base).ravel(), lv.ravel(), la[:-1].ravel(),
                                 [last.max_error_m]])
            self.solver.warm_start(x=x0)
        res = self.solver.solve(raise_error=False)
        if str(res.info.status) not in _ACCEPTED:
            return None
        x = np.asarray(res.x)
        acc = x[self.oA: self.oS].reshape(L, 3)
        # Roll the accelerations out exactly (ADMM meets the dynamics only to tolerance).
        pos = np.empty((L + 1, 3))
        vel = np.empty((L + 1, 3))
        pos[0], vel[0] = base, start_v
        for k in range(L):
            pos[k + 1] = pos[k] + dt * vel[k] + 0.5 * dt * dt * acc[k]
            vel[k + 1] = vel[k] + dt * acc[k]
        out = Retimed(float(t0), dt, pos, vel, acc.copy(), float(x[self.oS]))
        self._last = out
        return out
