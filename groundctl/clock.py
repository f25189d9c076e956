"""Clocks that can be passed in.

Everything that needs the time takes a ``Clock`` (or a plain ``now()``
callable), never ``time.monotonic`` directly, so that

* a dry-run can run K times faster than real time (:class:`ScaledClock`), and
  the simulator and the executor agree on that time even in two processes:
  ``CLOCK_MONOTONIC`` is system-wide on Linux, so two ScaledClocks built with
  the same ``epoch`` and ``speed`` read the same value;
* a dry-run's clock waits for whichever of its loops is late
  (:class:`PacedClock`), so a busy machine slows the rehearsal down instead of
  making the ground station and the simulator late for each other;
* a test can step time by hand (:class:`ManualClock`) and a fault test is
  repeatable.
"""

from __future__ import annotations

import copy
import math
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

    def ago(self, wall_seconds: float) -> float:
        """This clock's seconds since ``wall_seconds`` of real time ago (a datagram's
        age from its kernel time stamp)."""
        ...

    def idle_until(self, t: float) -> None:
        """A loop on this clock has nothing to do before ``t`` (only a
        :class:`PacedClock` waits for it; the others ignore it)."""
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

    def ago(self, wall_seconds: float) -> float:
        return wall_seconds * self.speed

    def idle_until(self, t: float) -> None:
        pass  # runs on whatever anybody does


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

    def ago(self, wall_seconds: float) -> float:
        return 0.0  # real time does not move this clock

    def idle_until(self, t: float) -> None:
        pass


