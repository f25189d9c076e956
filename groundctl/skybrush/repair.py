"""Re-planning only the conflicting stretches of an imported show.

For each conflict, the two drones are re-planned over a *window*: from the
last knot at or before the conflict at which both are at rest to the first
one after it at which both are at rest again (the formation holds on either
side, or the plan's start and end).  The window's start and end states are
those of the show, so everything outside it is kept exactly; inside it the
pair flies what the SCP planner finds (:func:`groundctl.plan.scp_quad.plan_among`),
among every other drone flying its own show trajectory as a moving obstacle.
Windows that overlap in time and share a drone are merged into one (their
drones planned together).  The result is spliced onto the union of the knots:
a cubic split at a knot is the same cubic, so nothing else moves.  Then the
whole plan is checked again; what is still in conflict gets another round.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import InfeasibleTransition, PlanningError
from groundctl.plan.plan import Plan
from groundctl.plan.scp_quad import plan_among
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import PlannerSettings
from groundctl.skybrush.conflicts import Conflict, find_conflicts
from groundctl.skybrush.convert import REST_SPEED

FloatArray = NDArray[np.float64]

#: Rounds of repair before giving up.
ROUNDS = 3
#: Knots closer than this are one knot, s.
KNOT_TOL = 1e-6


@dataclass(frozen=True)
class Window:
    """One re-planned stretch."""

    drones: tuple[int, ...]
    """The drones re-planned (0-based)."""
    start: float
    """Show time it begins, s."""
    end: float
    """Show time it ends, s."""


@dataclass(frozen=True)
class Repair:
    """What ``--repair`` did."""

    plan: Plan
    """The repaired plan."""
    windows: tuple[Window, ...]
    """Every stretch re-planned, in the order they were."""
    remaining: tuple[Conflict, ...]
    """Conflicts still there after the last round (empty: repaired)."""


def _rest_knots(tr: Trajectories, drones: tuple[int, ...]) -> NDArray[np.intp]:
    speed = np.linalg.norm(tr.vel[list(drones)], axis=2).max(axis=0)
    rest = np.flatnonzero(speed <= REST_SPEED)
    return np.union1d(rest, [0, len(tr.times) - 1]).astype(np.intp)


def _window(tr: Trajectories, drones: tuple[int, ...], start: float, end: float) -> Window:
    rest = _rest_knots(tr, drones)
    times = tr.times[rest]
    before = times[times <= start + 1e-9]
    after = times[times >= end - 1e-9]
    return Window(drones, float(before[-1]), float(after[0]))


def _merge(tr: Trajectories, windows: list[Window]) -> list[Window]:
    """Windows that overlap in time and share a drone, as one (until none do)."""
    changed = True
    while changed:
        changed = False
        for x in range(len(windows)):
            for y in range(x + 1, len(windows)):
                a, b = windows[x], windows[y]
                if set(a.drones) & set(b.drones) and a.start < b.end and b.start < a.end:
                    drones = tuple(sorted(set(a.drones) | set(b.drones)))
                    windows[x] = _window(tr, drones, min(a.start, b.start), max(a.end, b.end))
                    del windows[y]
                    changed = True
                    break
            if changed:
                break
    return sorted(windows, key=lambda w: w.start)


def _widen(tr: Trajectories, w: Window) -> Window | None:
    """The window one rest knot longer on each side, or None at the plan's ends."""
    rest = tr.times[_rest_knots(tr, w.drones)]
    before, after = rest[rest < w.start - 1e-9], rest[rest > w.end + 1e-9]
    if not len(before) and not len(after):
        return None
    return Window(w.drones, float(before[-1]) if len(before) else w.start,
                  float(after[0]) if len(after) else w.end)


def _splice(tr: Trajectories, w: Window, new: Trajectories) -> Trajectories:
    """``tr`` with ``w.drones`` flying ``new`` (times from 0 = ``w.start``) inside ``w``."""
    all_t = np.sort(np.concatenate([tr.times, new.times + w.start]))
    knots = all_t[np.concatenate([[True], np.diff(all_t) > KNOT_TOL])]
    pos, vel, _ = tr.evaluate(knots)
    inside = (knots >= w.start - KNOT_TOL) & (knots <= w.end + KNOT_TOL)
    p_new, v_new, _ = new.evaluate(np.clip(knots[inside] - w.start, 0.0, new.end))
    rows = np.array(w.drones, dtype=np.intp)
    pos[np.ix_(rows, np.flatnonzero(inside))] = p_new
    vel[np.ix_(rows, np.flatnonzero(inside))] = v_new
    return Trajectories(knots, pos, vel)


def _replan(plan: Plan, tr: Trajectories, w: Window, settings: PlannerSettings
            ) -> tuple[Trajectories, Window]:
    while True:
        moving = np.array(w.drones, dtype=np.intp)
        others = np.setdiff1d(np.arange(tr.drones), moving)
        start = tr.evaluate(w.start)[0][moving]
        goal = tr.evaluate(w.end)[0][moving]

        def others_at(times: FloatArray, w: Window = w, others: NDArray[np.intp] = others
                      ) -> FloatArray:
            return tr.evaluate(w.start + np.asarray(times), others)[0]

        try:
            res = plan_among(1, f"repair of drones {', '.join(str(d + 1) for d in w.drones)}",
                             start, goal, w.end - w.start, plan.limits, settings, others_at)
        except (InfeasibleTransition, PlanningError):
            wider = _widen(tr, w)
            if wider is None:
                raise
            w = wider
            continue
        return _splice(tr, w, res.trajectories), w


def repair(plan: Plan, conflicts: list[Conflict],
           settings: PlannerSettings | None = None) -> Repair:
    """Re-plan the stretches of ``conflicts`` (see the module's docstring).

    Raises PlanningError (or InfeasibleTransition) if a stretch cannot be
    re-planned even between the plan's own ends.
    """
    settings = settings or PlannerSettings(tracking_margin=0.0)
    tr = plan.trajectories
    done: list[Window] = []
    remaining = list(conflicts)
    for _ in range(ROUNDS):
        if not remaining:
            break
        windows = _merge(tr, [_window(tr, (c.a, c.b), c.start, c.end) for c in remaining])
        for w in windows:
            tr, used = _replan(plan, tr, w, settings)
            done.append(used)
        remaining = find_conflicts(tr, plan.limits.min_separation)
    fixed = replace(plan, trajectories=tr)
    return Repair(plan=fixed, windows=tuple(done), remaining=tuple(remaining))
