"""One flight's recordings: flight.tlog, events.jsonl and report.json in one directory."""

from __future__ import annotations

import datetime as dt
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from groundctl.errors import GroundctlError
from groundctl.record.events import EventLog
from groundctl.record.tlog import TlogWriter

#: How long the show's part of a recording directory's name may be.
MAX_NAME_PART = 64


def safe_name(name: str, fallback: str = "show") -> str:
    """``name`` as one safe path component: letters, digits, ``.``, ``-`` and ``_``.

    A show's name comes from a show or plan file, which may come from
    anywhere: ``../../../../elsewhere/quick`` must not put the recordings
    outside ``recordings/``.  Every other character becomes ``_``, leading dots
    are dropped (no ``..``, no hidden directory) and the result is at most
    :data:`MAX_NAME_PART` characters; nothing usable left gives ``fallback``.
    """
    cleaned = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")[:MAX_NAME_PART]
    return cleaned if cleaned.strip("_") else fallback


def default_directory(show: str, command: str, root: Path = Path("recordings")) -> Path:
    """``recordings/<show>-<command>-<UTC time>``, the show's name made a safe component."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    return root / f"{safe_name(show)}-{safe_name(command, 'run')}-{stamp}"


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
