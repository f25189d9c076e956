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


def fly_dry(plan: Plan, record: Path) -> dict[str, Any]:
    """The same plan in the dry-run at x1, recorded like the real flight."""
    from groundctl.flight.dryrun import DryRunOptions, fly_dry_run

    print("dry-run: x1", flush=True)
    result = asyncio.run(fly_dry_run(plan, DryRunOptions(speed=1.0, record_dir=record)))
    return result.report


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
        "closest pair, m": f"{r['min_separation_m']:.2f}",
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
    dry = None if args.no_dry_run else fly_dry(plan, out / "dry")
    print(table(real, dry))
    print(f"recordings: {out}")
    return 0 if real is not None and real["safe"] else 1


if __name__ == "__main__":
    sys.exit(main())
