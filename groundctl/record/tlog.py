"""MAVLink .tlog writer, in the format pymavlink and Mission Planner read.

Each record is an 8-byte big-endian uint64 of microseconds since the Unix
epoch followed by the raw bytes of exactly one MAVLink packet (the reader
parses one packet after each timestamp, so a datagram holding several packets
must be written as several records).  Both directions go in one file.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from groundctl.record.background import BackgroundFile

_STAMP = struct.Struct(">Q")
#: A stamp read from ``wall`` serves the packets of the next this many real seconds: a
#: paced dry-run's clock is read under a lock shared with the simulator, and a read per
#: packet (35,000 a second at 1,000 vehicles) was a sixth of the control loop's time.
STAMP_REUSE_S = 0.001


class TlogWriter:
    """Appends timestamped packets to a .tlog, written by a thread of its own
    (:class:`~groundctl.record.background.BackgroundFile`: the control loop never waits
    on the disk); flushed every ``flush_interval`` s and on close."""

    def __init__(
        self,
        path: str | Path,
        *,
        wall: Callable[[], float] = time.time,
        flush_interval: float = 1.0,
    ) -> None:
        if flush_interval < 0:
            raise ValueError(f"`flush_interval` must be non-negative, got {flush_interval}")
        self.path = Path(path)
        # Wall time on purpose: tlog timestamps are absolute Unix times, not show time.
        self._wall = wall
        self._flush_interval = flush_interval
        self._file: BackgroundFile | None = BackgroundFile(self.path, "tlog")
        self._last_flush = wall()
        self._complete = True
        self.packets = 0
        self._stamp = (-float("inf"), 0.0)  # (monotonic when read, Unix time read)

    def write(self, packet: bytes, unix_s: float | None = None) -> None:
        """Record one MAVLink packet, stamped ``unix_s`` (default: now; a received packet
        is stamped when it arrived, from :meth:`stamp` less its wait)."""
        if self._file is None:
            return  # closed: late packets during shutdown are dropped, not an error
        t = self._now() if unix_s is None else unix_s
        self._file.write(_STAMP.pack(max(int(t * 1e6), 0)) + bytes(packet))
        self.packets += 1
        if t - self._last_flush >= self._flush_interval:
            self.flush()

    def stamp(self) -> float:
        """Now, as this tlog stamps it (Unix seconds)."""
        return self._now()

    def _now(self) -> float:
        mono = time.monotonic()
        read_at, t = self._stamp
        if mono - read_at > STAMP_REUSE_S:
            t = self._wall()
            self._stamp = (mono, t)
        return t

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()
            self._last_flush = self._wall()

    def close(self) -> bool:
        """Write out, flush and close; idempotent.  False if packets were lost on the way
        to the disk (it fell too far behind, or failed)."""
        if self._file is not None:
            self._complete = self._file.close()
            self._file = None
        return self._complete

    @property
    def closed(self) -> bool:
        return self._file is None

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
