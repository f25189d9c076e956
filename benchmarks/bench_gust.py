"""A step gust on one hovering vehicle, real ArduCopter against ``groundctl sim`` (issue 32).

    .venv/bin/python benchmarks/bench_gust.py [--speeds 9 15] [--duration 4]
        [--from 270] [--only sitl|sim] [--sitl ../shared/sitl] [--port 14600]

One vehicle, one UDP link on loopback, wall time.  GUIDED, take off to 5 m, settle, then
the gust: on SITL SIM_WIND_T 1 (the same wind at every height), SIM_WIND_DIR and
SIM_WIND_SPD set in flight and SIM_WIND_SPD back to 0 after the duration; on the
simulator ``groundctl sim --gust-on 1@T:SPEED@FROM,DURATION``.  Nothing is sent to the
vehicle meanwhile: GUIDED holds its last target, so what is measured is the autopilot
alone against the wind.  Per gust: the largest horizontal distance from where it hovered
(LOCAL_POSITION_NED), and how long after the gust began it was back within 0.5 m.

Skips the SITL side with one line when the binary is absent.  Loopback only.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_line import (  # noqa: E402
    Link,
    add_sides,
    run,
    sides,
    sim_command,
    sitl_command,
    take_off,
)

#: Simulated seconds after boot the simulator's gust starts: after take_off's arming (the
#: simulator is ready 4 s after boot), climb and settling.
SIM_GUST_AT = 35.0
#: Watched after the gust began, s.
WATCH_S = 25.0
#: "Back" means within this of the hover point, m.
BACK_M = 0.5


def _after(link: Link, t_boot: float) -> None:
    """Pump until the vehicle's clock passes ``t_boot``."""
    while not link.samples or link.samples[-1][0] < t_boot:
        link.pump(0.1)


def response(link: Link, gust_start: float) -> tuple[float, float]:
    """(largest distance from the hover point, s from the gust's start until back within
    BACK_M; inf if never) over the samples from ``gust_start`` (vehicle clock)."""
    s = np.array(link.samples)
    before = s[(s[:, 0] < gust_start) & (s[:, 0] >= gust_start - 1.0)]
    home = before[:, 1:3].mean(axis=0)
    after = s[s[:, 0] >= gust_start]
    d = np.hypot(after[:, 1] - home[0], after[:, 2] - home[1])
    out = np.nonzero(d >= BACK_M)[0]
    back = float("inf")
    if len(out) == 0:
        back = 0.0
    elif out[-1] + 1 < len(d):
        back = float(after[out[-1] + 1, 0] - gust_start)
    return float(d.max()), back


def sitl_gust(speed: float, frm: float, duration: float) -> Callable[[Link], tuple[float, float]]:
    def fly(link: Link) -> tuple[float, float]:
        take_off(link)
        link.pump(3.0)
        start = link.samples[-1][0]
        for name, value in (("SIM_WIND_T", 1.0), ("SIM_WIND_DIR", frm),
                            ("SIM_WIND_SPD", speed)):
            link.m.param_set_send(name, value)
        link.pump(duration)
        link.m.param_set_send("SIM_WIND_SPD", 0.0)
        link.pump(WATCH_S - duration)
        return response(link, start)
    return fly


def sim_gust(link: Link) -> tuple[float, float]:
    """The simulator's gust is on its command line (at SIM_GUST_AT): take off, watch it."""
    take_off(link)
    _after(link, SIM_GUST_AT + WATCH_S)
    return response(link, SIM_GUST_AT)



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speeds", type=float, nargs="+", default=[9.0, 15.0])
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--from", dest="frm", type=float, default=270.0)
    add_sides(ap, 14600)
    args = ap.parse_args()
    flown = sides(args)
    rows = []
    for k, speed in enumerate(args.speeds):
        for side in flown:
            port = args.port + 2 * k + (side == "sim")
            started = time.monotonic()
            if side == "sitl":
                figure = run(sitl_command(args.sitl.resolve(), port), port,
                             sitl_gust(speed, args.frm, args.duration))
            else:
                gust = f"1@{SIM_GUST_AT:g}:{speed:g}@{args.frm:g},{args.duration:g}"
                figure = run([*sim_command(port), "--gust-on", gust], port, sim_gust)
            name = "real ArduCopter" if side == "sitl" else "groundctl sim"
            rows.append((speed, name, *figure))
            print(f"{name}, {speed:g} m/s for {args.duration:g} s: largest {figure[0]:.2f} m, "
                  f"back within {BACK_M} m after {figure[1]:.1f} s "
                  f"({time.monotonic() - started:.0f} s wall)", flush=True)
    print(f"{'gust':<10} {'vehicle':<18} {'largest, m':>11} {'back, s':>8}")
    for speed, name, worst, back in rows:
        print(f"{speed:>4g} m/s   {name:<18} {worst:>11.2f} {back:>8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
