"""SCP for the paper's unicycle model: constant speed V, turn rate |u| <= V / r_min.

Per drone: positions p (N+1, 2), headings theta (N+1), turn rates u (N) and a
terminal slack e (2).  The dynamics

    p[k+1] = p[k] + dt V [cos theta[k], sin theta[k]],   theta[k+1] = theta[k] + dt u[k]

are linearised around the previous iterate's headings; after every QP the
headings are rolled out through the *nonlinear* dynamics, so each iterate
(and the result) flies at exactly V.  The pattern constraint
|p[N] - target| <= eps is a box of half-width eps/sqrt(2) softened by a
penalised slack, and separation uses the same segment rows as the quadrotor.

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
only polish J by a few per cent (paper transitions: 9 iterations -> 5-7).
After a feasible iterate the QP keeps its linearisation and only its trust
region moves: no KKT refactorisation, and the old separation rows remain a
valid restriction (the rollout is checked as always).  Paper transitions: 5
iterations each, 0.09-0.12 s.
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
from groundctl.plan.conflicts import close_pair_segments, segment_keys, widen
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
COST_TOL = 1e-2
#: OSQP settings of the unicycle QP: no solution polishing.  The QP only proposes
#: headings; positions are rolled out through the nonlinear dynamics and checked
#: after every solve, so ADMM's 1e-3 accuracy is enough, and polishing (one more
#: KKT factorisation per solve, ~40 % of the solve time, and it often fails on
#: these problems anyway) bought nothing.
#:
#: rho starts at 0.1, where OSQP's own estimate settles on these QPs (0.03-0.2), and
#: is adapted every 50 ADMM iterations rather than on OSQP's timing heuristic: from
#: rho 1.0 the first solve after a build needed up to 4 rho updates, each one more
#: KKT factorisation (~5 ms).
UNICYCLE_OSQP_SETTINGS: dict[str, float | int | bool] = {
    **OSQP_SETTINGS, "polishing": False, "rho": 0.1, "adaptive_rho_interval": 50}


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


def within(P: FloatArray, segments: NDArray[np.int64], radius: float) -> NDArray[np.int64]:
    """The rows (i, j, k) of ``segments`` whose drones are within ``radius`` at step k or k+1.

    ``close_pair_segments(P, r)`` equals ``within(P, close_pair_segments(P, R), r)`` for
    any R >= r (same test, same order), so one spatial query per iterate serves every
    radius the SCP needs.
    """
    i, j, k = segments[:, 0], segments[:, 1], segments[:, 2]
    d0 = np.sum((P[i, k] - P[j, k]) ** 2, axis=1)
    d1 = np.sum((P[i, k + 1] - P[j, k + 1]) ** 2, axis=1)
    return segments[np.minimum(d0, d1) <= radius * radius]


def separation_clearance(P: FloatArray, radius: float,
                         near: NDArray[np.int64] | None = None) -> float:
    """Smallest separation-row value (see :func:`chord_clearance`) over all pair-segments
    of ``P`` (n, N+1, 2) with a sample within ``radius``; inf if there are none.

    A row value >= d means the straight segment between the samples keeps >= d.
    ``near``, if given, is ``close_pair_segments(P, R)`` for some R >= ``radius``.
    """
    segs = close_pair_segments(P, radius) if near is None else within(P, near, radius)
    return float(chord_clearance(P, segs).min()) if len(segs) else np.inf


def rollout_cost(theta: FloatArray, P: FloatArray, ref: FloatArray, dt: float, alpha: float,
                 beta: float) -> float:
    """The paper's cost J of headings ``theta`` and their rollout ``P``."""
    return (alpha / dt * float(np.sum(np.diff(theta, axis=1) ** 2))
            + beta * dt * float(np.sum((P - ref) ** 2)))


