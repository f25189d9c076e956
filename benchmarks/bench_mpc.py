"""MPC benchmarks: one vehicle's solve time (``solve``), flight scenarios (``flight``), and
the gust matrix (``gusts``).

    .venv/bin/python benchmarks/bench_mpc.py solve                  # N = 30, 8 neighbours
    .venv/bin/python benchmarks/bench_mpc.py solve --ticks 400 --neighbours 0 4 8
    .venv/bin/python benchmarks/bench_mpc.py solve --kick 0          # noise only, no rejoins

``solve``: a vehicle on a gently curving 3 m/s path inside a 3 x 3 block of
neighbours 4 m apart flying the same path (8 in its QP), starting 3 m off its
path diagonally between two of them, and knocked 3 m off again every
``--kick-every`` ticks (a rejoin each time).  Each tick the controller is fed its
own previous result carried one step on, plus seeded noise on position and
velocity (what telemetry carried to the solve instant looks like).  Pure solve
time: no processes, no I/O.  Prints p50/p95/p99/max per neighbour count, the
first (cold) tick apart, OSQP iterations and the statuses.

``flight``: the same seeded scenarios flown by the dry-run with ``--no-mpc``
and with MPC side by side, for each autopilot flavour::

    .venv/bin/python benchmarks/bench_mpc.py flight                 # quick show, x4
    .venv/bin/python benchmarks/bench_mpc.py flight --show demo --speed 2 \
        --scenarios calm push

Scenarios: ``calm``; ``wind`` (6 m/s gusting about 4 m/s: ``--gust 2``); ``weak`` (three vehicles at
0.6 of their speed and acceleration); ``push`` (vehicle 1 pushed 3 m towards the
formation's middle at 40 % of the show); ``shove`` (pushed 4.2 m straight at its
neighbour, not in the default list).  Per run: safe, max / RMS tracking error, min separation
(telemetry and simulator truth), worst pattern error, MPC activations, solve
time p50 / p95 / p99 / max, fallbacks and late batches.

``gusts``: issue 32's matrix.  Seeded single-vehicle gusts (``--gust-on``: a force
through the airframe's drag that the vehicle's autopilot fights), 6-12 m/s for 2-4 s, each
blowing one vehicle towards its nearest neighbour at a show time spread over the show,
each flown with ``--no-mpc`` and with MPC, per autopilot::

    .venv/bin/python benchmarks/bench_mpc.py gusts                  # demo, 24 gusts, x3
    .venv/bin/python benchmarks/bench_mpc.py gusts --gusts 8 --autopilot ardupilot

Per flight: the gusted vehicle's largest error and its ``recovery_s`` (time back within
0.5 m of its plan after each excursion; ``never``: it left the show off its plan), the
simulator's true minimum separation, whether it fell below the limit, MPC activations
and start states recovered from.  Then per autopilot and MPC setting: how many flights
lost separation (the target: with MPC at most half as many as without).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from groundctl.execute.mpc import MpcConfig, MpcController, MpcRequest
from groundctl.plan.plan import Plan
from groundctl.show.model import Limits

#: The 8 grid neighbours around the vehicle, offsets from its path (x along the path).
GRID = np.array([(0.0, dy, dz) for dy in (-4.0, 0.0, 4.0) for dz in (-4.0, 0.0, 4.0)
                 if (dy, dz) != (0.0, 0.0)])
#: The rejoin offset: 3 m, between the neighbours above and beside.
KICK = np.array([0.0, 2.0, np.sqrt(5.0)]) / 3.0


def path(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity, acceleration of the vehicle's path at times ``t`` (T,)."""
    t = np.asarray(t, dtype=float)
    pos = np.stack([3.0 * t, 2.0 * np.sin(0.3 * t), 10.0 + np.sin(0.2 * t)], axis=-1)
    vel = np.stack([np.full_like(t, 3.0), 0.6 * np.cos(0.3 * t), 0.2 * np.cos(0.2 * t)],
                   axis=-1)
    acc = np.stack([np.zeros_like(t), -0.18 * np.sin(0.3 * t), -0.04 * np.sin(0.2 * t)],
                   axis=-1)
    return pos, vel, acc


@dataclass
class SolveRun:
    """What one ``solve`` run measured."""

    neighbours: int
    ms: np.ndarray
    iterations: np.ndarray
    passes: np.ndarray
    statuses: dict[str, int]
    final_offset_m: float


