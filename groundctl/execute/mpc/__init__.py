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

Envelope
--------
A start state above a speed limit (a gust carried the vehicle, or an escape left it
faster than even the escape's raised limits: within them the escape goes on, below)
is a state to recover from, never a reason to give up. Each speed limit (horizontal,
climb, descent) becomes an envelope that starts at the measured speed and closes to
the limit at ``envelope_brake`` (0.5) of ``max_accel``: at step k the row's bound is
``max(limit, start - b k dt)``, linear between the steps (:func:`speed_envelope`). A
speed within its limit gives the limit itself, so an in-limit start is solved
exactly as before. The verifier judges a solution against that envelope
(``verify(..., brake=b)``): between two steps the speed of the piecewise-linear
velocity is at most the linear interpolation of its ends' speeds, which the
interpolated bound covers. The QP's rows close ``ENVELOPE_QP_MARGIN`` (1.25) times
faster than the verifier's: an acceleration that overshoots its cuts is projected
back onto the ball, which takes braking away, and without the margin 12 of 300
random over-speed starts rolled out over the envelope (3 with it, where braking hard
horizontally and vertically at once asks more than ``max_accel``): those are checked
fallbacks, never an unchecked flight. The rest of the acceleration is left for
steering: braking at the full ``max_accel`` leaves exactly one trajectory, the
straight stop. A solved result from such a start says so in its reason. The
acceleration needs no envelope: the QP's first acceleration is a decision bounded by
``max_accel`` (the measured one only enters the jerk cost). A position outside the
altitude band or the geofence is still a fallback (the autopilot's own fence reacts
to it; the path or the stop is checked "no worse than now"). Before this, a vehicle
a 15 m/s gust pushed to 4.7 m/s got "start state: horizontal speed 4.69 m/s above
max_speed_h 4.0 m/s; keeping its path", tick after tick, exactly while it needed a
correction.

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
altitude and the geofence (speeds within the envelope, above).  Every neighbour
given is verified, also those that got no slot.  Anything else -- a start
position already outside the altitude band or the geofence, an
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

Modules
-------
The package is split along the sections above (every name the single module had is
importable from here)::

    types       the configuration (MpcWeights, MpcConfig), MpcRequest, MpcResult,
                TrajectoryCheck
    checks      rollout, the straight stop, the continuous-time verifier, neighbour
                selection, convex fences, start-state and escape limits
    qp          MpcQp: the QP built once, relinearised and warm-started every tick
    controller  MpcController(MpcQp): solve, its passes, acceptance, escape and fallbacks
    priority    with_predictions, solve_in_priority: many vehicles at once
"""

from __future__ import annotations

# Every public name the module had before it became a package stays importable from here.
from groundctl.execute.mpc.checks import (
    DIST_TOL,
    ESCAPE_SPEED_MARGIN,
    brake_trajectory,
    convex_fence,
    escape_limits,
    position_violations,
    rollout,
    select_neighbours,
    speed_envelope,
    speed_violations,
    start_violations,
    verify,
)
from groundctl.execute.mpc.controller import (
    PATH_SETTLE_S,
    RETIME_EVERY_S,
    RETIME_PATH_TOL_M,
    MpcController,
)
from groundctl.execute.mpc.priority import solve_in_priority, with_predictions
from groundctl.execute.mpc.qp import RECOVERY_MPS, MpcQp
from groundctl.execute.mpc.types import (
    MPC_OSQP_SETTINGS,
    FloatArray,
    IntArray,
    MpcConfig,
    MpcRequest,
    MpcResult,
    MpcWeights,
    Status,
    TrajectoryCheck,
)

__all__ = [
    "DIST_TOL",
    "ESCAPE_SPEED_MARGIN",
    "MPC_OSQP_SETTINGS",
    "PATH_SETTLE_S",
    "RECOVERY_MPS",
    "RETIME_EVERY_S",
    "RETIME_PATH_TOL_M",
    "FloatArray",
    "IntArray",
    "MpcConfig",
    "MpcController",
    "MpcQp",
    "MpcRequest",
    "MpcResult",
    "MpcWeights",
    "Status",
    "TrajectoryCheck",
    "brake_trajectory",
    "convex_fence",
    "escape_limits",
    "position_violations",
    "rollout",
    "select_neighbours",
    "solve_in_priority",
    "speed_envelope",
    "speed_violations",
    "start_violations",
    "verify",
    "with_predictions",
]
