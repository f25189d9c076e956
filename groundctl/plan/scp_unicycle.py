"""SCP for the paper's unicycle model: constant speed V, turn rate |u| <= V / r_min.

Per drone: positions p (N+1, 2), headings theta (N+1), turn rates u (N).  The
dynamics

    p[k+1] = p[k] + dt V [cos theta[k], sin theta[k]],   theta[k+1] = theta[k] + dt u[k]

are linearised around the previous iterate's headings; after every QP the
headings are rolled out through the *nonlinear* dynamics, so each iterate
(and the result) flies at exactly V.  The QP (:class:`UnicycleQP`) is written in
the step from that rollout, with u and the fixed start eliminated.  The
pattern constraint |p[N] - target| <= eps aims at eps/2: a box inscribed in
that circle (half-width eps/2 / sqrt(2), see :func:`pattern_half_width`),
softened by a penalised slack, and separation uses the same segment rows as
the quadrotor.

Initial guess.  The paper starts from the straight line.  With constant speed
that is a stationary point whenever the straight distance d is shorter than
V T: along the line, the first-order change of the along-track distance with
heading is zero, so the linearised QP can never shorten the path and the SCP
stalls with a terminal error of V T - d.  We therefore start from the line
plus a heading weave theta = theta_line + a sin(2 pi t / T) whose amplitude
solves J0(a) = d / (V T): its mean along-track speed is exactly d / T and its
lateral drift integrates to zero, so the guess ends on the target.

Convergence.  Feasibility is judged on the rollout the plan will fly, not on the
QP's linear model: every drone within eps of its slot, and every pair-segment
(of all pairs, not only those with QP rows) with a separation-row value
>= d_min + margin - SLACK_TOL at the rollout itself, which bounds the distance
along the whole straight segment between samples.  A feasible iterate ends the
SCP when no sample moved more than the tolerance (the paper's test) or when it
follows a feasible iterate and lowered the cost J by less than COST_TOL: once
feasible, the trust region shrinks geometrically and the remaining iterations
only polish J by a few per cent (paper transitions: 9 iterations -> 5-7).  An
iterate that would end the SCP with an end point further than eps/2 from its
slot (the rollout off the linear model's pattern box) gets one more iteration.
After a feasible iterate the QP keeps its Jacobian (dynamics coefficients and
separation normals: no KKT refactorisation) but is shifted to pass through the
new rollout, a simplified Newton step; the trust region moves with it.
Relinearising in this polishing phase as well bought nothing but refactorisations
and longer ADMM restarts; keeping the Jacobian from the first iterate on, on
the other hand, converged to plans with 45 % more turning effort (a fixed point
of simplified Newton is feasible but not optimal), so the Jacobian is fresh
until the fleet is feasible.  Paper star and transitions: 3-5 iterations,
0.03-0.08 s, pattern error <= 0.05 m (`benchmarks/bench_plan.py`).
"""

from __future__ import annotations

import time

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.optimize import brentq
from scipy.special import j0

from groundctl.errors import InfeasibleTransition, PlanningError
from groundctl.plan.conflicts import close_pair_segments, segment_keys, widen, within
from groundctl.plan.qp_build import (
    BUILD_MARGIN,
    BUILD_WIDEN,
    NEED_MARGIN,
    OSQP_SETTINGS,
    SLACK_TOL,
    SLACK_WEIGHT,
    FixedPattern,
    RowBuilder,
    chord_clearance,
    segment_normals,
    solve_checked,
)
from groundctl.plan.scp_quad import TransitionResult
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import Limits, PlannerSettings, UnicycleModel

FloatArray = NDArray[np.float64]

