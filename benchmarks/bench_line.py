"""The 10 m line flown as a ground station flies it, against real ArduCopter and against
``groundctl sim`` (issue 33).

    .venv/bin/python benchmarks/bench_line.py [--sitl ../shared/sitl] [--runs 3]
        [--only sitl|sim] [--port 14590]

One vehicle, one UDP link on loopback, wall time (no stepped clock): GUIDED, arm, take
off to 5 m, settle, then a minimum-jerk line of 10 m north in 10 s from
SET_POSITION_TARGET_LOCAL_NED (position + velocity) sent every 100 ms of wall time.
LOCAL_POSITION_NED is asked for at 10 Hz; each sample is dated on the vehicle's clock
(time_boot_ms) and put on ours through TIMESYNC (its offset measured before the line),
then compared with the line where the setpoints said the vehicle should be then.  RMS
and largest horizontal error over the line's 10 s, per run, for each side.

``sitl_tests/test_sim_calibration.py`` flies the same line on a stepped clock (setpoints
exactly on the physics' steps, no link, no timing noise); this is the figure an operator
sees.  Skips the SITL side with one line when the binary is absent.  Loopback only.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
ALT = 5.0
LENGTH, DURATION = 10.0, 10.0
POS_VEL = 0x0DC0
#: ArduPilot SITL's default home (the simulator's default origin too).
HOME = (-35.363261, 149.165230, 584.0)


def minjerk(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity along the line at ``t`` s from its start."""
    s = np.clip(t / DURATION, 0.0, 1.0)
    return (LENGTH * (10 * s**3 - 15 * s**4 + 6 * s**5),
            LENGTH / DURATION * (30 * s**2 - 60 * s**3 + 30 * s**4))


class Link:
    """A ground station's end of one vehicle's link (pymavlink, UDP on loopback)."""

    def __init__(self, port: int) -> None:
        from pymavlink import mavutil

        self.m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255,
                                            source_component=190)
        self.mav = self.m.mav
        self.samples: list[tuple[float, float, float, float]] = []  # (t_boot, x, y, z)
        self.offset_s: float | None = None  # our monotonic clock - the vehicle's boot clock
        self._asked: dict[int, float] = {}
        self._best_rtt = float("inf")

    def pump(self, seconds: float = 0.0, want: str | None = None) -> Any:
        end = time.monotonic() + seconds
        while True:
            msg = self.m.recv_match(blocking=True, timeout=max(0.0, end - time.monotonic())
                                    or 0.001)
            if msg is not None:
                kind = msg.get_type()
                if kind == "LOCAL_POSITION_NED":
                    self.samples.append((msg.time_boot_ms / 1000.0, msg.x, msg.y, msg.z))
                elif kind == "TIMESYNC" and msg.tc1 != 0 and msg.ts1 in self._asked:
                    sent = self._asked.pop(msg.ts1)
                    now = time.monotonic()
                    # The vehicle's clock (ns) read halfway through the round trip.
                    offset = (sent + now) / 2.0 - msg.tc1 * 1e-9
                    rtt = now - sent
                    if self.offset_s is None or rtt < self._best_rtt:
                        self.offset_s, self._best_rtt = offset, rtt
                if want is not None and kind == want:
                    return msg
            if time.monotonic() >= end:
                return None

    def command(self, command: int, *params: float, timeout: float = 5.0) -> bool:
        p = list(params) + [0.0] * (7 - len(params))
        self.mav.command_long_send(self.m.target_system, 1, command, 0, *p)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            ack = self.pump(end - time.monotonic(), "COMMAND_ACK")
            if ack is not None and ack.command == command:
                return bool(ack.result == 0)
        return False

    def timesync(self, count: int = 20) -> None:
        self._best_rtt = float("inf")
        for k in range(count):
            stamp = 1_000_000 + k
            self._asked[stamp] = time.monotonic()
            self.mav.timesync_send(0, stamp)
            self.pump(0.05)


def take_off(link: Link) -> None:
    """GUIDED, arm (once the vehicle lets us), NAV_TAKEOFF to ALT, 12 s to settle; its
    position streamed at 10 Hz."""
    from pymavlink import mavutil

    mav = mavutil.mavlink
    link.m.wait_heartbeat(timeout=120)
    link.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                 100_000)
    mode = link.m.mode_mapping()["GUIDED"]
    deadline = time.monotonic() + 120
    while True:  # SITL refuses arming until its EKF has a position
        link.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)
        if link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1):
            break
        if time.monotonic() > deadline:
            raise SystemExit("the vehicle would not arm within 120 s")
        link.pump(1.0)
    if not link.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, ALT):
        raise SystemExit("takeoff refused")
    link.pump(12.0)


