"""One flight's recordings in one directory.

``flight.tlog`` (every MAVLink packet), ``events.jsonl``, ``showclock.csv``
(the show clock against wall time, per tick: what puts the tlog on the show's
timeline), ``plan.npz`` (the plan flown, in the plan file format) and
``report.json``.  ``groundctl replay DIR`` reads them back into Rerun.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from groundctl.errors import GroundctlError
from groundctl.record.events import EventLog
from groundctl.record.showclock import ShowClockLog
from groundctl.record.tlog import TlogWriter

if TYPE_CHECKING:
    from groundctl.flight.runner import ShowRunner
    from groundctl.plan.plan import Plan

#: The files of a recording directory.
log = logging.getLogger(__name__)

TLOG, EVENTS, SHOW_CLOCK, PLAN, REPORT = ("flight.tlog", "events.jsonl", "showclock.csv",
                                          "plan.npz", "report.json")

#: How long the show's part of a recording directory's name may be.
MAX_NAME_PART = 64


def network_tlog_name(network: int) -> str:
    """The tlog file of MAVLink network ``network`` (from 1)."""
    return TLOG if network == 1 else f"flight-net{network}.tlog"


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
    """Opens the tlog, the event log and the show clock log, and keeps ``plan``;
    :meth:`finish` writes the report and closes them.

    Call :meth:`follow` with the runner so the show clock is logged every tick,
    and :meth:`finish` from a ``finally``: whatever happened, what was recorded
    reaches the disk.
    """

    def __init__(self, directory: Path, now: Callable[[], float],
                 plan: Plan | None = None, *,
                 wall: Callable[[], float] = time.time) -> None:
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise GroundctlError(f"{directory}: cannot create the recording directory: "
                                 f"{exc.strerror or exc}") from exc
        self.directory = directory
        if plan is not None:
            try:
                plan.save(directory / PLAN)  # before the flight: a crash keeps it too
            except OSError as exc:
                raise GroundctlError(f"{directory / PLAN}: cannot write the plan: "
                                     f"{exc.strerror or exc}") from exc
        # ``wall`` stamps the tlog and the show clock log (Unix time); a paced dry-run
        # passes its clock made Unix time, so its waits leave no gaps in the recording.
        self.tlog = TlogWriter(directory / TLOG, wall=wall)
        self._tlogs = [self.tlog]
        self._wall = wall
        self.events = EventLog(directory / EVENTS, now)
        self.show_clock = ShowClockLog(directory / SHOW_CLOCK, wall=wall)

    def network_tlogs(self, count: int) -> list[TlogWriter]:
        """One tlog per MAVLink network: network 1's is ``flight.tlog``, network n's
        ``flight-net<n>.tlog``.  One each, because a packet carries only its system id:
        two networks' vehicle 17 in one log could not be told apart, whereas each of
        these is a plain tlog any MAVLink tool reads."""
        while len(self._tlogs) < count:
            n = len(self._tlogs) + 1
            self._tlogs.append(TlogWriter(self.directory / network_tlog_name(n),
                                          wall=self._wall))
        return self._tlogs[:count]

    def follow(self, runner: ShowRunner) -> None:
        """Log the show clock on every tick of ``runner``, chained before any
        ``on_tick`` it already has (the dry-run's truth probe)."""
        previous = runner.on_tick
        log = self.show_clock

        def tick(now: float, show_time: float) -> None:
            seq = runner.sequence
            started = seq is not None and seq.started_at is not None
            late = runner.lateness_s[-1] if runner.lateness_s else None
            # The Unix time of ``now`` (the tick's start), not of this call at its end.
            behind = runner.clock.wall_interval(max(runner.clock.now() - now, 0.0))
            log.tick(now, show_time if started else None, late, behind)
            if previous is not None:
                previous(now, show_time)

        runner.on_tick = tick

    def finish(self, report: dict[str, Any]) -> None:
        """Write report.json, log its verdict, flush and close the tlog and the event log."""
        try:
            (self.directory / REPORT).write_text(json.dumps(report, indent=1) + "\n")
            self.events.emit("report", safe=report.get("safe"),
                             min_separation_m=report.get("min_separation_m"),
                             max_tracking_error_m=report.get("max_tracking_error_m"))
        finally:
            whole = [self.show_clock.close(), self.events.close()]
            whole += [tlog.close() for tlog in self._tlogs]
            if not all(whole):
                log.warning("%s: the recording is not whole: the disk fell too far behind "
                            "(or failed) and some of it was dropped rather than wait on it",
                            self.directory)
