"""Local planning against a local Ray cluster (2 CPUs): wall time per show.

    .venv/bin/python benchmarks/bench_ray.py [--shows quick demo] [--repeat 3]

Prints the cluster's start-up time, then per show the best wall time of local
planning (2 worker processes) and of planning over Ray, and whether the
trajectories are exactly equal.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import ray

from groundctl.plan.distribute import LocalExecutor, RayExecutor
from groundctl.plan.planner import plan_show
from groundctl.show.loader import load_show

SHOWS = Path(__file__).resolve().parent.parent / "shows"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shows", nargs="+", default=["quick", "demo"])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    t0 = time.perf_counter()
    ray_ex = RayExecutor("local", num_cpus=2)
    print(f"ray start-up: {time.perf_counter() - t0:.2f} s")
    try:
        for name in args.shows:
            show = load_show(SHOWS / f"{name}.toml")
            best: dict[str, float] = {}
            plans = {}
            for label, ex in (("local", LocalExecutor(2)), ("ray", ray_ex)):
                for _ in range(args.repeat):
                    t = time.perf_counter()
                    plans[label] = plan_show(show, executor=ex)
                    best[label] = min(best.get(label, 1e9), time.perf_counter() - t)
            same = np.array_equal(plans["local"].plan.trajectories.pos,
                                  plans["ray"].plan.trajectories.pos)
            print(f"{name}: {len(plans['local'].transitions)} transitions, local "
                  f"{best['local']:.2f} s, ray {best['ray']:.2f} s, identical {same}")
    finally:
        ray_ex.close()
        ray.shutdown()


if __name__ == "__main__":
    main()
