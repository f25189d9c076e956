"""``groundctl replay``: a recording directory (or a bare tlog) into a Rerun recording.

A directory holds flight.tlog, events.jsonl, showclock.csv, plan.npz and
report.json (:mod:`groundctl.record.recording`); any of them but the tlog may
be missing (an older recording, a crash), and a bare ``.tlog`` has only
itself: then what needs the missing part is left out and said once.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from groundctl.errors import DamagedTlog, RecordingError
from groundctl.plan.plan import Plan
from groundctl.record.recording import EVENTS, PLAN, REPORT, SHOW_CLOCK, TLOG
from groundctl.record.showclock import ShowClockTable, read_show_clock
from groundctl.vehicleid import NETWORK_STRIDE
from groundctl.viz import scene
from groundctl.viz.eventlog import LogLine, event_line, mode_line, statustext_line
from groundctl.viz.flight import FlightArrays, flight_arrays
from groundctl.viz.tlogread import TlogData, decode_tlog, merge_tlogs

_NETWORK_TLOG = re.compile(r"flight-net(\d+)\.tlog")

#: A vehicle is matched to the takeoff slot it stands on within this, m (as pre-flight).
SLOT_TOLERANCE_M = 3.0


@dataclass(frozen=True)
class ReplaySource:
    """The files one replay reads (None: not there)."""

    tlog: Path
    """The tlog."""
    plan: Path | None = None
    """The plan flown."""
    events: Path | None = None
    """events.jsonl."""
    clock: Path | None = None
    """showclock.csv."""
    report: Path | None = None
    """report.json."""
    networks: tuple[tuple[int, Path], ...] = ()
    """The other MAVLink networks' tlogs, (network, path), network 2 on
    (``flight-net<n>.tlog``): their vehicles are named by their vehicle ids (2:17)."""


@dataclass
class ReplaySummary:
    """What a replay wrote."""

    vehicles: int = 0
    ticks: int = 0
    lines: int = 0
    show_seconds: float = 0.0
    notes: list[str] = field(default_factory=list)
    """What was left out and why (no plan, no show clock)."""
    damage: DamagedTlog | None = None
    """The tlog's damage, if it had one (what came before was replayed)."""


def find_source(recording: Path, plan: Path | None = None) -> ReplaySource:
    """The files of ``recording`` (a directory or a ``.tlog``); ``plan`` overrides the
    recording's own."""
    if recording.is_dir():
        tlog = recording / TLOG
        if not tlog.is_file():
            raise RecordingError(recording, f"no {TLOG} in this directory: not a recording")

        def there(name: str) -> Path | None:
            p = recording / name
            return p if p.is_file() else None

        others = sorted((int(m.group(1)), p) for p in recording.glob("flight-net*.tlog")
                        if (m := _NETWORK_TLOG.fullmatch(p.name)) and int(m.group(1)) >= 2)
        return ReplaySource(tlog, plan or there(PLAN), there(EVENTS), there(SHOW_CLOCK),
                            there(REPORT), tuple(others))
    if not recording.is_file():
        raise RecordingError(recording, "no such recording directory or tlog")
    return ReplaySource(recording, plan)


def default_output(recording: Path) -> Path:
    """``DIR/replay.rrd`` for a directory, ``X.rrd`` beside a bare ``X.tlog``."""
    return recording / "replay.rrd" if recording.is_dir() else recording.with_suffix(".rrd")


def read_events_tolerant(path: Path) -> list[dict[str, Any]]:
    """events.jsonl, skipping lines that are not JSON objects (a crash can cut the last)."""
    out: list[dict[str, Any]] = []
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise RecordingError(path, f"cannot read: {exc.strerror or exc}") from exc
    for line in text.splitlines():
        try:
            obj = json.loads(line)
        except ValueError:
            continue
        if isinstance(obj, dict):
            out.append(obj)
    return out


def tracks_from(report: Mapping[str, Any] | None, events: Sequence[Mapping[str, Any]]
                ) -> dict[int, int] | None:
    """System id -> plan track, from the report's vehicles or the pre-flight event."""
    if report is not None:
        got = {int(v["system_id"]): int(v["track"]) for v in report.get("vehicles", [])
               if isinstance(v, dict) and isinstance(v.get("track"), int)
               and isinstance(v.get("system_id"), int)}
        if got:
            return got
    for e in events:
        if e.get("event") == "preflight_passed" and isinstance(e.get("tracks"), dict):
            try:
                return {int(k): int(v) for k, v in e["tracks"].items()}
            except (TypeError, ValueError):
                return None
    return None


def tracks_by_slot(fa: FlightArrays, plan: Plan) -> dict[int, int]:
    """Without a report: each vehicle on the takeoff slot its first position is within
    :data:`SLOT_TOLERANCE_M` of (horizontally)."""
    out: dict[int, int] = {}
    for j, sysid in enumerate(fa.sysids):
        first = np.flatnonzero(np.isfinite(fa.positions[:, j, 0]))
        if first.size == 0:
            continue
        p = fa.positions[first[0], j, :2]
        d = np.linalg.norm(plan.home[:, :2] - p, axis=1)
        k = int(np.argmin(d))
        if d[k] <= SLOT_TOLERANCE_M and k not in out.values():
            out[sysid] = k
    return out


