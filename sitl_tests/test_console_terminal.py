"""The console never stalls the flight (issue 27): `groundctl dry-run` on a real
pseudo-terminal that stops reading, closes, or whose process is killed.

Each test runs the CLI as an operator does: the pty is the process's controlling
terminal (so closing it sends SIGHUP as a closed terminal window or a dropped SSH
connection does) and its stdin, stdout and stderr.  What is checked is the exit
code, the recording (report.json, events.jsonl) and the processes left.
"""

from __future__ import annotations

import fcntl
import json
import os
import pty
import select
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from console_fixtures import Terminal

from groundctl.console.terminal import TerminalWriter
from groundctl.errors import EXIT_ABORTED, EXIT_OK
from groundctl.record.events import read_events

pytestmark = pytest.mark.slow

def _report(record: Path) -> dict[str, Any]:
    return json.loads((record / "report.json").read_text())


def test_a_terminal_that_stops_reading_slows_only_the_picture(tmp_path: Path) -> None:
    # The operator's terminal takes no output from mid-show on (paused, a stuck SSH
    # connection): the flight goes on at its rate to its end, and the console catches up
    # once it reads again.  A stall of 10 s was absorbed by the pty's and Textual's
    # buffers even before; a longer one filled them, and Textual's writer held the loop:
    # 58 s of lateness in a 40 s stall at x2, measured with the code before this test.
    record = tmp_path / "rec"
    term = Terminal(record, "--go", speed=2.0)
    term.wait_for("SHOW")
    deadline = time.monotonic() + 90.0  # a liveness deadline for a blocked ground station
    while not (record / "report.json").exists() and time.monotonic() < deadline:
        time.sleep(0.5)  # nothing read: the pty's buffer fills, then the writer's
    assert (record / "report.json").exists(), "the flight did not end while not read"
    drawn_before = len(term.out)
    rc = term.finish()
    assert rc == EXIT_OK, term.out[-3000:].decode(errors="replace")
    assert len(term.out) > drawn_before  # it drew again once read
    report = _report(record)
    assert report["safe"] and report["landed"]
    # The loop never waited on the terminal: no tick later than the paced clock's slack
    # (a blocked write would have held the loop, and the clock with it, for the whole
    # 10 s), and the guard never held the show for the ground station's own trouble.
    late = report["setpoint_lateness_ms"]
    assert late["max"] <= 50.0 + 1e-6 and late["overruns"] == 0, late
    events = [e["event"] for e in read_events(record / "events.jsonl")]
    assert "show_held" not in events and "terminal_lost" not in events


def test_a_terminal_closed_mid_show_lands_everyone_and_exits_5(tmp_path: Path) -> None:
    record = tmp_path / "rec"
    term = Terminal(record, "--go")
    term.wait_for("SHOW")
    term.read_for(2.0)
    term.close()
    assert term.finish() == EXIT_ABORTED
    report = _report(record)
    assert [v["phase"] for v in report["vehicles"]] == ["landed"] * 9
    assert report["min_separation_m"] >= report["separation_limit_m"]
    events = read_events(record / "events.jsonl")
    # The console found the terminal gone and SIGHUP came too: one stop, not two (a
    # second would abandon the fleet to its failsafes).
    stops = [e for e in events if e["event"] == "signal"]
    assert len(stops) == 1 and stops[0]["count"] == 1, stops
    assert [e["command"] for e in events if e["event"] == "operator"] == ["land all"]
    assert events[-1]["event"] == "report"


def test_a_terminal_closed_at_the_go_question_is_a_no_go(tmp_path: Path) -> None:
    record = tmp_path / "rec"
    term = Terminal(record)  # no --go: the console asks the operator
    term.wait_for("PRE-FLIGHT")
    term.read_for(3.0)
    term.close()
    assert term.finish(timeout=60.0) == EXIT_ABORTED
    events = read_events(record / "events.jsonl")
    kinds = [e["event"] for e in events]
    assert "sequence_started" not in kinds and "armed" not in kinds
    assert [e["count"] for e in events if e["event"] == "signal"] == [1]
    assert _report(record)["unsafe_reasons"][0] == "stopped before the show: nothing was armed"


def _alive_in_session(sid: int) -> list[str]:
    out = subprocess.run(["ps", "-e", "-o", "pid=,sid=,stat=,args="], capture_output=True,
                         text=True, check=True).stdout
    rows = [line.split(None, 3) for line in out.splitlines()]
    # Zombies have exited: only their reaping is left (to init).
    return [" ".join(r) for r in rows if int(r[1]) == sid and not r[2].startswith("Z")]


