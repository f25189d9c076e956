"""A show flown against real ArduCopter (SITL), side by side with the dry-run (issue 33).

    .venv/bin/python benchmarks/bench_sitl.py [--show quick] [--sitl ../shared/sitl]
        [--port 14570] [--keep DIR] [--no-dry-run]

Starts one ArduCopter SITL instance (``../shared/sitl/arducopter``, see its README) per
drone of the show, each standing on its takeoff slot and sending MAVLink to
127.0.0.1:PORT, and flies the show with ``groundctl fly SHOW --connect
udp:127.0.0.1:PORT --no-console --record DIR`` (the command an operator runs).  Then
flies the same plan in the dry-run at x1 (``groundctl dry-run``'s own code) and prints
both sides' tracking figures in one table: largest error, per-vehicle RMS, measured
response delay, leads, closest pair.  The real side takes about 40 s before the
vehicles have a position, then the show.

Below the table, from both recordings: how each side wanders about its plan in the
formations' holds (at least 1 s into a hold) -- RMS per axis (east, north, up), the median
distance the reported position moves in 2 s -- and how fast the error decorrelates over
the whole show (its correlation 1 s and 2 s later, averaged over vehicles and axes).
``--dry-runs K`` flies the dry-run K times (seeds 0..K-1: the simulated vehicles' random
wander differs) and says the spread of its figures: one dry-run of nine vehicles is a
small sample (session 38: per-vehicle RMS means 0.030-0.042 m over three).

Skips with one line when the SITL binary is absent; the test suite never depends on it.
Loopback only.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from groundctl.plan.plan import Plan

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _slots(plan: Plan) -> list[tuple[float, float, float]]:
    """Each drone's takeoff slot as (lat, lon, alt AMSL), in drone order."""
    from groundctl.execute.frames import show_to_geodetic

    lat, lon, alt = show_to_geodetic(plan.origin, plan.home)
    return [(float(a), float(b), float(c)) for a, b, c in zip(lat, lon, alt, strict=True)]


def _start_sitl(sitl: Path, work: Path, slots: list[tuple[float, float, float]],
                port: int) -> list[subprocess.Popen[bytes]]:
    procs = []
    for i, (lat, lon, alt) in enumerate(slots):
        here = work / f"i{i}"
        here.mkdir(parents=True, exist_ok=True)
        procs.append(subprocess.Popen(
            [str(sitl / "arducopter"), "--model", "quad", "--speedup", "1", f"-I{i}",
             "--sysid", str(i + 1), "-w", "--defaults", str(sitl / "copter.parm"),
             "--home", f"{lat:.8f},{lon:.8f},{alt:.2f},0", "--sim-address=127.0.0.1",
             "--serial0", f"udpclient:127.0.0.1:{port}", "--serial1", "none",
             "--serial2", "none"],
            cwd=here, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))
    return procs


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()


def fly_real(show: Path, plan: Plan, sitl: Path, port: int, record: Path
             ) -> dict[str, Any] | None:
    """``groundctl fly`` against one SITL instance per drone standing on ``plan``'s slots;
    its report (None if none)."""
    work = Path(tempfile.mkdtemp(prefix="bench-sitl-"))
    slots = _slots(plan)
    procs = _start_sitl(sitl, work, slots, port)
    started = time.monotonic()
    try:
        cmd = [sys.executable, "-m", "groundctl", "fly", str(show), "--connect",
               f"udp:127.0.0.1:{port}", "--connect-timeout", "90", "--preflight-timeout",
               "120", "--no-console", "--record", str(record), "-q"]
        print(f"real: {len(slots)} ArduCopter SITL instance(s); {' '.join(cmd[2:])}",
              flush=True)
        run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
        print(f"real: exit {run.returncode} after {time.monotonic() - started:.0f} s wall",
              flush=True)
        if run.returncode != 0:
            print("\n".join(("    " + line) for line in
                            (run.stdout + run.stderr).strip().splitlines()[-8:]))
        report = record / "report.json"
        return json.loads(report.read_text()) if report.exists() else None
    finally:
        _stop(procs)
        shutil.rmtree(work, ignore_errors=True)


def fly_dry(plan: Plan, record: Path, seed: int = 0) -> dict[str, Any]:
    """The same plan in the dry-run at x1, recorded like the real flight."""
    from groundctl.flight.dryrun import DryRunOptions, fly_dry_run

    print(f"dry-run: x1, seed {seed}", flush=True)
    result = asyncio.run(fly_dry_run(plan, DryRunOptions(speed=1.0, record_dir=record,
                                                         seed=seed)))
    return result.report


