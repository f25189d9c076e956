"""The quadrotor QP of one group of interacting drones, built once, updated in place.

Decision variables (all flattened C-order): positions P (g, N+1, 3),
velocities V (g, N+1, 3), accelerations A (g, N, 3) held constant over each
step (a double integrator, exact discretisation), and one slack per
separation pair-segment and per obstacle segment S (m + m_o,).

Constraints (rows of OSQP's l <= Ax <= u):

* dynamics: p[k+1] = p[k] + dt v[k] + dt^2/2 a[k],  v[k+1] = v[k] + dt a[k];
* boxes: start/goal positions and end velocities fixed (zero, or the goal's own for
  a drone handed over in motion: :meth:`GroupQP.end_on_the_move`); altitude limits
  and an SCP trust region on interior positions; per-axis speed and
  acceleration boxes;
* tangent planes of the norm limits at the previous iterate,
  n.v_h <= v_max_h and n.a <= a_max (exact at convergence, checked after);
* separation, linearised around the previous iterate pbar (the paper's
  constraint), imposed on *segments*: for pair (i, j) and step k, with the
  normal n taken at the middle of the segment, n.(p_i - p_j) + s >= d' at
  both ends k and k+1, d' the limit plus a numerical buffer.  Both ends sharing
  one normal keeps the whole chord on the safe side.  Between the samples the
  pair's relative motion is a parabola (constant accelerations), which bulges
  from its chord towards the other drone by dt^2 / 8 times n.(a_i - a_j)[k]
  where that is positive: two more rows per pair-segment,
  n.(p_i - p_j) - dt^2/8 n.(a_i - a_j)[k] + s >= d' at both ends, make the
  minimum over the segment of n.(p_i - p_j) at least d' exactly -- the pair's
  own motion, not the most any two drones could bulge (2 a_max dt^2 / 8,
  which a pair whose goal slots are just above the limit could never meet at
  its fixed end).  The slack s >= 0 (l1-penalised) keeps every QP feasible even
  from a straight-line guess that runs two drones through each other;
* obstacle rows: the same four segment rows for a pair whose other drone is
  outside the group, with that drone's trajectory o held fixed, n.p_i + s >=
  n.o + d' at both ends, and less the bulge with the other drone's own
  acceleration on the segment if it flies the same knots (else the worst it can
  have, a_max); the bounds are refreshed from its latest trajectory at every
  linearisation.  They touch the group's own variables only, so they add rows
  but no coupling to the KKT system.

Only the values of the tangent, separation and obstacle rows, the bounds and the linear
cost change between SCP iterations: the sparsity pattern is fixed at build
time, so OSQP factorises the KKT structure once and warm-starts each solve.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import NDArray

from groundctl.plan.profile import JERK_WEIGHT
from groundctl.plan.qp_build import (
    SLACK_WEIGHT,
    FixedPattern,
    RowBuilder,
    chord_normals,
    segment_normals,
    solve_checked,
)
from groundctl.show.model import Limits

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Numerical buffer on separation on top of the geometric tightening, m.
SEPARATION_BUFFER = 0.02


@dataclass(frozen=True)
class PairSegments:
    """Separation rows: drone pair (local indices) and the step k of each segment."""

    i: IntArray
    """(m,) first drone of each pair-segment (group-local index)."""
    j: IntArray
    """(m,) second drone."""
    k: IntArray
    """(m,) segment index: the segment runs from step k to step k+1."""
    extra: FloatArray | None = None
    """(m,) separation asked on top of the tightened limit (tracking margin), m."""


def chord_separation(limits: Limits, dt: float) -> float:
    """The limit a pair's samples must keep so that the trajectories keep it in between:
    each drone may bulge up to a dt^2 / 8 from the chord between two samples."""
    return limits.min_separation + 2 * limits.max_accel * dt * dt / 8


@dataclass(frozen=True)
class ObstacleSegments:
    """Separation rows against drones outside the group, whose trajectory is held fixed."""

    i: IntArray
    """(m,) the group's drone of each pair-segment (group-local index)."""
    k: IntArray
    """(m,) segment index: the segment runs from step k to step k+1."""
    extra: FloatArray | None = None
    """(m,) separation asked on top of the tightened limit (tracking margin), m."""

    @staticmethod
    def empty() -> ObstacleSegments:
        return ObstacleSegments(np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp))


