"""Calls at instants of the flight's clock, on the running event loop's timers: what the
tick's stages that act between ticks (a tick's setpoint slots, LED changes sent ahead)
share.  A timer is armed for the clock interval in real time; a paced dry-run clock that
waited for a late participant runs slower than real time, so a timer can fire before its
instant: the call is then armed again until the clock is there."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from groundctl.clock import HELD_POLL_S, Clock

#: A call whose instant is at most this far ahead of the clock is made now, s.
DUE_WITHIN_S = 1e-3


class ClockTimers:
    """Calls pending at clock instants; each made once, at or just after its instant."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self._calls: dict[int, tuple[float, Callable[[], None]]] = {}
        self._handles: dict[int, asyncio.TimerHandle] = {}
        self._next = 0

    def add(self, due: float, wait: float, call: Callable[[], None]) -> int:
        """``call`` at clock time ``due``, ``wait`` clock seconds from now; armed on a
        timer when ``wait`` is positive, else left for the caller to :meth:`fire`.
        Returns its key."""
        key = self._next
        self._next += 1
        self._calls[key] = (due, call)
        if wait > 0.0:
            self._handles[key] = asyncio.get_running_loop().call_later(
                self.clock.wall_interval(wait), self.fire, key)
        return key

    def fire(self, key: int, *, force: bool = False) -> None:
        """Make call ``key`` if its instant has come (or ``force``), else arm it again;
        nothing if it was made or cancelled already."""
        entry = self._calls.get(key)
        if entry is None:
            return
        handle = self._handles.pop(key, None)
        if handle is not None:
            handle.cancel()
        due, call = entry
        wait = due - self.clock.now()
        if not force and wait > DUE_WITHIN_S:
            self._handles[key] = asyncio.get_running_loop().call_later(
                max(self.clock.wall_interval(wait), HELD_POLL_S), self.fire, key)
            return
        del self._calls[key]
        call()

    def pending(self) -> list[int]:
        """The pending calls' keys, in the order they were added."""
        return sorted(self._calls)

    def dues(self) -> list[float]:
        """Clock instants of the pending calls."""
        return [due for due, _ in self._calls.values()]

    def __len__(self) -> int:
        return len(self._calls)

    def cancel(self) -> None:
        """Drop every pending call."""
        for handle in self._handles.values():
            handle.cancel()
        self._handles.clear()
        self._calls.clear()
