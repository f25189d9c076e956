"""The terminal as an output that can never make the control loop wait.

Everything groundctl writes to a terminal during a flight -- the console's
frames and the plain mode's lines -- goes through a :class:`TerminalWriter`.
The caller (the control loop's thread) only appends text to a bounded buffer
and returns; a thread of the writer's own does the writing.

- A terminal that stops reading (paused with Ctrl-S, a stuck SSH connection, a
  suspended terminal emulator) blocks that thread only.  The buffer fills,
  and what does not fit is dropped and counted, never waited for: the picture
  falls behind, the flight does not.  Once the terminal has taken everything
  again, ``on_caught_up(dropped)`` says how much was skipped (the console
  repaints its whole screen, the plain mode says how many lines it left out).
- A terminal that is gone (a write fails: EIO after a hangup, EPIPE; or the
  descriptor polls HUP or ERR while idle) is *lost*: :attr:`TerminalWriter.lost`
  says why, ``on_lost(why)`` is called once, and nothing more is written.

Both callbacks are called on the event loop given (``loop.call_soon_threadsafe``),
never on the writer's thread and never waited for.

Why the console still renders in the control loop's process (the alternative
is a console process fed with view snapshots): Textual builds a frame on the
loop's thread in a few milliseconds (5 ms at 200 vehicles, at most 5 times a
second, right after a tick's setpoints have left: ``bench_console.py``
measured setpoint lateness p99 within 2 ms of a run without the console).
What stopped the flight was never that work but a blocking write: Textual's
writer thread holds at most 30 frames and ``Queue.put`` waits for room, and
after a hangup that thread dies on its first failed write, so the 31st frame
waited for ever and the loop with it (issue 27's stack dump).  With this writer
in its place nothing on the loop's thread waits on the terminal at all, which
is the property asked for; reading the terminal was already on a thread of its
own (Textual's input thread), and a terminal that goes away is noticed here and
ends the console (:class:`groundctl.console.session.ConsoleSession`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import select
import threading
from collections.abc import Callable
from typing import IO

#: Characters buffered for the terminal before more are dropped (a few full frames of
#: a large console; about a minute of plain status lines).
LIMIT_CHARS = 1 << 20
#: How often an idle writer looks whether its terminal is still there, s.
WATCH_S = 0.25
#: Longest wait for the writer's thread when it is stopped, s.  A thread stuck in a
#: write to a terminal that never reads again is left behind (it is a daemon).
STOP_WAIT_S = 1.0


class TerminalWriter(threading.Thread):
    """A file-like for one terminal whose :meth:`write` never blocks (module docstring).

    It also stands in for Textual's ``WriterThread`` (``write``, ``flush``,
    ``isatty``, ``fileno``, ``stop``).
    """

    def __init__(self, file: IO[str], *, loop: asyncio.AbstractEventLoop | None = None,
                 on_lost: Callable[[str], None] | None = None,
                 on_caught_up: Callable[[int], None] | None = None,
                 limit_chars: int = LIMIT_CHARS, name: str = "terminal-writer") -> None:
        super().__init__(daemon=True, name=name)
        if limit_chars <= 0:
            raise ValueError("`limit_chars` must be positive")
        self._file = file
        self._loop = loop
        self._on_lost = on_lost
        self._on_caught_up = on_caught_up
        self._limit = limit_chars
        self._cond = threading.Condition()
        self._chunks: list[str] = []
        self._queued = 0
        self._stopping = False
        self._dropped_since = 0
        self._busy = False
        self.dropped = 0
        """Writes dropped because the terminal was not taking output."""
        self.lost: str | None = None
        """Why the terminal is gone (None while it is there)."""

    # -- the caller's side (never blocks) ----------------------------------------------
    def write(self, text: str) -> None:
        if not text or self.lost is not None:
            return
        with self._cond:
            if self._stopping:
                return
            if self._queued + len(text) > self._limit:
                self.dropped += 1
                self._dropped_since += 1
                return
            self._chunks.append(text)
            self._queued += len(text)
            self._cond.notify()

    def flush(self) -> None:
        """Nothing to do: the writer's thread flushes after every batch."""

    def isatty(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._file.fileno()

    @property
    def queued(self) -> int:
        """Characters waiting for the terminal."""
        return self._queued

    def wait_written(self, timeout: float = STOP_WAIT_S) -> bool:
        """Wait (at most ``timeout``) until the terminal took what is queued; whether it
        did.  For the end of a command, never for the control loop."""
        with self._cond:
            return self._cond.wait_for(
                lambda: (not self._chunks and not self._busy) or self.lost is not None
                or not self.is_alive(), timeout)

    def stop(self, timeout: float = STOP_WAIT_S) -> None:
        """Write what is queued (for at most ``timeout``), then end the thread."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout)

    # -- the writer's thread -----------------------------------------------------------
    def run(self) -> None:
        while True:
            with self._cond:
                if not self._chunks and not self._stopping:
                    self._cond.wait(WATCH_S)
                chunks, self._chunks = self._chunks, []
                self._queued = 0
                self._busy = bool(chunks)
                stopping = self._stopping
            if chunks:
                text = "".join(chunks)
                try:
                    self._write(text)
                except (OSError, ValueError) as exc:
                    self._gone(_why(exc))
                    return
                dropped = 0
                with self._cond:
                    self._busy = False
                    if not self._chunks and self._dropped_since:
                        dropped, self._dropped_since = self._dropped_since, 0
                    self._cond.notify_all()  # for wait_written
                if dropped:
                    self._call(self._on_caught_up, dropped)
            elif stopping:
                return
            else:
                hung = _hung_up(self._file)
                if hung is not None:
                    self._gone(hung)
                    return

    def _write(self, text: str) -> None:
        """Write ``text`` whole.  To a descriptor, with ``os.write`` and waiting for room
        as a blocking write does, also when someone sharing the terminal made it
        non-blocking (EAGAIN is a terminal not reading, not a terminal gone); to a
        stream without one (a test's capture), through the stream."""
        fd = _descriptor(self._file)
        if fd is None:
            self._file.write(text)
            self._file.flush()
            return
        encoding = getattr(self._file, "encoding", None) or "utf-8"
        view = memoryview(text.encode(encoding, "replace"))
        while view:
            try:
                view = view[os.write(fd, view):]
            except (BlockingIOError, InterruptedError):
                if self._stopping:
                    return
                select.select([], [fd], [], WATCH_S)

    def _gone(self, why: str) -> None:
        with self._cond:
            self.lost = why
            self._chunks = []
            self._queued = 0
            self._busy = False
            self._cond.notify_all()
        self._call(self._on_lost, why)

    def _call(self, callback: Callable[..., None] | None, arg: object) -> None:
        if callback is None:
            return
        if self._loop is None:
            with contextlib.suppress(Exception):
                callback(arg)
            return
        with contextlib.suppress(RuntimeError):  # the loop is closed: nobody to tell
            self._loop.call_soon_threadsafe(callback, arg)


def _descriptor(file: IO[str]) -> int | None:
    """``file``'s descriptor, or None for a stream that has none."""
    try:
        fd = file.fileno()
    except Exception:  # closed, or a stand-in stream (a test's capture) without one
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


def _why(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return f"writing to it failed ({exc.strerror})"
    return f"writing to it failed ({exc!r})"


def _hung_up(file: IO[str]) -> str | None:
    """Why ``file``'s terminal is gone (hung up, an error on it), or None (also for a
    stream with no descriptor to watch: its writes say when it is gone)."""
    fd = _descriptor(file)
    if fd is None:
        return None
    poller = select.poll()
    try:
        poller.register(fd, select.POLLOUT)
        events = poller.poll(0)
    except (OSError, ValueError) as exc:
        return _why(exc)
    for _, mask in events:
        if mask & select.POLLNVAL:
            return "its descriptor is closed"
        if mask & (select.POLLHUP | select.POLLERR):
            return "it hung up"
    return None


class LineWriter:
    """Lines for a terminal (the plain mode's status lines and notices), never blocking.

    Lines that do not fit while the terminal is not reading are dropped; once it
    reads again one line says how many.  Once the terminal is lost, lines go
    nowhere (every one of them is also in the recording's ``events.jsonl``).
    """

    def __init__(self, file: IO[str], limit_chars: int = LIMIT_CHARS) -> None:
        self._writer = TerminalWriter(file, on_caught_up=self._skipped, limit_chars=limit_chars,
                                      name="terminal-lines")
        self._writer.start()

    def line(self, text: str) -> None:
        self._writer.write(text + "\n")

    def _skipped(self, count: int) -> None:
        self._writer.write(f"({count} line{'s' if count != 1 else ''} not shown: the "
                           "terminal was not reading)\n")

    def wait_written(self, timeout: float = STOP_WAIT_S) -> bool:
        """Wait (at most ``timeout``) until the terminal took every line; whether it did."""
        return self._writer.wait_written(timeout)

    def close(self) -> None:
        """End the writer's thread once it has written what is queued (not waited for)."""
        self._writer.stop(timeout=0.0)


class LineHandler(logging.Handler):
    """Log records as lines on standard error through :func:`stderr_lines`: a log line
    (a link conflict, a warning) never makes the control loop wait on the terminal."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            stderr_lines().line(self.format(record))
        except Exception:
            self.handleError(record)


_stderr_lines: tuple[object, LineWriter] | None = None
_stderr_lock = threading.Lock()


def stderr_lines() -> LineWriter:
    """A :class:`LineWriter` on the process's standard error as it is now (one per
    stream: a test that captures ``sys.stderr`` gets its own)."""
    global _stderr_lines
    import sys
    stream = sys.stderr if sys.stderr is not None else sys.__stderr__
    with _stderr_lock:
        if _stderr_lines is None or _stderr_lines[0] is not stream:
            if _stderr_lines is not None:
                _stderr_lines[1].close()  # the stream it wrote to was replaced
            if stream is None:
                stream = open(os.devnull, "w")  # noqa: SIM115 - lives with the process
            _stderr_lines = (stream, LineWriter(stream))
        return _stderr_lines[1]