def _extra(rows: PairSegments | ObstacleSegments) -> FloatArray:
    return np.zeros(len(rows.i)) if rows.extra is None else np.asarray(rows.extra, dtype=float)


class GroupQP:
    """The QP for ``g`` drones over one transition."""

    def __init__(self, start: FloatArray, goal: FloatArray, ref: FloatArray, steps: int,
                 dt: float, limits: Limits, pairs: PairSegments, alpha: float, beta: float,
                 osqp_settings: dict[str, float | int | bool],
                 obstacles: ObstacleSegments | None = None) -> None:
        g = start.shape[0]
        n_steps = steps
        self.g, self.N, self.dt, self.limits = g, n_steps, dt, limits
        self.start, self.goal, self.ref = start, goal, ref
        self.goal_vel = np.zeros_like(goal)
        """(g, 3) velocities at the goal: zero (rest to rest) unless
        :meth:`end_on_the_move` set them."""
        self.pairs = pairs
        self.obstacles = obstacles if obstacles is not None else ObstacleSegments.empty()
        self._alpha, self._beta = alpha, beta
        m = len(pairs.i) + len(self.obstacles.i)
        self.nP = g * (n_steps + 1) * 3
        self.nV = self.nP
        self.nA = g * n_steps * 3
        self.nS = m
        self.oV = self.nP
        self.oA = self.oV + self.nV
        self.oS = self.oA + self.nA
        self.nx = self.oS + self.nS
        # Every pair-segment has rows at both ends on the positions alone and rows with
        # the pair's own relative acceleration along the normal (the bulge of its
        # relative parabola from the chord, dt^2 / 8 times that): see _build.
        self.d_sep = limits.min_separation + SEPARATION_BUFFER
        self.bulge = dt * dt / 8.0

        self._build(osqp_settings)

    # -- index helpers --------------------------------------------------------------
    def _ip(self, i: IntArray, k: IntArray, c: int | IntArray) -> IntArray:
        return (i * (self.N + 1) + k) * 3 + c

    def _iv(self, i: IntArray, k: IntArray, c: int | IntArray) -> IntArray:
        return self.oV + (i * (self.N + 1) + k) * 3 + c

    def _ia(self, i: IntArray, k: IntArray, c: int | IntArray) -> IntArray:
        return self.oA + (i * self.N + k) * 3 + c

    def _build(self, settings: dict[str, float | int | bool]) -> None:
        g, N, dt, lim = self.g, self.N, self.dt, self.limits
        rows = RowBuilder()
        # Dynamics: one row per (drone, step, axis).
        gi, kk, cc = (x.ravel() for x in np.meshgrid(np.arange(g), np.arange(N), np.arange(3),
                                                      indexing="ij"))
        nd = len(gi)
        r = np.arange(nd)
        rows.block(nd, np.tile(r, 4),
                   np.concatenate([self._ip(gi, kk + 1, cc), self._ip(gi, kk, cc),
                                   self._iv(gi, kk, cc), self._ia(gi, kk, cc)]),
                   np.concatenate([np.ones(nd), -np.ones(nd), np.full(nd, -dt),
                                   np.full(nd, -0.5 * dt * dt)]))
        rows.block(nd, np.tile(r, 3),
                   np.concatenate([self._iv(gi, kk + 1, cc), self._iv(gi, kk, cc),
                                   self._ia(gi, kk, cc)]),
                   np.concatenate([np.ones(nd), -np.ones(nd), np.full(nd, -dt)]))
        # Boxes on every P, V, A variable and slack.
        nbox = self.nx
        self.box_rows, _ = rows.block(nbox, np.arange(nbox), np.arange(nbox), np.ones(nbox))
        # Tangent planes of the horizontal speed limit at interior steps.
        ti, tk = (x.ravel() for x in np.meshgrid(np.arange(g), np.arange(1, N), indexing="ij"))
        nt = len(ti)
        self.tan_v = (ti, tk)
        self.tan_v_rows, self.tan_v_coo = rows.block(nt, np.tile(np.arange(nt), 2),
                                     np.concatenate([self._iv(ti, tk, 0), self._iv(ti, tk, 1)]),
                                     np.ones(2 * nt))
        # Tangent planes of the acceleration limit.
        ai, ak = (x.ravel() for x in np.meshgrid(np.arange(g), np.arange(N), indexing="ij"))
        na = len(ai)
        self.tan_a = (ai, ak)
        self.tan_a_rows, self.tan_a_coo = rows.block(na, np.tile(np.arange(na), 3),
                                     np.concatenate([self._ia(ai, ak, c) for c in range(3)]),
                                     np.ones(3 * na))
        # Separation: two rows (segment ends) per pair-segment, 6 coefficients + slack.
        p = self.pairs
        m = len(p.i)
        if m:
            end = np.concatenate([p.k, p.k + 1])  # row q < m: start of segment; q >= m: end
            ii = np.concatenate([p.i, p.i])
            jj = np.concatenate([p.j, p.j])
            rr = np.arange(2 * m)
            cols = [self._ip(ii, end, c) for c in range(3)] + [self._ip(jj, end, c)
                                                               for c in range(3)]
            slack = self.oS + np.concatenate([np.arange(m), np.arange(m)])
            self.sep_rows, sep_coo = rows.block(2 * m, np.concatenate([np.tile(rr, 6), rr]),
                                       np.concatenate([*cols, slack]),
                                       np.concatenate([np.ones(12 * m), np.ones(2 * m)]))
            # The slack coefficients (last 2m entries) never change.
            self.sep_coo = slice(sep_coo.start, sep_coo.start + 12 * m)
            # The same rows less the bulge of the pair's relative parabola over segment k:
            # n.(p_i - p_j)(e) - dt^2/8 n.(a_i - a_j)(k) >= limit.  With the rows above,
            # min over the segment of n.(p_i - p_j) >= limit exactly (module docstring).
            kk2 = np.concatenate([p.k, p.k])
            acc = [self._ia(ii, kk2, c) for c in range(3)] + [self._ia(jj, kk2, c)
                                                               for c in range(3)]
            self.bul_rows, bul_coo = rows.block(2 * m, np.concatenate([np.tile(rr, 12), rr]),
                                       np.concatenate([*cols, *acc, slack]),
                                       np.ones(26 * m))
            self.bul_coo = slice(bul_coo.start, bul_coo.start + 24 * m)
        else:
            self.sep_rows = slice(rows.count, rows.count)
            self.sep_coo = slice(rows.nnz, rows.nnz)
            self.bul_rows = slice(rows.count, rows.count)
            self.bul_coo = slice(rows.nnz, rows.nnz)
        # Obstacle rows: the same two segment-end rows, on the group's drone only.
        ob = self.obstacles
        mo = len(ob.i)
        end = np.concatenate([ob.k, ob.k + 1])
        ii = np.concatenate([ob.i, ob.i])
        rr = np.arange(2 * mo)
        slack = self.oS + m + np.concatenate([np.arange(mo), np.arange(mo)])
        self.obs_rows, obs_coo = rows.block(
            2 * mo, np.concatenate([np.tile(rr, 3), rr]),
            np.concatenate([*(self._ip(ii, end, c) for c in range(3)), slack]), np.ones(8 * mo))
        self.obs_coo = slice(obs_coo.start, obs_coo.start + 6 * mo)
        kk2 = np.concatenate([ob.k, ob.k])
        self.obs_bul_rows, obs_bul_coo = rows.block(
            2 * mo, np.concatenate([np.tile(rr, 6), rr]),
            np.concatenate([*(self._ip(ii, end, c) for c in range(3)),
                            *(self._ia(ii, kk2, c) for c in range(3)), slack]),
            np.ones(14 * mo))
        self.obs_bul_coo = slice(obs_bul_coo.start, obs_bul_coo.start + 12 * mo)

        self.n_rows = rows.count
        self._pattern = FixedPattern(rows, self.nx)
        self._values = self._pattern.values
        self.A = self._pattern.matrix

        self._P = self._cost_matrix()
        self.q = np.zeros(self.nx)
        self.q[: self.nP] = -2.0 * self.beta_dt * self.ref.ravel()
        self.q[self.oS:] = SLACK_WEIGHT
        self.l = np.full(self.n_rows, -np.inf)
        self.u = np.full(self.n_rows, np.inf)
        self.l[: 6 * g * N] = 0.0  # both dynamics blocks are equalities
        self.u[: 6 * g * N] = 0.0
        self.u[self.tan_v_rows] = lim.max_speed_h
        self.u[self.tan_a_rows] = lim.max_accel
        self.l[self.sep_rows] = self.d_sep + np.tile(_extra(self.pairs), 2)
        self.l[self.bul_rows] = self.l[self.sep_rows]
        self.l[self.obs_rows] = self.d_sep  # replaced by every linearise()
        self.l[self.obs_bul_rows] = self.d_sep
        self._static_boxes()
        self.solver = osqp.OSQP()
        self._time_limited = False
        self.solver.setup(P=self._P, q=self.q, A=self.A, l=self.l, u=self.u, **settings)

    @property
    def beta_dt(self) -> float:
        """Weight of squared reference deviation per sample (beta times the step)."""
        return self._beta * self.dt

    def _cost_matrix(self) -> sp.csc_matrix:
        g, N, dt = self.g, self.N, self.dt
        # Effort on each drone's accelerations, axis by axis: sum a^2 dt + w sum (da/dt)^2 dt.
        diff = sp.diags([-np.ones(N - 1), np.ones(N - 1)], [0, 1], shape=(N - 1, N))
        h1 = 2.0 * (dt * sp.identity(N) + (JERK_WEIGHT / dt) * (diff.T @ diff))
        # Accelerations are laid out (drone, step, axis): kron over axes inside.
        h_a = sp.kron(sp.identity(g), sp.kron(h1, sp.identity(3)))
        blocks = [
            2.0 * self.beta_dt * sp.identity(self.nP),
            sp.csc_matrix((self.nV, self.nV)),
            self._alpha * h_a,
            1e-3 * sp.identity(self.nS),  # keeps the slack part strictly convex
        ]
        return sp.triu(sp.block_diag(blocks, format="csc"), format="csc")

    def _static_boxes(self) -> None:
        g, N, lim = self.g, self.N, self.limits
        lo = np.full(self.nx, -np.inf)
        hi = np.full(self.nx, np.inf)
        P_lo = lo[: self.nP].reshape(g, N + 1, 3)
        P_hi = hi[: self.nP].reshape(g, N + 1, 3)
        P_lo[:, :, 2] = lim.min_alt
        P_hi[:, :, 2] = lim.max_alt
        # The start and goal may sit below min_alt (a landing grid): never tighter than them.
        P_lo[:, :, 2] = np.minimum(P_lo[:, :, 2], np.minimum(self.start[:, None, 2],
                                                             self.goal[:, None, 2]))
        # End states last: they are equalities and nothing may loosen them afterwards.
        P_lo[:, 0], P_hi[:, 0] = self.start, self.start
        P_lo[:, -1], P_hi[:, -1] = self.goal, self.goal
        V_lo = lo[self.oV: self.oA].reshape(g, N + 1, 3)
        V_hi = hi[self.oV: self.oA].reshape(g, N + 1, 3)
        V_lo[:, :, :2], V_hi[:, :, :2] = -lim.max_speed_h, lim.max_speed_h
        V_lo[:, :, 2], V_hi[:, :, 2] = -lim.max_speed_down, lim.max_speed_up
        V_lo[:, [0, -1]] = 0.0
        V_hi[:, [0, -1]] = 0.0
        lo[self.oA: self.oS] = -lim.max_accel
        hi[self.oA: self.oS] = lim.max_accel
        lo[self.oS:] = 0.0
        self._box_lo, self._box_hi = lo, hi
        self.l[self.box_rows] = lo
        self.u[self.box_rows] = hi

    def end_on_the_move(self, goal_vel: FloatArray, goal_acc: FloatArray | None = None
                        ) -> None:
        """End at the goals with velocities ``goal_vel`` (g, 3), not at rest, and (if
        given) the last step's accelerations ``goal_acc`` (g, 3, each axis clipped to the
        limit): a drone handed over onto a trajectory in motion (a spare joining its
        track mid-transition), without a jump in its setpoints.  Taken by the next
        :meth:`linearise`."""
        g, N = self.g, self.N
        self.goal_vel = np.asarray(goal_vel, dtype=float).reshape(g, 3).copy()
        V_lo = self._box_lo[self.oV: self.oA].reshape(g, N + 1, 3)
        V_hi = self._box_hi[self.oV: self.oA].reshape(g, N + 1, 3)
        V_lo[:, -1], V_hi[:, -1] = self.goal_vel, self.goal_vel
        if goal_acc is not None:
            acc = np.clip(np.asarray(goal_acc, dtype=float).reshape(g, 3),
                          -self.limits.max_accel, self.limits.max_accel)
            A_lo = self._box_lo[self.oA: self.oS].reshape(g, N, 3)
            A_hi = self._box_hi[self.oA: self.oS].reshape(g, N, 3)
            A_lo[:, -1], A_hi[:, -1] = acc, acc

    def linearise(self, P: FloatArray, V: FloatArray, A: FloatArray, trust: float,
                  others: FloatArray | None = None,
                  others_acc: FloatArray | None = None) -> None:
        """Relinearise every iterate-dependent row around (P, V, A) and push to OSQP.

        ``trust`` bounds how far any interior position may move in this solve (m).
        ``others`` (m_o, 2, 3) are the positions of the drone outside the group at
        both ends of each obstacle segment: fixed obstacles for this solve;
        ``others_acc`` (m_o, 3) its (constant) acceleration over the segment, if it
        flies a trajectory of the same knots (else anything within ``max_accel``).
        """
        g, N = self.g, self.N
        # Speed tangent planes at interior steps: normal of the previous horizontal velocity.
        ti, tk = self.tan_v
        vh = V[ti, tk, :2]
        nv = np.linalg.norm(vh, axis=1, keepdims=True)
        n_h = np.where(nv > 1e-6, vh / np.maximum(nv, 1e-12), 0.0)
        self._values[self.tan_v_coo] = np.concatenate([n_h[:, 0], n_h[:, 1]])
        ai, ak = self.tan_a
        av = A[ai, ak]
        na = np.linalg.norm(av, axis=1, keepdims=True)
        n_a = np.where(na > 1e-6, av / np.maximum(na, 1e-12), 0.0)
        self._values[self.tan_a_coo] = n_a.T.ravel()
        p = self.pairs
        m = len(p.i)
        ob = self.obstacles
        if len(ob.i):
            if others is None or others.shape != (len(ob.i), 2, 3):
                raise ValueError("`others` must be (m_o, 2, 3): one segment per obstacle row")
            rel0 = P[ob.i, ob.k] - others[:, 0]
            rel1 = P[ob.i, ob.k + 1] - others[:, 1]
            n_ob = chord_normals(rel0, rel1)
            self._values[self.obs_coo] = np.tile(n_ob, (2, 1)).T.ravel()
            # n.p_i >= n.o + d' at both ends: the chord of p_i - o stays on the safe side.
            self.l[self.obs_rows] = self.d_sep + np.tile(_extra(ob), 2) + np.concatenate([
                np.einsum("md,md->m", n_ob, others[:, 0]),
                np.einsum("md,md->m", n_ob, others[:, 1])])
            # ... and less the bulge: n.p_i - dt^2/8 n.a_i >= that - dt^2/8 n.a_o.
            n2 = np.tile(n_ob, (2, 1))
            self._values[self.obs_bul_coo] = np.concatenate(
                [n2[:, 0], n2[:, 1], n2[:, 2], -self.bulge * n2[:, 0],
                 -self.bulge * n2[:, 1], -self.bulge * n2[:, 2]])
            if others_acc is None:
                their = np.full(len(ob.i), -self.limits.max_accel)  # the worst they can do
            else:
                if others_acc.shape != (len(ob.i), 3):
                    raise ValueError("`others_acc` must be (m_o, 3)")
                their = np.einsum("md,md->m", n_ob, others_acc)
            self.l[self.obs_bul_rows] = self.l[self.obs_rows] - self.bulge * np.tile(their, 2)
        lo = self._box_lo.copy()
        hi = self._box_hi.copy()
        if m:
            n_sep = segment_normals(P, p.i, p.j, p.k)
            coef = np.concatenate([n_sep, n_sep], axis=0)  # both segment ends
            self._values[self.sep_coo] = np.concatenate(
                [coef[:, 0], coef[:, 1], coef[:, 2], -coef[:, 0], -coef[:, 1], -coef[:, 2]])
            b = self.bulge * coef
            self._values[self.bul_coo] = np.concatenate(
                [coef[:, 0], coef[:, 1], coef[:, 2], -coef[:, 0], -coef[:, 1], -coef[:, 2],
                 -b[:, 0], -b[:, 1], -b[:, 2], b[:, 0], b[:, 1], b[:, 2]])
        # Trust region on interior positions, inside the altitude box.
        tr = trust
        P_lo = lo[: self.nP].reshape(g, N + 1, 3)
        P_hi = hi[: self.nP].reshape(g, N + 1, 3)
        P_lo[:, 1:-1] = np.maximum(P_lo[:, 1:-1], P[:, 1:-1] - tr)
        P_hi[:, 1:-1] = np.minimum(P_hi[:, 1:-1], P[:, 1:-1] + tr)
        # An iterate outside the altitude box (a guess) must not empty it: OSQP refuses
        # bounds that cross and would keep solving on the old ones.
        np.minimum(P_lo, P_hi, out=P_lo)
        self.l[self.box_rows] = lo
        self.u[self.box_rows] = hi
        self.solver.update(Ax=self._pattern.refresh(), l=self.l, u=self.u)
        x0 = np.concatenate([P.ravel(), V.ravel(), A.ravel(), np.zeros(self.nS)])
        self.solver.warm_start(x=x0)

    def solve(self, transition: int, time_limit: float = 0.0
              ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Solve; return (P, V, A, slack).  Raises PlanningError unless OSQP solved it
        (OSQP stops at ``time_limit`` seconds if given: status "run time limit reached")."""
        time_left = None
        if time_limit > 0 or self._time_limited:
            self.solver.update_settings(time_limit=max(time_limit, 0.0))
            self._time_limited = time_limit > 0
        if time_limit > 0:
            until = time.perf_counter() + time_limit

            def time_left() -> float:
                return until - time.perf_counter()
        x = solve_checked(self.solver, transition,
                          f"{self.g} drones, {self.N} steps, {len(self.pairs.i)} pair-segments, "
                          f"{len(self.obstacles.i)} obstacle segments", time_left)
        g, N = self.g, self.N
        P = x[: self.nP].reshape(g, N + 1, 3).copy()
        V = x[self.oV: self.oA].reshape(g, N + 1, 3).copy()
        A = x[self.oA: self.oS].reshape(g, N, 3).copy()
        S = x[self.oS:].copy()
        # End states are equalities by construction; ADMM only meets them to its
        # tolerance (1e-7 when polishing fails), so return them exactly.
        P[:, 0], P[:, -1] = self.start, self.goal
        V[:, 0], V[:, -1] = 0.0, self.goal_vel
        return P, V, A, S
