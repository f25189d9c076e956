"""Carrying out: the sequence's actions become link commands (each in its own
task) and notices (folded per kind), the operator's commands go to the
sequence, and the status line says where the flight is."""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import CommandRefused, LinkError
from groundctl.execute.sequence import (
    Action,
    Arm,
    Command,
    Disarm,
    Kill,
    Land,
    Notice,
    SetMode,
    Takeoff,
)
from groundctl.flight.runner.config import FOLD_AFTER, _ids
from groundctl.flight.runner.preflight import Preflight

#: Notices that are also events of their own name (issue 29's contract).
_SPARE_EVENTS = frozenset({"spare_planned", "spare_joined", "spare_failed"})


class Commands(Preflight):
    """Actions carried out, the operator's commands, the status line (a layer of
    :class:`ShowRunner`)."""

    def _perform(self, actions: list[Action]) -> None:
        for a in actions:
            if isinstance(a, Notice):
                if a.kind in ("heard_again", "retaken") and a.sysid is not None:
                    self._leds.forget(a.sysid)  # back from a silence: its colour afresh
                if a.kind in _SPARE_EVENTS and self.events is not None:
                    self.events.emit(a.kind, system_id=a.sysid, text=a.text)
                if a.kind and a.sysid is not None:
                    self._pending_notices.append(a)  # folded per kind at the tick's end
                else:
                    self._say(a.text, "sequence", system_id=a.sysid)
            else:
                self._spawn(self._command(a))

    def _flush_notices(self) -> None:
        """Notices of one kind for many vehicles in one tick become one line (each is
        still one event)."""
        pending, self._pending_notices = self._pending_notices, []
        by_kind: dict[str, list[Notice]] = {}
        for n in pending:
            by_kind.setdefault(n.kind, []).append(n)
        for kind, notes in by_kind.items():
            if len(notes) <= FOLD_AFTER:
                for n in notes:
                    self._say(n.text, "sequence", system_id=n.sysid, kind=kind)
                continue
            ids = sorted({n.sysid for n in notes if n.sysid is not None})
            for n in notes:
                if self.events is not None:
                    self.events.emit("sequence", text=n.text, system_id=n.sysid, kind=kind)
            self._notify(f"{len(ids)} vehicles {_ids(ids)}: {notes[0].summary or kind}")

    async def _command(self, a: Command) -> None:
        link = self.link
        if self.events is not None:
            self.events.emit("command", system_id=a.sysid, action=type(a).__name__,
                             **{k: v for k, v in vars(a).items() if k != "sysid"})
        try:
            if isinstance(a, SetMode):
                await link.set_mode(a.sysid, a.mode)
            elif isinstance(a, Arm):
                await link.arm(a.sysid)
            elif isinstance(a, Takeoff):
                await link.takeoff(a.sysid, a.alt_m)
            elif isinstance(a, Land):
                await link.land(a.sysid)
            elif isinstance(a, Disarm):
                await link.disarm(a.sysid)
            elif isinstance(a, Kill):
                await link.disarm(a.sysid, force=True)
        except LinkError as exc:
            reason = (exc.reason or exc.result) if isinstance(exc, CommandRefused) else str(exc)
            rec = self._record(a.sysid)
            rec.commands_refused += 1
            rec.last_refusal = reason
            self._perform([Notice(a.sysid, f"vehicle {a.sysid}: {type(a).__name__.lower()} "
                                           f"not done: {reason}", "command_failed",
                                  f"{type(a).__name__.lower()} not done: {reason}")])
            if self.events is not None:
                self.events.emit("command_failed", system_id=a.sysid, reason=reason)
            if self.sequence is not None:
                self._perform(self.sequence.command_failed(a, reason, self.clock.now()))
            self._flush_notices()

    async def _drain(self) -> None:
        # Commands still in flight (a final disarm's ACK): give them a moment, then cancel.
        if self._tasks:
            await asyncio.wait(list(self._tasks), timeout=max(self.clock.wall_interval(2.0),
                                                              0.01))
        for task in list(self._tasks):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    def commanded_now(self) -> tuple[float, dict[int, NDArray[np.float64]]] | None:
        """(the last tick's time, where its paths put every streamed vehicle then, show
        frame): what the guard measures tracking errors against.  For the console."""
        if self.sequence is None or self._request is None:
            return None
        at, req = self._request
        return at, self.sequence.commanded_all(req, at)

    # -- operator ---------------------------------------------------------------------
    def _operator(self, name: str, call: Callable[[float], list[Action]]) -> None:
        if self.sequence is None:
            self._say(f"{name}: the flight has not started", "operator", command=name)
            return
        if self.events is not None:
            self.events.emit("operator", command=name)
        self._perform(call(self.clock.now()))

    def hold(self) -> None:
        """Every drone hovers at its current plan point; the show clock stops."""
        self._operator("hold", lambda now: self.sequence.hold(now))  # type: ignore[union-attr]

    def resume(self) -> None:
        """The show clock runs again from where it was held."""
        self._operator("resume", lambda now: self.sequence.resume(now))  # type: ignore[union-attr]

    def land_all(self) -> None:
        """Every vehicle to its landing slot and down; the show is over."""
        self._operator("land all",
                       lambda now: self.sequence.land_all(now))  # type: ignore[union-attr]

    def land_one(self, sysid: int) -> None:
        """Vehicle ``sysid`` back to its landing slot and down."""
        self._operator(f"land {sysid}",
                       lambda now: self.sequence.land_one(sysid, now))  # type: ignore[union-attr]

    def replace(self, sysid: int) -> None:
        """Vehicle ``sysid`` out of the show on a way out, and a spare into its track."""
        self._operator(f"replace {sysid}",
                       lambda now: self.sequence.replace(sysid, now))  # type: ignore[union-attr]

    def land_here(self, sysid: int) -> None:
        """Vehicle ``sysid`` straight down where it is."""
        self._operator(f"land {sysid} here",
                       lambda now: self.sequence.land_here(sysid, now))  # type: ignore[union-attr]

    def kill(self, sysid: int, confirm: bool = False) -> None:
        """Stop ``sysid``'s motors (only with ``confirm``: the drone falls)."""
        self._operator(f"kill {sysid}", lambda now: self.sequence.kill(  # type: ignore[union-attr]
            sysid, now, confirm))

    # -- status -------------------------------------------------------------------------
    def status_line(self) -> str:
        """One line for a plain terminal: phase, show clock, vehicle phases, separation;
        before the show, the pre-flight checks still pending, fleet-wide (and with
        ``--rtk`` the vehicles' fix types and correction age)."""
        line = self._status_text()
        if self.rtk is not None:
            line += "; " + self.rtk.summary(
                {s: v.gps_fix_type for s, v in sorted(self.link.vehicles.items())})
        return line

    def _status_text(self) -> str:
        seq = self.sequence
        if seq is None:
            n = len(self.link.vehicles)
            report = self.preflight_report
            if report is None:
                return f"pre-flight: {n} vehicle(s) heard"
            return "pre-flight: " + report.summary(self.config.excluded)
        now = self.clock.now()
        counts: dict[str, int] = {}
        for v in seq.vehicles.values():
            counts[str(v.phase)] = counts.get(str(v.phase), 0) + 1
        phases = " ".join(f"{k}:{n}" for k, n in sorted(counts.items()))
        mon = self.monitor
        sep = mon.separation.distance_m if mon is not None else math.inf
        err = mon.max_tracking_error() if mon is not None else 0.0
        held = f" HOLD ({', '.join(sorted(seq.holds))})" if seq.paused else ""
        return (f"{seq.phase}{held} t={seq.show_time(now):6.1f}/{self.plan.duration:.0f} s "
                f"[{phases}] min sep {sep:.2f} m, max err {err:.2f} m")
