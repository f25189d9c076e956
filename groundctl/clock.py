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

import asyncio
import bisect
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

    def dated(self, wall_seconds: list[float]) -> tuple[float, list[float]]:
        """The clock now, and its reading ``w`` real seconds ago for each ``w`` (when each
        of a batch of datagrams arrived), from one reading of the clock."""
        ...

    def idle_until(self, t: float) -> None:
        """A loop on this clock has nothing to do before ``t`` (only a
        :class:`PacedClock` waits for it; the others ignore it)."""
        ...


#: Real seconds between looks at a clock that has stopped (a paced dry-run clock waiting
#: for another loop): no polling it at a loop's own rate meanwhile.
HELD_POLL_S = 0.002


async def sleep_until(clock: Clock, t: float) -> None:
    """Sleep until ``clock`` reads ``t`` (within 1 ms).  A wall-time sleep is only an
    estimate of a paced clock's time, which runs slower while it waits for a late loop:
    the sleep is repeated until the clock is there, every HELD_POLL_S while it stands."""
    wait = t - clock.now()
    while wait > 1e-3:
        await asyncio.sleep(clock.wall_interval(wait))
        left = t - clock.now()
        if left == wait:  # it has not moved: it waits for someone else
            await asyncio.sleep(HELD_POLL_S)
            left = t - clock.now()
        wait = left


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

    def dated(self, wall_seconds: list[float]) -> tuple[float, list[float]]:
        now = self.now()
        return now, [now - w * self.speed for w in wall_seconds]

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

    def dated(self, wall_seconds: list[float]) -> tuple[float, list[float]]:
        return self._t, [self._t] * len(wall_seconds)

    def idle_until(self, t: float) -> None:
        pass


#: How far a dry-run's paced clock may run past its slowest participant, in *real* time:
#: a few milliseconds, like a tick's own jitter.  Clock seconds are real seconds times the
#: speed, so the same real slack is more clock time at x8 than at x1.
PACE_SLACK_REAL_S = 0.00625
#: ... and never more than this much clock time (what a fast rehearsal allowed before).
PACE_SLACK_MAX_S = 0.05


def pace_slack(speed: float) -> float:
    """The paced clock's ``slack`` (clock seconds) for a dry-run at ``speed``: 6.25 ms of
    real time, at most 50 ms of the clock.  A fixed 50 ms of clock time was 50 ms of real
    time at x1, and the 1,000-drone rehearsal (x0.3 effective) showed it as 76 ms of
    setpoint lateness at the median that no real flight would have."""
    return min(PACE_SLACK_MAX_S, PACE_SLACK_REAL_S * speed)


