"""The MPC's vocabulary: its configuration (:class:`MpcWeights`, :class:`MpcConfig`), one
solve's input (:class:`MpcRequest`) and outcome (:class:`MpcResult`), and what the
verifier finds on a trajectory (:class:`TrajectoryCheck`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from groundctl.plan.qp_build import SLACK_TOL
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
    envelope_brake: float = 0.5
    """A start above a speed limit is flown back within it: the limit closes from the
    measured speed at this fraction of ``max_accel`` (package docstring, "Envelope"; the
    rest of the acceleration is left for steering back to the path)."""
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
        if not 0 < self.envelope_brake <= 1:
            raise ValueError(f"`envelope_brake` must be within (0, 1], got {self.envelope_brake}")
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
    """Why it is not ``"solved"`` (when it is: "", or the limits a start above them was
    flown back within, ``recovering``)."""
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
    recovering: bool = False
    """Solved from a start above a speed limit, within the envelope closing from it
    (package docstring, "Envelope"); ``reason`` says which limits."""

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
