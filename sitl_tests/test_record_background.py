"""Recording files the control loop never waits on (groundctl/record/background.py),
against a disk that stops: a named pipe whose reader stops reading, the same blocked
write() a stalled SD card or network share gives."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from groundctl.errors import GroundctlError
from groundctl.record.background import BackgroundFile
from groundctl.record.events import EventLog, read_events
from groundctl.record.tlog import TlogWriter


class StalledDisk:
    """A FIFO whose reader opens it and reads nothing until :meth:`resume`."""

    def __init__(self, path: Path) -> None:
        os.mkfifo(path)
        self.path = path
        self.data = bytearray()
        self._go = threading.Event()
        self._opened = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        fd = os.open(self.path, os.O_RDONLY)
        self._opened.set()
        self._go.wait()
        while chunk := os.read(fd, 1 << 16):
            self.data += chunk
        os.close(fd)

    def resume(self) -> None:
        self._go.set()

    def join(self) -> None:
        self._thread.join(10.0)


def test_writes_return_at_once_while_the_disk_is_stalled(tmp_path: Path) -> None:
    disk = StalledDisk(tmp_path / "stalled.tlog")
    out = BackgroundFile(disk.path, "tlog", max_buffer=1 << 20)
    packet = bytes(range(256)) * 4
    for _ in range(600):  # 600 kB: ten times the pipe's own buffer; written to the file
        assert out.write(packet)  # directly, the first of them would block here for good
    out.flush()
    assert out.waiting > 0  # the disk has not taken it: the thread is blocked in write()
    disk.resume()
    assert out.close(timeout=10.0)
    disk.join()
    assert bytes(disk.data) == packet * 600 and out.dropped == 0


def test_a_disk_further_behind_than_the_buffer_drops_and_says_so(tmp_path: Path) -> None:
    disk = StalledDisk(tmp_path / "stalled.jsonl")
    out = BackgroundFile(disk.path, "event log", max_buffer=200_000)
    kept = sum(out.write(b"x" * 1000) for _ in range(1000))
    assert 0 < kept < 1000 and out.dropped == 1000 - kept
    disk.resume()
    assert not out.close(timeout=10.0)  # something was lost: said, not hidden
    disk.join()
    assert len(disk.data) == kept * 1000


def test_the_event_log_and_the_tlog_keep_everything_once_the_disk_is_back(
        tmp_path: Path) -> None:
    events = StalledDisk(tmp_path / "events.jsonl")
    log = EventLog(events.path, lambda: 1.0)
    for i in range(2000):
        log.emit("vehicle_appeared", system_id=i % 254 + 1, n=i)
    tlog_disk = StalledDisk(tmp_path / "flight.tlog")
    tlog = TlogWriter(tlog_disk.path, wall=lambda: 1.0)
    for _ in range(5000):
        tlog.write(b"\xfd" + bytes(20))
    events.resume()
    tlog_disk.resume()
    log.close()
    tlog.close()
    events.join()
    tlog_disk.join()
    copy = tmp_path / "copy.jsonl"
    copy.write_bytes(bytes(events.data))
    assert [e["n"] for e in read_events(copy)] == list(range(2000))
    assert len(tlog_disk.data) == 5000 * (8 + 21)


def test_an_unwritable_directory_is_refused_at_once_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(GroundctlError) as info:
        BackgroundFile(tmp_path / "missing" / "flight.tlog", "tlog")
    assert "cannot write tlog" in str(info.value) and "\n" not in str(info.value)