class _Held:
    """A ``with`` block holding a paced clock's (multiprocessing) lock: ``as`` gives
    whether it was taken within :attr:`PacedClock.LOCK_TIMEOUT_S`; released on the way
    out only if it was.

    Once a wait has timed out (its holder died holding it), the clock's later readings in
    this process only look at the lock (taking it if it is free again) instead of waiting
    again: a loop reads its clock thousands of times a second, and a dry-run whose
    simulator was killed holding the lock waited 2 s at every reading, until pytest's
    120 s timeout (test_flight_simdeath.py, once in a suite run)."""

    __slots__ = ("_clock", "_ok")

    def __init__(self, clock: PacedClock) -> None:
        self._clock, self._ok = clock, False

    def __enter__(self) -> bool:
        c = self._clock
        self._ok = bool(c._lock.acquire(timeout=0.0 if c._orphaned else c.LOCK_TIMEOUT_S))
        c._orphaned = not self._ok
        return self._ok

    def __exit__(self, *exc: object) -> None:
        if self._ok:
            self._clock._lock.release()


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

    A participant that has held the clock for more than ``valve_s`` real
    seconds on end (stopped in a debugger, frozen by SIGSTOP, killed) is left
    behind: the clock runs on without it until it reports again, so nothing
    else hangs on it.  A process killed while it held the lock (a few
    microseconds at a time) cannot hang the others either: after
    :data:`LOCK_TIMEOUT_S` each reader runs on at full pace from what it last saw.

    Every instance made by :meth:`participant` shares one block of memory with
    its parent, across processes started by ``multiprocessing`` (pass it as a
    ``Process`` argument).  The clock is piecewise linear: it rises at
    ``speed`` from an *anchor* and is flat while held; the last :data:`ANCHORS`
    anchors are kept so that a moment in the recent past (a datagram's kernel
    time stamp) is dated on the clock as it ran (:meth:`at_wall`).
    """

    ANCHORS = 512
    LOCK_TIMEOUT_S = 2.0
    # Shared memory: the head of the anchor ring, the last reading and when, the ring
    # (wall, clock) pairs, then per participant its due time, holding since (wall; NaN
    # when not holding), real seconds held and times left behind.
    _HEAD, _LAST, _LAST_WALL = range(3)
    _RING = 3
    _DUE, _SINCE, _HELD, _BEHIND = range(4)

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
        self.speed = float(speed)
        self.slack = float(slack)
        self.valve_s = float(valve_s)
        self._n = participants
        self._p0 = self._RING + 2 * self.ANCHORS
        self._mem = ctx.RawArray("d", self._p0 + 4 * participants)
        self._lock = ctx.Lock()
        self._orphaned = False  # a wait for the lock timed out: its holder died holding it
        self._slot: int | None = None
        wall = time.monotonic()
        self._seen = (0.0, wall)  # this process's last reading, and when
        m = self._mem
        m[self._RING], m[self._RING + 1] = wall, 0.0  # anchor 0: zero, now
        m[self._LAST], m[self._LAST_WALL] = 0.0, wall
        for p in range(participants):
            m[self._at(p, self._DUE)] = math.inf  # not taking part until it says so
            m[self._at(p, self._SINCE)] = math.nan

    def _at(self, participant: int, field: int) -> int:
        return self._p0 + field * self._n + participant

    def _anchor(self, k: int) -> int:
        return self._RING + 2 * (k % self.ANCHORS)

    def participant(self, slot: int) -> PacedClock:
        """The same clock, as seen by participant ``slot`` (its :meth:`idle_until` speaks
        for that slot)."""
        if not 0 <= slot < self._n:
            raise ValueError(f"`slot` must be in 0..{self._n - 1}, got {slot}")
        view = copy.copy(self)
        view._slot = slot
        return view

    def _locked(self) -> _Held:
        """The lock, held for a ``with`` block; ``as`` gives False if its holder died
        holding it (after LOCK_TIMEOUT_S).  A small class, not a ``contextlib``
        generator: the loops read the clock thousands of times a second, and the
        generator was most of a reading's cost."""
        return _Held(self)

    # -- reading ---------------------------------------------------------------------

    def now(self) -> float:
        with self._locked() as ok:
            return self._read() if ok else self._unlocked()

    def _unlocked(self) -> float:
        """The lock's holder died holding it: at full pace from this process's last
        reading (never back), without waiting for anybody."""
        value, wall = self._seen
        return value + self.speed * max(time.monotonic() - wall, 0.0)

    def _read(self) -> float:
        """The clock now; with the lock held.  The time is read under the lock, so a
        reader that waited for it never works with an older time than the last writer."""
        m = self._mem
        wall = max(time.monotonic(), m[self._LAST_WALL])
        last = m[self._LAST]
        at = self._anchor(int(m[self._HEAD]))
        value = m[at + 1] + self.speed * (wall - m[at])
        first = self._at(0, self._DUE)
        while True:
            dues = m[first:first + self._n]
            soonest = min(dues)
            cap = soonest + self.slack
            if value <= cap:
                break
            due = dues.index(soonest)
            # Held by ``due``: since the clock met its cap, or the last reading if later.
            since = self._at(due, self._SINCE)
            if math.isnan(m[since]):
                met = m[at] + max(cap - m[at + 1], 0.0) / self.speed
                m[since] = max(met, m[self._LAST_WALL])
            held = wall - m[since]
            value = max(cap, last)
            at = self._stand(value, wall)
            if held <= self.valve_s:
                break
            # Held too long on end: left behind, and the clock runs on from where it
            # waited (the others did not hold it meanwhile).
            m[self._at(due, self._HELD)] += held
            m[self._at(due, self._BEHIND)] += 1.0
            m[self._at(due, self._DUE)] = math.inf
            m[since] = math.nan
        value = max(value, last)
        m[self._LAST], m[self._LAST_WALL] = value, wall
        self._seen = (value, wall)
        return value

    def _stand(self, value: float, wall: float) -> int:
        """The clock stands at ``value`` at ``wall`` and rises from there once released:
        the flat stretch of the last anchor goes on, or a new anchor; its index."""
        m = self._mem
        head = int(m[self._HEAD])
        at = self._anchor(head)
        if value > m[at + 1]:  # it rose, then met the cap
            m[self._HEAD] = float(head + 1)
            at = self._anchor(head + 1)
            m[at + 1] = value
        m[at] = wall
        return at

    def wall_interval(self, seconds: float) -> float:
        """Real seconds that ``seconds`` take at full pace (longer while the clock waits:
        a caller sleeping for this rechecks the clock)."""
        return seconds / self.speed

    def _dated(self, wall: float, now: float) -> float:
        """The clock at ``time.monotonic()`` = ``wall`` (not in the future), given that it
        reads ``now``; with the lock held."""
        m = self._mem
        head = int(m[self._HEAD])
        later = now
        oldest = head
        for k in range(head, max(head - self.ANCHORS, -1), -1):
            at = self._anchor(k)
            a_wall, a_sim = m[at], m[at + 1]
            if a_wall <= wall:
                return min(a_sim + self.speed * (wall - a_wall), later)
            later, oldest = a_sim, k
        # Older than every anchor kept: the oldest one's reading, at most (it may have
        # waited before it; it never ran faster than its pace).
        at = self._anchor(oldest)
        return min(m[at + 1], later) - self.speed * max(m[at] - wall, 0.0)

    def at_wall(self, wall: float) -> float:
        """The clock's reading at ``time.monotonic()`` = ``wall`` (not in the future)."""
        with self._locked() as ok:
            if not ok:
                return self._unlocked() - self.speed * max(time.monotonic() - wall, 0.0)
            return self._dated(wall, self._read())

    def dated(self, wall_seconds: list[float]) -> tuple[float, list[float]]:
        """The clock now, and its reading ``w`` real seconds ago for each ``w`` of
        ``wall_seconds`` (when each of a drain's datagrams arrived), with one look at
        the lock."""
        if len(wall_seconds) == 1:
            with self._locked() as ok:
                if not ok:  # its holder died holding it: as _ago_many does then
                    now = self._unlocked()
                    return now, [now - self.speed * wall_seconds[0]]
                now = self._read()
                return now, [self._dated(time.monotonic() - wall_seconds[0], now)]
        if not wall_seconds:
            return self.now(), []
        now, agos = self._ago_many(wall_seconds)
        return now, [now - a for a in agos]

    def _ago_many(self, wall_seconds: list[float]) -> tuple[float, list[float]]:
        """The clock now, and its seconds since each of ``wall_seconds`` ago (not empty), with
        one short look at the lock: the anchors the batch reaches back to are copied
        under it, the datagrams dated outside it (a lock held while thousands were dated
        against hundreds of anchors starved the simulator's processes of it)."""
        with self._locked() as ok:
            if not ok:
                return self._unlocked(), [self.speed * w for w in wall_seconds]
            now = self._read()
            wall = time.monotonic()
            oldest = wall - max(wall_seconds)
            m = self._mem
            head = int(m[self._HEAD])
            anchors: list[tuple[float, float]] = []  # (wall, clock), newest first
            for k in range(head, max(head - self.ANCHORS, -1), -1):
                at = self._anchor(k)
                anchors.append((m[at], m[at + 1]))
                if m[at] <= oldest:
                    break
        # As _dated: the newest anchor at or before each moment, capped by the next one.
        keys = [-a[0] for a in anchors]  # increasing
        out = []
        for w in wall_seconds:
            t = wall - w
            j = bisect.bisect_left(keys, -t)
            if j < len(anchors):
                later = anchors[j - 1][1] if j > 0 else now
                a_wall, a_sim = anchors[j]
                out.append(now - min(a_sim + self.speed * (t - a_wall), later))
            else:
                a_wall, a_sim = anchors[-1]
                later = anchors[-2][1] if len(anchors) > 1 else now
                out.append(now - (min(a_sim, later) - self.speed * max(a_wall - t, 0.0)))
        return now, out

    # -- taking part -------------------------------------------------------------------

    def idle_until(self, t: float) -> None:
        """This participant has done everything due before clock time ``t``: the clock
        may run to ``t + slack`` without it (``math.inf``: it takes no more part)."""
        if self._slot is None:
            raise ValueError("idle_until() on the shared clock itself: use participant()")
        with self._locked() as ok:
            if not ok:
                return
            self._read()  # a wait for us ends now, not at whoever read the clock last
            m = self._mem
            since = self._at(self._slot, self._SINCE)
            if not math.isnan(m[since]):
                m[self._at(self._slot, self._HELD)] += max(m[self._LAST_WALL] - m[since], 0.0)
                m[since] = math.nan
            m[self._at(self._slot, self._DUE)] = t

    def held_s(self) -> list[float]:
        """Real seconds each participant has held the clock, by slot (up to its last
        report).  Read without the lock if its holder died holding it."""
        with self._locked():
            return [self._mem[self._at(p, self._HELD)] for p in range(self._n)]

    def left_behind(self) -> list[int]:
        """Times each participant was left behind (held the clock over ``valve_s``).  Read
        without the lock if its holder died holding it."""
        with self._locked():
            return [int(self._mem[self._at(p, self._BEHIND)]) for p in range(self._n)]
