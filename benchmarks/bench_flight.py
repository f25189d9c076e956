"""Executor benchmarks: the demo show flown by the dry-run, and the executor's load.

    .venv/bin/python benchmarks/bench_flight.py demo --speed 2          # both flavours
    .venv/bin/python benchmarks/bench_flight.py load --sizes 100 200 254 [--console off on]
    .venv/bin/python benchmarks/bench_flight.py overload [--speeds 2 4] [--hog-speeds 2] \
        [--pace off on]
    .venv/bin/python benchmarks/bench_flight.py tracking [--shows quick demo] [--leads auto 0 150]

``demo`` flies shows/demo.toml (64 drones, ~130 s) through ``groundctl
dry-run``'s machinery for ArduPilot and PX4 and prints the report's figures:
max / RMS tracking error (target < 0.5 m without wind), min separation from
telemetry and from the simulator's truth, setpoint lateness, LED timing.

``load`` measures the ground station alone: N simulated vehicles (the
simulator in its own process, so it does not share the executor's core)
hover-and-drift on a plan built here for ``--seconds`` of show at real time;
the executor streams setpoints at 10 Hz to each.  Reported for the show
phase: the executor process's CPU share of one core (its own CPU time, not
the simulator's), the lateness of each tick's last setpoint against its
scheduled instant on the show clock (p50 / p99 / max; target p99 < 20 ms),
and the per-vehicle cost, from which the largest fleet one core sustains is
extrapolated (the dry-run's system ids stop at 254).  ``--console off on`` flies each
size without and with the operator console in the executor's event loop (drawn on
stderr when it is a terminal, else headless: laid out and rendered but not written)
and adds the console's refresh time (p99, view model and widget updates).

``overload`` flies the demo at ``--speeds`` (faster than real time loads the
ground station and the simulator alike) and at ``--hog-speeds`` beside two
busy processes, one per core, and prints per run: safe, the simulator's true
minimum separation, overruns, show-clock freezes for our own trouble (stall,
overload, silence), ``vehicle_lost`` events, lines printed to the operator.
Target: every run safe, no ``vehicle_lost`` (there are no link faults).

``tracking`` flies each of ``--shows`` (bundled names) for both flavours with
each of ``--leads`` (``auto``: measured per vehicle in flight; a number: one
fixed lead in ms) and prints the tracking error split into along-track (early
or late) and cross-track parts while the plan moves, how far ahead of the
plan the fleet flew (ms, negative: behind), the per-vehicle leads the
executor settled on (min / median / max) and the vehicles' measured response
delays, and "late" flags.  Reference, nine real ArduCopter V4.8 SITL
instances flying the quick show: max / RMS 0.347 / 0.109 m with a fixed 150 ms
lead (flown 150 ms ahead), 0.164 / 0.043 m with 0 ms.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from groundctl.flight.dryrun import DryRunOptions, fly_dry_run
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.link.flavours import Flavour
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import GeoOrigin, Limits

ROOT = Path(__file__).resolve().parent.parent


def drift_plan(n: int, seconds: float, spacing: float = 3.0) -> Plan:
    """n drones on a grid at 5 m drifting 8 m east and back together (separated by design)."""
    cols = math.ceil(math.sqrt(n))
    idx = np.arange(n)
    home = np.column_stack([(idx % cols) * spacing, (idx // cols) * spacing, np.zeros(n)])
    home[:, :2] -= home[:, :2].mean(axis=0)
    up = home + np.array([0.0, 0.0, 5.0])
    times = np.linspace(0.0, seconds, 5)
    offsets = np.array([0.0, 4.0, 8.0, 4.0, 0.0])
    pos = up[:, None, :] + offsets[None, :, None] * np.array([1.0, 0.0, 0.0])
    speed = 8.0 / (seconds / 2)
    vel = np.zeros_like(pos)
    vel[:, 1:4, 0] = [speed, 0.0, -speed]
    colors = np.zeros((n, 2, 3))
    colors[:, 1] = [0.0, 0.4, 1.0]
    return Plan(show_name=f"drift{n}", origin=GeoOrigin(47.3977, 8.5456, 488.0, 0.0),
                limits=Limits(min_separation=1.5), model="quadrotor", home=home,
                takeoff_altitude=5.0, trajectories=Trajectories(times, pos, vel),
                color_times=np.array([0.0, seconds]), colors=colors,
                formations=(FormationWindow(1, "drift", 0.0, 0.0, seconds, up),))


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system) process ``pid`` has used; 0 once it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _descendants(root: int) -> list[int]:
    """Every process started (transitively) by ``root``: its helpers, forked by the
    fork server, the simulator, the link's receive workers."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    out, todo = [], [root]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


