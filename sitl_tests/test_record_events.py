"""The JSON-lines event log: one object per line, flushed as written."""

from __future__ import annotations

import json
import time
from pathlib import Path

from groundctl.clock import ManualClock
from groundctl.record.events import EventLog, read_events


def test_lines_are_flushed_as_written(tmp_path: Path) -> None:
    clock = ManualClock(12.5)
    path = tmp_path / "events.jsonl"
    log = EventLog(path, clock.now)
    try:
        log.emit("vehicle_appeared", system_id=3, address="127.0.0.1:5000")
        # Readable before close, as soon as the writer thread has written it (the emit
        # itself never touches the disk): a crash a moment later would lose nothing.
        want = [{"t": 12.5, "event": "vehicle_appeared", "system_id": 3,
                 "address": "127.0.0.1:5000"}]
        deadline = time.monotonic() + 10.0
        while read_events(path) != want and time.monotonic() < deadline:
            time.sleep(0.01)
        assert read_events(path) == want
        clock.advance(1.0)
        log.emit("command_refused", system_id=3, reason="Arm: Need Position Estimate",
                 odd=Path("x"), t=99)
    finally:
        log.close()
    lines = path.read_text().splitlines()
    assert len(lines) == 2
    second = json.loads(lines[1])
    assert second["t"] == 13.5 and second["event"] == "command_refused" and second["odd"] == "x"
    log.emit("late")  # after close: ignored
    assert len(read_events(path)) == 2
