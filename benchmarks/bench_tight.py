"""Tight formations: a stress generator for the planner (issue 14).

    .venv/bin/python benchmarks/bench_tight.py                       # 100 drones
    .venv/bin/python benchmarks/bench_tight.py --sizes 100 300 --timeout 60
    .venv/bin/python benchmarks/bench_tight.py --families wall sphere --spacings 1.02 1.05
    .venv/bin/python benchmarks/bench_tight.py --sizes 1000 --times 1.2 --workers 2

One transition per case, from a horizontal takeoff-height grid to a formation
whose closest slots are ``spacing`` x the minimum separation apart, in
``time`` x the minimum transition time, planned by the real planner
(``plan_quad_transition``) in a process of its own that is killed at the
timeout.  Families:

* ``shift``: the same grid, higher and moved sideways (straight lines are safe);
* ``wall``: a vertical wall (rows stacked in height) in front of the grid;
* ``rotated``: that wall turned 45 degrees about the vertical;
* ``sphere``: a Fibonacci sphere scaled so its closest slots are ``spacing`` apart.

Per case: time, SCP iterations, drones in QPs, groups, the closest pair on the
straight lines, the plan's minimum separation in continuous time, and the
outcome (planned on the straight lines, planned, refused with its message, or
timed out).
"""

from __future__ import annotations

import argparse
import itertools
import math
import multiprocessing as mp
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.errors import GroundctlError
from groundctl.plan.feasibility import min_transition_time
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.scp_quad import plan_quad_transition
from groundctl.plan.straight import check_straight_lines
from groundctl.plan.verify import verify
from groundctl.show.model import GeoOrigin, Limits, PlannerSettings, QuadrotorModel
from groundctl.show.shapes import grid, sphere

FloatArray = NDArray[np.float64]
LIMITS = Limits(max_speed_h=4.0, max_speed_up=2.5, max_speed_down=1.5, max_accel=2.5,
                min_separation=1.5, min_alt=2.0, max_alt=200.0)
FAMILIES = ("shift", "wall", "rotated", "sphere")


def closest(points: FloatArray) -> float:
    d, _ = cKDTree(points).query(points, k=2)
    return float(d[:, 1].min())


def formation(family: str, n: int, spacing: float) -> tuple[FloatArray, FloatArray]:
    """(start, goal) (n, 3): the takeoff-height grid and the family's formation."""
    flat = grid(n, spacing)
    flat = flat - flat.mean(axis=0)
    start = np.column_stack([flat, np.full(n, 3.0)])
    side = math.ceil(math.sqrt(n))
    if family == "shift":
        goal = start + np.array([4.0, 3.0, 7.0])
    elif family in ("wall", "rotated"):
        # Columns along x, rows stacked upwards, 8 m in front of the grid.
        w = grid(n, spacing, side)
        w = w - w.mean(axis=0)
        goal = np.column_stack([w[:, 0], np.full(n, flat[:, 1].max() + 8.0),
                                w[:, 1] + 6.0 + w[:, 1].max()])
        if family == "rotated":
            c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
            xy = goal[:, :2] - goal[:, :2].mean(axis=0)
            goal[:, :2] = xy @ np.array([[c, s], [-s, c]]) + goal[:, :2].mean(axis=0)
    elif family == "sphere":
        unit = sphere(n, 2.0)
        goal = unit * (spacing / closest(unit))
        goal = goal + np.array([0.0, 0.0, 6.0 + goal[:, 2].max()])
    else:
        raise ValueError(f"unknown family {family!r}")
    # Assign by nearest-first greedy (the planner's own assignment is per show).
    from scipy.optimize import linear_sum_assignment
    cost = np.linalg.norm(start[:, None] - goal[None], axis=2) ** 2
    _, cols = linear_sum_assignment(cost)
    return start, goal[cols]