async def _load_run(n: int, seconds: float, console: bool = False,
                    link_workers: str = "auto", slot_vehicles: int = 64,
                    speed: float = 1.0) -> dict[str, Any]:
    plan = drift_plan(n, seconds)
    marks: dict[str, tuple[float, float, int, dict[int, float], float]] = {}
    workers: list[int] = [0]
    holder: list[ShowRunner] = []
    simulator: list[int] = []
    session = None
    if console:  # the operator console in the same loop, drawn on stderr if a terminal
        from groundctl.console.session import ConsoleSession
        session = ConsoleSession(lambda label: None, go_gate=False, linger_s=0.0)
    me = os.getpid()

    def hook(runner: ShowRunner) -> None:
        holder.append(runner)
        if session is not None:
            session.attach(runner)
        inner = runner.on_tick
        last = [0.0]

        def on_tick(now: float, show_time: float) -> None:
            if inner is not None and n <= 64:
                inner(now, show_time)  # the truth probe costs RPCs: only for small fleets
            seq = runner.sequence
            if seq is None or seq.started_at is None:
                return
            wall = time.perf_counter()
            if "start" in marks and wall - last[0] < 1.0 and show_time < plan.duration:
                return  # other processes' CPU read once a second, not every tick
            last[0] = wall
            workers[0] = len(runner.link.worker_pids)
            sample = (wall, time.process_time(), len(runner.lateness_s),
                      {p: _cpu_s(p) for p in _descendants(me)}, runner.clock.now())
            if "start" not in marks:
                marks["start"] = sample
            if show_time < plan.duration:
                marks["end"] = sample

        runner.on_tick = on_tick

    options = DryRunOptions(speed=speed, ekf_origin_delay_s=1.0, ready_delay_s=2.0,
                            runner=RunnerConfig(preflight_timeout_s=120.0,
                                                send_slot_vehicles=slot_vehicles),
                            link_workers=link_workers)
    flight = fly_dry_run(plan, options, on_runner=hook, on_simulator=simulator.append,
                         notify=None if session is None else session.notify)
    if session is None:
        result = await flight
    else:
        from groundctl.console.session import run_with_console
        result = await run_with_console(session, flight, lambda r: "done",
                                        headless=not sys.stderr.isatty(), size=(200, 60))
    runner = holder[0]
    if "start" not in marks or "end" not in marks:
        raise SystemExit(f"{n} vehicles: the show never ran ({result.error})")
    (w0, c0, k0, p0, t0), (w1, c1, k1, p1, t1) = marks["start"], marks["end"]
    late = np.array(runner.lateness_s[k0:k1]) * 1000.0
    refresh = np.array(session.app.refresh_s) * 1000.0 if session is not None \
        else np.zeros(1)
    span = w1 - w0
    sims = set(simulator)  # one simulator process per network past 300 vehicles
    helpers = sum(p1[p] - p0.get(p, 0.0) for p in p1 if p not in sims)
    # The paced clock slows on a busy machine: CPU per simulated second is the cost of
    # flying the fleet (what a real flight at x1 would need), per real second the load.
    flown = max(t1 - t0, 1e-9)
    return {"n": n, "console": console, "refreshes": len(refresh) if console else 0,
            "speed": flown / span,
            "ms_per_vehicle_flown": ((c1 - c0) + helpers) / flown / n * 1000.0,
            "sim_ms_per_vehicle_flown": sum(p1.get(p, 0.0) - p0.get(p, 0.0) for p in sims)
            / flown / n * 1000.0,
            "refresh_p99": float(np.percentile(refresh, 99)),
            "cpu_share": (c1 - c0) / span, "helpers_share": helpers / span,
            "sim_share": sum(p1.get(p, 0.0) - p0.get(p, 0.0) for p in sims) / span,
            "p50": float(np.percentile(late, 50)),
            "p99": float(np.percentile(late, 99)), "max": float(late.max()),
            "ticks": len(late), "overruns": runner.overruns,
            "workers": workers[0],
            "safe": bool(result.report.get("safe")),
            "landed": sum(1 for v in result.report.get("vehicles", [])
                          if v.get("phase") == "landed"),
            "pacing": result.report.get("pacing") or {}}


