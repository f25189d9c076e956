"""Plan a whole show: assignment, every transition by SCP, holds, colours, verification.

Quadrotor transitions start and end at rest on exact slots, so once the
assignment chain is fixed they are independent problems and are planned in
parallel processes.  Unicycle transitions cannot stop: each starts with the
heading the previous one ended with, so they are planned in order.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import PlanningError
from groundctl.plan.assign import assign_chain
from groundctl.plan.distribute import LocalExecutor, RayExecutor, TransitionExecutor
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.scp_quad import TransitionResult, plan_quad_transition
from groundctl.plan.scp_unicycle import plan_unicycle_transition
from groundctl.plan.trajectory import Trajectories, concatenate, hold
from groundctl.plan.verify import Verification, verify
from groundctl.show.model import Show, UnicycleModel

FloatArray = NDArray[np.float64]

log = logging.getLogger(__name__)

#: Colour of every drone before the first formation's colours fade in.
START_COLOR = (0.1, 0.1, 0.1)

Progress = Callable[[int, int], None]
"""Called with (transitions done, transitions in all) as planning goes on."""


@dataclass(frozen=True)
class PlanResult:
    """A planned, verified show and the figures of how it was planned."""

    plan: Plan
    """The plan."""
    transitions: tuple[TransitionResult, ...]
    """Per-transition planner figures, in show order."""
    verification: Verification
    """Continuous-time verification of the whole plan."""
    seconds: float
    """Wall time of the whole planning, s."""


def _chain(show: Show) -> tuple[list[FloatArray], list[NDArray[np.intp]]]:
    """Assigned goals and slot indices of every formation, in show order."""
    slots_of = assign_chain(show.start_positions, [f.points for f in show.formations])
    goals = [f.points[idx] for f, idx in zip(show.formations, slots_of, strict=True)]
    return goals, slots_of


def _quad_job(args: tuple) -> TransitionResult:  # type: ignore[type-arg]
    index, name, start, goal, duration, limits, settings, group_workers, on_ray = args
    return plan_quad_transition(index, name, start, goal, duration, limits, settings,
                                workers=group_workers, ray=on_ray)


def _lost(job: tuple, why: str) -> PlanningError:  # type: ignore[type-arg]
    """The one line for a transition whose worker died."""
    return PlanningError(job[0], "planning worker died",
                         f"the process planning the transition into '{job[1]}' {why}")


def plan_show(show: Show, workers: int | None = None,
              progress: Progress | None = None,
              executor: TransitionExecutor | None = None) -> PlanResult:
    """Plan and verify ``show``.  Raises InfeasibleTransition or PlanningError.

    Quadrotor transitions run on ``executor`` (default: ``workers`` local processes,
    one per core); the caller owns and closes an executor it passes.  Local workers
    the transitions leave idle (one transition, two cores) solve its conflict groups.  Unicycle
    transitions depend on each other and are planned here, in order."""
    t0 = time.perf_counter()
    goals, slots_of = _chain(show)
    starts = [show.start_positions, *goals[:-1]]
    total = len(show.formations)
    results: list[TransitionResult] = []
    if isinstance(show.model, UnicycleModel):
        if show.start_headings is not None:
            heading = np.asarray(show.start_headings, dtype=float)
        else:
            heading = np.full(show.drones, np.pi / 2)
        here = show.start_positions
        for f, g in zip(show.formations, goals, strict=True):
            # A constant-speed drone ends within eps of its slot, not on it: the next
            # transition starts where this one really ended, with the heading it had.
            res, heading = plan_unicycle_transition(
                f.index, f.name, here, g, heading, f.transition_s, show.takeoff_altitude,
                show.limits, show.model, show.planner)
            here = res.trajectories.pos[:, -1]
            results.append(res)
            if progress:
                progress(len(results), total)
    else:
        if executor is None:
            executor = LocalExecutor(workers if workers is not None else os.cpu_count() or 1)
        # Fewer transitions than workers (local processes, or the Ray cluster's CPUs):
        # the spare ones solve conflict groups.
        on_ray = isinstance(executor, RayExecutor)
        capacity = executor.cpus if isinstance(executor, RayExecutor) else (
            executor.workers if isinstance(executor, LocalExecutor) else 1)
        spare = max(1, capacity // max(1, len(show.formations)))
        jobs = [(f.index, f.name, s, g, f.transition_s, show.limits, show.planner, spare,
                 on_ray)
                for f, s, g in zip(show.formations, starts, goals, strict=True)]
        for res in executor.map(_quad_job, jobs, _lost):
            results.append(res)
            if progress:
                progress(len(results), total)

    # Stitch transitions and holds onto one show clock; colours fade over each transition.
    parts: list[Trajectories] = []
    windows: list[FormationWindow] = []
    t = 0.0
    key_t = [0.0]
    key_c = [np.tile(START_COLOR, (show.drones, 1))]
    for f, res, g, idx in zip(show.formations, results, goals, slots_of, strict=True):
        parts.append(res.trajectories.shifted(t))
        arrive = t + f.transition_s
        key_t.append(arrive)
        key_c.append(f.colors[idx])
        end = arrive
        if f.hold_s > 0:
            if isinstance(show.model, UnicycleModel):
                # The loader refuses this in show files; a Show built in code may not.
                raise ValueError(f"formation {f.index} '{f.name}': `hold_s` must be 0 for the "
                                 "unicycle model (it cannot hover)")
            parts.append(hold(res.trajectories.pos[:, -1], arrive, f.hold_s))
            end = arrive + f.hold_s
            key_t.append(end)
            key_c.append(f.colors[idx])
        windows.append(FormationWindow(index=f.index, name=f.name, start=t, arrive=arrive,
                                       end=end, goals=g))
        t = end
    plan = Plan(
        show_name=show.name, origin=show.origin, limits=show.limits, model=show.model.kind,
        home=np.asarray(show.home, dtype=float), takeoff_altitude=show.takeoff_altitude,
        trajectories=concatenate(parts), color_times=np.asarray(key_t),
        colors=np.stack(key_c, axis=1), formations=tuple(windows), mpc=show.mpc,
        show_digest=show.digest)
    if show.spares is not None:
        from groundctl.plan.spares import place_spares

        plan = replace(plan, spares=place_spares(show.spares, plan))
    verification = verify(plan)  # the spares too
    return PlanResult(plan=plan, transitions=tuple(results), verification=verification,
                      seconds=time.perf_counter() - t0)