#: Weight of the terminal slack (m^-2): the pattern error dominates any effort.
TERMINAL_WEIGHT = 1e3
#: How far inside eps/2 the pattern box's corners are, m (see :func:`pattern_half_width`).
AIM_MARGIN = 2e-3
#: Max heading change per SCP iteration, rad (keeps the linearisation honest).
HEADING_TRUST = 0.5
#: Factor applied to the heading trust region after every feasible iteration.  Once
#: the fleet is feasible (separated, within eps) each iterate is already a valid
#: plan and the remaining iterations only polish; 0.3 instead of 0.5 reaches the
#: convergence tolerance in ~4 polishing iterations instead of ~7 (paper star: 9
#: SCP iterations instead of 11, same separation and pattern error).
TRUST_DECAY = 0.3
#: Relative cost decrease below which a feasible iterate that follows a feasible one
#: ends the SCP (see the module docstring).
COST_TOL = 1.5e-2
#: OSQP settings of the unicycle QP.  The QP only proposes headings: positions are
#: rolled out through the nonlinear dynamics and checked after every solve, so
#: ADMM's accuracy only has to be good enough to make progress.  Measured on the
#: paper's star (20 seeds) and transitions (`benchmarks/bench_plan.py`):
#:
#: - ``polishing`` off: one more KKT factorisation per solve (~40 % of the solve
#:   time), and it often failed on these problems anyway.
#: - ``check_dualgap`` off (as for the quadrotor): with it, 400-1500 ADMM
#:   iterations per solve instead of 25-75.
#: - ``eps_abs`` 1e-2 (m, rad): the QP is in step form, so its values are small
#:   and eps_rel no longer makes the tolerance loose by itself; 1 cm on a linear
#:   model whose end point is re-checked on the rollout (pattern box eps/2).
#: - ``check_termination`` 10: the trust-region-only solves of the polishing phase
#:   converge in 10-20 iterations and were held to 25.
#: - ``scaling`` 1: the step form is already well scaled, one Ruiz pass is enough
#:   (10 passes cost 4 ms per setup; none at all doubled the ADMM iterations).
#: - ``rho`` starts at OSQP's default 0.1 and adapts every 50 iterations rather
#:   than on OSQP's timing heuristic: every rho update is one more KKT
#:   factorisation.  It is not passed to ``setup()``: osqp-python then calls
#:   ``update_rho`` after the setup, one more factorisation (~0.6 ms) per build.
UNICYCLE_OSQP_SETTINGS: dict[str, float | int | bool] = {
    **{k: v for k, v in OSQP_SETTINGS.items() if k != "rho"}, "polishing": False,
    "adaptive_rho_interval": 50, "eps_abs": 1e-2, "eps_rel": 1e-3,
    "check_termination": 10, "scaling": 1}


def pattern_half_width(eps: float) -> float:
    """Half-width of the pattern box: its corners lie on the circle of radius eps/2.

    The QP aims every end point at eps/2 of its slot (half the paper's eps; the rest
    is room for the linearisation).  A box of half-width eps/2 let the end point sit
    in a corner, eps/2 sqrt(2) = 0.071 m off for eps 0.1, and the cost does push it
    there: the constant-speed drones save turning by arriving short or wide (paper
    star and transitions: 0.068-0.072 m, docs/benchmarks.md's old figures).  An octagon
    (two more rows per drone, sides at cos(pi/8) eps/2) gives more room but cost
    more ADMM iterations per solve (paper circle 0.062 -> 0.103 s); the inscribed
    box did not (`benchmarks/bench_plan.py`).  The corners sit AIM_MARGIN inside
    the circle: the rows are soft (the slack e costs TERMINAL_WEIGHT e^2 against
    the effort it saves), and the rollouts landed 0.3-0.4 mm past a box on the
    circle itself.
    """
    return float(np.sqrt(0.5) * (eps / 2 - AIM_MARGIN))


def _wrap(a: FloatArray) -> FloatArray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def rollout(p0: FloatArray, theta: FloatArray, speed: float, dt: float) -> FloatArray:
    """Positions (n, N+1, 2) flown from ``p0`` (n, 2) with headings ``theta`` (n, N+1)."""
    step = dt * speed * np.stack([np.cos(theta[:, :-1]), np.sin(theta[:, :-1])], axis=2)
    return np.concatenate([p0[:, None, :], p0[:, None, :] + np.cumsum(step, axis=1)], axis=1)