def log_lines_of(data: TlogData, events: Sequence[Mapping[str, Any]],
                 clock: ShowClockTable | None, fa: FlightArrays
                 ) -> tuple[list[LogLine], np.ndarray, np.ndarray]:
    """Every log line with its (show_time, Unix) times: the events (on the executor's
    clock, put on Unix time by the show clock log) or, without events, the HEARTBEAT mode
    changes and STATUSTEXTs of the tlog."""
    lines: list[LogLine] = []
    unix: list[float] = []
    ev_lines = [x for x in (event_line(e) for e in events) if x is not None]
    if ev_lines and clock is not None and clock.ticks:
        lines += ev_lines
        unix += clock.wall_at_now(np.array([x.t for x in ev_lines])).tolist()
    else:
        for t, sysid, mode, armed in data.modes:
            lines.append(mode_line(t, sysid, mode, armed))
            unix.append(t)
        for t, sysid, severity, text in data.texts:
            lines.append(statustext_line(t, sysid, severity, text))
            unix.append(t)
    u = np.array(unix, dtype=float)
    return lines, fa.show_time_at(u), u


def replay(source: ReplaySource, targets: Sequence[scene.RerunTarget],
           notify: Callable[[str], None] | None = None) -> ReplaySummary:
    """Write the Rerun recording of ``source`` to ``targets``; see the module docstring."""
    summary = ReplaySummary()
    parts: list[tuple[Path, TlogData]] = []
    for network, path in ((1, source.tlog), *source.networks):
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise RecordingError(path, f"cannot read: {exc.strerror or exc}") from exc
        part = decode_tlog(raw, offset=(network - 1) * NETWORK_STRIDE)
        if part.packets == 0:
            raise RecordingError(path, "no MAVLink packet could be read: not a tlog"
                                 + (f" ({part.damage.reason} at byte {part.damage.offset})"
                                    if part.damage is not None else ""))
        parts.append((path, part))
    data = merge_tlogs([part for _, part in parts])
    damaged = next((path for path, part in parts if part.damage is not None), source.tlog)
    plan: Plan | None = None
    if source.plan is not None:
        plan = Plan.load(source.plan)  # a PlanFileError is one line
    else:
        summary.notes.append("no plan: no planned paths or tracking error (use --plan)")
    clock = read_show_clock(source.clock) if source.clock is not None else None
    if clock is None or clock.ticks < 2:
        summary.notes.append("no show clock log: show_time estimated from the vehicles' "
                             "clocks, counted from the first packet")
        clock = None
    events = read_events_tolerant(source.events) if source.events is not None else []
    report: dict[str, Any] | None = None
    if source.report is not None:
        try:
            loaded = json.loads(source.report.read_text(encoding="utf-8"))
            report = loaded if isinstance(loaded, dict) else None
        except (OSError, ValueError):
            summary.notes.append(f"{source.report}: unreadable, ignored")
    tracks = tracks_from(report, events)
    fa = flight_arrays(data, plan, clock, tracks)
    if plan is not None and not fa.tracks:
        fa = flight_arrays(data, plan, clock, tracks_by_slot(fa, plan))
    lines, line_show, line_unix = log_lines_of(data, events, clock, fa)
    limit = plan.limits.min_separation if plan is not None else None

    name = source.tlog.parent.name if source.tlog.name == TLOG else source.tlog.stem
    rec = scene.open_recording(targets, f"replay {name}")
    done = False
    try:
        if plan is not None:
            scene.log_plan(rec, plan)
        scene.log_styles(rec, fa.sysids, limit)
        scene.log_vehicles(rec, fa)
        scene.log_series(rec, fa, limit)
        scene.log_lines(rec, line_show, line_unix, lines)
        if data.damage is not None:
            d = data.damage
            at = (float(fa.show_time_at(np.array([d.last_unix_s]))[0])
                  if d.last_unix_s is not None else None)
            summary.damage = DamagedTlog(damaged, d.offset, d.size, data.packets, d.reason,
                                         d.last_unix_s, at)
            stop = np.array([at if at is not None else 0.0])
            scene.log_lines(rec, stop, None if d.last_unix_s is None
                            else np.array([d.last_unix_s]),
                            [LogLine(0.0, "ERROR", f"tlog: {summary.damage}")])
        done = True
    finally:
        if done:
            scene.close_recording(rec)
        else:
            rec.disconnect()
    summary.vehicles = len(fa.sysids)
    summary.ticks = len(fa.unix_s)
    summary.lines = len(lines)
    started = fa.show_clock[np.isfinite(fa.show_clock)]
    summary.show_seconds = float(started.max()) if started.size else \
        float(fa.show_time[-1] - fa.show_time[0]) if len(fa.show_time) else 0.0
    if notify is not None:
        for note in summary.notes:
            notify(note)
    return summary
