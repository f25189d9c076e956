"""One vehicle's QP (package docstring, from "Model" to "Solver settings"): its rows laid
out once, the cost, limits, cuts and separation rows refreshed every tick around a
linearisation point, neighbour slots kept, and the warm start."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sp

from groundctl.execute.mpc.checks import _TINY, convex_fence, select_neighbours, speed_envelope
from groundctl.execute.mpc.types import (
    FloatArray,
    IntArray,
    MpcConfig,
    MpcRequest,
    MpcResult,
    _sample,
)
from groundctl.execute.retime import Retimed, Retimer
from groundctl.plan.qp_build import FixedPattern, RowBuilder, chord_normals
from groundctl.plan.quad_qp import SEPARATION_BUFFER, chord_separation

#: Inside a neighbour's separation at the start (pushed there), the MPC asks the
#: distance to grow at least this fast until the limit is met again, m/s.
RECOVERY_MPS = 0.75
#: The QP's speed envelope closes this much faster than the one a solution is verified
#: against (package docstring, "Envelope").
ENVELOPE_QP_MARGIN = 1.25


@dataclass(frozen=True)
class _Plan:
    """The rollout of the last QP solution, accepted or not: the next linearisation point."""

    t0: float
    pos: FloatArray
    vel: FloatArray
    acc: FloatArray
    duals: FloatArray
    """OSQP's duals of that solution (shifted for the next warm start)."""


