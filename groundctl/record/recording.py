"""One flight's recordings: flight.tlog, events.jsonl and report.json in one directory."""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from groundctl.errors import GroundctlError
from groundctl.record.events import EventLog
from groundctl.record.tlog import TlogWriter


def default_directory(show: str, command: str, root: Path = Path("recordings")) -> Path:
    """``recordings/<show>-<command>-<UTC time>``."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    return root / f"{show}-{command}-{stamp}"


class Recording:
    """Opens the tlog and the event log; :meth:`finish` writes the report and closes both.

    Call :meth:`finish` from a ``finally``: whatever happened, what was
    recorded reaches the disk.
    """

    def __init__(self, directory: Path, now: Callable[[], float]) -> None:
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise GroundctlError(f"{directory}: cannot create the recording directory: "
                                 f"{exc.strerror or exc}") from exc
        self.directory = directory
        self.tlog = TlogWriter(directory / "flight.tlog")
        self.events = EventLog(directory / "events.jsonl", now)

    def finish(self, report: dict[str, Any]) -> None:
        """Write report.json, log its verdict, flush and close the tlog and the event log."""
        try:
            (self.directory / "report.json").write_text(json.dumps(report, indent=1) + "\n")
            self.events.emit("report", safe=report.get("safe"),
                             min_separation_m=report.get("min_separation_m"),
                             max_tracking_error_m=report.get("max_tracking_error_m"))
        finally:
            self.events.close()
            self.tlog.close()