def bench_load(sizes: list[int], seconds: float, consoles: list[str] | None = None,
               repeat: int = 1, link_workers: list[str] | None = None,
               slot_vehicles: list[int] | None = None, speed: float = 1.0) -> None:
    pace = "real time" if speed == 1.0 else \
        f"the paced clock at x{speed:g} (a pace the machine keeps: no polling while it waits)"
    print(f"executor load: vehicles streamed at 10 Hz for {seconds:.0f} s of show, {pace}")
    modes = consoles or ["off"]
    if "on" in modes:
        print("console: " + ("drawn on this terminal (stderr)" if sys.stderr.isatty() else
                             "headless (stderr is not a terminal: laid out and rendered, "
                             "not written)"))
    print("CPU: the control loop's process; all: with its helpers (receive workers, "
          "planning and MPC workers), the executor's whole cost; sim: the simulator; per "
          "vehicle per real second, and per simulated second flown ('flown': the paced "
          "clock slows when the machine cannot keep x1, 'speed' says by how much)")
    print(f"{'vehicles':>8} {'slot':>5} {'workers':>7} {'console':>7} {'CPU':>6} {'all':>6} "
          f"{'ms/veh/s':>8} {'sim':>6} {'sim ms/veh/s':>12} {'speed':>5} {'ms/veh/s flown':>14} "
          f"{'sim flown':>9} {'p50 ms':>7} {'p99 ms':>7} "
          f"{'max ms':>7} {'ticks':>6} {'safe':>5} {'landed':>6} {'refresh p99 ms':>14}")
    per_vehicle: list[tuple[float, float]] = []
    for n in sizes:
        for _ in range(repeat):  # on and off alternate: the machine's load drifts
            for workers, slot, mode in itertools.product(link_workers or ["auto"],
                                                         slot_vehicles or [64], modes):
                r = asyncio.run(_load_run(n, seconds, console=mode == "on",
                                          link_workers=workers, slot_vehicles=slot,
                                          speed=speed))
                total = r["cpu_share"] + r["helpers_share"]
                cost = total / n * 1000.0
                per_vehicle.append((r["cpu_share"] / n * 1000.0,
                                    r["cpu_share"] / max(r["speed"], 1e-9) / n * 1000.0))
                refresh = f"{r['refresh_p99']:.2f} ({r['refreshes']})" if r["console"] \
                    else "-"
                print(f"{n:>8} {slot:>5} {r['workers']:>7} {mode:>7} {r['cpu_share']:>6.1%} "
                      f"{total:>6.1%} {cost:>8.2f} {r['sim_share']:>6.1%} "
                      f"{r['sim_share'] / n * 1000.0:>12.2f} {r['speed']:>5.2f} "
                      f"{r['ms_per_vehicle_flown']:>14.2f} {r['sim_ms_per_vehicle_flown']:>9.2f} "
                      f"{r['p50']:>7.2f} "
                      f"{r['p99']:>7.2f} {r['max']:>7.2f} {r['ticks']:>6} "
                      f"{r['safe']!s:>5} {r['landed']:>6} {refresh:>14}", flush=True)
                pacing = r["pacing"]
                if pacing:  # the whole flight's, pre-flight included
                    print("         the paced clock held by: ground station "
                          f"{pacing.get('held_by_ground_station_s', 0.0):.1f} s, simulator "
                          f"{pacing.get('held_by_simulator_s', 0.0):.1f} s, link workers "
                          f"{pacing.get('held_by_link_workers_s', 0.0):.1f} s (the whole "
                          "flight)", flush=True)
    real, flown = per_vehicle[-1]
    if speed != 1.0:
        return  # (per real second says nothing of x1 when the clock was slowed on purpose)
    # Per real second undercounts a paced run's cost (the clock ran slower than x1), per
    # flown second overcounts it (the loop's polling while the clock waited is in it):
    # a real flight at x1 needs between the two.
    print(f"largest fleet the control loop's core sustains at x1 (extrapolated from "
          f"{sizes[-1]} vehicles): between ~{int(1000.0 / flown)} (CPU per flown second) "
          f"and ~{int(1000.0 / real)} (per real second) vehicles at 10 Hz")