def initial_headings(start: FloatArray, goal: FloatArray, heading0: FloatArray,
                     model: UnicycleModel, steps: int, dt: float) -> FloatArray:
    """Line heading plus a length-matching weave, turning from the start heading first."""
    delta = goal - start
    d = np.linalg.norm(delta, axis=1)
    line = np.arctan2(delta[:, 1], delta[:, 0])
    total = model.speed * steps * dt
    ratio = np.clip(d / total, 0.0, 1.0)
    # J0 falls from 1 at 0 to 0 at 2.405: one root in between for every ratio in (0, 1).
    amp = np.array([0.0 if r > 1 - 1e-9 else brentq(lambda a, r=r: j0(a) - r, 0.0, 2.4048)
                    for r in ratio])
    t = np.arange(steps + 1) * dt
    phase = 2 * np.pi * t / (steps * dt)
    desired = line[:, None] + amp[:, None] * np.sin(phase)[None, :]
    # Follow the weave from the start heading without ever turning faster than the
    # limit, so the guess itself is flyable and every trust region around it feasible.
    theta = np.empty_like(desired)
    theta[:, 0] = heading0
    max_step = 0.95 * model.turn_rate_limit * dt
    for k in range(steps):
        turn = np.clip(_wrap(desired[:, k + 1] - theta[:, k]), -max_step, max_step)
        theta[:, k + 1] = theta[:, k] + turn
    return theta


def separation_clearance(P: FloatArray, radius: float, near: NDArray[np.int64]) -> float:
    """Smallest separation-row value (see :func:`chord_clearance`) over all pair-segments
    of ``P`` (n, N+1, 2) with a sample within ``radius``; inf if there are none.

    A row value >= d means the straight segment between the samples keeps >= d.
    ``near`` is ``close_pair_segments(P, R)`` for some R >= ``radius``.
    """
    segs = within(P, near, radius)
    return float(chord_clearance(P, segs).min()) if len(segs) else np.inf


def rollout_cost(theta: FloatArray, P: FloatArray, ref: FloatArray, dt: float, alpha: float,
                 beta: float) -> float:
    """The paper's cost J of headings ``theta`` and their rollout ``P``."""
    return (alpha / dt * float(np.sum(np.diff(theta, axis=1) ** 2))
            + beta * dt * float(np.sum((P - ref) ** 2)))


