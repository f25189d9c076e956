"""JSON-lines event log: one object per line with ``t`` and ``event`` plus fields.

Events are rare (a vehicle appeared, a mode changed, a command was refused)
and are exactly what one reads after something went wrong, so every line is
flushed as it is written: a crash loses nothing.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

from groundctl.record.background import BackgroundFile
from groundctl.vehicleid import NETWORK_STRIDE, spell


class EventSink(Protocol):
    """Anything that takes events: an :class:`EventLog`, a console, a test list."""

    def emit(self, event: str, /, **fields: Any) -> None: ...


class EventLog:
    """Writes events to a JSON-lines file; ``t`` comes from the ``now`` callable."""

    def __init__(self, path: str | Path, now: Callable[[], float]) -> None:
        self.path = Path(path)
        self._now = now
        self._lock = threading.Lock()
        # Written by a thread of its own: an event costs a JSON line, never a system call
        # on the control loop, and a stalled disk never reaches it.
        self._file: BackgroundFile | None = BackgroundFile(self.path, "event log",
                                                            flush_interval=0.0)
        self.count = 0
        self._complete = True

    def emit(self, event: str, /, **fields: Any) -> None:
        """Write one event line now (``t`` and ``event`` cannot be overridden by fields)."""
        record: dict[str, Any] = {"t": round(self._now(), 6), "event": event}
        record.update({k: v for k, v in fields.items() if k not in record})
        sysid = fields.get("system_id")
        if isinstance(sysid, int) and sysid >= NETWORK_STRIDE and "vehicle" not in record:
            record["vehicle"] = spell(sysid)  # 2:17 beside its vehicle id 1017
        line = json.dumps(record, default=str, separators=(",", ":"))
        with self._lock:
            if self._file is None:
                return
            self._file.write((line + "\n").encode("utf-8"))
            self.count += 1

    def close(self) -> bool:
        """Write out, flush and close; idempotent.  False if events were lost on the way
        to the disk."""
        with self._lock:
            if self._file is not None:
                self._complete = self._file.close()
                self._file = None
            return self._complete

    def __enter__(self) -> EventLog:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """All events in a JSON-lines log (for tests and post-flight tools)."""
    with open(path, encoding="utf-8") as f:
        return [json.loads(line) for line in f if line.strip()]
