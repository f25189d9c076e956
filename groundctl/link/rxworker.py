"""A network's receive path in a process of its own: socket reads, MAVLink framing,
checksums and signatures, off the control loop's interpreter.

The control loop's process keeps the network's socket (it sends from it, so the
vehicles keep answering to the one address they know) and hands a duplicate to a
:class:`ReceiveWorker`.  The worker reads every datagram, stamps when it arrived
(the kernel's time stamp), parses it with a :class:`~groundctl.link.codec.DatagramParser`
per remote address (signing checked there, with the network's key) and passes on, in
batches, what each datagram held: its sender, its arrival, its messages as plain
tuples (:func:`pack_message`), and its rejects.  The control loop rebuilds the
messages (:func:`unpack_message`, about a microsecond each, against six to fifteen
for parsing the bytes) and decides on them exactly as it does on its own reads; the
worker decides nothing.

A worker that dies is seen at once (its process sentinel is readable in the control
loop's selector): the network counts as silent, so the show holds, a new worker is
started on the same socket, and the datagrams that waited in the socket meanwhile
are read by it (the socket never closed: nothing between is lost but time).

The wire between the two is a ``multiprocessing`` pipe carrying one pickled list per
batch (:func:`encode_batch` / :func:`decode_batch`): a batch is sent as soon as the
socket is empty, or once :data:`BATCH_WAIT_S` has passed since its first datagram
while more keep coming, or at :data:`MAX_BATCH` datagrams.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.codec import DatagramParser, new_codec
from groundctl.link.signing import SigningConfig, new_guard
from groundctl.link.transport import ANCILLARY, arrival_age

log = logging.getLogger(__name__)

Address = tuple[str, int]

#: Datagrams per batch at most.
MAX_BATCH = 512
#: A batch waits for more datagrams no longer than this after its first, s.
BATCH_WAIT_S = 0.001
#: How often an idle worker looks whether the ground station is still there, s.
PARENT_CHECK_S = 0.25

#: ``--link-workers auto`` moves the receive path into workers for fleets this large:
#: below, a worker's batching and rebuilding cost more than the parsing they save the
#: control loop (measured: ``benchmarks/bench_flight.py load``).
WORKERS_FROM = 100

LINK_WORKER_MODES = ("auto", "on", "off")


def use_workers(mode: str, vehicles: int) -> bool:
    """Whether ``--link-workers MODE`` means receive workers for a fleet of ``vehicles``."""
    if mode not in LINK_WORKER_MODES:
        raise ValueError(f"--link-workers must be one of {', '.join(LINK_WORKER_MODES)}, "
                         f"got {mode!r}")
    return mode == "on" or (mode == "auto" and vehicles >= WORKERS_FROM)


_HEADER = ("msgId", "incompat_flags", "compat_flags", "mlen", "seq", "srcSystem",
           "srcComponent")

PackedMessage = tuple[int, tuple[int, ...], dict[str, Any]]


@dataclass(frozen=True)
class Datagram:
    """What one datagram held, as the worker passes it on."""

    address: Address
    """Who sent it."""
    arrived: float
    """When it arrived, ``time.monotonic()`` seconds (the kernel's stamp where it
    gives one)."""
    messages: tuple[PackedMessage, ...]
    """Its well-formed (and correctly signed) messages, packed (:func:`pack_message`)."""
    bad: tuple[str, ...] = ()
    """One reason per rejected piece."""
    refused_signatures: tuple[int, ...] = ()
    """The system id each packet refused by signing claimed."""
    unknown: int = 0
    """Well-formed packets of messages the dialect does not know."""


def pack_message(msg: mavlink.MAVLink_message) -> PackedMessage:
    """A decoded message as plain data: its id, its header, its attributes."""
    fields = dict(vars(msg))
    header = fields.pop("_header")
    fields["_msgbuf"] = bytes(fields["_msgbuf"])
    return (msg.get_msgId(), tuple(getattr(header, k) for k in _HEADER), fields)


def unpack_message(packed: PackedMessage) -> mavlink.MAVLink_message:
    """The message :func:`pack_message` packed, rebuilt without parsing its bytes again
    (they were checked by the worker)."""
    msg_id, header, fields = packed
    cls = mavlink.mavlink_map[msg_id]
    msg: mavlink.MAVLink_message = cls.__new__(cls)
    vars(msg).update(fields)
    head = mavlink.MAVLink_header.__new__(mavlink.MAVLink_header)
    for name, value in zip(_HEADER, header, strict=True):
        setattr(head, name, value)
    msg._header = head
    return msg


def encode_batch(datagrams: list[Datagram]) -> bytes:
    """A batch as bytes for the pipe."""
    return pickle.dumps([(d.address, d.arrived, d.messages, d.bad, d.refused_signatures,
                          d.unknown) for d in datagrams], protocol=pickle.HIGHEST_PROTOCOL)


def decode_batch(data: bytes) -> list[Datagram]:
    """The batch :func:`encode_batch` encoded."""
    return [Datagram((a[0], a[1]), arrived, messages, bad, refused, unknown)
            for a, arrived, messages, bad, refused, unknown in pickle.loads(data)]


@dataclass(frozen=True)
class WorkerSetup:
    """What a receive worker needs besides its socket and its pipe."""

    network: int
    """The network's index (0 for the first)."""
    system_id: int
    """The ground station's own MAVLink system id."""
    component_id: int
    """The ground station's component id."""
    signing: SigningConfig | None
    """The network's signing key and rules (None: unsigned)."""
    stamped: bool
    """The socket carries the kernel's arrival stamps (SO_TIMESTAMPNS is on)."""
    parent_pid: int
    """The ground station's process: the worker leaves once it is gone."""