def _case(q: Any, start: FloatArray, goal: FloatArray, duration: float, workers: int,
          budget: float | None) -> None:
    t0 = time.perf_counter()
    try:
        settings = PlannerSettings() if budget is None else PlannerSettings(budget_s=budget)
        res = plan_quad_transition(1, "tight", start, goal, duration, LIMITS, settings,
                                   workers=workers)
    except GroundctlError as exc:
        q.put({"outcome": "refused", "seconds": time.perf_counter() - t0,
               "message": str(exc)})
        return
    seconds = time.perf_counter() - t0
    tr = res.trajectories
    plan = Plan(show_name="tight", origin=GeoOrigin(47.0, 8.0, 400.0), limits=LIMITS,
                model="quadrotor", home=np.column_stack([start[:, :2], np.zeros(len(start))]),
                takeoff_altitude=3.0, trajectories=tr, color_times=np.array([0.0]),
                colors=np.ones((len(start), 1, 3)),
                formations=(FormationWindow(1, "tight", 0.0, duration, duration, goal),))
    t1 = time.perf_counter()
    ver = verify(plan)
    q.put({"outcome": "straight" if res.straight else "planned", "seconds": seconds,
           "verify_s": time.perf_counter() - t1, "iterations": res.iterations,
           "qp_drones": res.qp_drones, "groups": res.groups,
           "min_sep": ver.overall.min_separation, "safe": ver.safe})


def run(family: str, n: int, spacing_x: float, time_x: float, timeout: float,
        workers: int = 1, budget: float | None = None) -> dict[str, Any]:
    start, goal = formation(family, n, spacing_x * LIMITS.min_separation)
    bound = min_transition_time(start, goal, LIMITS, QuadrotorModel()).seconds
    duration = time_x * bound
    lines = check_straight_lines(start, goal, LIMITS.min_separation)
    row: dict[str, Any] = {"family": family, "n": n, "spacing": spacing_x, "time": time_x,
                           "duration": duration, "lines": lines.min_separation_m,
                           "lines_safe": lines.keeps_limit}
    q: Any = mp.get_context("spawn").Queue()
    p = mp.get_context("spawn").Process(target=_case,
                                        args=(q, start, goal, duration, workers, budget))
    t0 = time.perf_counter()
    p.start()
    p.join(timeout)
    if p.is_alive():
        p.kill()
        p.join()
        row.update(outcome="timeout", seconds=time.perf_counter() - t0)
        return row
    row.update(q.get() if not q.empty() else {"outcome": f"died ({p.exitcode})"})
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100])
    ap.add_argument("--families", nargs="+", choices=FAMILIES, default=list(FAMILIES))
    ap.add_argument("--spacings", type=float, nargs="+", default=[1.02, 1.3],
                    help="closest slots as multiples of the minimum separation")
    ap.add_argument("--times", type=float, nargs="+", default=[1.1, 1.5],
                    help="transition times as multiples of the minimum")
    ap.add_argument("--timeout", type=float, default=60.0, help="per case, s")
    ap.add_argument("--workers", type=int, default=1,
                    help="processes solving a transition's conflict groups (this one too)")
    ap.add_argument("--budget", type=float, default=None,
                    help="[planner] budget, s (default: the show default)")
    args = ap.parse_args()
    head = (f"{'family':>8} {'n':>5} {'space':>5} {'time':>5} {'T s':>6} {'lines m':>7} "
            f"{'outcome':>9} {'plan s':>7} {'ver s':>6} {'iter':>4} {'qp':>5} {'grp':>4} "
            f"{'min sep':>7}  message")
    print(head)
    print("-" * len(head))
    for n, fam, sp, tx in itertools.product(args.sizes, args.families, args.spacings,
                                            args.times):
        r = run(fam, n, sp, tx, args.timeout, args.workers, args.budget)

        def f(key: str, fmt: str, r: dict[str, Any] = r) -> str:
            v = r.get(key)
            return format(v, fmt) if isinstance(v, (int, float)) else "-"
        print(f"{fam:>8} {n:>5} {sp:>5.2f} {tx:>5.2f} {r['duration']:>6.1f} "
              f"{f('lines', '7.3f'):>7} {r['outcome']:>9} {f('seconds', '7.2f'):>7} "
              f"{f('verify_s', '6.2f'):>6} {f('iterations', 'd'):>4} {f('qp_drones', 'd'):>5} "
              f"{f('groups', 'd'):>4} {f('min_sep', '7.3f'):>7}  {r.get('message', '')[:90]}",
              flush=True)


if __name__ == "__main__":
    main()
