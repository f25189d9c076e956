"""Events as log lines with levels: pure (dicts in, strings out).

An event of ``events.jsonl`` (or a live event sink) becomes one line
``event [vehicle N]: text`` with a Rerun log level chosen by its kind; a
vehicle's STATUSTEXT keeps the level of its MAVLink severity.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: Event kinds logged as errors: the flight lost something or could not go on.
ERROR_EVENTS = frozenset({
    "error", "vehicle_lost", "command_failed", "guard_land_all", "waiting_for_lost",
    "crashed", "simulator_died"})
#: Event kinds logged as warnings: refusals, holds, fallbacks, forgeries, the operator's stop.
WARN_EVENTS = frozenset({
    "command_refused", "command_timeout", "show_held", "taken_out", "mpc_fallback",
    "mpc_recovering", "link_conflict", "address_conflict", "address_changed", "bad_packet",
    "bad_signature", "fleet_silent", "param_not_set", "signal", "late", "unknown_vehicle",
    "vehicle_late", "push"})
#: Event kinds logged as debug: chatter that repeats through every flight.
DEBUG_EVENTS = frozenset({"progress", "preflight", "prearm", "address_learnt"})
#: Longest line logged; the rest is cut.
MAX_TEXT = 400
#: Keys never repeated in a line's text.
_SKIP = frozenset({"t", "event", "system_id", "text"})


@dataclass(frozen=True)
class LogLine:
    """One line of the flight's log."""

    t: float
    """The executor's clock (an event's ``t``) or, for tlog lines, Unix time, s."""
    level: str
    """Rerun text log level: ERROR, WARN, INFO or DEBUG."""
    text: str
    """The line."""


def severity_level(severity: int) -> str:
    """MAVLink MAV_SEVERITY (0 emergency .. 7 debug) as a log level."""
    if severity <= 3:
        return "ERROR"
    if severity == 4:
        return "WARN"
    return "DEBUG" if severity >= 7 else "INFO"


def event_level(event: Mapping[str, Any]) -> str:
    """The level of one event."""
    kind = str(event.get("event", ""))
    if kind == "statustext":
        sev = event.get("severity")
        return severity_level(sev) if isinstance(sev, int) else "INFO"
    if kind == "report":
        return "INFO" if event.get("safe") else "ERROR"
    if kind in ERROR_EVENTS:
        return "ERROR"
    if kind in WARN_EVENTS:
        return "WARN"
    if kind in DEBUG_EVENTS:
        return "DEBUG"
    return "INFO"


def event_text(event: Mapping[str, Any]) -> str:
    """``kind [vehicle N]: text`` (or the event's other fields as ``key=value``)."""
    kind = str(event.get("event", "?"))
    head = kind
    sysid = event.get("system_id")
    if sysid is not None:
        head += f" vehicle {sysid}"
    text = event.get("text")
    if not isinstance(text, str):
        text = " ".join(f"{k}={json.dumps(v, default=str)}" for k, v in event.items()
                        if k not in _SKIP)
    line = f"{head}: {text}" if text else head
    return line if len(line) <= MAX_TEXT else line[:MAX_TEXT - 3] + "..."


def event_line(event: Mapping[str, Any]) -> LogLine | None:
    """One event as a :class:`LogLine` (None without a numeric ``t``)."""
    t = event.get("t")
    if not isinstance(t, (int, float)):
        return None
    return LogLine(float(t), event_level(event), event_text(event))


def mode_line(unix_s: float, sysid: int, mode: str, armed: bool) -> LogLine:
    """A vehicle's HEARTBEAT mode or arming change seen in a bare tlog."""
    return LogLine(unix_s, "INFO", f"heartbeat vehicle {sysid}: {mode}, "
                                   f"{'armed' if armed else 'disarmed'}")


def statustext_line(unix_s: float, sysid: int, severity: int, text: str) -> LogLine:
    """A vehicle's STATUSTEXT seen in a bare tlog."""
    return LogLine(unix_s, severity_level(severity), f"statustext vehicle {sysid}: {text}")
