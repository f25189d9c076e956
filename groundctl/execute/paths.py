"""One path per vehicle: what it is told to fly, as a function of time, and why.

Every streamed vehicle follows exactly one :class:`Path`, chosen in one place
(:meth:`groundctl.execute.sequence.ShowSequence.path`) from where it is in the
sequence:

* ``plan``: its track of the show plan, on the show clock;
* ``hold``: a fixed point (heard again off its plan, it hovers where it is);
* ``way_out``: a planned way out of the show (land-one, a low battery, a
  vehicle heard again off its plan), flown on the show clock from the way out's
  show time; before that it flies its plan, or holds its point;
* ``return``: its row of the fleet's land-all return, on the return's clock;
* ``landing_point``: the point above where it lands (after the show, or a spot
  re-assigned when its own was blocked);
* ``join``: a spare's way into a failed drone's track, on the show clock: over its pad
  at the way in's start until it begins, then the way in, then the track's plan.

The setpoint stream samples every path at each vehicle's own instant
(:func:`sample_paths`, vectorised per kind); the MPC takes a path sampled over
its horizon as its reference; the guard compares telemetry with the path's
position now.  So land-one, land-all, hold, rejoin and the landing are all
"follow another path", and nothing else decides where a vehicle should be.
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.execute.leaving import Join, Leave
from groundctl.execute.showclock import ShowClock
from groundctl.plan.plan import Plan
from groundctl.plan.trajectory import Trajectories

FloatArray = NDArray[np.float64]


class PathKind(enum.StrEnum):
    """What a vehicle's path is."""

    PLAN = "plan"
    HOLD = "hold"
    WAY_OUT = "way_out"
    RETURN = "return"
    LANDING_POINT = "landing_point"
    JOIN = "join"


@dataclass(frozen=True)
class Path:
    """The one trajectory a vehicle follows now, and why."""

    kind: PathKind
    """Which kind of path."""
    reason: str
    """Why it follows this one (for the operator and the event log)."""
    track: int
    """Its track of the show plan."""
    point: tuple[float, float, float] | None = None
    """``hold`` / ``landing_point``: the show-frame point; ``way_out``: where it holds until
    the way out begins (None: it flies its plan there)."""
    leave: Leave | None = None
    """``way_out``: the planned way out, flown from ``leave.at`` on the show clock."""
    row: int | None = None
    """``return``: its row of the return trajectories."""
    join: Join | None = None
    """``join``: the spare's way into the track, flown from ``join.at`` on the show clock."""

    def __post_init__(self) -> None:
        if self.kind in (PathKind.HOLD, PathKind.LANDING_POINT) and self.point is None:
            raise ValueError(f"a {self.kind} path needs a `point`")
        if self.kind is PathKind.WAY_OUT and self.leave is None:
            raise ValueError("a way_out path needs a `leave`")
        if self.kind is PathKind.RETURN and self.row is None:
            raise ValueError("a return path needs a `row`")
        if self.kind is PathKind.JOIN and self.join is None:
            raise ValueError("a join path needs a `join`")

    @property
    def on_show_clock(self) -> bool:
        """Sampled on the show clock (``plan``, ``hold``, ``way_out``, ``join``)."""
        return self.kind in (PathKind.PLAN, PathKind.HOLD, PathKind.WAY_OUT, PathKind.JOIN)

    def fixed_at(self, show_time: float) -> tuple[float, float, float] | None:
        """The point it holds at ``show_time`` (show clock), if it is holding one then."""
        if self.kind in (PathKind.HOLD, PathKind.LANDING_POINT):
            return self.point
        if self.kind is PathKind.WAY_OUT and self.point is not None:
            assert self.leave is not None
            return self.point if show_time < self.leave.at else None
        return None


def position_on_show_clock(path: Path, plan: Plan, show_time: float) -> FloatArray:
    """Where a show-clock path (``plan``, ``hold``, ``way_out``) is at ``show_time``; a
    landing point is where it is."""
    fixed = path.fixed_at(show_time) if path.kind is not PathKind.RETURN else None
    if fixed is not None:
        return np.asarray(fixed, dtype=float)
    if path.kind is PathKind.RETURN:
        raise ValueError("a return path is not on the show clock")
    t = min(max(show_time, 0.0), plan.duration)
    if path.kind is PathKind.WAY_OUT and path.leave is not None and t >= path.leave.at:
        return path.leave.state(t)[0]
    if path.kind is PathKind.JOIN and path.join is not None and t < path.join.until:
        return path.join.state(t)[0]
    return plan.trajectories.evaluate(t, np.array([path.track]))[0][0]


