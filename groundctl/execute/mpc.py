"""Model-predictive correction of ONE vehicle back onto its path.  Pure: no I/O, no clocks.

The executor calls :meth:`MpcController.solve` from a worker process at the
setpoint rate with the vehicle's measured state carried to the solve instant
``t0``; the result is a short reference trajectory (position, velocity and
acceleration) that the setpoint stream sends instead of the path while the
vehicle is off it.  Real autopilots track p + v + a setpoints with little lag
(DESIGN.md), so the MPC plans the vehicle's reference directly.

Model
-----
A double integrator per axis in the show frame (ENU metres, z up): state
(p, v), input a held constant over each step of ``dt`` (0.1 s), ``steps``
steps (30: 3 s), discretised exactly as the planner does
(:mod:`groundctl.plan.quad_qp`)::

    p[k+1] = p[k] + dt v[k] + dt^2/2 a[k],   v[k+1] = v[k] + dt a[k].

The QP's positions are taken relative to the measured ``p0`` (the show frame
may be hundreds of metres wide; OSQP scales better around zero).

Decision variables
------------------
``x = [P (N+1, 3) | V (N+1, 3) | A (N, 3) | s_sep (2 M N) | s_env (N)]``: one
slack per separation row, and one "envelope" slack per step shared by that
step's speed, altitude and geofence rows.  Slacks are l1-penalised
(``weights.slack`` = 1e3 per unit, far above any multiplier the tracking cost
can produce, so a feasible QP uses none) and keep the QP always feasible: OSQP
returns a trajectory, never an infeasibility certificate, and the slack says
which kind of limit could not be met.  A solution using more than
``slack_tol`` (the planner's 5 mm) is never accepted.  Why one slack per
separation row: a slack shared by the 2M rows of a step -- or by a neighbour's
rows, or by all -- made ADMM crawl even with every neighbour far away
(8 neighbours on a path: 200-400 iterations per warm tick instead of 5).

Cost
----
With ``dp = p - p_ref`` etc. (the reference is the vehicle's path sampled at
the step instants; its acceleration over a step is the mean of the samples at
both ends)::

    sum_{k=1}^{N-1} dt (w_p |dp_k|^2 + w_v |dv_k|^2) + W_p |dp_N|^2 + W_v |dv_N|^2
    + w_a sum_k dt |da_k|^2 + (w_j / dt) (sum_{k>=1} |da_k - da_{k-1}|^2 + |a_0 - a_now|^2)
    + slack weight * sum(s)

The terminal weights ``W`` put the vehicle back on its path *with the path's
velocity* by the horizon end; the effort is measured relative to the path's
own acceleration (a vehicle on its path costs nothing), the jerk term on
consecutive deviations, and on the first acceleration against what the
vehicle is doing now (``MpcRequest.a0`` if given, else the acceleration of
the previous result at ``t0``, else the path's).  That choice keeps the
Hessian constant: only the linear term ``q`` changes between ticks.

Rows (l <= A x <= u), in this order
-----------------------------------
* dynamics, 6N equalities; the start state (6 rows, ``p_0 = 0, v_0 = v0``);
* boxes: per-axis ``|a| <= a_max``, slacks ``>= 0``;
* acceleration norm: ``passes`` cut slots per step, tangent planes
  ``n . a_k <= a_max`` of the ball (each one contains the ball, so they only
  cut away what is over the limit): the first pass cuts at the linearisation
  point's direction, each later pass *adds* one at the previous pass's
  solution -- accumulated cutting planes, so the iterate cannot swing between
  corners of the box as it does when one plane is moved around (measured, with
  heavier tracking weights: a 3 m rejoin at the acceleration limit failed all
  three passes, tick after tick, until the vehicle was 20 m behind);
* horizontal speed: a regular ``speed_faces``-gon (8) circumscribing the
  circle of radius ``max_speed_h``, turned so that one face is normal to the
  linearisation velocity -- exact in the expected direction of flight, at most
  1/cos(pi/8) = 8 % over it 22.5 deg away -- plus ``passes - 1`` cut slots
  that the later passes fill like the acceleration's; climb and descent rates,
  two rows per step (the verifier's tolerance on all of them is 1 %);
* altitude, two rows per step, tightened by ``a_max dt^2/8`` (the most a
  constant-acceleration step bulges from its chord);
* geofence: a convex polygon gives one row per edge and step, the inward
  normal of the edge, tightened the same way (a convex region contains every
  chord between two inside points).  ``max_fence_edges`` slots (8): a fence with
  more edges gets rows for the ones nearest to the vehicle (an outer
  approximation; the verifier checks the whole polygon).  A non-convex fence
  gets no rows at all (a documented limitation): it is only verified;
* separation from every neighbour slot, linearised as the planner does
  (:mod:`groundctl.plan.quad_qp`): for neighbour j and segment k (steps k to
  k+1), with the unit normal n_jk from the neighbour's predicted chord to the
  linearisation point's chord at the segment's middle
  (:func:`~groundctl.plan.qp_build.chord_normals`), the two rows
  ``n_jk . (p_{k+e} - q_{j,k+e}) + s >= d'`` for e = 0, 1 share one normal, so
  the whole relative chord stays on the safe side; ``d'`` is
  :func:`~groundctl.plan.quad_qp.chord_separation` (the limit plus
  ``2 a_max dt^2/8``: both the vehicle and its neighbour may bulge from their
  chords) plus the planner's numerical buffer.  A half-space on the far side of
  a sphere is inside the sphere's complement, so a slack-free solution keeps
  the separation at every instant.  The first row (the measured position,
  which the QP cannot move) asks nothing, so a vehicle measured just outside
  the tightened limit can still move away (the verifier judges that segment).

Built once, updated in place
----------------------------
The sparsity is fixed at construction: ``max_neighbours`` slots (8) whose
unused ones keep their entries with zero coefficients and ``l = -inf``,
``max_fence_edges`` fence slots, ``passes`` cut slots.  Every tick only changes
values: the linear cost ``q`` (reference, current acceleration), the bounds
``l, u`` (state, limits, neighbours) and ``Ax`` (cuts, speed polygon, fence
and separation normals) -- one ``OSQP.update`` and one numeric
refactorisation per pass, never a new solver (``MpcController.solver`` keeps
its identity).  A neighbour keeps its slot while it stays in reach, so that
its rows' duals stay its own.

Warm start
----------
The linearisation point and the primal warm start are the last QP solution
(accepted or not: after a fallback it is still the best guess of a way round)
shifted to the new instants, plus the current state's offset from it fading
linearly to zero over the horizon; without one (first tick, after
:meth:`MpcController.reset`, a gap longer than the horizon) the path plus that
offset.  The duals are the last solution's, shifted by the same number of
steps along every step-indexed block; cold, they are zero except the slack
bounds', which start at minus the slack weight (their value at any slack-free
optimum: started at zero, ADMM spends hundreds of iterations growing them).

Solver settings
---------------
``eps`` 1e-3 with polishing: without polishing a warm-started ADMM stops at its
first termination check, close to the previous solution, and the tick-to-tick
error accumulates (a vehicle flying exactly on its path drifted 0.4 m off it);
tighter tolerances instead cost 4-5 times the iterations.  ``max_iter`` 600 and
``time_limit`` 15 ms per pass cap a solve; hitting ``max_iter`` is a fallback, and
so is ``time_limit`` once the solve has used 50 ms of the controller's clock.  OSQP's
limit is wall time, so a worker preempted on a busy machine hits it with its work not
done: the pass is resumed from its last iterate.  The flight's MPC worker times its
controllers on the thread's CPU time, so that only work done counts.

Linearisation passes
--------------------
The cuts and normals come from a guess of where the vehicle will be.  If the
rolled-out solution needs slack or fails verification (below) and ``passes``
(3) allow, the rows are relinearised around the solution and the QP solved
again from OSQP's last iterate -- sequential convex programming, usually one
pass (the previous tick's solution is a close guess).  A guess straight
through a neighbour needs the passes: its normals turn by 180 deg from one
segment to the next, half-spaces no trajectory meets at once, so the first
pass uses slack; the solution's own normals are consistent.

Acceptance
----------
The returned trajectory is the exact rollout of the QP's accelerations from
the measured state (ADMM meets the dynamics only to its tolerance: never
stream positions that do not integrate).  It is accepted (``"solved"``) only
if OSQP reported "solved" (or "solved inaccurate"), the slack is within
``slack_tol`` and :func:`verify` finds nothing in continuous time:
``substeps`` (10) samples per step of the piecewise-quadratic trajectory
against the neighbours' predictions interpolated linearly (at a distance
minimum the sampling error is below ``d'' h^2/8``: under a millimetre even for
a 10 m/s fly-by), the speed and acceleration limits within ``limit_tol`` (1 %),
altitude and the geofence.  Every neighbour given is verified, also those
that got no slot.  Anything else -- a start state already out of limits, an
OSQP failure or its iteration/time cap, slack or a verification failure after
the last pass -- is a fallback, one of two checked candidates: the straight
stop at ``max_accel`` from the current state (:func:`brake_trajectory`), and
the path itself as the autopilot would take the vehicle back to it (its
offset fading within ``PATH_SETTLE_S``), checked the same way, "no worse than
now" (a limit already broken at ``t0`` must not get worse), except that the
path must keep the separation outright.  A path that keeps every limit is kept
(status ``"path"``: the executor streams it): in a moving formation a stopped
vehicle is where the ones behind it are about to be (measured on the demo in
6 m/s gusting wind: stops took vehicles 2.6-3.6 m off their paths, against
0.73 m without MPC).  Otherwise the stop is flown if it keeps every limit
(``"fallback"``), else ``"unsafe"``: nothing is flown and the executor streams
the path and says so.  A separation that cannot be kept gets the escape below
first.  The reason names the cause.  No unchecked trajectory is ever
``"solved"``.

Escape
------
When the last pass still cannot keep the separation (a neighbour pushed into
the way, or the vehicle pushed inside one's limit), up to ``passes`` more QPs
are solved, from that pass's solution on, with the speed limits raised by ``ESCAPE_SPEED_MARGIN``
(20 %: the show's limits are planning limits, and an autopilot asked for a
little more clamps to its own rather than failing), the acceleration limit
unchanged.  A fallback that keeps every limit (the path, or the stop: above)
is preferred to it, unless the vehicle starts inside a neighbour's limit.  Its
solution is flown as a ``"fallback"`` only if, checked against those raised
speeds, nothing but the separation is short, and it keeps farther from every
neighbour than both the straight stop and the path (flown as an autopilot
would take the vehicle back to it); otherwise the stop if it keeps farther
than the path, else ``"unsafe"`` (the executor streams the path).  The reason
gives the distances.  Measured on the quick show with a 4.2 m push of vehicle
1 into vehicle 8 (``bench_mpc.py flight --scenarios shove``): 1.19 m without
MPC; 1.27-1.40 m with it (runs vary by the timing of the 10 Hz ticks against
the push) -- the push carries the vehicle 4.2 m in one second whatever is
commanded, so the neighbour alone must make up the gap within its
acceleration limit.

Weak vehicles
-------------
A vehicle with less authority than its fleet
(:mod:`groundctl.execute.authority`) gets its own, scaled limits and a
``lookahead`` of its path (20 s): the reference it is corrected towards is then
that path re-timed to what it can fly (:mod:`groundctl.execute.retime`: it sets
off early and lands late, halving the largest error of simply following), not
the path itself.  The re-timing is solved again every ``RETIME_EVERY_S``; the
MPC, its neighbours and its verification are as for any vehicle.

Many vehicles at once
---------------------
If every vehicle solved against the others' *old* predictions, two vehicles
closing on each other would both dodge, possibly into each other.
:func:`solve_in_priority` solves in a fixed order (ascending system id) and
feeds each later vehicle the fresh results of the earlier ones (replacing, or
adding, their predictions).  Every pair (i, j) with i before j is then verified
in j's solve against i's *final* trajectory, so every pair of returned
trajectories keeps the separation (or j's result says it could not: a
fallback or unsafe status).  The price: earlier vehicles plan against the
later ones' predictions, not their new plans, so the later ones give way.
One process solves them one after the other (a few ms each); parallel
workers would need the same order per group of interacting vehicles.

Past the horizon
----------------
:meth:`MpcResult.sample` past the horizon end continues at the final velocity
with zero acceleration: a solved result ends on the path with the path's
velocity, so a stale result degrades into "keep flying like the path" rather
than a commanded stop (a velocity step the autopilot would brake hard for); a
stop trajectory ends at rest and so holds.  Before ``t0`` it gives the start.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Literal

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from groundctl.execute.retime import Retimed, Retimer
from groundctl.plan.qp_build import SLACK_TOL, FixedPattern, RowBuilder, chord_normals
from groundctl.plan.quad_qp import SEPARATION_BUFFER, chord_separation
from groundctl.plan.verify import inside_polygon
from groundctl.show.model import Limits

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
Status = Literal["solved", "fallback", "path", "unsafe"]

#: OSQP settings of the MPC (module docstring, "Solver settings"): loose ADMM
#: tolerances made exact by polishing, termination checked every 5 iterations so a
#: warm-started solve stops early, caps that keep a pass within 15 ms.
MPC_OSQP_SETTINGS: dict[str, float | int | bool] = {
    "verbose": False,
    "eps_abs": 1e-3,
    "eps_rel": 1e-3,
    "max_iter": 600,
    "time_limit": 0.015,
    "polishing": True,
    "adaptive_rho": True,
    "check_termination": 5,
    "check_dualgap": False,
    "warm_starting": True,
}
#: OSQP's status when a pass hits ``time_limit``.
_TIME_LIMIT = "run time limit reached"
#: Times at most a pass that hit ``time_limit`` is resumed from its last iterate (a busy
#: machine preempts the worker mid-pass; the batch's own budget still bounds the whole)...
_TIME_LIMIT_RESUMES = 20
#: ... and only while the solve (all its passes) has taken less than this on the
#: controller's clock, s: the worker's batch budget is 60 % of its 0.2 s deadline,
#: shared by every vehicle.
_RESUME_WITHIN_S = 0.05
#: OSQP outcomes whose iterate is worth verifying.
_ACCEPTED_OSQP = ("solved", "solved inaccurate")
#: Absolute tolerance on separation and altitude in the verifier, m.
DIST_TOL = 1e-3
#: Inside a neighbour's separation at the start (pushed there), the MPC asks the
#: distance to grow at least this fast until the limit is met again, m/s.
RECOVERY_MPS = 0.75
#: How fast an autopilot streamed the path takes a vehicle back onto it (its offset
#: fades as exp(-t / PATH_SETTLE_S)), s: the "keep its path" escape candidate.
PATH_SETTLE_S = 1.0
#: A weak vehicle's re-timed reference is solved again after this long, s.
RETIME_EVERY_S = 1.0
#: ... or at once when its path ahead has moved by more than this from the one it was
#: re-timed from (the show clock held, a return or a way out replaced the path), m.
RETIME_PATH_TOL_M = 0.05
#: Below this a direction (speed, acceleration) is taken as undefined.
_TINY = 1e-6


@dataclass(frozen=True)
class MpcWeights:
    """Weights of the MPC cost (see the module docstring for the formula)."""

    position: float = 1.0
    """Squared position error along the horizon, per second of horizon, 1/(m^2 s)."""
    velocity: float = 0.3
    """Squared velocity error along the horizon, per second of horizon."""
    terminal_position: float = 30.0
    """Squared position error at the horizon end (not scaled by dt)."""
    terminal_velocity: float = 20.0
    """Squared velocity error at the horizon end."""
    accel: float = 0.1
    """Squared acceleration deviation from the path's, per second of horizon."""
    jerk: float = 0.01
    """Squared rate of change of the acceleration deviation, s^2 per second of horizon."""
    slack: float = 1e3
    """Penalty per unit of slack (m/s of speed, m of altitude or fence...): large enough
    that any feasible correction is preferred to breaking a limit."""
    separation_slack: float = 1e3
    """Penalty per metre of separation slack.  The same as the others' by default: ten
    times more left a plain 3 m rejoin 0.7 m off its path at the horizon end (ADMM
    stopped early on the worse-conditioned QP); distance is put before speed by the
    escape pass instead (module docstring, "Escape")."""

    def __post_init__(self) -> None:
        for name in ("position", "velocity", "terminal_position", "terminal_velocity",
                     "accel", "jerk", "slack", "separation_slack"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"`{name}` must be finite and non-negative, got {value}")
        if self.accel == 0 and self.jerk == 0:
            raise ValueError("`accel` and `jerk` must not both be zero (the QP needs effort)")