def bench_demo(speed: float, flavours: list[Flavour]) -> None:
    from groundctl.commands.flying import BUNDLED_DEMO, load_or_plan

    plan = load_or_plan(BUNDLED_DEMO, quiet=True)
    print(f"demo: {plan.drones} drones, {plan.duration:.0f} s show, dry-run at x{speed:g}")
    for flavour in flavours:
        t = time.perf_counter()
        options = DryRunOptions(flavour=flavour, speed=speed)
        result = asyncio.run(fly_dry_run(plan, options))
        r = result.report
        lat, led = r["setpoint_lateness_ms"], r["led_timing_error_s"]
        print(f"{flavour}: safe={r['safe']} landed={r['landed']} max tracking "
              f"{r['max_tracking_error_m']} m (RMS {r['rms_tracking_error_m']}), min separation "
              f"{r['min_separation_m']} m (truth {r['true_min_separation_m']}), worst pattern "
              f"{max(f['max_m'] or 0.0 for f in r['pattern_error_m'])} m, lateness p99 "
              f"{lat['p99']} "
              f"ms (show clock), LED |error| mean {led['mean_abs']} s, max {led['max_abs']} s "
              f"over {led['changes']} changes, {time.perf_counter() - t:.0f} s wall", flush=True)
        if r["unsafe_reasons"]:
            print("   ", "; ".join(r["unsafe_reasons"]))


def bench_tracking(shows: list[str], leads: list[str], speed: float,
                   flavours: list[Flavour]) -> None:
    from groundctl.commands.flying import load_or_plan

    print(f"tracking: dry-run at x{speed:g}; error while the plan moves split along / across "
          "the planned velocity; ahead > 0: flown ahead of the show clock")
    print(f"{'show':<6} {'autopilot':<9} {'lead':>5} {'max m':>6} {'RMS m':>6} {'along':>6} "
          f"{'cross':>6} {'ahead ms':>8} {'leads ms min/med/max':>21} {'resp ms med':>11} "
          f"{'late':>4} {'p99 ms':>6}")
    for name in shows:
        plan = load_or_plan(ROOT / "shows" / f"{name}.toml", quiet=True)
        for flavour in flavours:
            for lead in leads:
                lead_s = None if lead == "auto" else float(lead) / 1000.0
                options = DryRunOptions(flavour=flavour, speed=speed,
                                        runner=RunnerConfig(lead_s=lead_s))
                r = asyncio.run(fly_dry_run(plan, options)).report
                split = r["tracking_split"] or {}
                ls = np.array([v["lead_ms"] for v in r["vehicles"] if v["lead_ms"] is not None])
                resp = [v["response_ms"] for v in r["vehicles"] if v["response_ms"] is not None]
                late = sum(v["late_count"] for v in r["vehicles"])
                leads_txt = f"{ls.min():.0f}/{np.median(ls):.0f}/{ls.max():.0f}" if ls.size \
                    else "-"
                resp_txt = f"{np.median(resp):.0f}" if resp else "-"
                print(f"{name:<6} {flavour!s:<9} {lead:>5} {r['max_tracking_error_m']:>6.3f} "
                      f"{r['rms_tracking_error_m']:>6.3f} {split.get('along_rms_m') or 0:>6.3f} "
                      f"{split.get('cross_rms_m') or 0:>6.3f} {split.get('ahead_ms') or 0:>8.1f} "
                      f"{leads_txt:>21} {resp_txt:>11} {late:>4} "
                      f"{r['setpoint_lateness_ms']['p99']:>6.1f}", flush=True)
                if r["unsafe_reasons"]:
                    print("   ", "; ".join(r["unsafe_reasons"]))


def _hog() -> None:
    while True:
        pass


