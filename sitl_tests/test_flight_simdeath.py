"""The dry-run's simulator process dies mid-flight: the run still ends with a report.

One dry-run of the quick show; 3 s into the show the simulator's child process
is killed outright (SIGKILL, as the kernel's OOM killer would).  The ground
station must stop the flight, say why in one line, and still write its
report and recordings.  Plus the pieces: a dead :class:`SimProcess` answers
with :class:`SimulatorError`, not a broken pipe.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest
from flight_fixtures import dry_run, show_time, until

from groundctl.clock import ScaledClock
from groundctl.errors import SimulatorError
from groundctl.flight.runner import ShowRunner
from groundctl.record.events import read_events
from groundctl.sim import SimConfig
from groundctl.sim.process import SimProcess

DIED = "the simulator process died mid-flight (exit code -9): the simulated fleet is gone"


def test_a_dead_simulator_process_ends_the_flight_with_a_report(tmp_path: Path) -> None:
    killed: list[int] = []

    async def kill_simulator(runner: ShowRunner, sim: SimProcess) -> None:
        await until(runner, lambda: show_time(runner) > 3.0)
        assert sim.alive
        killed.append(sim.pid)
        os.kill(sim.pid, signal.SIGKILL)

    result = dry_run(tmp_path, during=kill_simulator)
    assert killed, "the show never started"
    assert isinstance(result.error, SimulatorError) and result.flown
    assert str(result.error) == DIED
    report = result.report
    assert report["safe"] is False
    assert report["unsafe_reasons"][0] == DIED
    assert report["simulator"]["exit_code"] == -9
    assert "died" in report["simulator"]["error"]
    # Written all the same: the report, and the events up to the end.
    assert json.loads((tmp_path / "report.json").read_text())["unsafe_reasons"][0] == DIED
    events = read_events(tmp_path / "events.jsonl")
    assert {"kind": "SimulatorError", "text": DIED}.items() <= next(
        e for e in events if e["event"] == "error").items()
    assert events[-1]["event"] == "report"


def test_calls_to_a_dead_simulator_process_raise_simulator_error() -> None:
    config = SimConfig(count=2, bind_host="127.0.0.1", gcs=("127.0.0.1", 9))
    sim = SimProcess(config, ScaledClock(1.0))
    try:
        assert sim.alive and sim.exitcode is None
        assert sim.get("overruns") == 0
        os.kill(sim.pid, signal.SIGKILL)
        deadline = time.monotonic() + 10.0
        while sim.alive and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not sim.alive
        with pytest.raises(SimulatorError, match=r"^the simulator process died \(exit code -9\) "
                                                 r"during truth$") as err:
            sim.call("truth")
        assert isinstance(err.value.__cause__, (EOFError, OSError))
        with pytest.raises(SimulatorError, match=r"died \(exit code -9\) during max_lag$"):
            sim.get("max_lag")
        with pytest.raises(SimulatorError, match=r"died \(exit code -9\) during stop$"):
            sim.stop()
        sim.stop()  # once stopped, again is nothing
        assert sim.exitcode == -9
    finally:
        sim.stop()


def test_a_call_asked_without_waiting_is_answered_later_and_never_lost() -> None:
    """The truth probe asks on one tick and reads on the next: a blocking call in between
    reads the outstanding answer first and keeps it; a dead child is still one error."""
    config = SimConfig(count=2, bind_host="127.0.0.1", gcs=("127.0.0.1", 9))
    sim = SimProcess(config, ScaledClock(1.0))
    try:
        assert sim.answer() == (False, None)  # nothing asked
        sim.ask("truth")
        sim.ask("truth")  # one at a time: this one is not sent
        deadline = time.monotonic() + 10.0
        while (got := sim.answer()) == (False, None) and time.monotonic() < deadline:
            time.sleep(0.001)
        ready, (positions, leds) = got
        assert ready and positions.shape == (2, 3) and len(leds) == 2
        assert sim.answer() == (False, None)  # read once
        sim.ask("truth")
        assert sim.get("overruns") == 0  # the truth's answer was on the pipe before it
        ready, (positions, _) = sim.answer()
        assert ready and positions.shape == (2, 3)
        sim.ask("no_such_call")
        with pytest.raises(AttributeError):
            while not sim.answer()[0]:
                time.sleep(0.001)
        sim.ask("truth")
        os.kill(sim.pid, signal.SIGKILL)
        while sim.alive and time.monotonic() < deadline:
            time.sleep(0.01)
        with pytest.raises(SimulatorError, match=r"died \(exit code -9\)"):
            for _ in range(10_000):  # (an answer sent before it died is read first)
                if sim.answer()[0]:
                    sim.ask("truth")
                time.sleep(0.001)
    finally:
        with pytest.raises(SimulatorError):
            sim.stop()