def _default_osqp() -> dict[str, float | int | bool]:
    return dict(MPC_OSQP_SETTINGS)


@dataclass(frozen=True)
class MpcConfig:
    """Shape and tuning of one vehicle's MPC (fixed for the controller's life)."""

    dt: float = 0.1
    """Step of the QP, s (the setpoint period)."""
    steps: int = 30
    """Steps in the horizon (30 x 0.1 s = 3 s)."""
    weights: MpcWeights = field(default_factory=MpcWeights)
    """Cost weights."""
    max_neighbours: int = 8
    """Neighbour slots in the QP; more neighbours in reach keep only the nearest ones
    in the QP (every neighbour is still verified)."""
    reach_m: float = 8.0
    """A neighbour whose prediction comes within this of the linearisation point over
    the horizon gets a slot, m."""
    max_fence_edges: int = 8
    """Geofence edge slots (a convex fence with more edges gets its nearest ones)."""
    speed_faces: int = 8
    """Faces of the polygon that bounds the horizontal speed."""
    passes: int = 3
    """Most linearisations (QP solves) per tick."""
    substeps: int = 10
    """Verification samples per step."""
    limit_tol: float = 0.01
    """Relative tolerance of the speed and acceleration checks."""
    slack_tol: float = SLACK_TOL
    """Largest slack (m or m/s) a solution may use and still be accepted: ADMM meets
    its rows only to its tolerance; the limits themselves are verified after."""
    osqp_settings: dict[str, float | int | bool] = field(default_factory=_default_osqp)
    """OSQP settings (iteration and time caps included)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"`dt` must be positive, got {self.dt}")
        if self.steps < 2:
            raise ValueError(f"`steps` must be at least 2, got {self.steps}")
        if self.max_neighbours < 0 or self.max_fence_edges < 0:
            raise ValueError("`max_neighbours` and `max_fence_edges` must be non-negative")
        if self.speed_faces < 4:
            raise ValueError(f"`speed_faces` must be at least 4, got {self.speed_faces}")
        if self.passes < 1 or self.substeps < 1:
            raise ValueError("`passes` and `substeps` must be at least 1")
        if not self.reach_m > 0:
            raise ValueError(f"`reach_m` must be positive, got {self.reach_m}")
        if not (0 <= self.limit_tol < 0.1 and 0 <= self.slack_tol < 0.1):
            raise ValueError("`limit_tol` and `slack_tol` must be within [0, 0.1)")

    @property
    def horizon_s(self) -> float:
        """Length of the horizon, s."""
        return self.dt * self.steps


def _array(name: str, value: ArrayLike, shape: tuple[int | None, ...]) -> FloatArray:
    """``value`` as a finite float array of ``shape`` (None: any length); ValueError naming it."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"`{name}` must be a numeric array") from exc
    if arr.ndim != len(shape) or any(s is not None and s != d for s, d in
                                     zip(shape, arr.shape, strict=True)):
        dims = ["*" if s is None else str(s) for s in shape]
        want = f"({dims[0]},)" if len(dims) == 1 else "(" + ", ".join(dims) + ")"
        raise ValueError(f"`{name}` must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"`{name}` must be finite (it holds NaN or inf)")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class MpcRequest:
    """Everything one solve needs; times are show-clock seconds."""

    sysid: int
    """MAVLink system id of the vehicle."""
    t0: float
    """The solve instant on the caller's clock (the executor's own clock, not the show
    clock): the state below is the vehicle's at this time."""
    p0: FloatArray
    """(3,) measured position carried to ``t0``, show frame, m."""
    v0: FloatArray
    """(3,) measured velocity at ``t0``, m/s."""
    ref_pos: FloatArray
    """(N+1, 3) the vehicle's path at ``t0 + k dt``, k = 0..N."""
    ref_vel: FloatArray
    """(N+1, 3) the path's velocity at the same instants."""
    ref_acc: FloatArray
    """(N+1, 3) the path's acceleration at the same instants."""
    limits: Limits
    """The flight envelope."""
    neighbours: FloatArray | None = None
    """(m, N+1, 3) predicted positions of the other vehicles at the same instants
    (their MPC output, or their path shifted by their current error); None: none."""
    neighbour_ids: IntArray | None = None
    """(m,) their system ids, distinct (messages, slots, :func:`solve_in_priority`);
    required with ``neighbours``."""
    a0: FloatArray | None = None
    """(3,) the vehicle's current acceleration, if known (smooths the first step)."""
    own: FloatArray | None = None
    """(N+1, 3) how far the vehicle is expected to fly from the trajectory it is given
    (its deviation now, drifting as forecast), when it is replanned from its reference
    rather than from where it is: ``neighbours`` are then given relative to it (minus
    it), and :func:`with_predictions` shifts fresh results the same way.  None: zeros."""
    lookahead: FloatArray | None = None
    """(L+1, 3) the path at ``t0 + k lookahead_dt`` far beyond the horizon, for a
    vehicle that cannot fly it as fast as it goes (``limits`` are then its own): the
    reference becomes the path re-timed to those limits (module docstring, "Weak
    vehicles").  None: the path as it is."""
    lookahead_dt: float = 0.25
    """Step of ``lookahead``, s."""

    def __post_init__(self) -> None:
        if not math.isfinite(self.t0):
            raise ValueError(f"`t0` must be finite, got {self.t0}")
        set_ = object.__setattr__
        set_(self, "p0", _array("p0", self.p0, (3,)))
        set_(self, "v0", _array("v0", self.v0, (3,)))
        ref = _array("ref_pos", self.ref_pos, (None, 3))
        if len(ref) < 3:
            raise ValueError(f"`ref_pos` must hold at least 3 samples, got {len(ref)}")
        set_(self, "ref_pos", ref)
        n = len(ref)
        set_(self, "ref_vel", _array("ref_vel", self.ref_vel, (n, 3)))
        set_(self, "ref_acc", _array("ref_acc", self.ref_acc, (n, 3)))
        if self.a0 is not None:
            set_(self, "a0", _array("a0", self.a0, (3,)))
        if self.own is not None:
            set_(self, "own", _array("own", self.own, (n, 3)))
        if self.lookahead is not None:
            set_(self, "lookahead", _array("lookahead", self.lookahead, (None, 3)))
            if len(self.lookahead) < 3 or not self.lookahead_dt > 0:
                raise ValueError("`lookahead` must hold at least 3 samples and "
                                 "`lookahead_dt` be positive")
        nb = np.empty((0, n, 3)) if self.neighbours is None else self.neighbours
        nb = _array("neighbours", nb, (None, n, 3))
        set_(self, "neighbours", nb)
        if self.neighbour_ids is None:
            if len(nb):
                raise ValueError("`neighbour_ids` must be given with `neighbours`")
            ids = np.empty(0, dtype=np.intp)
        else:
            ids = np.asarray(self.neighbour_ids)
            if ids.shape != (len(nb),) or (len(ids) and ids.dtype.kind not in "iu"):
                raise ValueError(f"`neighbour_ids` must be ({len(nb)},) integers, one per "
                                 f"neighbour, got shape {ids.shape}")
            ids = ids.astype(np.intp)
            if len(np.unique(ids)) != len(ids):
                raise ValueError("`neighbour_ids` must not repeat a vehicle")
        ids.setflags(write=False)
        set_(self, "neighbour_ids", ids)

    @property
    def others(self) -> FloatArray:
        """(m, N+1, 3) neighbour predictions (never None after construction)."""
        assert self.neighbours is not None
        return self.neighbours

    @property
    def other_ids(self) -> IntArray:
        """(m,) neighbour system ids (never None after construction)."""
        assert self.neighbour_ids is not None
        return self.neighbour_ids


@dataclass(frozen=True)
class MpcResult:
    """One solve's outcome: always a trajectory, and whether it may be flown as planned."""

    sysid: int
    """System id of the vehicle."""
    status: Status
    """``"solved"``: the MPC's correction, verified; ``"fallback"``: a verified stop
    (the MPC could not give one), or the escape; ``"path"``: neither, the path the
    executor streams keeps every limit (it streams it); ``"unsafe"``: nothing
    found keeps every limit, and the path is no worse than the rest (the executor
    streams it and says so).  The trajectory of a ``"path"`` or ``"unsafe"``
    result is the stop that was checked, never flown"""
    reason: str
    """Why it is not ``"solved"`` ("" when it is)."""
    t0: float
    """Show time of the first sample, s."""
    dt: float
    """Step, s."""
    pos: FloatArray
    """(N+1, 3) positions at ``t0 + k dt``, m."""
    vel: FloatArray
    """(N+1, 3) velocities, m/s."""
    acc: FloatArray
    """(N, 3) acceleration held over each step, m/s^2."""
    solve_ms: float
    """Wall time of the solve, ms (for reporting only)."""
    iterations: int
    """OSQP iterations, all passes together (0 when no QP was run)."""
    passes: int
    """QP solves (linearisations) this tick."""
    max_slack: float
    """Largest slack of the last QP solution (0 if none)."""
    min_separation: float
    """Smallest distance to any predicted neighbour over the horizon, m (inf: none)."""
    closest: int | None
    """System id of that neighbour (None: no neighbours)."""
    neighbours_used: int
    """Neighbours that had a slot in the QP."""

    @property
    def accepted(self) -> bool:
        return self.status == "solved"

    @property
    def times(self) -> FloatArray:
        """(N+1,) the sample instants."""
        return np.asarray(self.t0 + self.dt * np.arange(len(self.pos)), dtype=np.float64)

    @property
    def end(self) -> float:
        """Show time of the last sample."""
        return self.t0 + self.dt * (len(self.pos) - 1)

    def sample(self, t: float | ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, velocity and acceleration at show time(s) ``t``.

        Exact on the piecewise-quadratic trajectory; before ``t0`` the start; past the
        end, the final velocity continued with zero acceleration (module docstring).
        A scalar ``t`` gives (3,) arrays, ``t`` of shape (T,) gives (T, 3).
        """
        return _sample(self.t0, self.dt, self.pos, self.vel, self.acc, t)


def _sample(t0: float, dt: float, pos: FloatArray, vel: FloatArray, acc: FloatArray,
            t: float | ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    scalar = np.ndim(t) == 0
    rel = np.maximum(np.atleast_1d(np.asarray(t, dtype=float)) - t0, 0.0)
    n = len(acc)
    k = np.minimum(np.floor(rel / dt).astype(np.intp), n)
    tau = (rel - k * dt)[:, None]
    a = np.where((k < n)[:, None], acc[np.minimum(k, n - 1)], 0.0)
    p = pos[k] + vel[k] * tau + 0.5 * a * tau * tau
    v = vel[k] + a * tau
    if scalar:
        return p[0], v[0], a[0]
    return p, v, a


@dataclass(frozen=True)
class _Plan:
    """The rollout of the last QP solution, accepted or not: the next linearisation point."""

    t0: float
    pos: FloatArray
    vel: FloatArray
    acc: FloatArray
    duals: FloatArray
    """OSQP's duals of that solution (shifted for the next warm start)."""


@dataclass(frozen=True)
class TrajectoryCheck:
    """What :func:`verify` found on one trajectory."""

    violations: tuple[str, ...]
    """One line per broken limit; empty when the trajectory is safe."""
    min_separation: float
    """Smallest distance to any neighbour, m (inf: no neighbours)."""
    closest: int | None
    """System id of that neighbour."""

    @property
    def ok(self) -> bool:
        return not self.violations


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


def verify(pos: FloatArray, vel: FloatArray, acc: FloatArray, dt: float, limits: Limits,
           neighbours: FloatArray | None = None, neighbour_ids: ArrayLike | None = None, *,
           substeps: int = 10, limit_tol: float = 0.01, baseline: bool = False) -> TrajectoryCheck:
    """Check a trajectory (pos, vel (N+1, 3), acc (N, 3)) in continuous time.

    ``substeps`` samples per step of the piecewise-quadratic trajectory against the
    neighbours' predictions (m, N+1, 3) interpolated linearly; speeds and
    accelerations within ``limit_tol`` (relative), separation and altitude within
    :data:`DIST_TOL`, the geofence (any polygon, even-odd rule).  ``baseline``:
    every limit already broken at the first sample is relaxed to its value there
    ("no worse than now", for a stop from a bad state; a fence already left is not
    checked).  Time offsets in the messages are from the first sample.
    """
    ps, vs, offs = _dense(pos, vel, acc, dt, substeps)
    out: list[str] = []
    vh = np.linalg.norm(vs[:, :2], axis=1)
    an = np.linalg.norm(acc, axis=1)
    checks = [("horizontal speed", vh, limits.max_speed_h, "m/s", "max_speed_h"),
              ("climb rate", vs[:, 2], limits.max_speed_up, "m/s", "max_speed_up"),
              ("descent rate", -vs[:, 2], limits.max_speed_down, "m/s", "max_speed_down")]
    for what, values, limit, unit, name in checks:
        allowed = max(limit, float(values[0])) if baseline else limit
        worst = int(np.argmax(values))
        if values[worst] > allowed * (1 + limit_tol) + 1e-9:
            out.append(f"{what} {values[worst]:.2f} {unit} at +{offs[worst]:.2f} s "
                       f"({name} {limit} {unit})")
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
            out.append(f"separation from vehicle {int(ids[b])} {per[b]:.2f} m at "
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
    """Limits the measured state already breaks at ``t0`` (nothing a correction can fix)."""
    lim, p = request.limits, request.p0
    out = speed_violations(request.v0, lim, limit_tol)
    if p[2] < lim.min_alt - DIST_TOL or p[2] > lim.max_alt + DIST_TOL:
        out.append(f"altitude {p[2]:.2f} m outside [{lim.min_alt}, {lim.max_alt}] m")
    if lim.geofence and not inside_polygon(np.asarray(lim.geofence, dtype=float), p[None, :2])[0]:
        out.append(f"position ({p[0]:.2f}, {p[1]:.2f}) outside the geofence")
    nb = request.others
    if len(nb):
        d = np.linalg.norm(nb[:, 0] - p[None], axis=1)
        j = int(np.argmin(d))
        if d[j] < lim.min_separation - DIST_TOL:
            out.append(f"{d[j]:.2f} m from vehicle {int(request.other_ids[j])} "
                       f"(min_separation {lim.min_separation} m)")
    return out


class MpcController:
    """One vehicle's MPC: the QP built once, updated and warm-started every tick."""

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
        hi[self.vcut_rows] = lim.max_speed_h
        hi[self.vpoly_rows] = lim.max_speed_h
        up = np.tile([1.0, 0.0], N).astype(bool)
        vz_lo = np.where(up, -np.inf, -lim.max_speed_down)
        vz_hi = np.where(up, lim.max_speed_up, np.inf)
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

    def solve(self, request: MpcRequest) -> MpcResult:
        """One tick: the verified correction, or a stop with the reason why not."""
        self._continuing = False
        result = self._solve(request)
        if self._continuing and result.status in ("solved", "fallback"):
            # Solved with the escape's raised limits from a start above its own: it may
            # still be above them next tick, and the escape goes on until it is not.
            self._escaped = True
        return result

    def _solve(self, request: MpcRequest) -> MpcResult:
        self._check(request)
        # The path the executor streams when the MPC gives nothing: a weak vehicle's
        # is its plan, not the re-timed reference the QP tracks.
        self._streamed = request
        if request.lookahead is not None:
            request = self._retimed_request(request)
        start = self._clock()
        # Already inside a neighbour's separation (pushed there): not a reason to give
        # up, a reason to get out.  Anything else already broken is.
        bad_start = start_violations(replace(request, neighbours=None, neighbour_ids=None),
                                     self.config.limit_tol)
        escape_at = escape_limits(request.limits)  # never raised twice
        if bad_start and self._escaped:
            # Flying an escape, up to ESCAPE_SPEED_MARGIN over its speed limits: it goes on
            # with those raised limits until its speed is back within its own, instead of
            # ending after one tick on a start state it was told to fly.
            continued = replace(request, limits=escape_at)
            if not start_violations(replace(continued, neighbours=None, neighbour_ids=None),
                                    self.config.limit_tol):
                request, bad_start = continued, []
                self._continuing = True
        self._escaped = False
        if bad_start:
            return self._fallback(request, "start state: " + "; ".join(bad_start), start)
        d0 = np.linalg.norm(request.others[:, 0] - request.p0[None], axis=1)
        inside = d0 < request.limits.min_separation - DIST_TOL
        self._start_distance = d0 if inside.any() else None
        recovering = bool(inside.any())
        cfg = self.config
        gp, gv, ga = self._guess(request)
        self._update_cost(request)
        iterations = 0
        req, cause = request, ""
        for npass in range(1, 2 * cfg.passes + 1):
            escaping = npass > cfg.passes  # the escape passes (module docstring, "Escape")
            slots = self._assign_slots(req, gp)
            self._cuts(npass - cfg.passes if escaping else npass, req, gv, ga)
            self._linearise(req, gp, gv, ga, slots)
            if npass == 1:
                # After the update: warm_start sets OSQP's z = A x with the A it holds
                # (measured: half the iterations of a cold tick).  Later passes start
                # from OSQP's own last iterate.
                self._warm(request, gp, gv, ga)
            res = self.solver.solve(raise_error=False)
            iterations += int(res.info.iter)
            status = str(res.info.status)
            for _ in range(_TIME_LIMIT_RESUMES):
                if status != _TIME_LIMIT or self._clock() - start > _RESUME_WITHIN_S:
                    break
                # The pass ran out of (wall) time, usually because this process was not
                # scheduled: go on from OSQP's own last iterate rather than fall back
                # (while the whole solve is young: the batch has a deadline too).
                res = self.solver.solve(raise_error=False)
                iterations += int(res.info.iter)
                status = str(res.info.status)
            if status not in _ACCEPTED_OSQP:
                if escaping:  # the escape's QP failed: the last pass's cause stands
                    return self._fallback(request, cause, start, iterations, npass)
                return self._fallback(request, f"OSQP {status} after {res.info.iter} "
                                      f"iterations (pass {npass})", start, iterations, npass)
            x = np.asarray(res.x)
            acc = x[self.oA: self.oSs].reshape(self.N, 3).copy()
            # The norm limit is met through tangent-plane cuts, which a solution can still
            # overshoot at a corner (measured: 2.59 m/s^2 for 2.5 on a dodge): project each
            # step's acceleration onto the ball, then roll out and verify what is flown.
            a_max = req.limits.max_accel * (1.0 - cfg.limit_tol / 2)
            norm = np.linalg.norm(acc, axis=1, keepdims=True)
            acc *= np.minimum(1.0, a_max / np.maximum(norm, _TINY))
            pos, vel = rollout(request.p0, request.v0, acc, self.dt)
            self._lin = _Plan(request.t0, pos, vel, acc, np.array(res.y))
            slack = x[self.oSs:]
            max_slack = float(max(slack.max(), 0.0))
            used = int((slots >= 0).sum())
            if escaping:
                escape = verify(pos, vel, acc, self.dt, req.limits, req.others,
                                req.other_ids, substeps=cfg.substeps,
                                limit_tol=cfg.limit_tol, baseline=recovering)
                if npass < 2 * cfg.passes and (max_slack > cfg.slack_tol or not escape.ok):
                    gp, gv, ga = pos, vel, acc
                    continue
                last = verify(pos, vel, acc, self.dt, request.limits, request.others,
                              request.other_ids, substeps=cfg.substeps,
                              limit_tol=cfg.limit_tol, baseline=recovering)
                return self._escape(request, pos, vel, acc, last, escape, cause, start,
                                    iterations, npass, max_slack, used)
            check = verify(pos, vel, acc, self.dt, request.limits, request.others,
                           request.other_ids, substeps=cfg.substeps, limit_tol=cfg.limit_tol,
                           baseline=recovering)
            # The envelope's slack (speed, altitude, fence) is judged on what is flown: the
            # rollout, by the verifier, within ``limit_tol``.  The QP's own velocities meet
            # the dynamics only to ADMM's tolerance, and a weak vehicle re-timed at 60 % of
            # its limits was stopped mid-climb for 10 mm/s of slack on a rollout that kept
            # them.  The separation's slack is never accepted.
            sep_slack = float(np.max(slack[: self.oSe - self.oSs], initial=0.0))
            if sep_slack <= cfg.slack_tol and check.ok:
                result = MpcResult(
                    sysid=self.sysid, status="solved", reason="", t0=request.t0, dt=self.dt,
                    pos=pos, vel=vel, acc=acc, solve_ms=1e3 * (self._clock() - start),
                    iterations=iterations, passes=npass, max_slack=max_slack,
                    min_separation=check.min_separation, closest=check.closest,
                    neighbours_used=used)
                self._last = result
                return result
            if npass < cfg.passes:
                # Relinearise around this solution, slack and all (OSQP warm-starts from
                # it by itself): a guess through a neighbour gives half-spaces that no
                # trajectory can meet at once; the solution's own normals can be.
                gp, gv, ga = pos, vel, acc
                continue
            if max_slack > cfg.slack_tol:
                n_sep = self.oSe - self.oSs
                sep_slack = float(np.max(slack[:n_sep], initial=0.0))
                what = "separation" if sep_slack >= np.max(slack[n_sep:], initial=0.0) \
                    else "speed, altitude or geofence"
                detail = f": {check.violations[0]}" if check.violations else ""
                cause = (f"no correction keeps the limits after {npass} passes ({what} "
                         f"slack {max_slack:.3f}){detail}")
            else:
                sep_slack = 0.0
                cause = f"verification after {npass} passes: " + "; ".join(check.violations)
            if recovering or sep_slack > cfg.slack_tol or \
                    any(v.startswith("separation") for v in check.violations):
                # The separation is what cannot be kept: one more pass with the speeds
                # allowed ESCAPE_SPEED_MARGIN over their limits, from this solution.
                req, gp, gv, ga = (replace(request, limits=escape_at), pos, vel, acc)
                continue
            return self._fallback(request, cause, start, iterations, npass, max_slack, used)
        raise AssertionError("unreachable")  # pragma: no cover

    def _escape(self, req: MpcRequest, pos: FloatArray, vel: FloatArray, acc: FloatArray,
                check: TrajectoryCheck, escape: TrajectoryCheck, cause: str, start: float,
                iterations: int, passes: int, max_slack: float, used: int) -> MpcResult:
        recovering = self._start_distance is not None
        where = f"inside a neighbour's separation: {cause}" if recovering else cause
        stop, stop_check, on_path = self._judged_fallback(req, where, start, iterations,
                                                          passes, max_slack, used)
        if stop.status in ("fallback", "path") and not recovering:
            return stop  # a fallback that keeps every limit beats an escape that breaks one
        best_other = max(stop_check.min_separation, on_path.min_separation)
        usable = not escape.violations or _only_separation(escape)
        if usable and check.min_separation > best_other + DIST_TOL:
            result = MpcResult(
                sysid=self.sysid, status="fallback",
                reason=f"{where}: the best escape found keeps {check.min_separation:.2f} m "
                       f"(its path {on_path.min_separation:.2f} m, the stop "
                       f"{stop.min_separation:.2f} m)", t0=req.t0, dt=self.dt, pos=pos,
                vel=vel, acc=acc, solve_ms=1e3 * (self._clock() - start),
                iterations=iterations, passes=passes, max_slack=max_slack,
                min_separation=check.min_separation, closest=check.closest,
                neighbours_used=used)
            self._last = result
            self._escaped = True
            return result
        if stop.status == "fallback" and \
                on_path.min_separation > stop_check.min_separation + DIST_TOL:
            # The stop breaks nothing new but the path keeps farther away: the path.
            stop = replace(stop, status="unsafe",
                           reason=f"{stop.reason}; the stop keeps "
                                  f"{stop_check.min_separation:.2f} m, its path "
                                  f"{on_path.min_separation:.2f} m")
            self._last = None
        return stop

    def _retimed_request(self, req: MpcRequest) -> MpcRequest:
        """``req`` with its reference replaced by the path re-timed to its limits (solved
        again every ``RETIME_EVERY_S``, or when the last one no longer covers the
        horizon); as it is if the re-timing QP fails."""
        assert req.lookahead is not None
        steps = len(req.lookahead) - 1
        rt = self._retimed
        moved = rt is not None and self._path_moved(req.t0, req.lookahead, req.lookahead_dt)
        if moved or (rt is not None and rt.end < req.t0 + self.config.horizon_s):
            rt = self._retimed = None  # no reference to keep if the new one fails
        stale = rt is None or not (rt.t0 <= req.t0 < rt.t0 + RETIME_EVERY_S)
        if stale:
            self._retimed_from = (req.t0, req.lookahead_dt, req.lookahead)
            if self._retimer is None or self._retimer.steps != steps or \
                    self._retimer.dt != req.lookahead_dt:
                self._retimer = Retimer(steps=steps, dt=req.lookahead_dt)
            fresh = self._retimer.solve(req.t0, req.lookahead, req.p0, req.v0, req.limits)
            rt = self._retimed = fresh if fresh is not None else rt
        if rt is None:
            return replace(req, lookahead=None)
        rp, rv, ra = rt.sample(req.t0 + self.dt * np.arange(self.N + 1))
        return replace(req, ref_pos=rp, ref_vel=rv, ref_acc=ra, lookahead=None)

    def _path_moved(self, t0: float, lookahead: FloatArray, dt: float) -> bool:
        """Whether the path ahead (``lookahead`` from ``t0``) is no longer the one the
        reference was re-timed from, where the two overlap.

        The re-timed reference sets off before its path does; when the show clock holds
        (or a return replaces the path) the path's future stands still, and a reference
        kept for ``RETIME_EVERY_S`` would still lead the vehicle off towards where its
        path would have gone: under load, with the solves late, for seconds, into a
        neighbour hovering below (1.18 m, seen)."""
        if self._retimed_from is None:
            return True
        t_old, dt_old, old = self._retimed_from
        times = t0 + dt * np.arange(len(lookahead))
        u = (times - t_old) / dt_old
        inside = u <= len(old) - 1
        if not inside.any():
            return True
        u = u[inside]
        k = np.clip(u.astype(np.intp), 0, len(old) - 2)
        frac = (u - k)[:, None]
        then = old[k] * (1.0 - frac) + old[k + 1] * frac
        return bool(np.abs(then - lookahead[inside]).max() > RETIME_PATH_TOL_M)

    def _path_back(self, req: MpcRequest) -> TrajectoryCheck:
        """The path checked as the executor would fly it if the MPC gave nothing: the
        autopilot takes the vehicle back onto it, its offset decaying critically damped
        with time constant ``PATH_SETTLE_S`` (position and velocity consistent)."""
        tau = PATH_SETTLE_S
        t = (self.dt * np.arange(len(req.ref_pos)))[:, None]
        e0, de0 = req.p0 - req.ref_pos[0], req.v0 - req.ref_vel[0]
        c = de0 + e0 / tau  # critically damped: e = (e0 + c t) exp(-t / tau)
        fade = np.exp(-t / tau)
        back_pos = req.ref_pos + (e0 + c * t) * fade
        back_vel = req.ref_vel + (c - (e0 + c * t) / tau) * fade
        # The autopilot brings it back within its own acceleration limit: what is judged
        # here is where the path takes it (separation, speeds, altitude, fence).
        check = verify(back_pos, back_vel, np.diff(back_vel, axis=0) / self.dt, self.dt,
                       replace(req.limits, max_accel=math.inf), req.others, req.other_ids,
                       substeps=self.config.substeps, limit_tol=self.config.limit_tol,
                       baseline=True)
        if check.min_separation < req.limits.min_separation - DIST_TOL and check.ok:
            # "No worse than now" is for the envelope (a gust's 2.6 m/s climb is not the
            # path's doing); the separation it must keep outright.
            check = replace(check, violations=(
                f"separation from vehicle {check.closest} {check.min_separation:.2f} m "
                f"(min_separation {req.limits.min_separation} m)",))
        return check

    def _fallback(self, req: MpcRequest, cause: str, start: float, iterations: int = 0,
                  passes: int = 0, max_slack: float = 0.0, used: int = 0) -> MpcResult:
        return self._judged_fallback(req, cause, start, iterations, passes, max_slack,
                                     used)[0]

    def _judged_fallback(self, req: MpcRequest, cause: str, start: float, iterations: int,
                         passes: int, max_slack: float, used: int
                         ) -> tuple[MpcResult, TrajectoryCheck, TrajectoryCheck]:
        """The fallback (the checked stop, or the path if it keeps every limit), with the
        checks of both candidates: the stop's and the path's (the escape weighs them)."""
        pos, vel, acc = brake_trajectory(req.p0, req.v0, self.dt, self.N, req.limits.max_accel)
        check = verify(pos, vel, acc, self.dt, req.limits, req.others, req.other_ids,
                       substeps=self.config.substeps, limit_tol=self.config.limit_tol,
                       baseline=True)
        streamed = req if self._streamed is None else self._streamed
        on_path = self._path_back(replace(streamed, p0=req.p0, v0=req.v0, lookahead=None))
        status: Status = "fallback" if check.ok else "unsafe"
        reason = cause if check.ok else f"{cause}; the stop is unsafe too: " + \
            "; ".join(check.violations)
        if on_path.ok:
            # A stop in a moving formation is where the others are about to be: a path
            # that keeps every limit (the plan kept the fleet apart) is kept instead.
            status = "path"
            reason = f"{cause}; its path keeps every limit" + (
                f" ({on_path.min_separation:.2f} m from vehicle {on_path.closest})"
                if on_path.closest is not None else "")
        result = MpcResult(
            sysid=self.sysid, status=status, reason=reason, t0=req.t0, dt=self.dt, pos=pos,
            vel=vel, acc=acc, solve_ms=1e3 * (self._clock() - start), iterations=iterations,
            passes=passes, max_slack=max_slack, min_separation=check.min_separation,
            closest=check.closest, neighbours_used=used)
        # Only what is flown is the vehicle's last trajectory (its acceleration smooths
        # the next solve's first step).
        self._last = result if status == "fallback" else None
        return result, check, on_path


#: Speed limits (horizontal, climb, descent) an escape may exceed by this fraction
#: (module docstring, "Escape"); accelerations and everything else stay.
ESCAPE_SPEED_MARGIN = 0.2


def escape_limits(limits: Limits) -> Limits:
    """``limits`` with the speeds raised by :data:`ESCAPE_SPEED_MARGIN`."""
    return limits.scaled(1.0 + ESCAPE_SPEED_MARGIN)


def _only_separation(check: TrajectoryCheck) -> bool:
    """Whether ``check`` found a separation shortfall and nothing else."""
    return bool(check.violations) and all(v.startswith("separation") for v in check.violations)


def with_predictions(request: MpcRequest, fresh: Mapping[int, MpcResult],
                     dt: float, owns: Mapping[int, FloatArray | None] | None = None
                     ) -> MpcRequest:
    """``request`` with the neighbours in ``fresh`` predicted by those results (replaced
    where the request has them, added where it does not), sampled at its instants.

    ``owns`` (system id -> :attr:`MpcRequest.own`) says how far each vehicle is expected
    to fly from its result: a neighbour is where its result plus its own deviation puts
    it, given relative to this request's own deviation, like the request's other
    neighbours."""
    # A "path" or "unsafe" result is not flown (the executor streams that vehicle's
    # path): it must not stand for where that vehicle will be.
    others = {int(r.sysid): r for r in fresh.values()
              if r.sysid != request.sysid and r.status in ("solved", "fallback")}
    if not others:
        return request
    times = request.t0 + dt * np.arange(len(request.ref_pos))
    nb = request.others.copy()
    ids = list(request.other_ids)
    extra = []
    extra_ids = []
    mine = 0.0 if request.own is None else request.own
    for sid, res in others.items():
        traj, _, _ = res.sample(times)
        theirs = (owns or {}).get(sid)
        traj = traj + (0.0 if theirs is None else theirs) - mine
        if sid in ids:
            nb[ids.index(sid)] = traj
        else:
            extra.append(traj)
            extra_ids.append(sid)
    if extra:
        nb = np.concatenate([nb, np.stack(extra)])
        ids = ids + extra_ids
    return replace(request, neighbours=nb, neighbour_ids=np.asarray(ids, dtype=np.intp))


def solve_in_priority(controllers: Mapping[int, MpcController],
                      requests: Iterable[MpcRequest], budget_s: float = math.inf,
                      clock: Callable[[], float] = time.perf_counter
                      ) -> dict[int, MpcResult]:
    """Solve every request in ascending system id, each against the fresh results of the
    ones before it (module docstring: why every pair then keeps its separation).

    ``controllers`` maps system id to that vehicle's controller; ``requests`` hold the
    executor's predictions for everyone, of which the earlier vehicles' are replaced.
    Once ``budget_s`` (of ``clock``) is spent the rest are left unsolved: they get no
    result, rather than every result coming too late.
    """
    ordered = sorted(requests, key=lambda r: r.sysid)
    sysids = [r.sysid for r in ordered]
    if len(set(sysids)) != len(sysids):
        raise ValueError("`requests` holds two requests for the same vehicle")
    missing = [s for s in sysids if s not in controllers]
    if missing:
        raise ValueError(f"`controllers` has no controller for vehicle {missing[0]}")
    fresh: dict[int, MpcResult] = {}
    owns = {r.sysid: r.own for r in ordered}
    start = clock()
    for req in ordered:
        if clock() - start > budget_s:
            break
        ctrl = controllers[req.sysid]
        fresh[req.sysid] = ctrl.solve(with_predictions(req, fresh, ctrl.config.dt, owns))
    return fresh
