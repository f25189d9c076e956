"""The show's ``[vehicle]`` settings against a real ArduCopter (SITL), not the simulator.

    .venv/bin/python benchmarks/bench_sitl_params.py [--sitl ../shared/sitl]
        [--rtl-alt 20] [--land-speed 0.6]

Starts one ArduCopter SITL instance (``../shared/sitl/arducopter``, see its README)
sending MAVLink to a FleetLink on 127.0.0.1, runs groundctl's vehicle-settings step
(:func:`groundctl.execute.vehset.enforce`: every parameter read, the differing ones
set and confirmed) for ``rtl_alt`` and ``land_speed``, reads them back, and prints
which parameter names the firmware answered to, what was changed, and the time it
took.  Skips with one line when the SITL binary is absent.  Loopback only.
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from groundctl.clock import ScaledClock
from groundctl.execute.vehset import enforce
from groundctl.link import Flavour, FleetLink
from groundctl.link.params import ParamClient, run_params
from groundctl.show.model import GeoOrigin, Limits, VehicleSettings

HERE = Path(__file__).resolve().parent
HOME = (47.3977, 8.5456, 488.0)


async def _measure(sitl: Path, port: int, rtl_alt: float, land_speed: float) -> int:
    clock = ScaledClock()
    link = FleetLink(("127.0.0.1", port), clock=clock, heartbeat_period=0.5)
    await link.start()
    work = Path(tempfile.mkdtemp(prefix="sitl-params-"))
    try:
        return await _settings(sitl, port, rtl_alt, land_speed, link, clock, work)
    finally:
        await link.close()
        shutil.rmtree(work, ignore_errors=True)


async def _settings(sitl: Path, port: int, rtl_alt: float, land_speed: float,
                    link: FleetLink, clock: ScaledClock, work: Path) -> int:
    proc = subprocess.Popen(
        [str(sitl / "arducopter"), "--model", "quad", "--speedup", "1", "-I0", "--sysid", "1",
         "-w", "--defaults", str(sitl / "copter.parm"),
         "--home", f"{HOME[0]},{HOME[1]},{HOME[2]},0", "--sim-address=127.0.0.1",
         "--serial0", f"udpclient:127.0.0.1:{port}", "--serial1", "none", "--serial2", "none"],
        cwd=work, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        start = time.monotonic()
        await link.wait_for_vehicles([1], timeout=60.0)
        print(f"heard ArduCopter SITL after {time.monotonic() - start:.1f} s")
        settings = VehicleSettings(rtl_alt=rtl_alt, land_speed=land_speed)
        start = time.monotonic()
        out = (await enforce(link, clock, {1: Flavour.ARDUPILOT}, settings,
                             GeoOrigin(*HOME), Limits(max_alt=40.0)))[1]
        took = time.monotonic() - start
        print(f"vehicle settings in {took:.2f} s: names {out.names}, changed {out.changed}, "
              f"problems {out.problems}")
        check = ParamClient(1, Flavour.ARDUPILOT, attempts=3)
        for name in sorted({*out.names.values()}):
            check.read(name)
        await run_params(link, check, clock, 10.0)
        print("read back: " + ", ".join(f"{n} = {v.value:g}" for n, v in
                                        sorted(check.values.items())))
        return 1 if out.problems else 0
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sitl", type=Path, default=HERE.parent.parent / "shared" / "sitl")
    ap.add_argument("--port", type=int, default=14561)
    ap.add_argument("--rtl-alt", type=float, default=20.0)
    ap.add_argument("--land-speed", type=float, default=0.6)
    args = ap.parse_args()
    if not (args.sitl / "arducopter").exists():
        print(f"skipped: no ArduCopter SITL at {args.sitl / 'arducopter'}")
        return 0
    return asyncio.run(_measure(args.sitl.resolve(), args.port, args.rtl_alt,
                                args.land_speed))


if __name__ == "__main__":
    sys.exit(main())
