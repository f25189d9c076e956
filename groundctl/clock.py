"""Clocks that can be passed in.

Everything that needs the time takes a ``Clock`` (or a plain ``now()``
callable), never ``time.monotonic`` directly, so that

* a dry-run can run K times faster than real time (:class:`ScaledClock`), and
  the simulator and the executor agree on that time even in two processes:
  ``CLOCK_MONOTONIC`` is system-wide on Linux, so two ScaledClocks built with
  the same ``epoch`` and ``speed`` read the same value;
* a test can step time by hand (:class:`ManualClock`) and a fault test is
  repeatable.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Seconds on some monotonic timeline, and a way to wait on it."""

    def now(self) -> float:
        """Current time in seconds."""
        ...

    def wall_interval(self, seconds: float) -> float:
        """Real (wall-clock) seconds that ``seconds`` of this clock's time take."""
        ...


class ScaledClock:
    """Monotonic time running ``speed`` times faster than real time.

    ``now()`` is ``(time.monotonic() - epoch) * speed``: zero at ``epoch``.
    """

    def __init__(self, speed: float = 1.0, epoch: float | None = None) -> None:
        if not speed > 0:
            raise ValueError("`speed` must be positive")
        self.speed = float(speed)
        self.epoch = time.monotonic() if epoch is None else float(epoch)

    def now(self) -> float:
        return (time.monotonic() - self.epoch) * self.speed

    def wall_interval(self, seconds: float) -> float:
        return seconds / self.speed


class ManualClock:
    """A clock that moves only when told to: for deterministic tests."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("`seconds` must be non-negative")
        self._t += seconds

    def wall_interval(self, seconds: float) -> float:
        return 0.0