class MpcQp:
    """One vehicle's MPC QP: built once, updated and warm-started every tick
    (:class:`~groundctl.execute.mpc.controller.MpcController` solves it)."""

    def __init__(self, sysid: int, config: MpcConfig | None = None,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        """``clock`` times the solve (:attr:`MpcResult.solve_ms`, and how long a pass
        stopped by OSQP's wall-time limit is resumed: module docstring)."""
        self.sysid = sysid
        self.config = config if config is not None else MpcConfig()
        self._clock = clock
        c = self.config
        self.N, self.dt = c.steps, c.dt
        self.M, self.E, self.F = c.max_neighbours, c.max_fence_edges, c.speed_faces
        self._build()
        self._last: MpcResult | None = None
        self._escaped = False  # the last result flown was an escape (or went on with one)
        self._continuing = False
        self._lin: _Plan | None = None
        self._slot_ids = np.full(self.M, -1, dtype=np.intp)
        self._start_distance: FloatArray | None = None
        self._retimer: Retimer | None = None
        self._retimed: Retimed | None = None
        self._retimed_from: tuple[float, float, FloatArray] | None = None
        """The path ahead the reference was re-timed from: start, step, samples."""
        self._streamed: MpcRequest | None = None

    # -- layout -----------------------------------------------------------------------
    def _ip(self, k: IntArray, c: int | IntArray) -> IntArray:
        return 3 * k + c

    def _iv(self, k: IntArray, c: int | IntArray) -> IntArray:
        return self.oV + 3 * k + c

    def _ia(self, k: IntArray, c: int | IntArray) -> IntArray:
        return self.oA + 3 * k + c

    def _build(self) -> None:
        N, dt, M, E, F = self.N, self.dt, self.M, self.E, self.F
        self.nP = 3 * (N + 1)
        self.oV = self.nP
        self.oA = 2 * self.nP
        self.oSs = self.oA + 3 * N  # separation slacks: one per separation row
        self.oSe = self.oSs + 2 * M * N  # envelope slacks: one per step 1..N
        self.nx = self.oSe + N

        def env_cols(k_of_row: IntArray) -> IntArray:
            return self.oSe + k_of_row - 1

        rows = RowBuilder()
        kk, cc = (x.ravel() for x in np.meshgrid(np.arange(N), np.arange(3), indexing="ij"))
        nd = 3 * N
        r = np.arange(nd)
        self.dyn_rows, _ = rows.block(
            nd, np.tile(r, 4),
            np.concatenate([self._ip(kk + 1, cc), self._ip(kk, cc), self._iv(kk, cc),
                            self._ia(kk, cc)]),
            np.concatenate([np.ones(nd), -np.ones(nd), np.full(nd, -dt),
                            np.full(nd, -0.5 * dt * dt)]))
        rows.block(nd, np.tile(r, 3),
                   np.concatenate([self._iv(kk + 1, cc), self._iv(kk, cc), self._ia(kk, cc)]),
                   np.concatenate([np.ones(nd), -np.ones(nd), np.full(nd, -dt)]))
        init_cols = np.concatenate([np.arange(3), self.oV + np.arange(3)])
        self.init_rows, _ = rows.block(6, np.arange(6), init_cols, np.ones(6))
        self.abox_rows, _ = rows.block(nd, r, self.oA + r, np.ones(nd))
        ns = self.nx - self.oSs
        self.sbox_rows, _ = rows.block(ns, np.arange(ns), self.oSs + np.arange(ns), np.ones(ns))
        # Acceleration cuts: C = passes tangent planes per step, row k C + c; COO order
        # [x of all rows, y..., z...].  Pass p sets cut p - 1 and keeps the earlier ones.
        C = self.config.passes
        kc = np.repeat(np.arange(N), C)
        self.acut_rows, self.acut_coo = rows.block(
            N * C, np.tile(np.arange(N * C), 3),
            np.concatenate([self._ia(kc, c) for c in range(3)]),
            np.full(3 * N * C, 1 / math.sqrt(3)))
        # Horizontal speed polygon at steps 1..N: row (k-1) F + f; [vx..., vy..., slack...].
        kf = np.repeat(np.arange(1, N + 1), F)
        nf = N * F
        ang = 2 * math.pi * np.arange(F) / F
        self.vpoly_rows, coo = rows.block(
            nf, np.tile(np.arange(nf), 3),
            np.concatenate([self._iv(kf, 0), self._iv(kf, 1), env_cols(kf)]),
            np.concatenate([np.tile(np.cos(ang), N), np.tile(np.sin(ang), N), -np.ones(nf)]))
        self.vpoly_coo = slice(coo.start, coo.start + 2 * nf)
        # Speed cuts of the later passes: row (k-1) (C-1) + c, like the polygon's.
        kv = np.repeat(np.arange(1, N + 1), C - 1)
        nv = len(kv)
        self.vcut_rows, coo = rows.block(
            nv, np.tile(np.arange(nv), 3),
            np.concatenate([self._iv(kv, 0), self._iv(kv, 1), env_cols(kv)]),
            np.concatenate([np.full(2 * nv, 1 / math.sqrt(2)), -np.ones(nv)]))
        self.vcut_coo = slice(coo.start, coo.start + 2 * nv)
        # Climb/descent and altitude: rows 2 (k-1) + e, e = 0 upper (value - s <= u),
        # e = 1 lower (value + s >= l).
        k2 = np.repeat(np.arange(1, N + 1), 2)
        sgn = np.tile([-1.0, 1.0], N)
        self.vz_rows, _ = rows.block(2 * N, np.tile(np.arange(2 * N), 2),
                                     np.concatenate([self._iv(k2, 2), env_cols(k2)]),
                                     np.concatenate([np.ones(2 * N), sgn]))
        self.alt_rows, _ = rows.block(2 * N, np.tile(np.arange(2 * N), 2),
                                      np.concatenate([self._ip(k2, 2), env_cols(k2)]),
                                      np.concatenate([np.ones(2 * N), sgn]))
        # Geofence: row (k-1) E + e; [x..., y..., slack...].
        ke = np.repeat(np.arange(1, N + 1), E)
        ne = N * E
        self.fence_rows, coo = rows.block(
            ne, np.tile(np.arange(ne), 3),
            np.concatenate([self._ip(ke, 0), self._ip(ke, 1), env_cols(ke)]),
            np.concatenate([np.full(2 * ne, 1 / math.sqrt(2)), np.ones(ne)]))
        self.fence_coo = slice(coo.start, coo.start + 2 * ne)
        # Separation: slot j, segment k, end e -> row (j N + k) 2 + e, on p_{k+e}.
        ends = np.tile(np.concatenate([np.arange(N)[:, None], np.arange(1, N + 1)[:, None]],
                                      axis=1).ravel(), M)
        ns_rows = 2 * N * M
        self.sep_rows, coo = rows.block(
            ns_rows, np.tile(np.arange(ns_rows), 4),
            np.concatenate([*(self._ip(ends, c) for c in range(3)),
                            self.oSs + np.arange(ns_rows)]),
            np.concatenate([np.full(3 * ns_rows, 1 / math.sqrt(3)), np.ones(ns_rows)]))
        self.sep_coo = slice(coo.start, coo.start + 3 * ns_rows)
        self.n_rows = rows.count
        sep_box = slice(self.sbox_rows.start, self.sbox_rows.start + 2 * M * N)
        env_box = slice(sep_box.stop, self.sbox_rows.stop)
        dyn_v = slice(self.dyn_rows.stop, self.dyn_rows.stop + nd)
        #: Row blocks indexed by step, for shifting the duals: (rows, shape, step axis).
        self._step_blocks = [
            (self.dyn_rows, (N, 3), 0), (dyn_v, (N, 3), 0), (self.abox_rows, (N, 3), 0),
            (sep_box, (M, N, 2), 1), (env_box, (N,), 0), (self.acut_rows, (N, C), 0),
            (self.vpoly_rows, (N, F), 0), (self.vcut_rows, (N, C - 1), 0),
            (self.vz_rows, (N, 2), 0), (self.alt_rows, (N, 2), 0),
            (self.fence_rows, (N, E), 0), (self.sep_rows, (M, N, 2), 1)]
        self._pattern = FixedPattern(rows, self.nx)
        self._values = self._pattern.values

        w = self.config.weights
        wp = np.full(N + 1, w.position * dt)
        wv = np.full(N + 1, w.velocity * dt)
        wp[0] = wv[0] = 0.0  # the start is fixed
        wp[-1], wv[-1] = w.terminal_position, w.terminal_velocity
        self._wp3 = np.repeat(wp, 3)
        self._wv3 = np.repeat(wv, 3)
        diff = sp.diags([-np.ones(N - 1), np.ones(N - 1)], [0, 1], shape=(N - 1, N))
        jw = w.jerk / dt
        effort = w.accel * dt * sp.identity(N) + jw * (diff.T @ diff)
        self._effort3 = sp.csr_matrix(sp.kron(effort, sp.identity(3)))
        first = sp.csr_matrix(([jw], ([0], [0])), shape=(N, N))
        self._jw = jw
        h_a = 2.0 * sp.kron(effort + first, sp.identity(3))
        hess = sp.block_diag([sp.diags(2.0 * self._wp3), sp.diags(2.0 * self._wv3), h_a,
                              sp.diags(np.full(self.nx - self.oSs, 2e-3))], format="csc")
        # Keep the zero diagonal entries of the fixed start structurally: harmless.
        self._P = sp.triu(hess, format="csc")
        self.q = np.zeros(self.nx)
        self.q[self.oSs:] = w.slack
        self.q[self.oSs:self.oSe] = w.separation_slack
        self.l = np.full(self.n_rows, -np.inf)
        self.u = np.full(self.n_rows, np.inf)
        self.l[: 6 * N] = 0.0
        self.u[: 6 * N] = 0.0
        self.solver = osqp.OSQP()
        self.solver.setup(P=self._P, q=self.q, A=self._pattern.matrix, l=self.l, u=self.u,
                          **self.config.osqp_settings)

    # -- per tick ---------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the previous solutions: the next solve starts cold (the QP is kept)."""
        self._last = None
        self._escaped = False
        self._lin = None
        self._slot_ids[:] = -1
        self._retimed = None
        self._retimed_from = None

    def _check(self, req: MpcRequest) -> None:
        if req.sysid != self.sysid:
            raise ValueError(f"`request.sysid` is {req.sysid} but this controller is vehicle "
                             f"{self.sysid}'s")
        if len(req.ref_pos) != self.N + 1:
            raise ValueError(f"`ref_pos` holds {len(req.ref_pos)} samples but the controller "
                             f"plans {self.N} steps ({self.N + 1} samples)")
        lim = req.limits
        for name in ("max_speed_h", "max_speed_up", "max_speed_down", "max_accel"):
            if not getattr(lim, name) > 0:
                raise ValueError(f"`limits.{name}` must be positive, got {getattr(lim, name)}")
        if not lim.max_alt > lim.min_alt:
            raise ValueError("`limits.max_alt` must be above `limits.min_alt`")
        if np.any(req.other_ids == self.sysid):
            raise ValueError(f"`neighbour_ids` holds vehicle {self.sysid} itself")

    def _guess(self, req: MpcRequest) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Linearisation point: the last QP solution shifted (or the path), plus the
        current offset from it decaying linearly to zero over the horizon."""
        N, dt = self.N, self.dt
        times = req.t0 + dt * np.arange(N + 1)
        prev = self._lin
        if prev is not None and prev.t0 <= req.t0 < prev.t0 + N * dt:
            bp, bv, _ = _sample(prev.t0, dt, prev.pos, prev.vel, prev.acc, times)
            _, _, ba = _sample(prev.t0, dt, prev.pos, prev.vel, prev.acc,
                               times[:-1] + 0.5 * dt)
        else:
            bp, bv, ba = req.ref_pos, req.ref_vel, 0.5 * (req.ref_acc[:-1] + req.ref_acc[1:])
        fade = (1.0 - np.arange(N + 1) / N)[:, None]
        off_p, off_v = req.p0 - bp[0], req.v0 - bv[0]
        gp = bp + fade * off_p
        gv = bv + fade * off_v - off_p / (N * dt)
        return gp, gv, ba

    def _current_accel(self, req: MpcRequest) -> FloatArray:
        if req.a0 is not None:
            return req.a0
        last = self._last
        if last is not None and last.t0 <= req.t0 < last.end:
            return last.sample(req.t0)[2]
        return 0.5 * (req.ref_acc[0] + req.ref_acc[1])

    def _update_cost(self, req: MpcRequest) -> None:
        rel = (req.ref_pos - req.p0).ravel()
        q = self.q
        q[: self.nP] = -2.0 * self._wp3 * rel
        q[self.oV: self.oA] = -2.0 * self._wv3 * req.ref_vel.ravel()
        ar = 0.5 * (req.ref_acc[:-1] + req.ref_acc[1:])
        qa = -2.0 * (self._effort3 @ ar.ravel())
        qa[:3] -= 2.0 * self._jw * self._current_accel(req)
        q[self.oA: self.oSs] = qa

    def _linearise(self, req: MpcRequest, gp: FloatArray, gv: FloatArray, ga: FloatArray,
                   slots: IntArray) -> None:
        """Refresh every row that depends on the limits, the neighbours or the guess."""
        N, dt, M, E = self.N, self.dt, self.M, self.E
        lim, p0 = req.limits, req.p0
        vals, lo, hi = self._values, self.l, self.u
        bulge = lim.max_accel * dt * dt / 8
        lo[self.init_rows] = np.concatenate([np.zeros(3), req.v0])
        hi[self.init_rows] = lo[self.init_rows]
        lo[self.abox_rows], hi[self.abox_rows] = -lim.max_accel, lim.max_accel
        lo[self.sbox_rows], hi[self.sbox_rows] = 0.0, np.inf
        hi[self.acut_rows] = lim.max_accel
        # Speeds: the envelope from the measured velocity (package docstring, "Envelope"),
        # the limits themselves when it is within them.  Steps 1..N.
        # The rows close ENVELOPE_QP_MARGIN faster than the verifier's envelope: the QP's
        # accelerations meet the norm limit only through cuts, and projecting an overshoot
        # back onto the ball takes braking away (seen: 12 of 300 random over-speed starts
        # rolled out over the envelope, e.g. a 1.69 m/s descent for 1.5).
        brake = min(self._brake(req) * ENVELOPE_QP_MARGIN, lim.max_accel)
        v0 = req.v0
        env_h = speed_envelope(lim.max_speed_h, float(np.hypot(v0[0], v0[1])), brake, N, dt)[1:]
        env_up = speed_envelope(lim.max_speed_up, float(v0[2]), brake, N, dt)[1:]
        env_dn = speed_envelope(lim.max_speed_down, float(-v0[2]), brake, N, dt)[1:]
        hi[self.vcut_rows] = np.repeat(env_h, self.config.passes - 1)
        hi[self.vpoly_rows] = np.repeat(env_h, self.F)
        up = np.tile([1.0, 0.0], N).astype(bool)
        vz_lo = np.where(up, -np.inf, -np.repeat(env_dn, 2))
        vz_hi = np.where(up, np.repeat(env_up, 2), np.inf)
        lo[self.vz_rows], hi[self.vz_rows] = vz_lo, vz_hi
        z_lo = lim.min_alt + bulge - p0[2]
        z_hi = lim.max_alt - bulge - p0[2]
        lo[self.alt_rows] = np.where(up, -np.inf, z_lo)
        hi[self.alt_rows] = np.where(up, z_hi, np.inf)
        # Geofence rows (convex fences only).
        fn = np.zeros((E, 2))
        fl = np.full(E, -np.inf)
        fence = convex_fence(lim.geofence) if lim.geofence and E else None
        if fence is not None:
            normals, offsets = fence
            dist = normals @ p0[:2] - offsets
            pick = np.argsort(dist, kind="stable")[:E]
            fn[: len(pick)] = normals[pick]
            fl[: len(pick)] = offsets[pick] + bulge + SEPARATION_BUFFER - normals[pick] @ p0[:2]
        vals[self.fence_coo] = np.concatenate([np.tile(fn[:, 0], N), np.tile(fn[:, 1], N)])
        lo[self.fence_rows] = np.tile(fl, N)
        # Separation rows: slot j holds neighbour slots[j] (-1: switched off).
        nrm = np.zeros((M, N, 3))
        sep_lo = np.full((M, N, 2), -np.inf)
        used = np.flatnonzero(slots >= 0)
        if len(used):
            q = req.others[slots[used]] - p0  # (s, N+1, 3) relative to p0, like the QP's P
            g = gp - p0
            n_s = chord_normals((g[None, :-1] - q[:, :-1]).reshape(-1, 3),
                                (g[None, 1:] - q[:, 1:]).reshape(-1, 3)).reshape(-1, N, 3)
            need = np.full((len(used), N + 1), chord_separation(lim, dt) + SEPARATION_BUFFER)
            start = self._start_distance
            if start is not None:
                # Recovering from inside a neighbour's separation: the distance must grow
                # at RECOVERY_MPS from where it is until the limit holds again.
                d0 = start[slots[used]][:, None]
                grow = d0 + RECOVERY_MPS * dt * np.arange(N + 1)[None, :]
                need = np.where(d0 < lim.min_separation, np.minimum(need, grow), need)
            nrm[used] = n_s
            first = np.einsum("skd,skd->sk", n_s, q[:, :-1]) + need[:, :-1]
            # The measured position is fixed: its row asks no more than it already has.
            first[:, 0] = np.minimum(first[:, 0], -self.config.slack_tol / 2)
            sep_lo[used, :, 0] = first
            sep_lo[used, :, 1] = np.einsum("skd,skd->sk", n_s, q[:, 1:]) + need[:, 1:]
        coef = np.repeat(nrm.reshape(-1, 3), 2, axis=0)  # both ends of each segment
        vals[self.sep_coo] = coef.T.ravel()
        lo[self.sep_rows] = sep_lo.ravel()
        self.solver.update(q=self.q, l=lo, u=hi, Ax=self._pattern.refresh())

    def _cuts(self, npass: int, req: MpcRequest, gv: FloatArray, ga: FloatArray) -> None:
        """Norm-limit rows for pass ``npass``: the first pass turns the speed polygon to
        the guess's velocity and cuts the acceleration ball at the guess's direction,
        clearing the other cuts; each later pass adds the tangent planes at the previous
        pass's solution (cutting planes: the earlier ones stay, so the iterate cannot
        swing back)."""
        N, C, F = self.N, self.config.passes, self.F
        vals = self._values
        acut = vals[self.acut_coo].reshape(3, N, C)  # a view: [axis, step, cut]
        vcut = vals[self.vcut_coo].reshape(2, N, C - 1)
        na = np.linalg.norm(ga, axis=1, keepdims=True)
        n_a = np.where(na > _TINY, ga / np.maximum(na, _TINY), 0.0)
        vh = gv[1:, :2]
        if npass == 1:
            acut[:] = 0.0
            vcut[:] = 0.0
            acut[:, :, 0] = n_a.T
            vh = np.where(np.linalg.norm(vh, axis=1, keepdims=True) > 1e-3, vh,
                          req.ref_vel[1:, :2])
            theta = np.arctan2(vh[:, 1], vh[:, 0])[:, None] + 2 * math.pi * np.arange(F) / F
            vals[self.vpoly_coo] = np.concatenate([np.cos(theta).ravel(),
                                                   np.sin(theta).ravel()])
        else:
            acut[:, :, npass - 1] = n_a.T
            nv = np.linalg.norm(vh, axis=1, keepdims=True)
            vcut[:, :, npass - 2] = np.where(nv > _TINY, vh / np.maximum(nv, _TINY), 0.0).T

    def _brake(self, req: MpcRequest) -> float:
        """The rate at which a speed limit the start is above closes in the verified
        envelope, m/s^2 (package docstring, "Envelope")."""
        return self.config.envelope_brake * req.limits.max_accel

    def _assign_slots(self, req: MpcRequest, guess: FloatArray) -> IntArray:
        """(M,) index into ``req.others`` held by each slot, -1 for a free slot.

        A neighbour keeps its slot from tick to tick while it stays selected, so that
        the shifted duals of its rows still belong to it.
        """
        chosen = select_neighbours(guess, req.others, self.M, self.config.reach_m)
        ids = req.other_ids[chosen]
        keep = np.isin(self._slot_ids, ids) & (self._slot_ids >= 0)
        self._slot_ids[~keep] = -1
        new = ids[~np.isin(ids, self._slot_ids)]
        free = np.flatnonzero(self._slot_ids < 0)
        self._slot_ids[free[: len(new)]] = new
        slots = np.full(self.M, -1, dtype=np.intp)
        pos = {int(sid): int(i) for sid, i in zip(ids, chosen, strict=True)}
        for j, sid in enumerate(self._slot_ids):
            if sid >= 0:
                slots[j] = pos[int(sid)]
        return slots

    def _shifted_duals(self, t0: float) -> FloatArray | None:
        """The last solve's duals moved ``t0 - t_last`` steps along every step-indexed
        row block (the last step repeated), or None if they do not apply."""
        last = self._lin
        if last is None:
            return None
        shift = (t0 - last.t0) / self.dt
        s = round(shift)
        if abs(shift - s) > 1e-3 or not 0 <= s < self.N:
            return None
        y = last.duals.copy()
        if s == 0:
            return y
        for rows, shape, axis in self._step_blocks:
            block = last.duals[rows].reshape(shape)
            tail = np.take(block, [shape[axis] - 1] * s, axis=axis)
            y[rows] = np.concatenate([np.take(block, np.arange(s, shape[axis]), axis=axis),
                                      tail], axis=axis).ravel()
        return y

    def _warm(self, req: MpcRequest, gp: FloatArray, gv: FloatArray, ga: FloatArray) -> None:
        x0 = np.concatenate([(gp - req.p0).ravel(), gv.ravel(), ga.ravel(),
                             np.zeros(self.nx - self.oSs)])
        y0 = self._shifted_duals(req.t0)
        if y0 is None:
            # Cold duals, except the slacks' bounds: at a slack-free optimum their
            # multipliers are minus the slack weight.  Starting them at zero, ADMM
            # spends hundreds of iterations growing them to 1e3.
            y0 = np.zeros(self.n_rows)
            y0[self.sbox_rows] = -self.q[self.oSs:]
        self.solver.warm_start(x=x0, y=y0)
