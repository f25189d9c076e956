"""The console's event log: a tee in front of the recording's event sink.

Every event still goes to ``events.jsonl`` (the wrapped sink) first; the feed
keeps a bounded copy for the log pane.  Two streams, so that neither view
floods nor repeats itself:

- *fleet* entries: what the runner says to the operator (its ``notify`` lines,
  already folded fleet-wide: "8 vehicles (2-9): landed"), the console's own
  lines (operator commands, refusals, bad input) and losses;
- *vehicle* entries: every event that names a vehicle (``system_id``), shown
  when the log is filtered by that vehicle.

No Textual here: the pane only renders :meth:`EventFeed.lines`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

from groundctl.record.events import EventSink

#: Events that are shown in the fleet-wide log although the runner does not say them.
FLEET_EVENTS = frozenset({"vehicle_lost", "fleet_silent", "fleet_heard", "signal", "error"})
#: Events never shown (their content is elsewhere on the screen, or huge).
HIDDEN_EVENTS = frozenset({"preflight", "link_closed"})
#: Entries kept for the pane (the recording keeps them all).
KEEP = 5000


@dataclass(frozen=True)
class Entry:
    """One line of the log pane."""

    seq: int
    """Running number (the pane appends what is newer than its last)."""
    t: float
    """Time of the flight's clock, s."""
    sysid: int | None
    """The vehicle it is about (None: fleet-wide)."""
    kind: str
    """``notice`` (the runner), ``console`` (operator and console), or the event name."""
    text: str
    """The line."""
    fleet: bool
    """Shown in the unfiltered (fleet-wide) log."""


def describe(event: str, fields: dict[str, Any]) -> str:
    """An event as one short line: its ``text`` if it has one, else name and fields."""
    text = fields.get("text")
    if isinstance(text, str) and text:
        return text.splitlines()[0]
    parts = [f"{k}={v}" for k, v in fields.items() if k not in ("system_id", "t")]
    line = event.replace("_", " ") + (": " + ", ".join(parts) if parts else "")
    return line if len(line) <= 160 else line[:157] + "..."


class EventFeed:
    """An :class:`EventSink` that records what it passes on (see the module docstring).

    ``now`` gives the time of new entries (the flight's clock; 0 until set).
    """

    def __init__(self, inner: EventSink | None = None) -> None:
        self.inner = inner
        self.now: Any = lambda: 0.0
        self._entries: deque[Entry] = deque(maxlen=KEEP)
        self._seq = 0

    # -- sink -------------------------------------------------------------------------
    def emit(self, event: str, /, **fields: Any) -> None:
        """Pass the event on to the recording, then keep it for the pane."""
        if self.inner is not None:
            self.inner.emit(event, **fields)
        if event in HIDDEN_EVENTS:
            return
        sysid = fields.get("system_id")
        sysid = sysid if isinstance(sysid, int) else None
        if sysid is None and event not in FLEET_EVENTS:
            return  # said by the runner through notify, or link housekeeping
        self._add(sysid, event, describe(event, fields), event in FLEET_EVENTS)

    def flush(self) -> None:
        """The link flushes its sink on close."""
        flush = getattr(self.inner, "flush", None)
        if callable(flush):
            flush()

    # -- lines from the runner and the console ----------------------------------------
    def notice(self, text: str) -> None:
        """A line the runner says to the operator (its ``notify``)."""
        for line in text.splitlines() or [""]:
            self._add(None, "notice", line, True)

    def console(self, text: str, sysid: int | None = None) -> None:
        """A line of the console's own: an answer to the operator."""
        self._add(sysid, "console", text, True)

    def _add(self, sysid: int | None, kind: str, text: str, fleet: bool) -> None:
        self._seq += 1
        try:
            t = float(self.now())
        except Exception:  # a clock not ready yet must not lose the line
            t = 0.0
        self._entries.append(Entry(self._seq, t, sysid, kind, text, fleet))

    # -- reading ------------------------------------------------------------------------
    @property
    def last_seq(self) -> int:
        """The newest entry's number (0: none yet)."""
        return self._seq

    def lines(self, sysid: int | None = None, after: int = 0, most: int = 500) -> list[Entry]:
        """Entries newer than ``after``, oldest first, at most ``most`` (the newest):
        the fleet-wide ones, or (``sysid``) every one about that vehicle."""
        out: list[Entry] = []
        for e in reversed(self._entries):
            if e.seq <= after or len(out) >= most:
                break
            if (e.fleet and sysid is None) or (sysid is not None and e.sysid == sysid):
                out.append(e)
        out.reverse()
        return out