def bench_overload(speeds: list[float], hog_speeds: list[float], flavour: Flavour,
                   paces: list[str]) -> None:
    """The demo dry-run pushed: faster than real time, and beside two busy processes;
    unpaced (the ground station's own overload, as with real vehicles) and/or paced
    (the dry-run's clock waits for whichever loop is late)."""
    import multiprocessing as mp
    import tempfile

    from groundctl.commands.flying import BUNDLED_DEMO, load_or_plan
    from groundctl.record.events import read_events

    plan = load_or_plan(BUNDLED_DEMO, quiet=True)
    print(f"overload: demo ({plan.drones} drones, {plan.duration:.0f} s), {flavour}; "
          f"{mp.cpu_count()} cores")
    print(f"{'run':<23} {'safe':>5} {'true sep m':>10} {'overruns':>8} {'ticks':>6} "
          f"{'freezes':>7} {'lost':>5} {'lines':>5} {'p99 ms':>7} {'wall s':>6} "
          f"{'kept':>5}  holds")
    runs = [(speed, False, pace) for pace in paces for speed in speeds] \
        + [(speed, True, pace) for pace in paces for speed in hog_speeds]
    for speed, hog, pace in runs:
        hogs = [mp.Process(target=_hog, daemon=True) for _ in range(2)] if hog else []
        for h in hogs:
            h.start()
        lines: list[str] = []
        try:
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                options = DryRunOptions(flavour=flavour, speed=speed, record_dir=Path(tmp),
                                        paced=pace == "on")
                result = asyncio.run(fly_dry_run(plan, options, notify=lines.append))
                wall = time.perf_counter() - t
                events = list(read_events(Path(tmp) / "events.jsonl"))
        finally:
            for h in hogs:
                h.kill()
                h.join()
        r = result.report
        held = [e["reason"] for e in events if e["event"] == "show_held"]
        freezes = sum(1 for x in held if x in ("stall", "overload", "silence"))
        lost = sum(1 for e in events if e["event"] == "vehicle_lost")
        lat = r["setpoint_lateness_ms"] or {}
        name = f"x{speed:g}" + (" + 2 hogs" if hog else "") + (" paced" if pace == "on" else "")
        kept = r.get("pacing", {}).get("effective_speed")
        print(f"{name:<23} {r['safe']!s:>5} {r.get('true_min_separation_m')!s:>10} "
              f"{lat.get('overruns')!s:>8} {lat.get('ticks')!s:>6} {freezes:>7} {lost:>5} "
              f"{len(lines):>5} {lat.get('p99')!s:>7} {wall:>6.0f} {kept!s:>5}  "
              f"{','.join(sorted(set(held))) or '-'}", flush=True)
        if r["unsafe_reasons"]:
            print("   ", "; ".join(r["unsafe_reasons"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    d = sub.add_parser("demo")
    d.add_argument("--speed", type=float, default=2.0)
    d.add_argument("--autopilot", choices=["ardupilot", "px4", "both"], default="both")
    ld = sub.add_parser("load")
    ld.add_argument("--sizes", type=int, nargs="+", default=[100, 200, 254])
    ld.add_argument("--seconds", type=float, default=30.0)
    ld.add_argument("--console", nargs="+", choices=["off", "on"], default=["off"],
                    help="fly with the operator console off, on, or both (alternating)")
    ld.add_argument("--repeat", type=int, default=1, help="runs of each console mode")
    ld.add_argument("--link-workers", nargs="+", choices=["auto", "on", "off"],
                    default=["auto"], help="the receive path in worker processes (each "
                    "size flown once per mode)")
    ld.add_argument("--slot-vehicles", type=int, nargs="+", default=[64],
                    help="setpoints sent in slots of at most this many vehicles spread over "
                         "the tick (a number >= the fleet: one burst); each size flown once "
                         "per value")
    ld.add_argument("--speed", type=float, default=1.0,
                    help="the dry-run's paced clock speed: below what the machine keeps, the "
                         "clock is never held, so the CPU per flown second is the cost of "
                         "flying the fleet without the polling of a held clock in it")
    o = sub.add_parser("overload")
    o.add_argument("--speeds", type=float, nargs="*", default=[2.0, 4.0, 6.0])
    o.add_argument("--hog-speeds", type=float, nargs="*", default=[2.0],
                   help="speeds flown beside two busy processes (a CPU hog on both cores)")
    o.add_argument("--autopilot", choices=["ardupilot", "px4"], default="ardupilot")
    o.add_argument("--pace", nargs="+", choices=["off", "on"], default=["off"],
                   help="off: the clock runs at --speed whatever the machine keeps up with "
                        "(the ground station's own overload); on: the dry-run's default, "
                        "the clock waits for a late loop")
    tr = sub.add_parser("tracking")
    tr.add_argument("--shows", nargs="+", default=["quick", "demo"])
    tr.add_argument("--leads", nargs="+", default=["auto", "0", "150"])
    tr.add_argument("--speed", type=float, default=2.0)
    tr.add_argument("--autopilot", choices=["ardupilot", "px4", "both"], default="both")
    args = parser.parse_args()
    if args.what == "overload":
        bench_overload(args.speeds, args.hog_speeds, Flavour(args.autopilot), args.pace)
    elif args.what == "tracking":
        flavours = list(Flavour) if args.autopilot == "both" else [Flavour(args.autopilot)]
        bench_tracking(args.shows, args.leads, args.speed, flavours)
    elif args.what == "demo":
        flavours = list(Flavour) if args.autopilot == "both" else [Flavour(args.autopilot)]
        bench_demo(args.speed, flavours)
    else:
        bench_load(args.sizes, args.seconds, args.console, args.repeat, args.link_workers,
                   args.slot_vehicles, args.speed)


if __name__ == "__main__":
    main()
