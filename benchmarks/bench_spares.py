"""Spare drones at scale (issue 29): where they wait, and a join into a failed track.

    .venv/bin/python benchmarks/bench_spares.py [--show benchmarks/fleet1000.toml]
        [--plan PLAN.npz] [--spares 20] [--joins 5] [--seed 1] [--save PLAN.npz]

Plans the show with ``[spares] count = N, standby = "air"`` added (or loads ``--plan``, a
plan of it that already places its spares; ``--save`` keeps the one planned here), then
prints:

- the time to lay the spares out (ground and air) on the plan and the clearance they
  keep, and what they add to ``verify``;
- for ``--joins`` seeded failures (a track, a show time), the join a spare waiting in
  the air (``--standby ground``: on its pad, climbing first) would fly
  (:func:`groundctl.flight.joining.plan_join`): how long planning it took, when it
  leaves and arrives, and the dark time (arrival - failure), the failed drone leaving
  on its own way out as the executor would send it.

Issue 29's target: planning a join at 1,000 drones under 2 s.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from groundctl.execute.leaving import leave_time
from groundctl.flight.joining import plan_join
from groundctl.flight.returning import plan_leave
from groundctl.plan.plan import Plan
from groundctl.plan.planner import plan_show
from groundctl.plan.spares import place_spares
from groundctl.plan.verify import verify
from groundctl.show.loader import load_show
from groundctl.show.model import SpareSettings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--show", default="benchmarks/fleet1000.toml")
    ap.add_argument("--plan", type=Path, default=None,
                    help="a plan of --show with its spares already placed")
    ap.add_argument("--save", type=Path, default=None, help="keep the plan made here")
    ap.add_argument("--spares", type=int, default=20)
    ap.add_argument("--joins", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--standby", choices=("air", "ground"), default="air",
                    help="join from spares hovering at their points, or on their pads "
                         "(climbing first)")
    args = ap.parse_args()
    show = load_show(args.show)
    settings = SpareSettings(count=args.spares, standby="air")
    if args.plan is not None:
        plan = Plan.load(args.plan)
        print(f"plan {args.plan}: {plan.drones} drones, {plan.duration:.0f} s")
    else:
        t = time.perf_counter()
        result = plan_show(replace(show, spares=settings))
        plan = result.plan
        print(f"planned {show.name}: {plan.drones} drones, {plan.duration:.0f} s, "
              f"{time.perf_counter() - t:.1f} s")
        if args.save is not None:
            plan.save(args.save)
    bare = replace(plan, spares=None)
    placed = {}
    for standby in ("ground", "air"):
        t = time.perf_counter()
        sp = place_spares(replace(settings, standby=standby), bare)  # type: ignore[arg-type]
        placed[standby] = sp
        print(f"lay out {sp.count} spares ({standby}): {time.perf_counter() - t:.2f} s, "
              f"clearance {sp.clearance_m:.2f} m, first pad {np.round(sp.pads[0], 2).tolist()}")
    t = time.perf_counter()
    verify(bare)
    base = time.perf_counter() - t
    t = time.perf_counter()
    verify(plan)
    print(f"verify: {base:.2f} s without the spares, {time.perf_counter() - t:.2f} s with them")
    spares = placed[args.standby]
    climb = plan.takeoff_altitude if args.standby == "ground" else 0.0
    print(f"joins from spares waiting {'on their pads' if climb else 'in the air'}")
    rng = np.random.default_rng(args.seed)
    print(f"{'track':>5} {'fails s':>8} {'leaves s':>8} {'spare':>5} {'join s':>7} "
          f"{'arrives s':>9} {'dark s':>7} {'plan ms':>8}")
    times = []
    for _ in range(args.joins):
        track = int(rng.integers(plan.drones))
        failed = float(rng.uniform(0.0, plan.duration * 0.6))
        at = leave_time(plan, track, failed)
        leaves = {}
        if at is not None:
            leaves[track] = plan_leave(plan, track, at, {})
        spare = int(rng.integers(spares.count))
        others = np.delete(spares.points, spare, axis=0)
        t = time.perf_counter()
        try:
            join = plan_join(plan, track, spares.points[spare], failed + 1.0,
                             leaves=leaves, static=others, climb=climb)
        except Exception as exc:  # a benchmark reports and goes on
            print(f"{track + 1:>5} {failed:8.1f} {'-' if at is None else f'{at:.1f}':>8} "
                  f"{spare + 1:>5}  no join: {exc}")
            continue
        took = time.perf_counter() - t
        times.append(took)
        print(f"{track + 1:>5} {failed:8.1f} {'-' if at is None else f'{at:.1f}':>8} "
              f"{spare + 1:>5} {join.at:7.1f} {join.until:9.1f} {join.until - failed:7.1f} "
              f"{took * 1000:8.0f}")
    if times:
        print(f"join planning: median {np.median(times):.2f} s, max {max(times):.2f} s "
              f"({len(times)} of {args.joins} planned)")


if __name__ == "__main__":
    main()
