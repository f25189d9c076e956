"""The ``groundctl dry-run`` and ``groundctl fly`` commands, run as an operator runs them."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from flight_fixtures import QUICK_SHOW, REPO
from ports import reserved_udp_port

from groundctl.errors import EXIT_ABORTED, EXIT_LINK, EXIT_OK, EXIT_USAGE
from groundctl.record.events import read_events

GROUNDCTL = [sys.executable, "-m", "groundctl"]

#: Four drones on the simulator's default grid (`groundctl sim --count 4`: 3 m apart
#: from its default origin), out to a line and back.
FLY_SHOW = """
[show]
name = "four"
drones = 4
takeoff_altitude = 3.0

[origin]
lat = -35.363261
lon = 149.165230
alt = 584.0

[limits]
min_separation = 1.5
min_altitude = 2.0
max_altitude = 20.0

[takeoff]
layout = "points"
points = [[0.0, 0.0], [3.0, 0.0], [0.0, 3.0], [3.0, 3.0]]

[[formation]]
name = "line"
shape = "line"
center = [1.5, 1.5, 6.0]
size = 9.0
transition = 8.0
hold = 4.0
color = "#ff0000"

[landing]
transition = 8.0
"""


def _run(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GROUNDCTL, *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout, check=False)



def test_dry_run_json_report_and_recordings(tmp_path: Path) -> None:
    out = _run("dry-run", str(QUICK_SHOW), "--speed", "8", "--ready-delay", "2", "--json",
               "--record", str(tmp_path), "--seed", "3")
    assert out.returncode == EXIT_OK, out.stderr
    report = json.loads(out.stdout)
    for key in ("safe", "vehicles", "min_separation_m", "max_tracking_error_m", "landed"):
        assert key in report
    assert report["safe"] and report["landed"] and len(report["vehicles"]) == 9
    assert report["autopilot"] == "ardupilot" and report["speed"] == 8.0
    pacing = report["pacing"]  # paced by default: the pace kept and who held the clock
    assert pacing["paced"] and 0 < pacing["effective_speed"] <= 8.0
    assert set(pacing) >= {"held_by_simulator_s", "held_by_ground_station_s", "left_behind"}
    assert json.loads((tmp_path / "report.json").read_text())["safe"]
    assert (tmp_path / "flight.tlog").stat().st_size > 10_000


def test_dry_run_no_pace_lets_the_clock_run_free() -> None:
    from groundctl.cli import build_parser

    parser = build_parser()
    assert parser.parse_args(["dry-run"]).paced is True
    assert parser.parse_args(["dry-run", "--no-pace"]).paced is False


def test_dry_run_of_a_malformed_show_is_one_clear_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(QUICK_SHOW.read_text().replace("takeoff_altitude", "takeof_altitude"))
    out = _run("dry-run", str(bad), "--no-record")
    assert out.returncode == EXIT_USAGE
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("groundctl dry-run: error: ")
    assert "takeof_altitude" in lines[0] and "takeoff_altitude" in lines[0]


@pytest.mark.parametrize("args, message", [
    (["--loss", "1.5"], "--loss must be in [0, 1)"),
    (["--wind", "north"], "--wind must be EAST,NORTH[,UP]"),
    (["--speed", "0"], "must be positive"),
    (["--autopilot", "inav"], "invalid choice: 'inav'"),
])
def test_dry_run_refuses_bad_options(args: list[str], message: str) -> None:
    out = _run("dry-run", str(QUICK_SHOW), *args)
    assert out.returncode == EXIT_USAGE
    assert message in out.stderr


@pytest.mark.parametrize("option, value", [("--gust-on", "12@5:9@270"),
                                            ("--push", "2:3@5:0,0,3"), ("--weak", "10:0.5"),
                                            ("--fail", "11@5:motor")])
def test_a_fault_on_a_vehicle_the_fleet_does_not_have_is_one_line_before_the_flight(
        option: str, value: str) -> None:
    out = _run("dry-run", str(QUICK_SHOW), option, value, "--no-record")
    assert out.returncode == EXIT_USAGE
    lines = out.stderr.strip().splitlines()  # the planning's progress, then the refusal
    who = value.split("@")[0].split(":0.5")[0]
    assert lines[-1] == (f"groundctl dry-run: error: {option} names vehicle {who}, which "
                         "this fleet does not have (1-9)")
    assert not any("arm" in line for line in lines)


def test_fly_without_vehicles_gives_up_with_a_link_error(tmp_path: Path) -> None:
    show = tmp_path / "four.toml"
    show.write_text(FLY_SHOW)
    port = reserved_udp_port()
    out = _run("fly", str(show), "--connect", f"udp:127.0.0.1:{port}", "--connect-timeout",
               "1", "--record", str(tmp_path / "rec"))
    assert out.returncode == EXIT_LINK
    assert "only 0 of 4 vehicles sent a HEARTBEAT within 1.0 s" in out.stderr
    events = [e["event"] for e in read_events(tmp_path / "rec" / "events.jsonl")]
    assert "error" in events and events[-1] == "report"  # flushed and closed on the way out


def test_fly_against_groundctl_sim_and_ctrl_c_lands_everyone(tmp_path: Path) -> None:
    """Real time, two processes, as in the README: `groundctl sim` and `groundctl fly`."""
    show = tmp_path / "four.toml"
    show.write_text(FLY_SHOW)
    port = reserved_udp_port()
    sim = subprocess.Popen([*GROUNDCTL, "sim", "--count", "4", "--gcs", f"127.0.0.1:{port}",
                            "--ekf-delay", "1", "--ready-delay", "2"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
    fly = subprocess.Popen([*GROUNDCTL, "fly", str(show), "--connect", f"udp:127.0.0.1:{port}",
                            "--record", str(tmp_path / "rec"), "--json"],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert fly.stderr is not None and fly.stdin is not None
        deadline = time.monotonic() + 90
        for line in fly.stderr:
            if "show started" in line:
                break
            assert time.monotonic() < deadline, "the show never started"
        # Operator commands typed on stdin: hold, an unconfirmed kill, resume.
        fly.stdin.write("hold\nkill 2\n")
        fly.stdin.flush()
        time.sleep(1.5)
        fly.stdin.write("resume\n")
        fly.stdin.flush()
        time.sleep(3.0)  # mid-transition
        fly.send_signal(signal.SIGINT)
        stdout, stderr = fly.communicate(timeout=120)
    finally:
        if fly.poll() is None:
            fly.kill()
        sim.send_signal(signal.SIGINT)
        sim.wait(timeout=20)
    assert fly.returncode == EXIT_ABORTED, stderr
    report = json.loads(stdout)
    assert [v["phase"] for v in report["vehicles"]] == ["landed"] * 4
    assert report["min_separation_m"] >= 1.5
    events = read_events(tmp_path / "rec" / "events.jsonl")
    kinds = [e["event"] for e in events]
    assert "return_planning" in kinds and kinds[-1] == "report"
    operator = [e["command"] for e in events if e["event"] == "operator"]
    assert operator == ["hold", "kill 2", "resume", "land all"]
    assert any("confirm to kill" in e.get("text", "") for e in events)


@pytest.mark.parametrize("sig, label", [(signal.SIGTERM, "SIGTERM"),
                                        (signal.SIGHUP, "SIGHUP (terminal closed)")])
def test_sigterm_or_sighup_mid_show_lands_everyone_and_flushes(
        tmp_path: Path, sig: signal.Signals, label: str) -> None:
    """A service manager's stop or a closed terminal is a stop, not a crash: land first.

    The signal goes to the whole process group, as a terminal or a service manager
    sends it: the simulator child must outlive it until the fleet is down.
    """
    show = tmp_path / "four.toml"
    show.write_text(FLY_SHOW)
    run = subprocess.Popen([*GROUNDCTL, "dry-run", str(show), "--speed", "4", "--ready-delay",
                            "1", "--record", str(tmp_path / "rec"), "--json"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                           env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True)
    try:
        assert run.stderr is not None
        deadline = time.monotonic() + 90
        for line in run.stderr:
            if "show started" in line:
                break
            assert time.monotonic() < deadline, "the show never started"
        time.sleep(1.0)  # show clock x4: mid-transition
        os.killpg(run.pid, sig)
        stdout, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    assert run.returncode == EXIT_ABORTED, stderr
    assert f"{label}: landing every vehicle" in stderr
    report = json.loads(stdout)
    assert [v["phase"] for v in report["vehicles"]] == ["landed"] * 4
    assert report["min_separation_m"] >= 1.5
    events = read_events(tmp_path / "rec" / "events.jsonl")
    signals = [e for e in events if e["event"] == "signal"]
    assert [(e["signal"], e["count"]) for e in signals] == [(label, 1)]
    assert [e["command"] for e in events if e["event"] == "operator"] == ["land all"]
    assert events[-1]["event"] == "report"


def _two_network_fleet(tmp_path: Path, ports: tuple[int, int]) -> Path:
    fleet = tmp_path / "fleet.toml"
    fleet.write_text("".join(
        f'[[network]]\nname = "{name}"\nconnection = "udp:127.0.0.1:{port}"\n'
        for name, port in zip(("north", "south"), ports, strict=True))
        + "".join(f'[[vehicle]]\nnetwork = "{net}"\nsystem_id = {sysid}\n'
                  for net, sysid in (("north", 1), ("north", 2), ("south", 1), ("south", 2))))
    return fleet


def test_fly_two_networks_from_a_fleet_file_against_groundctl_sim(tmp_path: Path) -> None:
    """Issue 34, as an operator runs it: `groundctl sim` with one --gcs per network and
    `groundctl fly --fleet` whose [[network]] tables name the two links; the operator's
    `land 2:1` names network 2's system id 1; Ctrl-C lands the rest."""
    show = tmp_path / "four.toml"
    show.write_text(FLY_SHOW)
    ports = (reserved_udp_port(), reserved_udp_port())
    fleet = _two_network_fleet(tmp_path, ports)
    sim = subprocess.Popen([*GROUNDCTL, "sim", "--count", "4", "--gcs", f"127.0.0.1:{ports[0]}",
                            "--gcs", f"127.0.0.1:{ports[1]}", "--ekf-delay", "1",
                            "--ready-delay", "2"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
    fly = subprocess.Popen([*GROUNDCTL, "fly", str(show), "--fleet", str(fleet),
                            "--record", str(tmp_path / "rec"), "--json"],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert fly.stderr is not None and fly.stdin is not None
        deadline = time.monotonic() + 90
        before = []
        for line in fly.stderr:
            before.append(line)
            if "show started" in line:
                break
            assert time.monotonic() < deadline, "the show never started"
        fly.stdin.write("land 2:1\n")
        fly.stdin.flush()
        time.sleep(2.0)
        fly.send_signal(signal.SIGINT)
        stdout, stderr = fly.communicate(timeout=120)
    finally:
        if fly.poll() is None:
            fly.kill()
        sim.send_signal(signal.SIGINT)
        sim.wait(timeout=20)
    assert fly.returncode == EXIT_ABORTED, stderr
    assert f"listening on 127.0.0.1:{ports[0]} (network 1), 127.0.0.1:{ports[1]} " \
           "(network 2) for 4 vehicle(s)\n" in before
    report = json.loads(stdout)
    assert [(v["vehicle"], v["phase"]) for v in report["vehicles"]] == \
        [("1", "landed"), ("2", "landed"), ("2:1", "landed"), ("2:2", "landed")]
    assert report["min_separation_m"] >= 1.5
    events = read_events(tmp_path / "rec" / "events.jsonl")
    assert next(e["command"] for e in events if e["event"] == "operator") == "land 2:1"
    assert (tmp_path / "rec" / "flight-net2.tlog").stat().st_size > 0


def test_fly_refuses_connections_said_twice(tmp_path: Path) -> None:
    show = tmp_path / "four.toml"
    show.write_text(FLY_SHOW)
    fleet = _two_network_fleet(tmp_path, (reserved_udp_port(), reserved_udp_port()))
    out = _run("fly", str(show), "--fleet", str(fleet), "--connect", "udp:127.0.0.1:14551",
               "--record", str(tmp_path / "rec"))
    assert out.returncode == EXIT_USAGE
    assert "--connect conflicts with the [[network]] tables of" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
