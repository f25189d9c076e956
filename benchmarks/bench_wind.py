"""Wind: the line and a position hold of both flavours in SITL's winds (loopback only).

    .venv/bin/python benchmarks/bench_wind.py              # seeds 0-2
    .venv/bin/python benchmarks/bench_wind.py --seeds 5

For each flavour (ArduPilot, PX4) and wind, one vehicle over real UDP on a
ManualClock (a few seconds of wall time per flight) takes off to 5 m, hovers
10 s, holds position 20 s, then flies the 10 m minimum-jerk line of
sitl_tests/test_sim_calibration.py from 10 Hz position + velocity setpoints.
Printed: the hold's largest horizontal excursion (the worst seed), the line's
RMS and max tracking error from LOCAL_POSITION_NED and how far the vehicle
moved in the 4 s after the line's last setpoint (means over the seeds).

Winds as SITL sets them, blowing north (SIM_WIND_DIR 180) along the line,
turbulence 2 (SIM_WIND_TURB): calm; 8 m/s at every height (SIM_WIND_T 1);
12 m/s with SITL's default profile (SIM_WIND_T 0, sqrt(h / 60 m): 3.5 m/s at
5 m).  The last rows are ArduCopter V4.8.0-dev SITL's own figures.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "sitl_tests"))

from test_sim_calibration import SITL_48
from test_sim_wind import (
    CALM,
    SITL_DRIFT_8,
    SITL_HOLD_12,
    SITL_LINE_8,
    WIND_8,
    WIND_12_PROFILE,
    mean_figures,
)

from groundctl.link.flavours import Flavour

WINDS = (("calm", CALM), ("8 m/s", WIND_8), ("12 m/s profile", WIND_12_PROFILE))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=3, help="flights per case (default 3)")
    args = parser.parse_args()
    seeds = tuple(range(args.seeds))
    header = (f"{'flavour':<10} {'wind':<15} {'hold max':>9} {'line RMS':>9} "
              f"{'line max':>9} {'drift 4s':>9}")
    print(header)
    print("-" * len(header))
    started = time.monotonic()
    for flavour in (Flavour.ARDUPILOT, Flavour.PX4):
        for name, wind in WINDS:
            f = mean_figures(flavour, wind, seeds)
            print(f"{flavour.value:<10} {name:<15} {f.hold_max:>9.3f} {f.line_rms:>9.3f} "
                  f"{f.line_max:>9.3f} {f.drift_4s:>9.3f}", flush=True)
    print("-" * len(header))
    rms, worst = SITL_48.line_pos_vel
    print(f"{'SITL 4.8':<10} {'calm':<15} {'':>9} {rms:>9.3f} {worst:>9.3f} {'':>9}")
    print(f"{'SITL 4.8':<10} {'8 m/s':<15} {'':>9} {SITL_LINE_8[0]:>9.3f} "
          f"{SITL_LINE_8[1]:>9.3f} {SITL_DRIFT_8:>9.3f}")
    print(f"{'SITL 4.8':<10} {'12 m/s profile':<15} {'<' + format(SITL_HOLD_12, '.2f'):>9}")
    print(f"\n{len(seeds)} seed(s), {time.monotonic() - started:.0f} s")


if __name__ == "__main__":
    main()