class UnicycleQP:
    """The linearised unicycle QP for all drones of a transition (2D)."""

    def __init__(self, start: FloatArray, goal: FloatArray, heading0: FloatArray, ref: FloatArray,
                 model: UnicycleModel, steps: int, dt: float, d_sep: float, eps: float,
                 segs: NDArray[np.int64], alpha: float, beta: float) -> None:
        n, N = start.shape[0], steps
        self.n, self.N, self.dt, self.model, self.eps = n, N, dt, model, eps
        self.start, self.goal, self.heading0 = start, goal, heading0
        self.segs = segs
        m = len(segs)
        self.nP = n * (N + 1) * 2
        self.oT = self.nP
        self.oU = self.oT + n * (N + 1)
        self.oE = self.oU + n * N
        self.oS = self.oE + 2 * n
        self.nx = self.oS + m

        Ints = NDArray[np.intp]

        def ip(i: Ints, k: Ints, c: int | Ints) -> Ints:
            return (i * (N + 1) + k) * 2 + c

        def it(i: NDArray[np.intp], k: NDArray[np.intp]) -> NDArray[np.intp]:
            return self.oT + i * (N + 1) + k

        rows = RowBuilder()
        gi, kk = (x.ravel() for x in np.meshgrid(np.arange(n), np.arange(N), indexing="ij"))
        nd = len(gi)
        self._dyn = (gi, kk)
        r = np.arange(nd)
        # Position dynamics, x then y rows: p[k+1] - p[k] - dt V perp(thbar) theta[k] = const.
        self.dyn_rows, self.dyn_coo = rows.block(
            2 * nd, np.concatenate([r, r, r, r + nd, r + nd, r + nd]),
            np.concatenate([ip(gi, kk + 1, 0), ip(gi, kk, 0), it(gi, kk),
                            ip(gi, kk + 1, 1), ip(gi, kk, 1), it(gi, kk)]),
            np.concatenate([np.ones(nd), -np.ones(nd), np.zeros(nd),
                            np.ones(nd), -np.ones(nd), np.zeros(nd)]))
        self.th_rows, _ = rows.block(
            nd, np.concatenate([r, r, r]),
            np.concatenate([it(gi, kk + 1), it(gi, kk), self.oU + gi * N + kk]),
            np.concatenate([np.ones(nd), -np.ones(nd), np.full(nd, -dt)]))
        # Box rows only where a variable has bounds: interior positions are free, and an
        # unbounded row still costs a row in OSQP's KKT factorisation.
        pos_fixed = ip(np.repeat(np.arange(n), 2), np.zeros(2 * n, dtype=np.intp),
                       np.tile([0, 1], n))
        self._boxed = np.concatenate([pos_fixed, np.arange(self.oT, self.oE),
                                      np.arange(self.oS, self.nx)])
        nb = len(self._boxed)
        self.box_rows, _ = rows.block(nb, np.arange(nb), self._boxed, np.ones(nb))
        # Terminal box with slack: p[N] - e in target +- eps / sqrt(2).
        ti = np.arange(n)
        tr = np.concatenate([ti, ti, ti + n, ti + n])
        self.term_rows, _ = rows.block(
            2 * n, tr, np.concatenate([ip(ti, np.full(n, N), 0), self.oE + 2 * ti,
                                       ip(ti, np.full(n, N), 1), self.oE + 2 * ti + 1]),
            np.concatenate([np.ones(n), -np.ones(n), np.ones(n), -np.ones(n)]))
        if m:
            end = np.concatenate([segs[:, 2], segs[:, 2] + 1])
            ii = np.concatenate([segs[:, 0], segs[:, 0]])
            jj = np.concatenate([segs[:, 1], segs[:, 1]])
            rr = np.arange(2 * m)
            slack = self.oS + np.concatenate([np.arange(m), np.arange(m)])
            self.sep_rows, sep_coo = rows.block(
                2 * m, np.concatenate([np.tile(rr, 4), rr]),
                np.concatenate([ip(ii, end, 0), ip(ii, end, 1), ip(jj, end, 0), ip(jj, end, 1),
                                slack]),
                np.ones(10 * m))
            self.sep_coo = slice(sep_coo.start, sep_coo.start + 8 * m)
        else:
            self.sep_rows = slice(rows.count, rows.count)
            self.sep_coo = slice(rows.nnz, rows.nnz)
        self.n_rows = rows.count
        self._pattern = FixedPattern(rows, self.nx)
        self._values = self._pattern.values
        self.A = self._pattern.matrix

        cost = np.zeros(self.nx)
        cost[: self.nP] = 2 * beta * dt
        cost[self.oU: self.oE] = 2 * alpha * dt
        cost[self.oE: self.oS] = 2 * TERMINAL_WEIGHT
        cost[self.oS:] = 1e-3
        self.P = sp.diags(cost, format="csc")
        self.q = np.zeros(self.nx)
        self.q[: self.nP] = -2 * beta * dt * ref.ravel()
        self.q[self.oS:] = SLACK_WEIGHT
        self.l = np.full(self.n_rows, -np.inf)
        self.u = np.full(self.n_rows, np.inf)
        self.l[self.th_rows] = 0.0
        self.u[self.th_rows] = 0.0
        # Half-width eps/2 rather than eps/sqrt(2): the rolled-out (nonlinear) end point
        # differs a little from the QP's linear one and must still land within eps.
        half = eps / 2
        self.l[self.term_rows] = np.concatenate([goal[:, 0], goal[:, 1]]) - half
        self.u[self.term_rows] = np.concatenate([goal[:, 0], goal[:, 1]]) + half
        self.l[self.sep_rows] = d_sep
        lo = np.full(self.nx, -np.inf)
        hi = np.full(self.nx, np.inf)
        Pl = lo[: self.nP].reshape(n, N + 1, 2)
        Ph = hi[: self.nP].reshape(n, N + 1, 2)
        Pl[:, 0], Ph[:, 0] = start, start
        lo[self.oU: self.oE] = -model.turn_rate_limit
        hi[self.oU: self.oE] = model.turn_rate_limit
        lo[self.oS:] = 0.0
        self._lo, self._hi = lo, hi
        # OSQP is set up by the first linearise(): a setup factorises the KKT matrix,
        # and one done here, before the dynamics coefficients exist, would be thrown
        # away by the refactorisation of that first update (~5 ms per build).
        self._solver: osqp.OSQP | None = None

    def linearise(self, P: FloatArray, theta: FloatArray, trust: FloatArray,
                  relinearise: bool = True) -> None:
        """Linearise around (P, theta) and set the trust region.

        ``relinearise=False`` moves only the trust region and keeps the previous
        dynamics and separation linearisation: no KKT refactorisation.  The old
        separation rows are still a valid (conservative) restriction, and every
        iterate is rolled out and checked anyway.
        """
        dt, V = self.dt, self.model.speed
        if not relinearise and self._solver is not None:
            self._trust_box(theta, trust)
            self._solver.update(l=self.l, u=self.u)
            return
        gi, kk = self._dyn
        th = theta[gi, kk]
        nd = len(gi)
        vals = self._values[self.dyn_coo]
        vals[2 * nd: 3 * nd] = dt * V * np.sin(th)  # x row: -(-sin) coefficient
        vals[5 * nd: 6 * nd] = -dt * V * np.cos(th)
        self._values[self.dyn_coo] = vals
        cx = dt * V * (np.cos(th) + np.sin(th) * th)
        cy = dt * V * (np.sin(th) - np.cos(th) * th)
        self.l[self.dyn_rows] = np.concatenate([cx, cy])
        self.u[self.dyn_rows] = np.concatenate([cx, cy])
        segs = self.segs
        if len(segs):
            nvec = segment_normals(P, segs[:, 0], segs[:, 1], segs[:, 2])
            c2 = np.concatenate([nvec, nvec])
            self._values[self.sep_coo] = np.concatenate([c2[:, 0], c2[:, 1], -c2[:, 0],
                                                         -c2[:, 1]])
        self._trust_box(theta, trust)
        if self._solver is None:
            self._pattern.refresh()
            self._solver = osqp.OSQP()
            self._solver.setup(P=self.P, q=self.q, A=self.A, l=self.l, u=self.u,
                               **UNICYCLE_OSQP_SETTINGS)
        else:
            self._solver.update(Ax=self._pattern.refresh(), l=self.l, u=self.u)

    def _trust_box(self, theta: FloatArray, trust: FloatArray) -> None:
        """Headings within ``trust`` of ``theta`` (the first one fixed), inside the static box."""
        n, N = self.n, self.N
        lo, hi = self._lo.copy(), self._hi.copy()
        Tl = lo[self.oT: self.oU].reshape(n, N + 1)
        Th = hi[self.oT: self.oU].reshape(n, N + 1)
        Tl[:] = theta - trust[:, None]
        Th[:] = theta + trust[:, None]
        Tl[:, 0] = Th[:, 0] = self.heading0
        self.l[self.box_rows] = lo[self._boxed]
        self.u[self.box_rows] = hi[self._boxed]

    def solve(self, transition: int) -> tuple[FloatArray, FloatArray]:
        """Headings and separation slacks of the QP linearised last; PlanningError unless solved."""
        if self._solver is None:
            raise RuntimeError("UnicycleQP.solve() before linearise()")
        x = solve_checked(self._solver, transition, f"unicycle, {self.n} drones, {self.N} steps")
        theta = x[self.oT: self.oU].reshape(self.n, self.N + 1).copy()
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
    steps = settings.steps or max(4, int(np.ceil(duration / settings.dt - 1e-9)))
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
        # or, following a feasible one, improved the cost by less than COST_TOL.
        if feasible and (change < settings.tolerance
                         or (prev_feasible and prev_cost - cost < COST_TOL * prev_cost)):
            break
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
