"""A recording file the control loop never waits on: :class:`BackgroundFile`.

The tlog, the event log and the show clock log are written during the flight by the
loop that streams the setpoints.  A disk can stall for seconds (a full or failing SD
card, a USB stick, a network share, another process syncing): a ``write`` or ``flush``
on the loop would stall every vehicle's setpoints with it.  Here the loop only appends
bytes to a buffer in memory; a thread of the file's own writes them out and flushes
them (its system calls release the interpreter, so a blocked disk blocks only that
thread).  The buffer is bounded (``max_buffer`` bytes): past it, new writes are
dropped and counted (:attr:`BackgroundFile.dropped`), because losing recording is
better than growing without end or waiting; :meth:`BackgroundFile.close` writes out
what is left and says whether the disk kept up.

The file is opened in the constructor, before any flight, so a recording directory
that cannot be written is still refused at once with one line.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from pathlib import Path
from typing import BinaryIO

from groundctl.errors import GroundctlError

#: The most bytes waiting for the disk before new writes are dropped (a 1,000-drone
#: tlog is ~3 MB/s: a minute and a half of a stalled disk).
MAX_BUFFER = 256 << 20
#: How often the writer thread flushes what it wrote (s): the file on disk is never more
#: than this behind the flight, for a reader following it or a crash.
FLUSH_INTERVAL_S = 0.5
# (0: after every batch written, for a low-volume file such as the event log.)
#: A busy file's thread is woken once this many bytes wait (else by its flush interval):
#: not on every write, since a wake-up per packet (tens of thousands a second at 1,000
#: vehicles) cost the control loop more than the packets themselves.
WAKE_BYTES = 64 << 10


class BackgroundFile:
    """A binary file written by its own thread; :meth:`write` never blocks."""

    def __init__(self, path: str | Path, what: str, *, max_buffer: int = MAX_BUFFER,
                 flush_interval: float = FLUSH_INTERVAL_S) -> None:
        self.path = Path(path)
        try:
            self._file: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - the thread closes it
        except OSError as exc:
            raise GroundctlError(f"{self.path}: cannot write {what}: "
                                 f"{exc.strerror or exc}") from exc
        self.what = what
        self.max_buffer = max_buffer
        self.flush_interval = flush_interval
        self._chunks: deque[bytes] = deque()
        self._waiting = 0
        self._cond = threading.Condition()
        self._closing = False
        self._flush_asked = False
        self.dropped = 0
        """Writes dropped because ``max_buffer`` bytes were already waiting."""
        self.late = 0
        """Writes after :meth:`close` (ignored)."""
        self.written = 0
        """Bytes on their way to the disk or written (not dropped)."""
        self.error: OSError | None = None
        """The first write error; nothing more is written after it."""
        self._thread = threading.Thread(target=self._run, name=f"writer-{self.path.name}",
                                        daemon=True)
        self._thread.start()

    # -- the loop's side: never waits on the disk --------------------------------------
    def write(self, data: bytes) -> bool:
        """Queue ``data``; False if it was dropped (the disk is behind by ``max_buffer``
        bytes, or the file is closed)."""
        with self._cond:
            if self._closing:
                self.late += 1  # after the end (a packet during shutdown): not a loss
                return False
            if self._waiting + len(data) > self.max_buffer:
                self.dropped += 1
                return False
            was = self._waiting
            self._chunks.append(data)
            self._waiting += len(data)
            self.written += len(data)
            if not self.flush_interval or was < WAKE_BYTES <= self._waiting:
                self._cond.notify()
        return True

    def flush(self) -> None:
        """Ask the thread to flush soon (it does by itself every ``flush_interval`` s)."""
        with self._cond:
            self._flush_asked = True
            self._cond.notify()

    @property
    def waiting(self) -> int:
        """Bytes queued and not yet handed to the disk."""
        with self._cond:
            return self._waiting

    @property
    def closed(self) -> bool:
        return self._closing

    def close(self, timeout: float | None = 30.0) -> bool:
        """Write out what is queued, flush and close; True if everything reached the
        file (False: it is still stuck after ``timeout`` s, or writes were dropped or
        failed).  Idempotent.  Called off the control loop (at the end of a flight)."""
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join(timeout)
        return not self._thread.is_alive() and not self.dropped and self.error is None

    # -- the thread's side ---------------------------------------------------------------
    def _run(self) -> None:
        last_flush = time.monotonic()
        while True:
            with self._cond:
                while not self._chunks and not self._closing and not self._flush_asked:
                    self._cond.wait(self.flush_interval or None)
                    if self.flush_interval and \
                            time.monotonic() - last_flush >= self.flush_interval:
                        break
                batch = list(self._chunks)
                self._chunks.clear()
                closing, flush_asked = self._closing, self._flush_asked
                self._flush_asked = False
            if batch and self.error is None:
                try:
                    self._file.write(b"".join(batch))
                except OSError as exc:
                    self.error = exc
            with self._cond:
                self._waiting -= sum(len(b) for b in batch)
            now = time.monotonic()
            if self.error is None and (closing or flush_asked
                                       or now - last_flush >= self.flush_interval):
                try:
                    self._file.flush()
                except OSError as exc:
                    self.error = exc
                last_flush = now
            if closing:
                with self._cond:
                    if self._chunks:
                        continue  # written while we wrote: out before closing
                try:
                    self._file.close()
                except OSError as exc:
                    if self.error is None:
                        self.error = exc
                return