class Receiver:
    """The worker's own loop, apart from its process (tests drive it directly): reads
    what waits in the socket and returns it as :class:`Datagram` records."""

    def __init__(self, sock: socket.socket, setup: WorkerSetup) -> None:
        self.sock = sock
        self.setup = setup
        self._guard = None if setup.signing is None else new_guard(setup.signing)
        self._parsers: dict[Address, DatagramParser] = {}
        self.errors = 0

    def _parser(self, addr: Address) -> DatagramParser:
        parser = self._parsers.get(addr)
        if parser is None:
            parser = DatagramParser(new_codec(self.setup.system_id, self.setup.component_id,
                                              self.setup.signing, guard=self._guard))
            self._parsers[addr] = parser
        return parser

    def read(self, limit: int = MAX_BATCH) -> list[Datagram]:
        """Every datagram waiting (at most ``limit``), parsed; never blocks."""
        out: list[Datagram] = []
        sock = self.sock
        while len(out) < limit:
            try:
                if self.setup.stamped:
                    data, ancillary, _, addr = sock.recvmsg(65535, ANCILLARY)
                    age = arrival_age(ancillary)
                else:
                    data, addr = sock.recvfrom(65535)
                    age = 0.0
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:
                self.errors += 1  # ICMP from a vehicle that went away: read on
                continue
            except OSError:
                self.errors += 1
                break
            address = (addr[0], addr[1])
            result = self._parser(address).feed(data)
            out.append(Datagram(address, time.monotonic() - age,
                                tuple(pack_message(m) for m in result.messages),
                                tuple(result.bad), tuple(result.refused_signatures),
                                result.unknown))
        return out


def serve(sock: socket.socket, conn: Any, setup: WorkerSetup) -> None:
    """The worker process's body: read, batch, pass on, until the pipe or the ground
    station goes away."""
    from groundctl.processes import settle_helper

    settle_helper()
    sock.setblocking(False)
    receiver = Receiver(sock, setup)
    poller = select.poll()
    poller.register(sock.fileno(), select.POLLIN)
    try:
        while True:
            if not poller.poll(PARENT_CHECK_S * 1000.0):
                if os.getppid() != setup.parent_pid:
                    return
                continue
            batch = receiver.read()
            first = time.monotonic()
            while len(batch) < MAX_BATCH:
                left = BATCH_WAIT_S - (time.monotonic() - first)
                if left <= 0.0 or not poller.poll(left * 1000.0):
                    break
                batch.extend(receiver.read(MAX_BATCH - len(batch)))
            if batch:
                conn.send_bytes(encode_batch(batch))
    except (BrokenPipeError, EOFError, OSError):
        return  # the ground station closed its end
    finally:
        with contextlib.suppress(OSError):
            conn.close()


class ReceiveWorker:
    """The ground station's handle on one network's receive worker: starts it on a
    duplicate of the network's socket, reads its batches, sees it die, starts another."""

    def __init__(self, sock: socket.socket, setup: WorkerSetup,
                 on_batch: Callable[[list[Datagram]], None],
                 on_death: Callable[[int | None], None]) -> None:
        import asyncio

        self._sock = sock
        self.setup = setup
        self._on_batch = on_batch
        self._on_death = on_death
        self._loop = asyncio.get_running_loop()
        self._proc: Any = None
        self._conn: Any = None
        self.starts = 0
        """How many worker processes were started (1 + restarts)."""
        self.batches = 0
        self.closed = False

    @property
    def pid(self) -> int | None:
        """The running worker's process id."""
        return None if self._proc is None else self._proc.pid

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    def start(self) -> None:
        """Start a worker process (the previous one, if any, is gone)."""
        from groundctl.processes import helper_context

        ctx = helper_context()
        parent, child = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=serve, args=(self._sock, child, self.setup),
                           name=f"groundctl-link-rx{self.setup.network + 1}", daemon=True)
        proc.start()
        child.close()
        self._proc, self._conn = proc, parent
        self.starts += 1
        self._loop.add_reader(parent.fileno(), self.drain)
        self._loop.add_reader(proc.sentinel, self._died)

    def drain(self) -> int:
        """Hand on every batch waiting in the pipe; returns how many datagrams."""
        conn = self._conn
        count = 0
        while conn is not None:
            try:
                if not conn.poll(0):
                    break
                data = conn.recv_bytes()
            except (EOFError, OSError):
                self._close_pipe()  # it died or is dying: its sentinel says so next
                break
            batch = decode_batch(data)
            self.batches += 1
            count += len(batch)
            self._on_batch(batch)
            conn = self._conn
        return count

    def _close_pipe(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._conn.fileno())
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def _unwatch(self) -> None:
        self._close_pipe()
        if self._proc is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._proc.sentinel)

    def _died(self) -> None:
        self.drain()  # what it passed on before it died
        proc = self._proc
        self._unwatch()
        proc.join(0.5)
        self._proc = None
        if not self.closed:
            self._on_death(proc.exitcode)

    def kill(self) -> None:
        """Kill the worker process (tests: a worker that dies)."""
        if self._proc is not None:
            self._proc.kill()

    def close(self) -> None:
        """Read what is left, then stop the worker."""
        self.closed = True
        self.drain()
        proc = self._proc
        self._unwatch()
        self._proc = None
        if proc is not None:
            proc.kill()
            proc.join(1.0)