class PacedClock:
    """A dry-run's clock, shared by processes that wait for one another.

    It runs ``speed`` times faster than real time, like :class:`ScaledClock`,
    but never more than ``slack`` seconds past the next due time of its
    slowest *participant*: a loop that must act at clock times (the ground
    station's 10 Hz tick, the simulator's physics tick) says, each time it goes
    to sleep, until when it has nothing to do (:meth:`idle_until`).  On a
    machine too busy to keep ``speed``, the clock waits for the late loop
    instead of running on without it, the way a simulator in lockstep lowers
    its real-time factor: the rehearsal then runs slower, but what every
    participant sees -- tick lateness, telemetry age, timeouts -- is the
    flight's, not the machine's.  Waits are counted per participant
    (:meth:`held_s`) so a report can say who held the clock and for how long.

    A participant that holds the clock for more than ``valve_s`` real seconds
    (stopped in a debugger, frozen by SIGSTOP, killed) is left behind: the clock
    runs on without it until it reports again, so nothing else hangs on it.

    Every instance made by :meth:`participant` shares one block of memory with
    its parent, across processes started by ``multiprocessing`` (pass it as a
    ``Process`` argument); a lock makes each read consistent.  The clock is
    piecewise linear: it rises at ``speed`` from an *anchor* and is flat while
    held; the last :data:`ANCHORS` anchors are kept so that a moment in the
    recent past (a datagram's kernel time stamp) is dated exactly
    (:meth:`at_wall`).
    """

    ANCHORS = 64
    _SPEED, _SLACK, _VALVE, _HEAD, _LAST, _LAST_WALL = range(6)
    _RING = 8

    def __init__(self, speed: float = 1.0, participants: int = 2, *, slack: float = 0.05,
                 valve_s: float = 5.0) -> None:
        if not speed > 0:
            raise ValueError("`speed` must be positive")
        if participants < 1:
            raise ValueError("`participants` must be at least 1")
        if not slack > 0:
            raise ValueError("`slack` must be positive")
        if not valve_s > 0:
            raise ValueError("`valve_s` must be positive")
        from groundctl.processes import helper_context

        ctx = helper_context()
        self._n = participants
        self._due0 = self._RING + 2 * self.ANCHORS
        size = self._due0 + 4 * participants
        self._mem = ctx.RawArray("d", size)
        self._lock = ctx.Lock()
        self._slot: int | None = None
        self.speed = float(speed)
        m = self._mem
        m[self._SPEED], m[self._SLACK], m[self._VALVE] = self.speed, slack, valve_s
        wall = time.monotonic()
        m[self._HEAD] = 0.0
        m[self._RING], m[self._RING + 1] = wall, 0.0
        m[self._LAST], m[self._LAST_WALL] = 0.0, wall
        for p in range(participants):
            m[self._due0 + p] = math.inf  # not taking part until it first says so
            m[self._due0 + participants + p] = wall  # when it last said so
            m[self._due0 + 2 * participants + p] = 0.0  # real seconds it held the clock
            m[self._due0 + 3 * participants + p] = 0.0  # times it was left behind

    def participant(self, slot: int) -> PacedClock:
        """The same clock, as seen by participant ``slot`` (its :meth:`idle_until` speaks
        for that slot)."""
        if not 0 <= slot < self._n:
            raise ValueError(f"`slot` must be in 0..{self._n - 1}, got {slot}")
        view = copy.copy(self)
        view._slot = slot
        return view

    # -- reading ---------------------------------------------------------------------

    def now(self) -> float:
        wall = time.monotonic()
        with self._lock:
            return self._read(wall)

    def _read(self, wall: float) -> float:
        m, n, d0 = self._mem, self._n, self._due0
        head = int(m[self._HEAD])
        at = self._RING + 2 * (head % self.ANCHORS)
        a_wall, a_sim = m[at], m[at + 1]
        free = a_sim + self.speed * (wall - a_wall)
        while True:
            due = min(range(n), key=lambda p: m[d0 + p])
            cap = m[d0 + due] + m[self._SLACK]
            if free <= cap:
                value = free
                break
            # Held by ``due``.  Left behind once it has held the clock too long.
            if wall - m[d0 + n + due] > m[self._VALVE]:
                m[d0 + due] = math.inf
                m[d0 + 3 * n + due] += 1.0
                continue
            value = max(cap, m[self._LAST])
            # Who held it, for how long (real seconds since it met the cap, or since the
            # last read if that was later).
            met = a_wall + max(value - a_sim, 0.0) / self.speed
            m[d0 + 2 * n + due] += max(wall - max(met, m[self._LAST_WALL]), 0.0)
            if value <= a_sim:  # flat since the anchor: the flat stretch goes on
                m[at] = wall
            else:  # it rose, then met the cap: it rises again from here once released
                head += 1
                nxt = self._RING + 2 * (head % self.ANCHORS)
                m[nxt], m[nxt + 1] = wall, value
                m[self._HEAD] = float(head)
            break
        m[self._LAST], m[self._LAST_WALL] = value, wall
        return value

    def wall_interval(self, seconds: float) -> float:
        """Real seconds that ``seconds`` take at full pace (longer while the clock waits:
        a caller sleeping for this rechecks the clock)."""
        return seconds / self.speed

    def at_wall(self, wall: float) -> float:
        """The clock's reading at ``time.monotonic()`` = ``wall`` (not in the future)."""
        with self._lock:
            now = self._read(time.monotonic())
            m = self._mem
            head = int(m[self._HEAD])
            later: float | None = None
            for k in range(head, max(head - self.ANCHORS, -1), -1):
                at = self._RING + 2 * (k % self.ANCHORS)
                a_wall, a_sim = m[at], m[at + 1]
                if a_wall <= wall:
                    value = a_sim + self.speed * (wall - a_wall)
                    return min(value, now if later is None else later)
                later = a_sim
            # Older than every anchor kept: as if it ran at full pace since (a bound).
            return (later if later is not None else now) - self.speed * (a_wall - wall)

    def ago(self, wall_seconds: float) -> float:
        """Clock seconds since ``wall_seconds`` of real time ago."""
        wall = time.monotonic()
        return self.now() - self.at_wall(wall - wall_seconds)

    # -- taking part -------------------------------------------------------------------

    def idle_until(self, t: float) -> None:
        """This participant has done everything due before clock time ``t``: the clock
        may run to ``t + slack`` without it (``math.inf``: it takes no more part)."""
        if self._slot is None:
            raise ValueError("idle_until() on the shared clock itself: use participant()")
        wall = time.monotonic()
        with self._lock:
            self._read(wall)  # a wait for us ends now, not at whoever read the clock last
            d = self._due0 + self._slot
            self._mem[d] = t
            self._mem[self._due0 + self._n + self._slot] = wall

    def held_s(self) -> list[float]:
        """Real seconds each participant has held the clock, by slot."""
        d = self._due0 + 2 * self._n
        with self._lock:
            return [self._mem[d + p] for p in range(self._n)]

    def left_behind(self) -> list[int]:
        """Times each participant was left behind (held the clock over ``valve_s``)."""
        d = self._due0 + 3 * self._n
        with self._lock:
            return [int(self._mem[d + p]) for p in range(self._n)]
