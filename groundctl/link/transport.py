"""The UDP socket: a thin asyncio DatagramProtocol that hands datagrams on.

All MAVLink knowledge lives elsewhere; this only moves bytes and translates
socket errors into :class:`~groundctl.errors.LinkError` at the boundary.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import struct
import sys
import time
from collections.abc import Callable

from groundctl.errors import LinkError

log = logging.getLogger(__name__)

#: Socket buffer asked for, bytes.  A fleet of 200 sends ~4000 datagrams a
#: second; the default (~200 kB, a few hundred datagrams) overflows during a
#: half-second pause of the event loop and the kernel drops the rest.
SOCKET_BUFFER_BYTES = 4 * 1024 * 1024

Address = tuple[str, int]
#: A datagram as read: its bytes, its sender, and when it arrived (``time.monotonic()``:
#: the kernel's stamp, or when it was read where the kernel gives none).
Received = tuple[bytes, Address, float]


#: Datagrams read per readiness callback (and per :meth:`UdpTransport.drain`): enough
#: to empty a backlog at once, bounded so a flood cannot starve the event loop.
MAX_READS = 4096

#: Linux's SO_TIMESTAMPNS (the kernel stamps each datagram as it arrives, CLOCK_REALTIME
#: in a struct timespec); Python's socket module does not name it.
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35 if sys.platform.startswith("linux")
                         else None)
_TIMESPEC = struct.Struct("@qq")
ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size)
#: An arrival stamp further back than this is not believed (the wall clock was stepped):
#: the datagram is taken as arrived when it is read, s.
MAX_AGE_S = 2.0


class UdpTransport:
    """One bound, non-blocking UDP socket read straight from the event loop's selector.

    Not asyncio's DatagramTransport: that reads one datagram per loop iteration, so
    after a stall of the loop a backlog of thousands is handed over interleaved with
    everything else and the control loop decides on stale telemetry.  Here each
    readiness callback empties the socket, and :meth:`drain` lets the control loop
    do so itself before it decides anything.
    """

    def __init__(self, on_datagrams: Callable[[list[Received]], None],
                 on_error: Callable[[Exception], None] | None = None) -> None:
        """``on_datagrams(batch)``: every datagram one :meth:`drain` read, in order, each
        ``(data, address, arrived)``: ``arrived`` is when (``time.monotonic()``) the
        kernel stamped its arrival, or when it was read where the kernel gives no stamp.
        On a busy ground station the wait in the socket is ours, not the link's:
        telemetry is dated, and a TIMESYNC round trip measured, from when the datagram
        arrived.  One call per drain, not per datagram: a dry-run's paced clock is read
        once for the batch (about 10 µs a reading, a third of what the control loop
        spent on each datagram)."""
        self._on_datagrams = on_datagrams
        self._on_error = on_error or (lambda exc: None)
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stamped = False
        self.send_errors = 0

    async def open(self, listen: Address) -> Address:
        """Bind to ``listen``; returns the bound (host, port)."""
        loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            # The kernel caps it at net.core.rmem_max / wmem_max; best effort.
            for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, opt, SOCKET_BUFFER_BYTES)
            if SO_TIMESTAMPNS is not None:
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                    self._stamped = True
            sock.bind(listen)
        except OSError as exc:
            sock.close()
            raise LinkError(f"cannot listen on {listen[0]}:{listen[1]}: {exc}") from exc
        self._sock, self._loop = sock, loop
        loop.add_reader(sock.fileno(), self.drain)
        name = sock.getsockname()
        return (name[0], name[1])

    def drain(self) -> int:
        """Hand on every datagram waiting in the socket (at most MAX_READS), in one
        batch; returns how many were read.  Never raises."""
        sock = self._sock
        count = 0
        batch: list[Received] = []
        while sock is not None and count < MAX_READS:
            try:
                batch.append(read_datagram(sock, self._stamped))
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError as exc:
                # ICMP port-unreachable from a vehicle that went away lands here on Linux;
                # the datagrams queued behind it are still to be read.
                self._on_error(exc)
                count += 1
                continue
            except OSError as exc:
                self._on_error(exc)
                break
            count += 1
        if batch:
            try:
                self._on_datagrams(batch)
            except Exception:  # a bug in a handler must not kill the socket
                log.exception("error handling %d datagrams", len(batch))
        return count

    @property
    def stamped(self) -> bool:
        """The kernel stamps each datagram's arrival (SO_TIMESTAMPNS is on)."""
        return self._stamped

    def pause_reading(self) -> socket.socket:
        """Stop reading the socket here (a link worker reads it instead); returns the
        socket, still open for :meth:`send`."""
        if self._sock is None:
            raise LinkError("link is not open")
        if self._loop is not None and not self._loop.is_closed():
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._sock.fileno())
        return self._sock

    def send(self, data: bytes, addr: Address) -> None:
        """Send ``data`` to ``addr``; never blocks, never raises for a send failure (UDP:
        a full send buffer drops the datagram, as the network would)."""
        if self._sock is None:
            raise LinkError("link is not open")
        try:
            self._sock.sendto(data, addr)
        except (BlockingIOError, InterruptedError) as exc:
            self.send_errors += 1
            self._on_error(exc)
        except OSError as exc:
            self.send_errors += 1
            log.warning("send to %s:%s failed: %s", addr[0], addr[1], exc)
            self._on_error(exc)

    def close(self) -> None:
        if self._sock is not None:
            self.pause_reading()
            self._sock.close()
            self._sock = None


def read_datagram(sock: socket.socket, stamped: bool) -> Received:
    """One datagram, its sender and when it arrived (``time.monotonic()``: the read less
    its age since the kernel stamped it; the read itself unstamped); raises what the
    socket raises (BlockingIOError once it is empty)."""
    if stamped:
        data, ancillary, _, addr = sock.recvmsg(65535, ANCILLARY)
        return data, (addr[0], addr[1]), time.monotonic() - arrival_age(ancillary)
    data, addr = sock.recvfrom(65535)
    return data, (addr[0], addr[1]), time.monotonic()


def arrival_age(ancillary: list[tuple[int, int, bytes]]) -> float:
    """Wall seconds since the kernel stamped the datagram (0 without a believable stamp)."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and \
                len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            age = time.time() - (sec + nsec * 1e-9)
            return age if 0.0 < age <= MAX_AGE_S else 0.0
    return 0.0