class UnicycleQP:
    """The linearised unicycle QP for all drones of a transition (2D), in step form.

    The variables are the *changes* from the linearisation point (Pbar, thbar), a
    rollout that meets the nonlinear dynamics exactly, so the dynamics rows have a
    zero right-hand side and the start (p[0], theta[0]) is no variable at all:

        dp[k+1] - dp[k] - dt V perp(thbar[k]) dth[k] = 0            (k = 0..N-1)
        |thbar[k+1] + dth[k+1] - thbar[k] - dth[k]| <= dt u_max        (turn rate)
        |dth[k]| <= trust_i                                            (trust region)
        n.(dp_i - dp_j) + s >= d_sep - n.(Pbar_i - Pbar_j), s >= 0    (separation)
        Pbar[N] + dp[N] - e in target +- pattern_half_width(eps)       (pattern)

    The last heading theta[N] moves no position; its only cost is the last turn,
    so it equals theta[N-1] and is no variable either.  The turn rate u is no
    variable: its bound is a row on the heading difference and its cost
    alpha/dt |theta[k+1] - theta[k]|^2 a tridiagonal block.  Against the
    absolute form (positions, N+1 headings, N turn rates, their equality rows)
    the KKT system is a fifth smaller (paper transitions: 18,500 instead of
    23,800), and its values are steps, well scaled: one pass of OSQP's
    equilibration is enough.
    """

    def __init__(self, start: FloatArray, goal: FloatArray, heading0: FloatArray, ref: FloatArray,
                 model: UnicycleModel, steps: int, dt: float, d_sep: float, eps: float,
                 segs: NDArray[np.int64], alpha: float, beta: float) -> None:
        n, N = start.shape[0], steps
        if N < 3:
            raise ValueError("the unicycle QP needs at least 3 steps")
        self.n, self.N, self.dt, self.model, self.eps = n, N, dt, model, eps
        self.goal, self.heading0 = goal, heading0
        self.ref, self.beta, self.d_sep = ref, beta, d_sep
        self.segs = segs
        m = len(segs)
        H = N - 1                      # free headings theta[1..N-1] per drone
        self.nP = n * N * 2            # dp[1..N]
        self.oT = self.nP
        self.oE = self.oT + n * H
        self.oS = self.oE + 2 * n
        self.nx = self.oS + m

        Ints = NDArray[np.intp]

        def ip(i: Ints, k: Ints, c: int | Ints) -> Ints:
            """Column of dp[i, k, c], k = 1..N."""
            return (i * N + k - 1) * 2 + c

        def it(i: Ints, k: Ints) -> Ints:
            """Column of dth[i, k], k = 1..N-1."""
            return self.oT + i * H + k - 1

        rows = RowBuilder()
        # Dynamics, x then y rows, k = 0..N-1; dp[0] and dth[0] are zero (no entry).
        gi, kk = (x.ravel() for x in np.meshgrid(np.arange(n), np.arange(N), indexing="ij"))
        nd = len(gi)
        r = np.arange(nd)
        inner = kk > 0
        ri, gin, kin = r[inner], gi[inner], kk[inner]
        self._dyn_head = (gin, kin)
        nh = len(ri)
        ones_n, ones_i = np.ones(nd), np.ones(nh)
        self.dyn_rows, dyn_coo = rows.block(
            2 * nd, np.concatenate([r, ri, ri, r + nd, ri + nd, ri + nd]),
            np.concatenate([ip(gi, kk + 1, 0), ip(gin, kin, 0), it(gin, kin),
                            ip(gi, kk + 1, 1), ip(gin, kin, 1), it(gin, kin)]),
            np.concatenate([ones_n, -ones_i, np.zeros(nh), ones_n, -ones_i, np.zeros(nh)]))
        x0 = dyn_coo.start + nd + nh
        self.dyn_x_coo = slice(x0, x0 + nh)
        y0 = x0 + nh + nd + nh
        self.dyn_y_coo = slice(y0, y0 + nh)
        # Turn rate between free headings: dth[k+1] - dth[k], k = 1..N-2.
        ti_, tk = (x.ravel() for x in np.meshgrid(np.arange(n), np.arange(1, N - 1),
                                                  indexing="ij"))
        nt = len(ti_)
        self._turn = (ti_, tk)
        rt = np.arange(nt)
        self.turn_rows, _ = rows.block(
            nt, np.concatenate([rt, rt]), np.concatenate([it(ti_, tk + 1), it(ti_, tk)]),
            np.concatenate([np.ones(nt), -np.ones(nt)]))
        # Boxes: the heading trust region (and, for theta[1], the first turn) and s >= 0.
        boxed = np.concatenate([np.arange(self.oT, self.oE), np.arange(self.oS, self.nx)])
        self.box_rows, _ = rows.block(len(boxed), np.arange(len(boxed)), boxed,
                                      np.ones(len(boxed)))
        self.head_box = slice(self.box_rows.start, self.box_rows.start + n * H)
        # Pattern: dp[N] - e, x rows then y rows.
        ti = np.arange(n)
        tr = np.concatenate([ti, ti, ti + n, ti + n])
        self.term_rows, _ = rows.block(
            2 * n, tr, np.concatenate([ip(ti, np.full(n, N), 0), self.oE + 2 * ti,
                                       ip(ti, np.full(n, N), 1), self.oE + 2 * ti + 1]),
            np.concatenate([np.ones(n), -np.ones(n), np.ones(n), -np.ones(n)]))
        # Separation, one row per pair-segment end; an end at k = 0 has only its slack.
        if m:
            # Row r < m is segment r's start, row m + r its end.
            ends = np.concatenate([segs[:, 2], segs[:, 2] + 1])
            ii = np.concatenate([segs[:, 0], segs[:, 0]])
            jj = np.concatenate([segs[:, 1], segs[:, 1]])
            self._sep_ends = (ii, jj, ends)
            rr = np.arange(2 * m)
            mv = ends > 0
            self._sep_moving = mv
            rm, em, im, jm = rr[mv], ends[mv], ii[mv], jj[mv]
            nm = len(rm)
            self.sep_rows, sep_coo = rows.block(
                2 * m, np.concatenate([np.tile(rm, 4), rr]),
                np.concatenate([ip(im, em, 0), ip(im, em, 1), ip(jm, em, 0), ip(jm, em, 1),
                                self.oS + np.concatenate([np.arange(m), np.arange(m)])]),
                np.ones(4 * nm + 2 * m))
            self.sep_coo = slice(sep_coo.start, sep_coo.start + 4 * nm)
        else:
            self._sep_moving = np.zeros(0, dtype=bool)
            self.sep_rows = slice(rows.count, rows.count)
            self.sep_coo = slice(rows.nnz, rows.nnz)
        self.n_rows = rows.count
        self._pattern = FixedPattern(rows, self.nx)
        self._values = self._pattern.values
        self.A = self._pattern.matrix

        # Cost (OSQP's 1/2 x'Px + q'x): beta dt |p - ref|^2 over k = 1..N (p[0] is
        # fixed), alpha/dt sum over k = 0..N-2 of (theta[k+1] - theta[k])^2, the
        # terminal slack, and the separation slacks (linear, plus a small quadratic
        # term so the problem stays strictly convex).
        w = 2 * alpha / dt
        self._w = w
        head = np.full((n, H), 2 * w)
        head[:, -1] = w  # theta[N-1] is in one difference only
        diag = np.concatenate([np.full(self.nP, 2 * beta * dt), head.ravel(),
                               np.full(2 * n, 2 * TERMINAL_WEIGHT), np.full(m, 1e-3)])
        col = it(*self._turn)  # theta[k] and theta[k+1], k = 1..N-2, couple at -w
        self.P = (sp.diags(diag, format="csc")
                  + sp.csc_matrix((np.full(len(col), -w), (col, col + 1)),
                                  shape=(self.nx, self.nx))).tocsc()
        self.q = np.zeros(self.nx)
        self.q[self.oS:] = SLACK_WEIGHT
        self.l = np.full(self.n_rows, -np.inf)
        self.u = np.full(self.n_rows, np.inf)
        self.l[self.dyn_rows] = 0.0
        self.u[self.dyn_rows] = 0.0
        self.l[self.box_rows.start + n * H: self.box_rows.stop] = 0.0
        self._solver: osqp.OSQP | None = None
        self._theta_bar: FloatArray | None = None

    def linearise(self, P: FloatArray, theta: FloatArray, trust: FloatArray,
                  relinearise: bool = True) -> None:
        """Linearise around the rollout (P, theta) and set the trust region.

        ``relinearise=False`` keeps the Jacobian of the previous linearisation point
        (no KKT refactorisation) but not its constants: the model is shifted so that
        it passes through the rollout (P, theta) itself (a simplified Newton step),
        and the trust region moves to ``theta``.
        """
        n, N, dt, V = self.n, self.N, self.dt, self.model.speed
        if relinearise or self._solver is None:
            self._theta_bar = theta.copy()
            gin, kin = self._dyn_head
            th = theta[gin, kin]
            self._values[self.dyn_x_coo] = dt * V * np.sin(th)   # -(d/dth cos) = sin
            self._values[self.dyn_y_coo] = -dt * V * np.cos(th)
            segs = self.segs
            if len(segs):
                nvec = segment_normals(P, segs[:, 0], segs[:, 1], segs[:, 2])
                self._normals = np.concatenate([nvec, nvec])
                cm = self._normals[self._sep_moving]
                self._values[self.sep_coo] = np.concatenate([cm[:, 0], cm[:, 1], -cm[:, 0],
                                                             -cm[:, 1]])
            base = P
            # Turn-difference cost gradient at the point (theta[N] = theta[N-1]).
            diff = np.diff(theta[:, :N], axis=1)              # d_k, k = 0..N-2
            grad = diff.copy()                                 # d_{k-1} = th[k] - th[k-1]
            grad[:, :-1] -= diff[:, 1:]                        # d_k = th[k+1] - th[k]
            self.q[self.oT: self.oE] = (self._w * grad).ravel()
        else:
            bar = self._theta_bar
            assert bar is not None
            # Positions the kept linear model assigns to theta, from the linearisation
            # point: the model is moved by the defect so it passes through P.
            dth = theta[:, :N] - bar[:, :N]
            step = dt * V * np.stack([-np.sin(bar[:, :N]) * dth, np.cos(bar[:, :N]) * dth],
                                     axis=2)
            moved = np.concatenate([np.zeros((n, 1, 2)), np.cumsum(step, axis=1)], axis=1)
            base = P - moved
        self._set_constants(base)
        self._trust_box(theta, trust)
        if self._solver is None:
            self._pattern.refresh()
            self._solver = osqp.OSQP()
            self._solver.setup(P=self.P, q=self.q, A=self.A, l=self.l, u=self.u,
                               **UNICYCLE_OSQP_SETTINGS)
        elif relinearise:
            self._solver.update(Ax=self._pattern.refresh(), q=self.q, l=self.l, u=self.u)
            # The new point is the rolled-out solution: x = 0 is exactly where ADMM
            # should start (its own warm start would be the old step); duals stay.
            self._solver.warm_start(x=np.zeros(self.nx))
        else:
            self._solver.update(q=self.q, l=self.l, u=self.u)

    def _set_constants(self, base: FloatArray) -> None:
        """Right-hand sides and position cost for positions ``base`` + dp."""
        N = self.N
        self.q[: self.nP] = (2 * self.beta * self.dt * (base[:, 1:] - self.ref[:, 1:])).ravel()
        half = pattern_half_width(self.eps)
        miss = (self.goal - base[:, N]).T.ravel()       # x of every drone, then y
        self.l[self.term_rows] = miss - half
        self.u[self.term_rows] = miss + half
        segs = self.segs
        if len(segs):
            ii, jj, ends = self._sep_ends
            gap = np.einsum("md,md->m", self._normals, base[ii, ends] - base[jj, ends])
            self.l[self.sep_rows] = self.d_sep - gap

    def _trust_box(self, theta: FloatArray, trust: FloatArray) -> None:
        """Headings within ``trust`` of ``theta``, turns within the rate limit."""
        N, dt = self.N, self.dt
        turn = dt * self.model.turn_rate_limit
        bar = self._theta_bar
        assert bar is not None  # set by the first linearise(), which calls this
        centre = theta[:, 1:N] - bar[:, 1:N]
        lo = centre - trust[:, None]
        hi = centre + trust[:, None]
        # The first turn (theta[0] is fixed) bounds theta[1] alone.
        lo[:, 0] = np.maximum(lo[:, 0], self.heading0 - turn - bar[:, 1])
        hi[:, 0] = np.minimum(hi[:, 0], self.heading0 + turn - bar[:, 1])
        lo[:, 0] = np.minimum(lo[:, 0], hi[:, 0])
        self.l[self.head_box] = lo.ravel()
        self.u[self.head_box] = hi.ravel()
        ti_, tk = self._turn
        step = bar[ti_, tk + 1] - bar[ti_, tk]
        self.l[self.turn_rows] = -turn - step
        self.u[self.turn_rows] = turn - step

    def solve(self, transition: int) -> tuple[FloatArray, FloatArray]:
        """Headings (n, N+1) and separation slacks of the QP linearised last."""
        if self._solver is None or self._theta_bar is None:
            raise RuntimeError("UnicycleQP.solve() before linearise()")
        x = solve_checked(self._solver, transition, f"unicycle, {self.n} drones, {self.N} steps")
        n, N = self.n, self.N
        theta = self._theta_bar.copy()
        theta[:, 1:N] += x[self.oT: self.oE].reshape(n, N - 1)
        theta[:, 0] = self.heading0
        theta[:, N] = theta[:, N - 1]
        slack = x[self.oS:]
        return theta, slack


