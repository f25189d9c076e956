"""The UDP socket: a thin asyncio DatagramProtocol that hands datagrams on.

All MAVLink knowledge lives elsewhere; this only moves bytes and translates
socket errors into :class:`~groundctl.errors.LinkError` at the boundary.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from collections.abc import Callable

from groundctl.errors import LinkError

log = logging.getLogger(__name__)

#: Socket buffer asked for, bytes.  A fleet of 200 sends ~4000 datagrams a
#: second; the default (~200 kB, a few hundred datagrams) overflows during a
#: half-second pause of the event loop and the kernel drops the rest.
SOCKET_BUFFER_BYTES = 4 * 1024 * 1024

Address = tuple[str, int]


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: Callable[[bytes, Address], None],
                 on_error: Callable[[Exception], None]) -> None:
        self._on_datagram = on_datagram
        self._on_error = on_error

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        try:
            self._on_datagram(data, (addr[0], addr[1]))
        except Exception:  # a bug in a handler must not kill the socket
            log.exception("error handling datagram from %s:%s", addr[0], addr[1])

    def error_received(self, exc: Exception) -> None:
        # ICMP port-unreachable from a vehicle that went away lands here on Linux.
        self._on_error(exc)


class UdpTransport:
    """One bound UDP socket."""

    def __init__(self, on_datagram: Callable[[bytes, Address], None],
                 on_error: Callable[[Exception], None] | None = None) -> None:
        self._on_datagram = on_datagram
        self._on_error = on_error or (lambda exc: None)
        self._transport: asyncio.DatagramTransport | None = None
        self.send_errors = 0

    async def open(self, listen: Address) -> Address:
        """Bind to ``listen``; returns the bound (host, port)."""
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Protocol(self._on_datagram, self._on_error), local_addr=listen
            )
        except OSError as exc:
            raise LinkError(f"cannot listen on {listen[0]}:{listen[1]}: {exc}") from exc
        self._transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:
            # The kernel caps it at net.core.rmem_max / wmem_max; best effort.
            for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, opt, SOCKET_BUFFER_BYTES)
        sockname = transport.get_extra_info("sockname")
        return (sockname[0], sockname[1])

    def send(self, data: bytes, addr: Address) -> None:
        """Queue ``data`` for ``addr``; never blocks, never raises for a send failure."""
        if self._transport is None or self._transport.is_closing():
            raise LinkError("link is not open")
        try:
            self._transport.sendto(data, addr)
        except OSError as exc:
            self.send_errors += 1
            log.warning("send to %s:%s failed: %s", addr[0], addr[1], exc)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None
