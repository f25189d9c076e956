"""A tick's setpoints spread over its period: slots of at most ``send_slot_vehicles``
vehicles, each vehicle in the same slot every tick, each slot leaving at its own
instant (its setpoints taken for that instant), so a fleet's setpoints are not one burst
whose last leaves the burst's length late, and each vehicle still gets one setpoint per
period."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from groundctl.clock import Clock
from groundctl.flight.runner.timers import ClockTimers

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
        self._timers = ClockTimers(clock)
        self._late = 0.0

    def start(self, scheduled: float, now: float,
              slots: Sequence[tuple[float, Sequence[Send]]]) -> None:
        """A tick (due at ``scheduled``, run at ``now``): each (delay, sends) leaves
        ``delay`` after ``now``; a zero delay leaves at once."""
        self.flush()
        self._late = 0.0
        now_keys = []
        for delay, sends in slots:  # every slot pending before the first leaves
            key = self._timers.add(now + delay, delay,
                                   functools.partial(self._leave, scheduled + delay, sends))
            if delay <= 0.0:
                now_keys.append(key)
        for key in now_keys:
            self._timers.fire(key, force=True)
        if not slots:
            self._done(self.clock.now() - scheduled)

    def _leave(self, scheduled: float, sends: Sequence[Send]) -> None:
        for send in sends:
            self._send(*send)
        self._late = max(self._late, self.clock.now() - scheduled)
        if not self._timers:
            self._done(self._late)
        self._idle()

    def flush(self) -> None:
        """Send every slot still waiting, now."""
        for key in self._timers.pending():
            self._timers.fire(key, force=True)

    def cancel(self) -> None:
        """Drop every slot still waiting (the flight is over)."""
        self._timers.cancel()

    def dues(self) -> list[float]:
        """Clock instants of the slots still waiting."""
        return self._timers.dues()