def test_no_process_outlives_a_killed_ground_station(tmp_path: Path) -> None:
    term = Terminal(tmp_path / "rec", "--go")
    try:
        term.wait_for("SHOW")
        sid = os.getsid(term.proc.pid)
        assert len(_alive_in_session(sid)) >= 3  # the fork server, the simulator, workers
        os.kill(term.proc.pid, signal.SIGKILL)
        term.proc.wait(timeout=30)
        deadline = time.monotonic() + 30.0  # they leave within a second or two
        while (left := _alive_in_session(sid)) and time.monotonic() < deadline:
            term.read_for(0.2)
        assert not left, left
    finally:
        term.finish(timeout=5.0)


def test_the_writer_never_blocks_and_says_when_the_terminal_is_gone() -> None:
    # A pty nobody reads: writes queue up to the limit, then are dropped and counted;
    # closing the other end is a lost terminal, said once.
    master, slave = pty.openpty()
    lost: list[str] = []
    caught: list[int] = []
    writer = TerminalWriter(os.fdopen(slave, "w", closefd=True), on_lost=lost.append,
                            on_caught_up=caught.append, limit_chars=100_000)
    writer.start()
    for _ in range(200):  # 2 MB at once: far more than the pty and the limit hold
        writer.write("x" * 10_000)
    assert writer.dropped > 0 and writer.queued <= 100_000
    deadline = time.monotonic() + 30.0  # the terminal reads again: it catches up
    while not caught and time.monotonic() < deadline:
        if select.select([master], [], [], 0.1)[0]:
            os.read(master, 65536)
    assert caught and sum(caught) == writer.dropped
    os.close(master)
    writer.write("after the hangup")
    writer.join(30.0)
    assert not writer.is_alive() and len(lost) == 1
    assert writer.lost in {"it hung up"} or writer.lost.startswith("writing to it failed")


class _Runner:
    """The two things a stop signal does to a runner, recorded."""

    def __init__(self) -> None:
        self.events = None
        self.sequence = object()  # the show is under way
        self.landings = 0

    def land_all(self) -> None:
        self.landings += 1


def test_a_terminal_lost_after_ctrl_c_never_abandons_the_landing() -> None:
    # Ctrl-C lands the fleet; then the SSH connection drops (SIGHUP and the console's own
    # finding, both).  A second stop would abandon the fleet to its failsafes: it is not.
    from groundctl.commands.flying import Interrupts

    stops = Interrupts(lambda text: None)
    runner = _Runner()
    stops.attach(runner)  # type: ignore[arg-type]
    stops.stop("Ctrl-C")
    stops.hangup("SIGHUP (terminal closed)")
    stops.hangup("terminal closed (writing to it failed)")
    assert stops.presses == 1 and runner.landings == 1
    # A hangup first is one stop too, and the console's finding of it adds nothing.
    stops = Interrupts(lambda text: None)
    runner = _Runner()
    stops.attach(runner)  # type: ignore[arg-type]
    stops.hangup("terminal closed (writing to it failed)")
    stops.hangup("SIGHUP (terminal closed)")
    assert stops.presses == 1 and runner.landings == 1


def test_a_terminal_made_non_blocking_by_someone_else_is_slow_not_gone() -> None:
    # Another program on the same terminal set O_NONBLOCK: a full terminal then says
    # EAGAIN.  That is a terminal not reading (wait for it), not one that is gone.
    master, slave = pty.openpty()
    flags = fcntl.fcntl(slave, fcntl.F_GETFL)
    fcntl.fcntl(slave, fcntl.F_SETFL, flags | os.O_NONBLOCK)
    writer = TerminalWriter(os.fdopen(slave, "w", closefd=True), limit_chars=1_000_000)
    writer.start()
    text = "y" * 200_000  # far more than the pty holds
    writer.write(text)
    time.sleep(1.0)  # nobody reads meanwhile
    assert writer.lost is None
    got = 0
    deadline = time.monotonic() + 30.0
    while got < len(text) and time.monotonic() < deadline:
        if select.select([master], [], [], 0.2)[0]:
            got += len(os.read(master, 65536))
    assert got >= len(text) and writer.lost is None
    assert writer.wait_written(5.0)
    writer.stop()
    os.close(master)
