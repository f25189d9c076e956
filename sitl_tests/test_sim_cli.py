"""``groundctl sim`` as a subprocess: vehicles appear on the ground station's port."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest
from sim_fixtures import GcsPeer

from groundctl.cli import main


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_cli_fleet_is_seen_by_a_ground_station_and_stops_on_ctrl_c(stop: int) -> None:
    """Ctrl-C, or SIGTERM from a service manager: the fleet stops cleanly, exit 0."""
    peer = GcsPeer()
    host, port = peer.address
    proc = subprocess.Popen(
        [sys.executable, "-m", "groundctl", "sim", "--count", "3", "--autopilot", "px4",
         "--gcs", f"{host}:{port}", "--speed", "5", "--layout", "grid:4", "--seed", "1",
         "--ekf-delay", "0.5", "--ready-delay", "1", "--loss", "0.05"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for sid in (1, 2, 3):
            hb = peer.wait("HEARTBEAT", sid, timeout=10.0)
            assert hb.autopilot == 12  # MAV_AUTOPILOT_PX4
        peer.poll(1.5)
    finally:
        proc.send_signal(stop)
        out, err = proc.communicate(timeout=10)
        peer.close()
    assert proc.returncode == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("groundctl sim: 3 px4 vehicles")
    assert any(line.startswith("t=") and "vehicles=3" in line for line in lines[1:])
    assert "groundctl sim: stopping" in err


@pytest.mark.parametrize(("args", "message"), [
    (["--count", "0"], "`count` must be positive"),
    (["--origin", "1,2"], "--origin LAT,LON,ALT"),
    (["--layout", "ring:3"], "--layout must be grid:SPACING"),
    (["--loss", "2"], "`loss` must be a probability"),
    (["--autopilot", "px4", "--profile", "ardupilot-4.8"],
     "dynamics profile 'ardupilot-4.8' is not a px4 profile: expected one of px4-1.15"),
    (["--profile", "ardupilot-9"], "invalid choice: 'ardupilot-9'"),
    (["--push", "1@x:0,0,3"], "--push must be SYSID@T:E,N,U (e.g. 5@20:3,0,0), not '1@x:0,0,3'"),
    (["--weak", "3:1.5"], "--weak must be SYSID[,SYSID...]:FACTOR with FACTOR in (0, 1]"),
    (["--gust-on", "1@5:9"], "--gust-on must be SYSID@T:SPEED@FROM[,DURATION_S] (e.g. "
                             "5@20:9@270,4: 9 m/s from the west for 4 s), not '1@5:9'"),
    (["--count", "2", "--gust-on", "3@5:9@270"], "system id 3"),
    (["--count", "2", "--weak", "9:0.5"], "system id 9"),
    (["--fail", "1@5:engine"], "--fail must be SYSID@T:KIND with KIND one of motor, battery, "
                               "link (e.g. 5@20:motor), not '1@5:engine'"),
    (["--fail", "1@-2:motor"], "--fail must be SYSID@T:KIND"),
    (["--fail", "1:motor"], "--fail must be SYSID@T:KIND"),
    (["--count", "2", "--fail", "3@5:link"], "system id 3"),
])
def test_cli_rejects_bad_arguments(args: list[str], message: str,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = main(["sim", *args])
    except SystemExit as exc:  # argparse errors
        code = int(exc.code or 0)
    assert code == 2
    assert message in capsys.readouterr().err


def test_profile_and_boot_text_reach_the_simulator() -> None:
    import argparse

    from groundctl.commands.sim import add_parser, build_config
    from groundctl.sim.config import ARDUPILOT_47_DYNAMICS, ARDUPILOT_DYNAMICS

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    old = build_config(parser.parse_args(["sim", "--profile", "ardupilot-4.7",
                                          "--boot-text"]))
    assert old.dynamics == ARDUPILOT_47_DYNAMICS and old.boot_text
    new = build_config(parser.parse_args(["sim"]))
    assert new.dynamics == ARDUPILOT_DYNAMICS and not new.boot_text
