"""Planner benchmark: the paper's two experiments and a quadrotor scaling series.

    .venv/bin/python benchmarks/bench_plan.py                 # paper shows + 25, 100, 300
    .venv/bin/python benchmarks/bench_plan.py --sizes 25 100 300 1000
    .venv/bin/python benchmarks/bench_plan.py --sizes --repeat 20   # paper shows, spread
    .venv/bin/python benchmarks/bench_plan.py --skip-paper --sizes --leaves 16  # land-one

Prints time and quality per case: SCP iterations, seconds, min separation in
continuous time, worst violation, pattern error, and mean path length against
the straight-line lower bound of the same assignment.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from groundctl.plan.planner import plan_show
from groundctl.show.loader import load_show
from groundctl.show.model import (
    Formation,
    GeoOrigin,
    Limits,
    PlannerSettings,
    QuadrotorModel,
    Show,
)
from groundctl.show.shapes import grid, place, sphere

SHOWS = Path(__file__).resolve().parent.parent / "shows"


def scaling_show(n: int) -> Show:
    """n drones: takeoff grid (2 m) to a sphere sized for 2 m spacing, in a time 1.5 x the bound."""
    home = np.column_stack([grid(n, 2.0), np.zeros(n)])
    home[:, :2] -= home[:, :2].mean(axis=0)
    # Fibonacci sphere: neighbour spacing ~ sqrt(4 pi r^2 / n); 2.2 m keeps it above 1.5 m.
    radius = 2.2 * math.sqrt(n / (4 * math.pi))
    pts = place(sphere(n, 2 * radius), [0.0, 0.0, radius + 8.0])
    lim = Limits(max_speed_h=5.0, max_speed_up=3.0, max_speed_down=2.0, max_accel=3.0,
                 min_separation=1.5, min_alt=2.0, max_alt=200.0)
    far = float(np.linalg.norm(pts - home, axis=1).max())
    duration = max(10.0, round(1.5 * (far / 2.0 + 2.0)))
    form = Formation(name="sphere", shape="sphere", points=pts, colors=np.ones((n, 3)),
                     transition_s=duration, hold_s=0.0, index=1)
    return Show(name=f"scale{n}", drones=n, origin=GeoOrigin(47.0, 8.0, 400.0), limits=lim,
                model=QuadrotorModel(), home=home, takeoff_altitude=3.0, formations=(form,),
                planner=PlannerSettings(dt=0.5))


def report(label: str, show: Show) -> None:
    t0 = time.perf_counter()
    res = plan_show(show, workers=2)
    wall = time.perf_counter() - t0
    ver = res.verification
    for tr, w, pe in zip(res.transitions, ver.windows, ver.pattern_errors, strict=True):
        excess = (w.path_length_mean / tr.straight_length - 1) * 100 if tr.straight_length else 0
        print(f"{label:>18} {tr.name:>8} n={show.drones:<5d} N={tr.steps:<4d} "
              f"iter={tr.iterations:<3d} t={tr.seconds:7.3f}s "
              f"({tr.seconds / max(tr.iterations, 1):.3f} s/it) qp_drones={tr.qp_drones:<5d} "
              f"straight={tr.straight!s:<5} "
              f"minsep={w.min_separation:6.3f} "
              f"viol={max(0.0, show.limits.min_separation - w.min_separation):.3f} "
              f"pattern={pe:.3f} path={w.path_length_mean:6.2f} line={tr.straight_length:6.2f}"
              f" (+{excess:.1f} %)")
    print(f"{label:>18} total {wall:.2f} s wall (incl. verification), "
          f"safe={ver.safe} {list(ver.violations)[:2]}")


def spread(label: str, show: Show, repeat: int) -> None:
    """Plan ``show`` ``repeat`` more times; per transition: min / median / max seconds."""
    runs = np.array([[tr.seconds for tr in plan_show(show, workers=1).transitions]
                     for _ in range(repeat)])
    names = [f.name for f in show.formations]
    for name, col in zip(names, runs.T, strict=True):
        print(f"{label:>18} {name:>8} over {repeat} runs: min {col.min():.3f} s, "
              f"median {np.median(col):.3f} s, max {col.max():.3f} s")


def leaves(count: int, seed: int = 1) -> None:
    """Land-one mid-show on the demo: ways out for ``count`` random drones, each asked at
    four show times; planning time and separation against the others' plans."""
    from groundctl.errors import GroundctlError
    from groundctl.execute.leaving import leave_time
    from groundctl.flight.returning import plan_leave

    plan = plan_show(load_show(SHOWS / "demo.toml"), workers=2).plan
    rng = np.random.default_rng(seed)
    seconds: list[float] = []
    worst, failed = math.inf, 0
    for track in rng.choice(plan.drones, size=min(count, plan.drones), replace=False):
        for asked in np.linspace(0.05, 0.75, 4) * plan.duration:
            at = leave_time(plan, int(track), float(asked))
            if at is None:
                continue
            t0 = time.perf_counter()
            try:
                leave = plan_leave(plan, int(track), at, {})
            except GroundctlError:
                failed += 1
                continue
            seconds.append(time.perf_counter() - t0)
            t = np.linspace(at, plan.duration, 4000)
            others = np.array([j for j in range(plan.drones) if j != track])
            gap = np.linalg.norm(plan.trajectories.evaluate(t, others)[0]
                                 - leave.position(t)[None], axis=2)
            worst = min(worst, float(gap.min()))
    print(f"demo land-one: {len(seconds)} ways out planned, {failed} refused; planning "
          f"median {np.median(seconds):.3f} s, max {max(seconds):.3f} s; closest approach to "
          f"a drone flying on {worst:.3f} m (limit {plan.limits.min_separation} m)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[25, 100, 300])
    ap.add_argument("--skip-paper", action="store_true")
    ap.add_argument("--leaves", type=int, default=0,
                    help="land-one ways out for this many random demo drones")
    ap.add_argument("--repeat", type=int, default=0,
                    help="plan each paper show this many more times and print the spread")
    args = ap.parse_args()
    if not args.skip_paper:
        for name in ("paper_star", "paper_transitions"):
            show = load_show(SHOWS / f"{name}.toml")
            report(name, show)
            if args.repeat:
                spread(name, show, args.repeat)
    for n in args.sizes:
        report(f"grid->sphere {n}", scaling_show(n))
    if args.leaves:
        leaves(args.leaves)


if __name__ == "__main__":
    main()
