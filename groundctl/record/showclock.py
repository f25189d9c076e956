"""showclock.csv: the show clock against wall time, one line per executor tick.

The tlog is stamped with Unix wall time and the event log with the
executor's clock (a dry-run's runs K times faster than real time), while the
show clock holds, ramps and resumes as the flight goes.  Nothing in the tlog
says which show time a packet belongs to, so the recording keeps, every
tick: the Unix time, the executor's clock, the show time (NaN before the show
clock started) and the tick's setpoint lateness.  A replay interpolates
between these lines to put every packet and event on the ``show_time``
timeline.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import RecordingError
from groundctl.record.background import BackgroundFile

FloatArray = NDArray[np.float64]

HEADER = "wall_unix_s,now_s,show_time_s,lateness_ms"


class ShowClockLog:
    """Appends one line per tick, written by a thread of its own
    (:class:`~groundctl.record.background.BackgroundFile`): a tick costs a formatted
    string, never a system call, and a stalled disk never reaches the loop."""

    def __init__(self, path: str | Path, *, wall: Callable[[], float] = time.time,
                 flush_every: int = 50) -> None:
        self.path = Path(path)
        self._wall = wall
        self._flush_every = max(int(flush_every), 1)
        self._file: BackgroundFile | None = BackgroundFile(self.path, "the show clock log")
        self._file.write((HEADER + "\n").encode("ascii"))
        self.lines = 0
        self._complete = True

    def tick(self, now: float, show_time: float | None, lateness_s: float | None,
             behind_s: float = 0.0) -> None:
        """One tick: our clock ``now``, the show time (None before the show clock started)
        and how late the tick's setpoints left (None: unknown); ``behind_s`` is how many
        wall seconds ago ``now`` was (the tick's start), so the line's Unix time is that
        of ``now``."""
        if self._file is None:
            return
        st = "nan" if show_time is None else f"{show_time:.4f}"
        late = "nan" if lateness_s is None else f"{lateness_s * 1000.0:.3f}"
        self._file.write(f"{self._wall() - behind_s:.6f},{now:.6f},{st},{late}\n".encode())
        self.lines += 1
        if self.lines % self._flush_every == 0:
            self._file.flush()

    def close(self) -> bool:
        """Write out, flush and close; idempotent.  False if lines were lost on the way to
        the disk."""
        if self._file is not None:
            self._complete = self._file.close()
            self._file = None
        return self._complete


@dataclass(frozen=True)
class ShowClockTable:
    """A recording's show clock, one row per tick, rows in time order."""

    wall_unix_s: FloatArray
    """Unix time of the tick, s."""
    now_s: FloatArray
    """The executor's clock at the tick (the event log's ``t``), s."""
    show_time_s: FloatArray
    """The show clock at the tick, s (NaN before it started)."""
    lateness_ms: FloatArray
    """How late the tick's last setpoint left, ms (NaN: unknown)."""

    @property
    def ticks(self) -> int:
        return len(self.wall_unix_s)

    def timeline(self) -> FloatArray:
        """The ``show_time`` timeline at every tick: the show clock while the show runs,
        counting up to 0 before it starts and on past its end after it, so that takeoff
        and landing do not pile up on one instant."""
        st = self.show_time_s
        out = st.copy()
        started = np.flatnonzero(np.isfinite(st))
        if started.size == 0:  # the show never started: time relative to the last tick
            return self.now_s - self.now_s[-1] if self.ticks else out
        first = started[0]
        out[:first] = self.now_s[:first] - self.now_s[first]
        end = float(np.nanmax(st))
        at_end = np.flatnonzero(np.isfinite(st) & (st >= end - 1e-9))
        if at_end.size and at_end[0] < self.ticks - 1 and end > 0:
            k = at_end[0]
            # Capped at the end (or where land-all stopped it): run on with our clock.
            tail = np.arange(k, self.ticks)
            tail = tail[np.isfinite(st[tail]) & (st[tail] >= end - 1e-9)]
            out[tail] = end + (self.now_s[tail] - self.now_s[k])
        return out

    def show_time_at_wall(self, wall_unix_s: FloatArray) -> FloatArray:
        """The ``show_time`` timeline (:meth:`timeline`) at Unix times."""
        return np.interp(wall_unix_s, self.wall_unix_s, self.timeline())

    def show_time_at_now(self, now_s: FloatArray) -> FloatArray:
        """The ``show_time`` timeline at times of our clock (event ``t``)."""
        return np.interp(now_s, self.now_s, self.timeline())

    def wall_at_now(self, now_s: FloatArray) -> FloatArray:
        """Unix time at times of our clock: linear beyond the ends (the clock's speed)."""
        if self.ticks < 2:
            return np.asarray(now_s, dtype=float) - self.now_s[0] + self.wall_unix_s[0] \
                if self.ticks else np.asarray(now_s, dtype=float)
        speed = (self.now_s[-1] - self.now_s[0]) / max(
            self.wall_unix_s[-1] - self.wall_unix_s[0], 1e-9)
        now = np.asarray(now_s, dtype=float)
        inside = np.interp(now, self.now_s, self.wall_unix_s)
        before = self.wall_unix_s[0] + (now - self.now_s[0]) / speed
        after = self.wall_unix_s[-1] + (now - self.now_s[-1]) / speed
        return np.where(now < self.now_s[0], before, np.where(now > self.now_s[-1], after,
                                                               inside))


def read_show_clock(path: str | Path) -> ShowClockTable:
    """A showclock.csv; a damaged or cut last line (a crash mid-write) is left out."""
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii", errors="replace")
    except OSError as exc:
        raise RecordingError(path, f"cannot read: {exc.strerror or exc}") from exc
    lines = text.splitlines()
    if not lines or lines[0].strip() != HEADER:
        raise RecordingError(path, f"not a show clock log (first line is not {HEADER!r})")
    rows: list[tuple[float, float, float, float]] = []
    for line in lines[1:]:
        parts = line.split(",")
        if len(parts) != 4:
            break
        try:
            row = tuple(float(x) for x in parts)
        except ValueError:
            break
        if not (math.isfinite(row[0]) and math.isfinite(row[1])):
            break
        rows.append((row[0], row[1], row[2], row[3]))
    arr = np.array(rows, dtype=float).reshape(-1, 4)
    # Ticks are in time order; keep only strictly increasing ones (np.interp needs it).
    keep = np.ones(len(arr), dtype=bool)
    if len(arr) > 1:
        keep[1:] = np.diff(np.maximum.accumulate(arr[:, 0])) > 0
        keep &= arr[:, 0] >= np.maximum.accumulate(arr[:, 0])
    arr = arr[keep]
    return ShowClockTable(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])
