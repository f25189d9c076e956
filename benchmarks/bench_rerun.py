"""Rerun benchmarks: the live stream's cost to the executor, and replay time.

    .venv/bin/python benchmarks/bench_rerun.py lateness [--sizes 64 200] [--seconds 30] [--repeat N]
    .venv/bin/python benchmarks/bench_rerun.py replay RECORDING_DIR [-o OUT.rrd]

``lateness`` flies ``bench_flight.py load``'s drift plan (N simulated vehicles
in their own process, setpoints at 10 Hz, real time) twice per size: without
Rerun and with the live stream saving an .rrd (``--rerun save PATH``), and
prints per run the setpoint lateness of each show tick's last setpoint
against its scheduled instant (p50 / p99 / max), overruns, the executor
process's CPU share of one core, and the .rrd's size.

``replay`` times ``groundctl replay`` of a recording directory (make one with
``groundctl dry-run --speed 2 --record DIR``: the demo, 64 drones) in this
process, and prints the tlog's and the .rrd's sizes.
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_flight import drift_plan

from groundctl.flight.dryrun import DryRunOptions, fly_dry_run
from groundctl.flight.runner import RunnerConfig, ShowRunner


async def _run(n: int, seconds: float, rrd: Path | None) -> dict[str, float]:
    from groundctl.viz.live import LiveRerun
    from groundctl.viz.scene import RerunTarget

    plan = drift_plan(n, seconds)
    marks: dict[str, tuple[float, float, int]] = {}
    holder: list[ShowRunner] = []
    live = LiveRerun(plan, [RerunTarget("save", str(rrd))]) if rrd is not None else None

    def hook(runner: ShowRunner) -> None:
        holder.append(runner)
        inner = runner.on_tick

        def on_tick(now: float, show_time: float) -> None:
            if inner is not None and n <= 64:
                inner(now, show_time)  # as bench_flight: the truth probe only for small fleets
            seq = runner.sequence
            if seq is None or seq.started_at is None:
                return
            sample = (time.perf_counter(), time.process_time(), len(runner.lateness_s))
            if "start" not in marks:
                marks["start"] = sample
            if show_time < plan.duration:
                marks["end"] = sample

        runner.on_tick = on_tick
        if live is not None:
            live.attach(runner)  # chained after the marks, as the CLI chains it

    options = DryRunOptions(speed=1.0, ekf_origin_delay_s=1.0, ready_delay_s=2.0,
                            runner=RunnerConfig(preflight_timeout_s=60.0))
    try:
        result = await fly_dry_run(plan, options, on_runner=hook)
    finally:
        errors = live.close() if live is not None else []
    runner = holder[0]
    if "start" not in marks or "end" not in marks:
        raise SystemExit(f"{n} vehicles: the show never ran ({result.error})")
    (w0, c0, k0), (w1, c1, k1) = marks["start"], marks["end"]
    late = np.array(runner.lateness_s[k0:k1]) * 1000.0
    return {"cpu_share": (c1 - c0) / (w1 - w0), "p50": float(np.percentile(late, 50)),
            "p99": float(np.percentile(late, 99)), "max": float(late.max()),
            "ticks": len(late), "overruns": runner.overruns,
            "safe": bool(result.report.get("safe")),
            "rrd_mb": rrd.stat().st_size / 1e6 if rrd is not None and rrd.exists() else 0.0,
            "errors": len(errors),
            "tick_us": 1e6 * float(np.percentile(live.tick_s, 50)) if live and live.tick_s
            else 0.0,
            "tick_p99_us": 1e6 * float(np.percentile(live.tick_s, 99)) if live and live.tick_s
            else 0.0,
            "batch_ms": 1e3 * float(np.median(live.result.batch_s))
            if live and live.result and live.result.batch_s else 0.0}


def bench_lateness(sizes: list[int], seconds: float, repeat: int) -> None:
    print(f"executor lateness with and without the live Rerun stream: {seconds:.0f} s of "
          "show at 10 Hz, real time")
    print(f"{'vehicles':>8} {'rerun':>6} {'CPU':>6} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} "
          f"{'ticks':>6} {'overruns':>8} {'rrd MB':>7} {'safe':>5}")
    p99: dict[tuple[int, bool], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            # Off and on alternate, so that a neighbour's load falls on both alike.
            for on in [False, True] * repeat:
                rrd = Path(tmp) / f"live{n}.rrd" if on else None
                r = asyncio.run(_run(n, seconds, rrd))
                p99.setdefault((n, on), []).append(r["p99"])
                print(f"{n:>8} {'save' if on else 'off':>6} {r['cpu_share']:>6.1%} "
                      f"{r['p50']:>7.2f} {r['p99']:>7.2f} {r['max']:>7.2f} {r['ticks']:>6} "
                      f"{r['overruns']:>8} {r['rrd_mb']:>7.2f} {r['safe']!s:>5}"
                      + (f"  snapshot p50 {r['tick_us']:.0f} p99 {r['tick_p99_us']:.0f} us/tick "
                         "(wall, preemption included), batch median "
                         f"{r['batch_ms']:.1f} ms every 0.5 s (sender process)" if on else "")
                      + (f"  ({r['errors']} stream errors)" if r["errors"] else ""),
                      flush=True)
    if repeat > 1:
        for (n, on), values in sorted(p99.items()):
            print(f"{n} vehicles, rerun {'save' if on else 'off'}: p99 median "
                  f"{np.median(values):.2f} ms over {len(values)} runs "
                  f"({', '.join(f'{v:.1f}' for v in values)})")


def bench_replay(recording: Path, out: Path | None) -> None:
    from groundctl.viz.replay import default_output, find_source, replay
    from groundctl.viz.scene import RerunTarget

    out = out or default_output(recording)
    t0 = time.perf_counter()
    summary = replay(find_source(recording), [RerunTarget("save", str(out))])
    seconds = time.perf_counter() - t0
    tlog = recording / "flight.tlog"
    print(f"replay of {recording}: {tlog.stat().st_size / 1e6:.1f} MB tlog, "
          f"{summary.vehicles} vehicles, {summary.ticks} ticks, {summary.lines} log lines -> "
          f"{out} {out.stat().st_size / 1e6:.1f} MB in {seconds:.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    la = sub.add_parser("lateness")
    la.add_argument("--sizes", type=int, nargs="+", default=[64, 200])
    la.add_argument("--seconds", type=float, default=30.0)
    la.add_argument("--repeat", type=int, default=1, help="off/on pairs per size")
    rp = sub.add_parser("replay")
    rp.add_argument("recording", type=Path)
    rp.add_argument("-o", "--output", type=Path, default=None)
    args = parser.parse_args()
    if args.what == "lateness":
        bench_lateness(args.sizes, args.seconds, args.repeat)
    else:
        bench_replay(args.recording, args.output)


if __name__ == "__main__":
    main()
