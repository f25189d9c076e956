"""Skybrush export: segments and upload size per drone, for drones on their own clocks.

A Skybrush show whose drones each keep their own knot times (Skybrush Studio writes
them so: every drone's keyframes are its own) becomes one groundctl plan on the union
of every drone's knots.  Exporting that plan must give each drone its own segments
back, or every drone carries the whole fleet's and Skybrush's server refuses to upload
a trajectory past 65,535 bytes.  This builds such a show (N drones, moves at their own
times, one hold after each), imports it, exports it and prints, per drone, the
segments it was written with, the plan's union of knots, and the trajectory's size as
Skybrush's server encodes it; then the times taken.

    .venv/bin/python benchmarks/bench_skybrush.py export [--drones 8] [--seconds 346]
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any

from groundctl.skybrush.importing import export_skyc, import_show
from groundctl.skybrush.writer import MAX_TRAJECTORY_BYTES, trajectory_bytes

#: A light program: white for the whole show (SET_WHITE for 60,000 frames), end.
WHITE = bytes([0x07, 0xE0, 0xD4, 0x03, 0x00])


def own_clock_show(drones: int, seconds: float) -> dict[str, Any]:
    """``show.json`` of ``drones`` drones 4 m apart, each moving 0.3 m rest to rest in
    1 s and holding 0.66 s, again and again, on its own clock (drone i 0.037 i s later)."""
    out = []
    for i in range(drones):
        x = 4.0 * i
        home = [x, 0.0, 0.0]
        here = [x, 0.0, 5.0]
        pts: list[Any] = [[0.0, home, []], [3.0, here, [home, here]], [5.0, here, []]]
        t, k = 5.0 + 0.037 * i, 0
        while t + 1.66 < seconds - 5.0:
            to = [x + 0.3 * math.sin(k), 0.3 * math.cos(1.3 * k), 5.0 + 0.2 * math.sin(0.7 * k)]
            pts.append([round(t + 1.0, 6), to, [here, to]])
            pts.append([round(t + 1.66, 6), to, []])
            here, t, k = to, t + 1.66, k + 1
        ground = [here[0], here[1], 0.0]
        pts.append([round(t + 3.0, 6), ground, [here, ground]])
        out.append({"type": "generic", "settings": {
            "name": f"drone_{i + 1}", "home": home,
            "trajectory": {"version": 1, "points": pts},
            "lights": {"version": 1, "data": base64.b64encode(WHITE).decode()}}})
    return {"version": 1, "environment": {"type": "outdoor"}, "meta": {"title": "own clocks"},
            "settings": {"validation": {"minDistance": 1.5}}, "swarm": {"drones": out}}


def bench_export(drones: int, seconds: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "own.skyc"
        doc = own_clock_show(drones, seconds)
        with zipfile.ZipFile(src, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("show.json", json.dumps(doc))
        t0 = time.perf_counter()
        r = import_show(src)
        t1 = time.perf_counter()
        out = export_skyc(r.plan, Path(tmp) / "out.skyc")
        t2 = time.perf_counter()
        written = json.loads(zipfile.ZipFile(out).read("show.json"))["swarm"]["drones"]
        union = len(r.plan.trajectories.times) - 1
        print(f"{drones} drones, {r.plan.duration:.0f} s of plan ({seconds:g} s of show), "
              f"safe {r.safe}; the plan's union of knots: {union} segments")
        print(f"{'drone':>6} {'read':>6} {'written':>8} {'bytes':>7}  "
              f"(Skybrush's upload limit {MAX_TRAJECTORY_BYTES:,} bytes)")
        for i, (d, w) in enumerate(zip(doc["swarm"]["drones"], written, strict=True)):
            pts = w["settings"]["trajectory"]["points"]
            print(f"{i + 1:>6} {len(d['settings']['trajectory']['points']) - 1:>6} "
                  f"{len(pts) - 1:>8} {trajectory_bytes(pts):>7}")
        print(f"import and verify {t1 - t0:.2f} s, export {t2 - t1:.2f} s "
              f"({out.stat().st_size / 1e3:.0f} kB)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    e = sub.add_parser("export", help="per-drone segments and upload size of an export")
    e.add_argument("--drones", type=int, default=8)
    e.add_argument("--seconds", type=float, default=346.0)
    args = ap.parse_args()
    if args.what == "export":
        bench_export(args.drones, args.seconds)


if __name__ == "__main__":
    main()
