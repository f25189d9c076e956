"""A tick's setpoints spread over its period: slots of at most ``send_slot_vehicles``
vehicles, each vehicle in the same slot every tick, each slot leaving at its own
instant (its setpoints taken for that instant), so a fleet's setpoints are not one burst
whose last leaves the burst's length late, and each vehicle still gets one setpoint per
period."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from groundctl.clock import HELD_POLL_S, Clock

#: One setpoint to send: system id, time_boot_ms, then position, velocity and
#: acceleration (NED).
Send = tuple[int, int, list[float], list[float], list[float]]


def slot_delays(n: int, per_slot: int, period: float) -> NDArray[np.float64]:
    """Per vehicle (in stream order), how long after the tick its setpoint leaves: the
    fleet cut into ceil(n / per_slot) consecutive slots spread evenly over ``period``."""
    if n == 0:
        return np.zeros(0)
    k = max(1, math.ceil(n / per_slot))
    slots = (np.arange(n) * k) // n
    return (slots * (period / k)).astype(np.float64)


class SendSlots:
    """The sends of one tick still to leave, on the loop's timers.

    ``send`` sends one setpoint; ``done(lateness)`` is told, once a tick's last slot has
    left, how late the latest slot left against its own instant (the tick's lateness);
    ``idle()`` after each slot has left (a paced clock waits for the loop no further
    than its next due instant, which has just moved on).  A tick that starts before the
    previous one's slots have all left sends them first.
    """

    def __init__(self, clock: Clock, send: Callable[[int, int, list[float], list[float],
                                                     list[float]], None],
                 done: Callable[[float], None], idle: Callable[[], None]) -> None:
        self.clock = clock
        self._send = send
        self._done = done
        self._idle = idle
        self._handles: dict[int, asyncio.TimerHandle] = {}
        self._pending: dict[int, tuple[float, float, Sequence[Send]]] = {}
        self._late = 0.0
        self._next = 0

    def start(self, scheduled: float, now: float,
              slots: Sequence[tuple[float, Sequence[Send]]]) -> None:
        """A tick (due at ``scheduled``, run at ``now``): each (delay, sends) leaves
        ``delay`` after ``now``; a zero delay leaves at once."""
        self.flush()
        self._late = 0.0
        loop = asyncio.get_running_loop()
        now_keys = []
        for delay, sends in slots:  # every slot pending before the first leaves
            key = self._next
            self._next += 1
            self._pending[key] = (now + delay, scheduled + delay, sends)
            if delay <= 0.0:
                now_keys.append(key)
            else:
                self._handles[key] = loop.call_later(self.clock.wall_interval(delay),
                                                     self._fire, key)
        for key in now_keys:
            self._fire(key)
        if not slots:
            self._done(self.clock.now() - scheduled)

    def _fire(self, key: int) -> None:
        entry = self._pending.get(key)
        if entry is None:
            return
        due, scheduled, sends = entry
        self._handles.pop(key, None)
        wait = due - self.clock.now()
        if wait > 1e-3:  # a paced clock that waited for a late loop: not there yet
            self._handles[key] = asyncio.get_running_loop().call_later(
                max(self.clock.wall_interval(wait), HELD_POLL_S), self._fire, key)
            return
        del self._pending[key]
        for send in sends:
            self._send(*send)
        self._late = max(self._late, self.clock.now() - scheduled)
        if not self._pending:
            self._done(self._late)
        self._idle()

    def flush(self) -> None:
        """Send every slot still waiting, now."""
        for key in sorted(self._pending):
            handle = self._handles.pop(key, None)
            if handle is not None:
                handle.cancel()
            if key in self._pending:
                _, scheduled, sends = self._pending[key]
                self._pending[key] = (-math.inf, scheduled, sends)
                self._fire(key)

    def cancel(self) -> None:
        """Drop every slot still waiting (the flight is over)."""
        for handle in self._handles.values():
            handle.cancel()
        self._handles.clear()
        self._pending.clear()

    def dues(self) -> list[float]:
        """Clock instants of the slots still waiting."""
        return [due for due, _, _ in self._pending.values()]
