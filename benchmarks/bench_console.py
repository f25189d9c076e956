"""The console's cost to the control loop, with the console really drawn.

    .venv/bin/python benchmarks/bench_console.py [--sizes 200] [--seconds 20] [--repeat 2]
        [--stall S]

Runs ``bench_flight.py load --console off on`` with stdin and stderr on a
pseudo-terminal (200 x 60), where Textual draws, and prints its table: setpoint
lateness p99 with the console off and on, alternating.  Without a terminal the
console would not be drawn at all, and its cost would not be measured.

``--stall S``: the terminal stops reading for S seconds after every 5 s of reading
(a paused terminal, a stuck SSH connection), so the runs with the console are
drawn into a terminal that keeps filling up: what it costs the control loop.

``--view N [N ...]``: no flight; the view model alone, for a fleet of N ready vehicles
(the tests' fabricated runner: a grid plan, each vehicle on its slot): ms per view with
the pre-flight grid and without it, ms for every row's cells, and the refresh interval
the console keeps at that cost (``MAX_SHARE`` of the loop at most).
"""

from __future__ import annotations

import argparse
import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import tempfile
import termios
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["200"])
    ap.add_argument("--seconds", default="20")
    ap.add_argument("--repeat", default="2")
    ap.add_argument("--stall", type=float, default=0.0,
                    help="stop reading the terminal this long after every 5 s of reading")
    ap.add_argument("--view", nargs="+", type=int, default=None, metavar="N",
                    help="time the view model alone for fleets of N vehicles")
    args = ap.parse_args()
    if args.view:
        return view_costs(args.view)
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 60, 200, 0, 0))
    env = dict(os.environ, TERM="xterm-256color")
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen(
            [sys.executable, str(HERE / "bench_flight.py"), "load", "--sizes", *args.sizes,
             "--seconds", args.seconds, "--console", "off", "on", "--repeat", args.repeat],
            stdin=slave, stdout=out, stderr=slave, env=env, cwd=HERE.parent)
        os.close(slave)
        reading_since = time.monotonic()
        while True:  # drain what the console draws (between stalls, with --stall)
            if args.stall > 0 and time.monotonic() - reading_since >= 5.0:
                time.sleep(args.stall)  # the terminal takes nothing meanwhile
                reading_since = time.monotonic()
            ready, _, _ = select.select([master], [], [], 0.5)
            if ready:
                try:
                    if not os.read(master, 1 << 16):
                        break
                except OSError:
                    break
            elif proc.poll() is not None:
                break
        code = proc.wait()
        out.seek(0)
        print(out.read(), end="")
    return code


def view_costs(sizes: list[int], repeat: int = 20) -> int:
    sys.path.insert(0, str(HERE.parent / "sitl_tests"))
    from console_fixtures import fabricated_runner, grid_plan

    from groundctl.console.app import refresh_interval
    from groundctl.console.model import ConsoleModel

    print(f"{'vehicles':>8} {'view+grid ms':>12} {'view ms':>8} {'cells ms':>8} "
          f"{'interval s':>10}")
    for n in sizes:
        runner = fabricated_runner(grid_plan(n))
        model = ConsoleModel()
        model.attach(runner)
        now = model.now()
        ms = {}
        for pre in (True, False):
            model.view(now, preflight=pre)  # the grid's first build is not a refresh's
            started = time.perf_counter()
            for _ in range(repeat):
                view = model.view(now, preflight=pre)
            ms[pre] = (time.perf_counter() - started) / repeat * 1000.0
        started = time.perf_counter()
        for _ in range(repeat):
            for row in view.rows:
                row.cells()
        cells = (time.perf_counter() - started) / repeat * 1000.0
        interval = refresh_interval((max(ms.values()) + cells) / 1000.0)
        print(f"{n:>8} {ms[True]:>12.2f} {ms[False]:>8.2f} {cells:>8.2f} {interval:>10.2f}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