#: A plan at most this fast is holding, m/s; and a sample counts as in a hold once the plan
#: has held this long, s (the move's own settling is not wander).
HOLD_SPEED, HOLD_AFTER_S = 0.05, 1.0


def wander(record: Path) -> dict[str, float] | None:
    """How a recorded flight wanders about its plan (see the module docstring), from its
    tlog, plan, show clock and report; None if the recording lacks one."""
    import numpy as np

    from groundctl.plan.plan import Plan
    from groundctl.record.showclock import read_show_clock
    from groundctl.viz.flight import flight_arrays
    from groundctl.viz.tlogread import decode_tlog

    try:
        data = decode_tlog((record / "flight.tlog").read_bytes())
        plan = Plan.load(record / "plan.npz")
        clock = read_show_clock(record / "showclock.csv")
        report = json.loads((record / "report.json").read_text())
    except (OSError, ValueError):
        return None
    tracks = {v["system_id"]: v["track"] for v in report["vehicles"] if v["track"] is not None}
    fa = flight_arrays(data, plan, clock, tracks)
    t = fa.show_clock
    ok = np.isfinite(t) & (t >= 0) & (t < plan.duration)
    if not fa.tracks or ok.sum() < 30:
        return None
    t = t[ok]
    step = float(np.median(np.diff(t)))
    if not step > 0:
        return None  # a show clock that stood still: no time to measure over
    cols = [fa.sysids.index(s) for s in fa.tracks]
    planned, vel, _ = plan.trajectories.evaluate(t, np.array(list(fa.tracks.values())))
    off = fa.positions[ok][:, cols] - planned.transpose(1, 0, 2)  # (T, n, 3)
    still = (np.linalg.norm(vel, axis=2) < HOLD_SPEED).T  # (T, n)
    run = np.zeros(still.shape)  # how long the plan has held, s
    for i in range(1, len(t)):
        run[i] = np.where(still[i] & still[i - 1], run[i - 1] + (t[i] - t[i - 1]), 0.0)
    hold = still & (run >= HOLD_AFTER_S)
    held = off[hold]
    held = held[np.all(np.isfinite(held), axis=1)]
    if not len(held):
        return None
    axes = np.sqrt(np.mean(held**2, axis=0))
    k2 = max(round(2.0 / step), 1)
    both = hold[:-k2] & hold[k2:] & (run[k2:] >= 2.0 + HOLD_AFTER_S)
    moved = np.linalg.norm(off[k2:] - off[:-k2], axis=2)[both]  # the plan stands still
    moved = moved[np.isfinite(moved)]

    def correlation(seconds: float) -> float:
        """Over pairs ``seconds`` apart whose both ends were heard (a gap is not closed
        up), per vehicle and axis, then averaged."""
        lag = max(round(seconds / step), 1)
        values = []
        for j in range(off.shape[1]):
            for a in range(3):
                x = off[:, j, a] - np.nanmean(off[:, j, a])
                pair = np.isfinite(x[:-lag]) & np.isfinite(x[lag:])
                var = np.nansum(x * x)
                if pair.sum() > 1 and var > 0:
                    values.append(float(np.sum(x[:-lag][pair] * x[lag:][pair]) / var))
        return float(np.mean(values)) if values else float("nan")

    return {"east": float(axes[0]), "north": float(axes[1]), "up": float(axes[2]),
            "drift_2s": float(np.median(moved)) if moved.size else float("nan"),
            "corr_1s": correlation(1.0), "corr_2s": correlation(2.0)}


def wander_lines(real: Path, dry: Path) -> list[str]:
    """The wander rows under the table: real against dry-run."""
    a, b = wander(real), wander(dry)

    def cell(w: dict[str, float] | None, fmt: str, *keys: str) -> str:
        return "-" if w is None else " / ".join(f"{w[k]:{fmt}}" for k in keys)

    rows = (("in holds, RMS E / N / U, m", ".3f", ("east", "north", "up")),
            ("in holds, moved in 2 s, m", ".3f", ("drift_2s",)),
            ("error correlation 1 s / 2 s", ".2f", ("corr_1s", "corr_2s")))
    return [f"{name:<28} {cell(a, fmt, *keys):>18} {cell(b, fmt, *keys):>18}"
            for name, fmt, keys in rows]


