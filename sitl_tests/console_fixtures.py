"""Shared pieces of the console tests: a runner over fabricated telemetry, artefacts.

No tests here.  The runner is the real :class:`ShowRunner` over a real (never
started) :class:`FleetLink`; its vehicles' states are written the way the link
writes them, so the view model reads exactly what it reads in flight.
"""

from __future__ import annotations

import fcntl
import math
import os
import pty
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import numpy as np

from groundctl.clock import ScaledClock
from groundctl.execute.frames import show_positions
from groundctl.execute.mapping import auto_assign
from groundctl.execute.preflight import run_preflight
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.link.flavours import Flavour
from groundctl.link.fleet import FleetLink
from groundctl.link.state import GeoPoint, VehicleState
from groundctl.link.timesync import TimesyncSample
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import GeoOrigin, Limits

REPO = Path(__file__).resolve().parents[1]
QUICK_SHOW = REPO / "shows" / "quick.toml"
#: SVG screenshots of the console go here (not committed: ``artifacts/`` is ignored).
ARTIFACTS = Path(os.environ.get("GROUNDCTL_ARTIFACTS", REPO / "artifacts" / "console"))


def screenshot_dir() -> Path:
    """The directory for the console's SVG screenshots (created)."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS


def grid_plan(n: int, seconds: float = 30.0, spacing: float = 3.0) -> Plan:
    """n drones on a grid drifting 4 m east and back at 5 m (separated by design)."""
    cols = math.ceil(math.sqrt(n))
    idx = np.arange(n)
    home = np.column_stack([(idx % cols) * spacing, (idx // cols) * spacing, np.zeros(n)])
    up = home + np.array([0.0, 0.0, 5.0])
    times = np.linspace(0.0, seconds, 3)
    pos = up[:, None, :] + np.array([0.0, 4.0, 0.0])[None, :, None] * np.array([1.0, 0, 0])
    vel = np.zeros_like(pos)
    colors = np.zeros((n, 2, 3))
    colors[:, 1] = [1.0, 0.5, 0.0]
    return Plan(show_name=f"grid{n}", origin=GeoOrigin(47.3977, 8.5456, 488.0, 0.0),
                limits=Limits(min_separation=1.5), model="quadrotor", home=home,
                takeoff_altitude=5.0, trajectories=Trajectories(times, pos, vel),
                color_times=np.array([0.0, seconds]), colors=colors,
                formations=(FormationWindow(1, "line", 0.0, 0.0, seconds / 2, up),
                            FormationWindow(2, "moved", seconds / 2, seconds * 0.75,
                                            seconds, pos[:, 2])))


def ready_state(sysid: int, plan: Plan, track: int, now: float) -> VehicleState:
    """A vehicle standing on ``track``'s slot, ready in every pre-flight check."""
    o = plan.origin
    state = VehicleState(sysid, flavour=Flavour.ARDUPILOT, mode="GUIDED",
                         battery_remaining_pct=95.0, gps_fix_type=3, gps_satellites=14,
                         prearm_ok=True, last_heartbeat=now, last_heard=now, first_heard=0.0,
                         ekf_origin=GeoPoint(o.lat, o.lon, o.alt))
    e, n, _ = plan.home[track]
    state.position_ned = (float(n), float(e), 0.0)  # heading 0: show frame E, N = NED y, x
    state.velocity_ned = (0.0, 0.0, 0.0)
    state.timesync.samples.append(TimesyncSample(offset_ns=0, rtt_ns=4_000_000, at=now))
    return state


def fabricated_runner(plan: Plan, n: int | None = None, now: float = 100.0,
                      config: RunnerConfig | None = None) -> ShowRunner:
    """A runner expecting the plan's vehicles (ids 1..drones) whose link knows ``n`` of them,
    ready (ids 1..n on tracks 0..n-1), and whose pre-flight checks ran once, at ``now``."""
    n = plan.drones if n is None else n
    clock = ScaledClock(1.0, epoch=time.monotonic() - now)  # reads ``now`` at the start
    ids = range(1, plan.drones + 1)
    link = FleetLink(("127.0.0.1", 0), clock=clock, expected_ids=ids)
    runner = ShowRunner(plan, link, clock, config or RunnerConfig(), expected_ids=ids)
    for k in range(n):
        link.vehicles[k + 1] = ready_state(k + 1, plan, k, now)
    refresh_preflight(runner, now)
    return runner


def refresh_preflight(runner: ShowRunner, now: float) -> None:
    """The pre-flight checks once, as :meth:`ShowRunner.preflight` runs them."""
    fleet = dict(runner.link.vehicles)
    runner.assignment = auto_assign(runner.plan.home, show_positions(runner.plan.origin, fleet))
    runner.preflight_report = run_preflight(fleet, runner.assignment, now,
                                            runner.config.thresholds)


# -- the CLI on a real pseudo-terminal ---------------------------------------------------
GROUNDCTL = [sys.executable, "-m", "groundctl"]
ENV = {**os.environ, "PYTHONPATH": str(REPO), "TERM": "xterm-256color"}


def _controlling_tty() -> None:  # in the child, after setsid: the pty becomes its terminal
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


class Terminal:
    """A dry-run of the quick show on a pty of 160 x 48 that is its controlling terminal
    (closing it sends SIGHUP, as a closed window does), read by the test."""

    def __init__(self, record: Path, *extra: str, speed: float = 4.0) -> None:
        self.master, slave = pty.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 48, 160, 0, 0))
        self.proc = subprocess.Popen(
            [*GROUNDCTL, "dry-run", str(QUICK_SHOW), "--speed", f"{speed:g}", "--ready-delay",
             "2", "--record", str(record), *extra],
            stdin=slave, stdout=slave, stderr=slave, env=ENV, cwd=REPO,
            start_new_session=True, preexec_fn=_controlling_tty)
        os.close(slave)
        self.out = b""
        self.open = True

    def read_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while self.open and time.monotonic() < end:
            ready, _, _ = select.select([self.master], [], [], 0.1)
            if not ready:
                if self.proc.poll() is not None:
                    return
                continue
            try:
                data = os.read(self.master, 65536)
            except OSError:  # the child closed its end
                return
            if not data:
                return
            self.out += data

    def wait_for(self, text: str, timeout: float = 120.0) -> None:
        """Read until ``text`` was drawn (a liveness deadline, not a speed bound)."""
        end = time.monotonic() + timeout
        while text.encode() not in self.out:
            assert time.monotonic() < end and self.proc.poll() is None, \
                (text, self.proc.poll(), self.out[-2000:].decode(errors="replace"))
            self.read_for(0.2)

    def close(self) -> None:
        """The terminal goes away: the window closed, the SSH connection dropped."""
        if self.open:
            os.close(self.master)
            self.open = False

    def finish(self, timeout: float = 180.0) -> int:
        try:
            if self.open:
                end = time.monotonic() + timeout
                while self.proc.poll() is None and time.monotonic() < end:
                    self.read_for(0.5)
            return self.proc.wait(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.close()