def fly_line(link: Link) -> tuple[float, float]:
    """Take off, fly the line; (RMS, max) horizontal error, m."""
    from pymavlink import mavutil

    mav = mavutil.mavlink
    take_off(link)
    link.timesync()
    last = link.samples[-1]
    x0, y0 = last[1], last[2]
    link.samples.clear()
    start = time.monotonic()
    for k in range(int(DURATION * 10) + 1):
        due = start + 0.1 * k
        link.pump(max(0.0, due - time.monotonic()))
        p, v = minjerk(np.array(time.monotonic() - start))
        link.mav.set_position_target_local_ned_send(
            0, link.m.target_system, 1, mav.MAV_FRAME_LOCAL_NED, POS_VEL, x0 + float(p), y0,
            -ALT, float(v), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    link.pump(0.5)
    assert link.offset_s is not None, "no TIMESYNC answer"
    t = np.array([s[0] for s in link.samples]) + link.offset_s - start
    xy = np.array([[s[1], s[2]] for s in link.samples])
    keep = (t >= 0.0) & (t <= DURATION)
    ref, _ = minjerk(t[keep])
    err = np.hypot(xy[keep, 0] - (x0 + ref), xy[keep, 1] - y0)
    if len(err) < 90:
        raise SystemExit(f"only {len(err)} position samples over the line")
    link.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                 link.m.mode_mapping()["LAND"])
    return float(np.sqrt(np.mean(err**2))), float(err.max())


def sitl_command(sitl: Path, port: int) -> list[str]:
    """One real ArduCopter at SITL's default home, sending to ``port``."""
    lat, lon, alt = HOME
    return [str(sitl / "arducopter"), "--model", "quad", "--speedup", "1", "-I0", "--sysid",
            "1", "-w", "--defaults", str(sitl / "copter.parm"), "--home",
            f"{lat},{lon},{alt},0", "--sim-address=127.0.0.1", "--serial0",
            f"udpclient:127.0.0.1:{port}", "--serial1", "none", "--serial2", "none"]


def sim_command(port: int) -> list[str]:
    """One vehicle of ``groundctl sim`` (its default profile, ArduCopter 4.8)."""
    return [sys.executable, "-m", "groundctl", "sim", "--count", "1", "--gcs",
            f"127.0.0.1:{port}", "--ready-delay", "4", "--seed", str(port)]


def run(command: list[str], port: int,
        fly: Callable[[Link], tuple[float, float]] = fly_line) -> tuple[float, float]:
    """Start the vehicle, ``fly`` against it (the line), stop it."""
    work = Path(tempfile.mkdtemp(prefix="bench-line-"))  # SITL writes its logs here
    proc = subprocess.Popen(command, cwd=work, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    link = Link(port)
    try:
        return fly(link)
    finally:
        link.m.close()
        proc.terminate()
        proc.wait(timeout=10)


def add_sides(ap: argparse.ArgumentParser, port: int) -> None:
    """The options saying which vehicles to fly against, and where they send to."""
    ap.add_argument("--only", choices=("sitl", "sim"), default=None)
    ap.add_argument("--sitl", type=Path, default=ROOT.parent / "shared" / "sitl")
    ap.add_argument("--port", type=int, default=port)


def sides(args: argparse.Namespace) -> list[str]:
    """The sides to fly ("sitl", "sim"): the real one only where its binary is."""
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    out = [s for s in ("sitl", "sim") if args.only in (None, s)]
    if "sitl" in out and not (args.sitl / "arducopter").exists():
        print(f"skipped the real side: no ArduCopter SITL at {args.sitl / 'arducopter'}")
        out.remove("sitl")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    add_sides(ap, 14590)
    args = ap.parse_args()
    results: dict[str, list[tuple[float, float]]] = {}
    for side in sides(args):
        for k in range(args.runs):
            port = args.port + k
            command = sitl_command(args.sitl.resolve(), port) if side == "sitl" \
                else sim_command(port)
            figure = run(command, port)
            print(f"{side} run {k + 1}: RMS {figure[0]:.3f} m, max {figure[1]:.3f} m",
                  flush=True)
            results.setdefault(side, []).append(figure)
    print(f"{'line, 10 Hz position + velocity':<34} {'RMS, m':>16} {'max, m':>16}")
    for side, figures in results.items():
        rms = [f[0] for f in figures]
        worst = [f[1] for f in figures]
        name = "real ArduCopter" if side == "sitl" else "groundctl sim"
        print(f"{name:<34} {np.mean(rms):>8.3f} ({min(rms):.3f}-{max(rms):.3f}) "
              f"{np.mean(worst):>6.3f} ({min(worst):.3f}-{max(worst):.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