def spread(reports: list[dict[str, Any]], real: dict[str, Any] | None) -> str:
    """One line on several dry-runs: their per-vehicle RMS means and largest errors, the
    range and the mean, against the real flight's."""
    def mean_rms(r: dict[str, Any]) -> float | None:
        xs = [v["rms_tracking_error_m"] for v in r["vehicles"]
              if v.get("rms_tracking_error_m") is not None]  # not flown: none
        return sum(xs) / len(xs) if xs else None

    means = [m for r in reports if (m := mean_rms(r)) is not None]
    largest = [r["max_tracking_error_m"] for r in reports if r.get("max_tracking_error_m")]
    if not means or not largest:
        return f"{len(reports)} dry-runs: no tracking figures"
    mean, big = sum(means) / len(means), sum(largest) / len(largest)
    line = (f"{len(reports)} dry-runs: per-vehicle RMS means {min(means):.3f} to "
            f"{max(means):.3f} (mean {mean:.3f} m), largest errors "
            f"{min(largest):.3f} to {max(largest):.3f} (mean {big:.3f} m)")
    rm = mean_rms(real) if real is not None else None
    if real is not None and rm and real.get("max_tracking_error_m"):
        line += (f"; gaps of the means {mean / rm - 1:+.0%} and "
                 f"{big / real['max_tracking_error_m'] - 1:+.0%}")
    return line


def _figures(r: dict[str, Any] | None) -> dict[str, str]:
    if r is None:
        return {k: "-" for k in ROWS}
    vs = r["vehicles"]

    def span(key: str, scale: float = 1.0, fmt: str = ".3f") -> str:
        xs = [v[key] * scale for v in vs if v.get(key) is not None]
        return f"{min(xs):{fmt}} to {max(xs):{fmt}}" if xs else "-"

    return {
        "largest tracking error, m": f"{r['max_tracking_error_m']:.3f}",
        "per-vehicle RMS, m": span("rms_tracking_error_m"),
        "response delay, ms": span("response_ms", fmt=".1f"),
        "lead, ms": span("lead_ms", fmt=".1f"),
        "ahead of the plan, ms": f"{(r.get('tracking_split') or {}).get('ahead_ms', '-')}",
        "closest pair, m": "-" if r["min_separation_m"] is None  # one drone
        else f"{r['min_separation_m']:.2f}",
        "safe / landed": f"{r['safe']} / {r['landed']}",
    }


ROWS = ("largest tracking error, m", "per-vehicle RMS, m", "response delay, ms", "lead, ms",
        "ahead of the plan, ms", "closest pair, m", "safe / landed")


def table(real: dict[str, Any] | None, dry: dict[str, Any] | None) -> str:
    a, b = _figures(real), _figures(dry)
    lines = [f"{'figure':<28} {'real ArduCopter':>18} {'dry-run':>18}  gap"]
    for row in ROWS:
        gap = ""
        if row == "largest tracking error, m" and real is not None and dry is not None:
            gap = f"{(dry['max_tracking_error_m'] / real['max_tracking_error_m'] - 1):+.0%}"
        if row == "per-vehicle RMS, m" and real is not None and dry is not None:
            mid = [sum(v["rms_tracking_error_m"] for v in x["vehicles"]) / len(x["vehicles"])
                   for x in (real, dry)]
            gap = f"{(mid[1] / mid[0] - 1):+.0%} (means)"
        lines.append(f"{row:<28} {a[row]:>18} {b[row]:>18}  {gap}")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--show", default="quick", help="a bundled show's name (shows/NAME.toml)")
    ap.add_argument("--sitl", type=Path, default=ROOT.parent / "shared" / "sitl")
    ap.add_argument("--port", type=int, default=14570)
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep both flights' recordings here (real/, dry/)")
    ap.add_argument("--no-dry-run", action="store_true")
    ap.add_argument("--dry-runs", type=int, default=1,
                    help="fly the dry-run this many times (seeds 0..K-1) and say the spread")
    args = ap.parse_args()
    if not (args.sitl / "arducopter").exists():
        print(f"skipped: no ArduCopter SITL at {args.sitl / 'arducopter'}")
        return 0
    show = ROOT / "shows" / f"{args.show}.toml"
    out = args.keep or Path(tempfile.mkdtemp(prefix="bench-sitl-rec-"))
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(130))  # SITL stopped in finally
    from groundctl.commands.flying import load_or_plan

    plan = load_or_plan(show, quiet=True)  # planned once, for the slots and the dry-run
    real = fly_real(show, plan, args.sitl.resolve(), args.port, out / "real")
    drys = [] if args.no_dry_run else [
        fly_dry(plan, out / ("dry" if k == 0 else f"dry{k}"), seed=k)
        for k in range(max(args.dry_runs, 1))]
    dry = drys[0] if drys else None
    print(table(real, dry))
    print("\n".join(wander_lines(out / "real", out / "dry")))
    if len(drys) > 1:
        print(spread(drys, real))
    print(f"recordings: {out}")
    return 0 if real is not None and real["safe"] else 1


if __name__ == "__main__":
    sys.exit(main())