def plan_unicycle_transition(index: int, name: str, start: FloatArray, goal: FloatArray,
                             heading0: FloatArray, duration: float, altitude: float,
                             limits: Limits, model: UnicycleModel,
                             settings: PlannerSettings) -> tuple[TransitionResult, FloatArray]:
    """Plan one constant-speed transition in the plane z = ``altitude``.

    Returns the result and the final headings (the next transition starts there).
    """
    t0 = time.perf_counter()
    s2, g2 = start[:, :2], goal[:, :2]
    d = np.linalg.norm(g2 - s2, axis=1)
    reach = model.speed * duration
    if d.max() > reach + settings.pattern_tolerance:
        worst = int(np.argmax(d))
        raise InfeasibleTransition(
            index, name, float(d[worst] / model.speed), duration,
            f"drone {worst + 1} must cover {d[worst]:.1f} m at a constant {model.speed:.1f} m/s")
    n = len(start)
    steps = settings.steps_for(duration)
    dt = duration / steps
    frac = np.linspace(0, 1, steps + 1)
    ref = s2[:, None, :] + frac[None, :, None] * (g2 - s2)[:, None, :]
    theta = initial_headings(s2, g2, heading0, model, steps, dt)
    P = rollout(s2, theta, model.speed, dt)
    d_sep = limits.min_separation + 0.05
    # Pair-segments whose ends are both farther apart than this cannot come within
    # d_sep in between: each drone moves dt V per step, so the relative position
    # moves at most 2 dt V and its midpoint is at least sqrt(r^2 - (dt V)^2) > d_sep away.
    check_radius = d_sep + model.speed * dt
    # One spatial query per iterate, at the largest radius the loop asks about.
    query_radius = d_sep + max(NEED_MARGIN, BUILD_MARGIN, model.speed * dt)
    near = close_pair_segments(P, query_radius)
    qp: UnicycleQP | None = None
    have = np.empty(0, dtype=np.int64)
    iterations, err, clearance = 0, np.inf, -np.inf
    trust = np.full(n, HEADING_TRUST)
    errs = np.full(n, np.inf)
    prev_cost, feasible, prev_feasible = np.inf, False, False
    aim, retried = settings.pattern_tolerance / 2, False
    for iterations in range(1, settings.max_iterations + 1):  # noqa: B007 (used after)
        need = segment_keys(within(P, near, d_sep + NEED_MARGIN), n, steps)
        if qp is None or not np.all(np.isin(need, have)):
            # Rows for every pair-segment that is anywhere near: generous, so that the
            # QP (and OSQP's factorisation and warm start) survives many iterations.
            built = widen(within(P, near, d_sep + BUILD_MARGIN), steps, BUILD_WIDEN)
            have = segment_keys(built, n, steps)
            qp = UnicycleQP(s2, g2, heading0, ref, model, steps, dt, d_sep,
                            settings.pattern_tolerance, built, settings.alpha, settings.beta)
        qp.linearise(P, theta, trust, relinearise=not prev_feasible)
        theta_new, slack = qp.solve(index)
        P_new = rollout(s2, theta_new, model.speed, dt)
        change = float(np.abs(P_new - P).max())
        theta, P = theta_new, P_new
        prev_errs, errs = errs, np.linalg.norm(P[:, -1] - g2, axis=1)
        err = float(errs.max())
        # Feasibility is judged on the rollout the plan will fly, over every pair, not
        # on the QP's linearised positions and separation slacks.
        near = close_pair_segments(P, query_radius)
        clearance = separation_clearance(P, check_radius, near)
        feasible = err <= settings.pattern_tolerance and clearance >= d_sep - SLACK_TOL
        cost = rollout_cost(theta, P, ref, dt, settings.alpha, settings.beta)
        # Per-drone trust regions: a drone whose end point got worse overshot (the
        # linearisation promised more than the nonlinear rollout gave) and gets half
        # the room; one that improved gets a little more; once the whole fleet is
        # feasible every region shrinks fast so the last iterations only polish.
        if err <= settings.pattern_tolerance and float(slack.max(initial=0.0)) < SLACK_TOL:
            trust = np.maximum(trust * TRUST_DECAY, 1e-3)
        else:
            worse = errs > prev_errs
            trust = np.where(worse, np.maximum(trust * 0.5, 1e-3),
                             np.minimum(trust * 1.2, HEADING_TRUST))
        # Converged: a feasible iterate that either stopped moving (the paper's test)
        # or, following a feasible one, improved the cost by less than COST_TOL.  One
        # whose end points are not all within the QP's aim (eps/2: the rollout can
        # land a little off the linear model's pattern box) gets one more iteration,
        # in the already shrunk trust region, to correct that.
        if feasible and (change < settings.tolerance
                         or (prev_feasible and prev_cost - cost < COST_TOL * prev_cost)):
            if err <= aim or retried:
                break
            retried = True
        prev_cost, prev_feasible = cost, feasible
    if not feasible:
        raise PlanningError(index, "did not converge",
                            f"pattern error {err:.2f} m, separation {clearance:.3f} m "
                            f"(needs {d_sep:.2f} m) after {iterations} SCP iterations")
    # Knot velocities along the polyline's tangent (mean of the two segment headings).
    head = theta.copy()
    head[:, 1:-1] = np.arctan2(np.sin(theta[:, :-2]) + np.sin(theta[:, 1:-1]),
                               np.cos(theta[:, :-2]) + np.cos(theta[:, 1:-1]))
    vel2 = model.speed * np.stack([np.cos(head), np.sin(head)], axis=2)
    pos = np.concatenate([P, np.full((n, steps + 1, 1), altitude)], axis=2)
    vel = np.concatenate([vel2, np.zeros((n, steps + 1, 1))], axis=2)
    times = np.linspace(0.0, duration, steps + 1)
    result = TransitionResult(
        index=index, name=name, trajectories=Trajectories(times, pos, vel), steps=steps,
        iterations=iterations, seconds=time.perf_counter() - t0, qp_drones=n, groups=1,
        max_slack=max(0.0, d_sep - clearance), straight_length=float(d.mean()))
    return result, theta[:, -1]
