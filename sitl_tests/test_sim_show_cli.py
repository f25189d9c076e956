"""``groundctl sim --show SHOW``: the simulated fleet stands where ``groundctl fly SHOW`` wants it.

Where fly wants it is the plan's ``home`` as ``fly`` itself gets it
(:func:`~groundctl.commands.flying.load_or_plan`: the show planned now, or a
``.npz`` plan), matched the way its pre-flight matches vehicles to slots
(:func:`~groundctl.execute.mapping.auto_assign` on the positions
:func:`~groundctl.execute.frames.show_positions` makes of each vehicle's EKF
origin and local position).  The simulator's side is its own geodetic EKF
origins, which it computes through ECEF independently of the executor.
The end-to-end test runs both commands as an operator does, over loopback UDP.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

import numpy as np
import pytest
from flight_fixtures import QUICK_SHOW, REPO, quick_plan
from ports import reserved_udp_port

from groundctl.cli import build_parser, main
from groundctl.commands.flying import load_or_plan
from groundctl.commands.sim import build_config
from groundctl.errors import EXIT_OK, EXIT_USAGE, SimulatorError
from groundctl.execute.frames import ned_to_show, show_to_enu
from groundctl.execute.mapping import auto_assign
from groundctl.link.state import GeoPoint
from groundctl.plan.plan import Plan
from groundctl.sim import SimConfig, SimFleet

GROUNDCTL = [sys.executable, "-m", "groundctl"]
BUNDLED_SHOWS = sorted((REPO / "shows").glob("*.toml"))


def _config(*argv: str) -> SimConfig:
    """The SimConfig ``groundctl sim ARGV`` would run."""
    return build_config(build_parser().parse_args(["sim", *argv]))


def _standing_positions(plan: Plan, config: SimConfig) -> np.ndarray:
    """Where fly's pre-flight sees each simulated vehicle right after boot, show frame.

    The simulator's own EKF origins (a vehicle's origin is where it boots), with
    a local position of zero, through the executor's conversion.
    """
    fleet = SimFleet(config)  # binds loopback sockets; never started
    try:
        ekf = fleet.frames.ekf_origins
    finally:
        fleet.close()
    origins = [GeoPoint(float(lat), float(lon), float(alt)) for lat, lon, alt in ekf]
    return ned_to_show(plan.origin, origins, np.zeros((len(origins), 3)))


def test_every_bundled_show_is_found() -> None:
    assert {p.name for p in BUNDLED_SHOWS} >= {"demo.toml", "quick.toml", "paper_star.toml",
                                               "paper_transitions.toml"}


@pytest.mark.parametrize("show", BUNDLED_SHOWS, ids=lambda p: p.stem)
def test_sim_stands_on_the_takeoff_slots_fly_expects(show: Path) -> None:
    plan = load_or_plan(show, quiet=True)  # exactly what `groundctl fly SHOW` flies
    config = _config("--show", str(show))
    o = plan.origin
    assert config.count == plan.drones
    assert config.origin == (o.lat, o.lon, o.alt)
    assert config.sysids() == list(range(1, plan.drones + 1))
    # ENU homes: the show frame turned by the show's heading, nothing else.
    np.testing.assert_allclose(config.homes_enu(), show_to_enu(o, plan.home), atol=1e-9)
    # Geodetic: every vehicle's EKF origin is its slot, to a millimetre, in fly's show frame.
    seen = _standing_positions(plan, config)
    np.testing.assert_allclose(seen, plan.home, atol=1e-3)
    # And fly's pre-flight assignment takes each vehicle on its own slot, none refused.
    assignment = auto_assign(plan.home, dict(enumerate(seen, start=1)))
    assert assignment.problems() == []
    assert assignment.tracks == {i + 1: i for i in range(plan.drones)}
    assert max(assignment.distances.values()) < 1e-3


def test_without_show_the_default_grid_is_off_quick_shows_slots() -> None:
    """The bug this option fixes: `sim --count 9` is not where `fly quick.toml` looks."""
    plan = quick_plan()
    seen = _standing_positions(plan, _config("--count", "9"))
    assert auto_assign(plan.home, dict(enumerate(seen, start=1))).refused


def test_a_plan_file_gives_the_same_slots_as_its_show(tmp_path: Path) -> None:
    path = quick_plan().save(tmp_path / "quick.npz")
    from_plan, from_show = _config("--show", str(path)), _config("--show", str(QUICK_SHOW))
    assert from_plan.count == from_show.count == 9
    assert from_plan.origin == from_show.origin
    np.testing.assert_allclose(from_plan.homes_enu(), from_show.homes_enu(), atol=1e-12)


def test_a_plan_with_spares_stands_them_on_their_pads(tmp_path: Path) -> None:
    """`groundctl sim --show PLAN.npz` of a plan with spares: one more vehicle per spare,
    standing on its pad, so `fly` against it finds them there (issue 29)."""
    from dataclasses import replace

    from groundctl.plan.spares import place_spares
    from groundctl.show.model import SpareSettings

    plan = quick_plan()
    plan = replace(plan, spares=place_spares(SpareSettings(count=2, standby="ground"), plan))
    assert plan.spares is not None
    path = plan.save(tmp_path / "spares.npz")
    config = _config("--show", str(path))
    assert config.count == 11
    np.testing.assert_allclose(config.homes_enu()[9:], show_to_enu(plan.origin,
                                                                   plan.spares.pads),
                               atol=1e-9)
    with pytest.raises(SimulatorError, match="9 drones, one per takeoff slot and 2 spare"):
        _config("--show", str(path), "--count", "9")


def test_a_count_equal_to_the_shows_is_accepted() -> None:
    assert _config("--show", str(QUICK_SHOW), "--count", "9").count == 9


@pytest.mark.parametrize(("args", "message"), [
    (["--count", "4"], f"--count 4 conflicts with --show {QUICK_SHOW}: the show has 9 drones, "
                       f"one per takeoff slot; leave --count out"),
    (["--origin", "47.4,8.5,488"], f"--origin conflicts with --show {QUICK_SHOW}: the fleet "
                                   f"stands at the show's own origin; leave --origin out"),
    (["--layout", "grid:2"], f"--layout conflicts with --show {QUICK_SHOW}: the fleet stands "
                             f"on the show's takeoff slots; leave --layout out"),
])
def test_conflicting_placement_options_are_one_clear_line(
        args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    # Refused while the configuration is built: before a socket is bound or a loop runs.
    code = main(["sim", "--show", str(QUICK_SHOW), *args])
    assert code == EXIT_USAGE
    assert capsys.readouterr().err.splitlines() == [f"groundctl sim: error: {message}"]


def _run(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GROUNDCTL, *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout, check=False)


def _bad_show(kind: str, tmp_path: Path) -> tuple[Path, str]:
    """A show file that cannot be used, and what its error line must say."""
    path = tmp_path / f"{kind}.toml"
    if kind == "missing":
        return path, f"{path}: no such file"
    if kind == "syntax":
        path.write_text("[show\nname = 'broken'\n")
        return path, f"{path}: line 1, column 6: TOML syntax error"
    if kind == "typo":
        path.write_text(QUICK_SHOW.read_text().replace("takeoff_altitude", "takeof_altitude"))
        return path, "takeof_altitude"
    path = tmp_path / "not_a_plan.npz"
    path.write_bytes(b"not a zip file")
    return path, f"{path}: not a groundctl plan"


@pytest.mark.parametrize("kind", ["missing", "syntax", "typo", "bad_plan"])
def test_a_missing_or_malformed_show_is_one_clear_line(kind: str, tmp_path: Path) -> None:
    path, message = _bad_show(kind, tmp_path)
    out = _run("sim", "--show", str(path))
    assert out.returncode == EXIT_USAGE, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("groundctl sim: error: ") and message in lines[0]
    assert out.stdout == ""  # no fleet was started



class _Lines:
    """A child's output read on a thread, so waiting for a line has a deadline."""

    def __init__(self, stream: IO[str]) -> None:
        self.lines: list[str] = []
        self._queue: queue.Queue[str | None] = queue.Queue()
        self._thread = threading.Thread(target=self._pump, args=(stream,), daemon=True)
        self._thread.start()

    def _pump(self, stream: IO[str]) -> None:
        for line in stream:
            self._queue.put(line.rstrip("\n"))
        self._queue.put(None)

    def wait_for(self, found: Callable[[str], bool], timeout_s: float) -> str | None:
        """The first line (from now on) ``found`` accepts; None at end of output or timeout."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self._queue.get(timeout=left)
            except queue.Empty:
                return None
            if line is None:
                return None
            self.lines.append(line)
            if found(line):
                return line
        return None


def _stop(proc: subprocess.Popen[str], sig: signal.Signals, timeout_s: float = 30.0) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=timeout_s)


def test_fly_quick_show_against_sim_show_passes_preflight(tmp_path: Path) -> None:
    """Two processes, real time, as in the README: `sim --show` then `fly` the same show."""
    port = reserved_udp_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    sim_out = tmp_path / "sim.out"
    with sim_out.open("w") as sim_log:
        sim = subprocess.Popen(
            [*GROUNDCTL, "sim", "--show", str(QUICK_SHOW), "--gcs", f"127.0.0.1:{port}",
             "--ekf-delay", "1", "--ready-delay", "2"],
            stdout=sim_log, stderr=subprocess.STDOUT, text=True, cwd=REPO, env=env)
    fly: subprocess.Popen[str] | None = None
    try:
        fly = subprocess.Popen(
            [*GROUNDCTL, "fly", str(QUICK_SHOW), "--connect", f"udp:127.0.0.1:{port}",
             "--connect-timeout", "60", "--preflight-timeout", "120",
             "--record", str(tmp_path / "rec")],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            cwd=REPO, env=env)
        assert fly.stderr is not None
        lines = _Lines(fly.stderr)
        passed = lines.wait_for(lambda s: s.startswith(("pre-flight passed", "pre-flight "
                                                         "refused", "pre-flight timed out")),
                                timeout_s=180.0)
        log = "\n".join(lines.lines)
        assert passed is not None and passed.startswith("pre-flight passed"), \
            f"fly never passed pre-flight:\n{log}\nsim:\n{sim_out.read_text()}"
        assert "9/9 ready" in passed
        assert not any("from its slot" in s or "takeoff slot" in s for s in lines.lines), log
        # The flight itself is not this test's subject: stop the ground station here
        # (Ctrl-C just before arming abandons, just after lands: either is racy to wait
        # for, and the sim is stopped next anyway).
        fly.kill()
        fly.wait(timeout=30)
    finally:
        if fly is not None and fly.poll() is None:
            fly.kill()
            fly.wait(timeout=30)
        _stop(sim, signal.SIGINT)
    assert sim.returncode == EXIT_OK, sim_out.read_text()
    first = sim_out.read_text().splitlines()[0]
    assert first.startswith(f"groundctl sim: 9 ardupilot vehicles on the takeoff slots of "
                            f"show 'quick' ({QUICK_SHOW})")