def run_solve(neighbours: int, ticks: int, kick_m: float, kick_every: int, noise: float,
              seed: int, config: MpcConfig) -> SolveRun:
    rng = np.random.default_rng(seed)
    limits = Limits()
    ctrl = MpcController(1, config)
    n, dt = config.steps, config.dt
    offsets = GRID[:neighbours]
    ids = np.arange(2, 2 + neighbours)
    t = 0.0
    p, v, _ = path(np.array(0.0))
    p = p + kick_m * KICK
    ms, its, passes = [], [], []
    statuses: dict[str, int] = {}
    for tick in range(ticks):
        times = t + dt * np.arange(n + 1)
        rp, rv, ra = path(times)
        req = MpcRequest(1, t, p, v, rp, rv, ra, limits, rp[None] + offsets[:, None], ids)
        r = ctrl.solve(req)
        ms.append(r.solve_ms)
        its.append(r.iterations)
        passes.append(r.passes)
        statuses[r.status] = statuses.get(r.status, 0) + 1
        t += dt
        p, v, _ = r.sample(t)
        p = p + rng.normal(0.0, noise, 3)
        v = v + rng.normal(0.0, noise, 3)
        if kick_m and kick_every and (tick + 1) % kick_every == 0 and tick + 1 < ticks:
            p = p + kick_m * KICK * (1 if (tick + 1) // kick_every % 2 else -1)
    offset = float(np.linalg.norm(p - path(np.array(t))[0]))
    return SolveRun(neighbours, np.array(ms), np.array(its), np.array(passes), statuses,
                    offset)


def cmd_solve(args: argparse.Namespace) -> None:
    config = MpcConfig(steps=args.steps)
    print(f"MPC solve time per vehicle: N = {config.steps}, dt = {config.dt} s, "
          f"{args.ticks} ticks, rejoin from {args.kick} m every {args.kick_every} ticks, "
          f"noise {args.noise} m, m/s")
    head = (f"{'nbrs':>4} {'p50 ms':>7} {'p95 ms':>7} {'p99 ms':>7} {'max ms':>7} "
            f"{'cold ms':>7} {'it p50':>6} {'it max':>6} {'passes':>6}  statuses")
    print(head)
    print("-" * len(head))
    for m in args.neighbours:
        if m > len(GRID):
            raise SystemExit(f"--neighbours: at most {len(GRID)}, got {m}")
        # One untimed run first: imports, caches and the CPU's clocks settle.
        run_solve(m, 5, args.kick, args.kick_every, args.noise, args.seed, config)
        res = run_solve(m, args.ticks, args.kick, args.kick_every, args.noise, args.seed,
                        config)
        p50, p95, p99 = np.percentile(res.ms, [50, 95, 99])
        st = ", ".join(f"{k} {v}" for k, v in sorted(res.statuses.items()))
        print(f"{m:>4} {p50:7.2f} {p95:7.2f} {p99:7.2f} {res.ms.max():7.2f} {res.ms[0]:7.2f} "
              f"{int(np.median(res.iterations)):>6} {int(res.iterations.max()):>6} "
              f"{int(res.passes.max()):>6}  {st}")
    print(f"(last run ends {res.final_offset_m:.2f} m from its path; times are "
          f"time.perf_counter around MpcController.solve)")


def _scenario(name: str, plan: Plan) -> dict[str, object]:
    """DryRunOptions keywords of one scenario (seeded, the same with and without MPC)."""
    from groundctl.flight.dryrun import Push

    plan_drones, duration = plan.drones, plan.duration
    middle = plan_drones // 2 + 1
    if name == "calm":
        return {}
    if name == "wind":
        # "Gusting 4 m/s": gusts of about +-4 m/s, i.e. a standard deviation of 2 m/s
        # per axis (a standard deviation of 4 gives +-8 m/s gusts: see the README).
        return {"wind": (6.0, 0.0, 0.0), "gust_std": 2.0, "seed": 3}
    if name == "weak":
        ids = sorted({1, middle, plan_drones})
        return {"weak": tuple((s, 0.6) for s in ids)}
    if name in ("push", "shove"):
        # At 40 % of the show, vehicle 1 pushed horizontally into the formation: 3 m
        # towards the fleet's middle (``push``, the scenario), or 3 m along
        # each of two axes, 4.2 m, straight at its neighbour (``shove``, harder).
        at = 0.4 * duration
        if name == "shove":
            return {"pushes": (Push(1, at, (3.0, 3.0, 0.0)),)}
        state = plan.state_at(at)
        towards = state.pos.mean(axis=0) - state.pos[0]
        towards[2] = 0.0
        vec = 3.0 * towards / max(float(np.linalg.norm(towards)), 1e-9)
        return {"pushes": (Push(1, at, (float(vec[0]), float(vec[1]), 0.0)),)}
    raise SystemExit(f"unknown scenario {name!r}")


def cmd_flight(args: argparse.Namespace) -> None:
    import asyncio
    from pathlib import Path

    from groundctl.commands.flying import load_or_plan
    from groundctl.flight.dryrun import DryRunOptions, fly_dry_run
    from groundctl.flight.runner import RunnerConfig
    from groundctl.link.flavours import Flavour

    root = Path(__file__).resolve().parent.parent
    plan = load_or_plan(root / "shows" / f"{args.show}.toml", quiet=True)
    flavours = list(Flavour) if args.autopilot == "both" else [Flavour(args.autopilot)]
    print(f"MPC flight scenarios: {args.show} ({plan.drones} drones, {plan.duration:.0f} s), "
          f"dry-run at x{args.speed:g}")
    print(f"{'scenario':<8} {'autopilot':<9} {'mpc':<4} {'safe':<5} {'max m':>6} {'RMS m':>6} "
          f"{'sep m':>6} {'true m':>6} {'pattern':>7} {'act':>4} {'p50':>5} {'p95':>5} "
          f"{'p99':>5} {'max':>5} {'fb':>3} {'late':>4}")
    for scenario in args.scenarios:
        extra = _scenario(scenario, plan)
        for flavour in flavours:
            for mpc in (False, True):
                options = DryRunOptions(flavour=flavour, speed=args.speed,
                                        ekf_origin_delay_s=2.0, ready_delay_s=4.0,
                                        runner=RunnerConfig(mpc=mpc),
                                        **extra)  # type: ignore[arg-type]
                r = asyncio.run(fly_dry_run(plan, options)).report
                m = r["mpc"]
                ms = m["solve_ms"]
                pattern = max((f["max_m"] or 0.0) for f in r["pattern_error_m"])

                def f(x: object) -> str:
                    return "-" if x is None else f"{x:.1f}" if isinstance(x, float) else str(x)
                print(f"{scenario:<8} {flavour!s:<9} {'on' if mpc else 'off':<4} "
                      f"{r['safe']!s:<5} {r['max_tracking_error_m']:>6.3f} "
                      f"{r['rms_tracking_error_m']:>6.3f} {r['min_separation_m']:>6.2f} "
                      f"{r['true_min_separation_m']:>6.2f} {pattern:>7.2f} "
                      f"{m['activations']:>4} {f(ms['p50']):>5} {f(ms['p95']):>5} "
                      f"{f(ms['p99']):>5} {f(ms['max']):>5} {m['fallbacks']:>3} "
                      f"{m['late']:>4}", flush=True)
                if r["unsafe_reasons"]:
                    print("   ", "; ".join(r["unsafe_reasons"]))


@dataclass(frozen=True)
class GustCase:
    """One gust of the matrix."""

    sysid: int
    at: float
    speed: float
    from_deg: float
    duration: float
    neighbour: int
    gap_m: float
    """Planned distance to that neighbour when the gust begins, m."""


def gust_cases(plan: Plan, n: int, seed: int) -> list[GustCase]:
    """``n`` seeded gusts: a vehicle, a show time between 10 s and 15 s before the end,
    a speed of 6-12 m/s and a duration of 2-4 s (cycled, so every combination comes up),
    blowing from the far side of the vehicle towards its nearest neighbour then."""
    from groundctl.execute.frames import show_vel_to_ned

    rng = np.random.default_rng(seed)
    speeds, durations = (6.0, 8.0, 10.0, 12.0), (2.0, 3.0, 4.0)
    times = np.linspace(10.0, plan.duration - 15.0, n) + rng.uniform(-2.0, 2.0, n)
    out = []
    for k in range(n):
        track = int(rng.integers(plan.drones))
        pos = plan.state_at(float(times[k])).pos
        d = np.linalg.norm(pos - pos[track], axis=1)
        d[track] = np.inf
        other = int(np.argmin(d))
        towards = pos[other] - pos[track]
        towards[2] = 0.0
        ned = show_vel_to_ned(plan.origin, towards[None, :])[0]
        bearing = np.degrees(np.arctan2(ned[1], ned[0]))  # where it blows to, compass
        out.append(GustCase(track + 1, round(float(times[k]), 1), speeds[k % 4],
                            round(float((bearing + 180.0) % 360.0), 1), durations[k % 3],
                            other + 1, float(d[other])))
    return out


def cmd_gusts(args: argparse.Namespace) -> None:
    import asyncio
    from pathlib import Path

    from groundctl.commands.flying import load_or_plan
    from groundctl.flight.dryrun import DryRunOptions, Gust, fly_dry_run
    from groundctl.flight.runner import RunnerConfig
    from groundctl.link.flavours import Flavour

    root = Path(__file__).resolve().parent.parent
    plan = load_or_plan(root / "shows" / f"{args.show}.toml", quiet=True)
    cases = gust_cases(plan, args.gusts, args.seed)
    flavours = list(Flavour) if args.autopilot == "both" else [Flavour(args.autopilot)]
    limit = plan.limits.min_separation
    print(f"gust matrix: {args.show} ({plan.drones} drones, {plan.duration:.0f} s, "
          f"separation limit {limit:.2f} m), {len(cases)} gusts, seed {args.seed}, dry-run "
          f"at x{args.speed:g}")
    print(f"{'#':>3} {'vehicle':>7} {'at s':>6} {'m/s':>4} {'from':>6} {'s':>3} "
          f"{'toward':>6} {'gap m':>6} {'autopilot':<9} {'mpc':<4} {'max m':>6} "
          f"{'recovery s':<14} {'true m':>6} {'lost':<5} {'act':>4} {'rec':>4} {'safe':<5}",
          flush=True)
    lost: dict[tuple[str, bool], int] = {}
    flown: dict[tuple[str, bool], int] = {}
    for k, case in enumerate(cases):
        for flavour in flavours:
            for mpc in (False, True):
                options = DryRunOptions(
                    flavour=flavour, speed=args.speed, ekf_origin_delay_s=2.0,
                    ready_delay_s=4.0, seed=args.seed + k, runner=RunnerConfig(mpc=mpc),
                    gusts=(Gust(case.sysid, case.at, case.speed, case.from_deg,
                                case.duration),))
                r = asyncio.run(fly_dry_run(plan, options)).report
                v = next(x for x in r["vehicles"] if x["system_id"] == case.sysid)
                true = r.get("true_min_separation_m")
                below = true is not None and true < limit
                key = (str(flavour), mpc)
                flown[key] = flown.get(key, 0) + 1
                lost[key] = lost.get(key, 0) + int(below)
                back = ",".join("never" if t is None else f"{t:.1f}"
                                for t in v["recovery_s"]) or "-"
                print(f"{k + 1:>3} {case.sysid:>7} {case.at:>6.1f} {case.speed:>4.0f} "
                      f"{case.from_deg:>6.1f} {case.duration:>3.0f} {case.neighbour:>6} "
                      f"{case.gap_m:>6.2f} {flavour!s:<9} {'on' if mpc else 'off':<4} "
                      f"{(v['max_tracking_error_m'] or 0.0):>6.2f} {back:<14} "
                      f"{(true if true is not None else float('nan')):>6.2f} "
                      f"{'LOST' if below else 'kept':<5} {r['mpc']['activations']:>4} "
                      f"{r['mpc'].get('recovered', 0):>4} {r['safe']!s:<5}", flush=True)
    print()
    for flavour in flavours:
        off, on = (lost.get((str(flavour), m), 0) for m in (False, True))
        n = flown.get((str(flavour), False), 0)
        print(f"{flavour!s:<9} separation lost in {off} of {n} flights without MPC, {on} of "
              f"{n} with MPC")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    solve = sub.add_parser("solve", help="pure solve time of one vehicle's MPC")
    solve.add_argument("--ticks", type=int, default=200, help="MPC ticks per run (10 Hz)")
    solve.add_argument("--neighbours", type=int, nargs="+", default=[8],
                       help="neighbour counts to run (0-8)")
    solve.add_argument("--steps", type=int, default=30, help="horizon steps N")
    solve.add_argument("--kick", type=float, default=3.0,
                       help="rejoin offset, m (0: none, noise only)")
    solve.add_argument("--kick-every", type=int, default=50, help="ticks between rejoins")
    solve.add_argument("--noise", type=float, default=0.02,
                       help="telemetry noise per tick, m and m/s (1 sigma)")
    solve.add_argument("--seed", type=int, default=1)
    solve.set_defaults(func=cmd_solve)
    flight = sub.add_parser("flight", help="dry-run scenarios with and without MPC")
    flight.add_argument("--show", default="quick", help="bundled show name")
    flight.add_argument("--speed", type=float, default=4.0)
    flight.add_argument("--scenarios", nargs="+", default=["calm", "wind", "weak", "push"])
    flight.add_argument("--autopilot", choices=["ardupilot", "px4", "both"], default="both")
    flight.set_defaults(func=cmd_flight)
    gusts = sub.add_parser("gusts", help="the gust matrix, with and without MPC")
    gusts.add_argument("--show", default="demo", help="bundled show name")
    gusts.add_argument("--gusts", type=int, default=24, help="how many gusts")
    gusts.add_argument("--seed", type=int, default=32)
    gusts.add_argument("--speed", type=float, default=3.0)
    gusts.add_argument("--autopilot", choices=["ardupilot", "px4", "both"], default="both")
    gusts.set_defaults(func=cmd_gusts)
    args = parser.parse_args()
    started = time.perf_counter()
    args.func(args)
    print(f"({time.perf_counter() - started:.1f} s)")


if __name__ == "__main__":
    main()