@dataclass(frozen=True)
class PathClocks:
    """The clocks and trajectories the paths are sampled on."""

    plan: Plan
    """The show plan (``plan`` paths, and ``way_out`` before the way out begins)."""
    show: ShowClock | None
    """The show clock; None (or ``ended``): the plan is held at ``show_time``."""
    show_time: float = 0.0
    """Show time to hold at without a running clock, s."""
    ended: bool = False
    """The show clock no longer drives anyone (after the show): no feed-forward."""
    returns: Trajectories | None = None
    """The land-all return's trajectories (``return`` paths)."""
    return_clock: ShowClock | None = None
    """The return's clock."""


def sample_paths(paths: Sequence[Path], at: FloatArray, clocks: PathClocks
                 ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position, velocity and acceleration (n, 3) of ``paths[i]`` at our time ``at[i]``.

    Velocity and acceleration carry the clocks' warp (``rate * p'`` and ``rate**2 * p''
    + rate' * p'``), so a braking clock brakes each drone along its own path; fixed
    points and anything past its trajectory's end have none.
    """
    n = len(paths)
    at = np.asarray(at, dtype=float)
    if at.shape != (n,):
        raise ValueError(f"`at` must have shape ({n},), not {at.shape}")
    pos, vel, acc = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    if n == 0:
        return pos, vel, acc
    duration = clocks.plan.duration
    if clocks.show is not None and not clocks.ended:
        t, rate, drate = clocks.show.at_many(at)
        t = np.clip(t, 0.0, duration)
    else:
        t = np.full(n, min(max(clocks.show_time, 0.0), duration))
        rate, drate = np.zeros(n), np.zeros(n)
    over = t >= duration  # past the end the plan holds its final state
    rate, drate = np.where(over, 0.0, rate), np.where(over, 0.0, drate)

    kinds = np.array([p.kind.value for p in paths])
    on_plan = (kinds == PathKind.PLAN.value) | (kinds == PathKind.WAY_OUT.value) \
        | (kinds == PathKind.JOIN.value)
    idx = np.flatnonzero(on_plan)
    if idx.size:
        tracks = np.array([paths[int(i)].track for i in idx], dtype=np.intp)
        p, v, a = clocks.plan.trajectories.evaluate_each(t[idx], tracks)
        pos[idx] = p
        vel[idx] = rate[idx, None] * v
        acc[idx] = (rate[idx] ** 2)[:, None] * a + drate[idx, None] * v
    for i in np.flatnonzero((kinds != PathKind.PLAN.value) & (kinds != PathKind.RETURN.value)):
        path = paths[int(i)]
        fixed = path.fixed_at(float(t[i]))
        if fixed is not None:
            pos[i], vel[i], acc[i] = fixed, 0.0, 0.0
        elif path.kind is PathKind.WAY_OUT:
            leave = path.leave
            assert leave is not None
            ti = float(t[i])
            if ti < leave.at:
                continue  # still on its plan (sampled above)
            lp, lv, la = leave.state(ti)
            if ti >= leave.until:
                pos[i], vel[i], acc[i] = lp, 0.0, 0.0
            else:
                r, dr = float(rate[i]), float(drate[i])
                pos[i], vel[i], acc[i] = lp, r * lv, r * r * la + dr * lv
        elif path.kind is PathKind.JOIN:
            join = path.join
            assert join is not None
            ti = float(t[i])
            if ti >= join.until:
                continue  # on the track's plan (sampled above)
            jp, jv, ja = join.state(ti)  # before it begins: at rest at its start
            r, dr = float(rate[i]), float(drate[i])
            pos[i], vel[i], acc[i] = jp, r * jv, r * r * ja + dr * jv
    ret = np.flatnonzero(kinds == PathKind.RETURN.value)
    if ret.size:
        if clocks.returns is None or clocks.return_clock is None:
            raise ValueError("`return` paths need the return's trajectories and clock")
        end = clocks.returns.end
        tr, fr, fdr = clocks.return_clock.at_many(at[ret])
        tr = np.clip(tr, 0.0, end)
        done = tr >= end
        fr, fdr = np.where(done, 0.0, fr), np.where(done, 0.0, fdr)
        rows = np.array([paths[int(i)].row for i in ret], dtype=np.intp)
        p, v, a = clocks.returns.evaluate_each(tr, rows)
        pos[ret] = p
        vel[ret] = fr[:, None] * v
        acc[ret] = (fr * fr)[:, None] * a + fdr[:, None] * v
    return pos, vel, acc


@functools.cache
def plan_path(track: int) -> Path:
    """Track ``track``'s show plan as a :class:`Path`: one object per track (paths are
    values, and most vehicles follow their plan every tick)."""
    return Path(PathKind.PLAN, "the show plan", track)
