"""A network's socket work in a process of its own: reads, MAVLink framing,
checksums and signatures, and the send system calls, off the control loop's
interpreter.

The control loop's process binds the network's socket (an address it cannot bind is
one line before the flight) and hands a duplicate to a :class:`LinkWorker`.  The
worker reads every datagram, stamps when it arrived (the kernel's time stamp), parses
it with a :class:`~groundctl.link.codec.DatagramParser` per remote address (signing
checked there, with the network's key) and passes on, in batches, what each datagram
held: its sender, its arrival, its messages as plain tuples (:func:`pack_message`),
and its rejects.  The control loop rebuilds the messages (:func:`unpack_message`,
about a microsecond each, against six to fifteen for parsing the bytes) and decides on
them exactly as on its own reads.  The other way, the control loop encodes each
message (its sequence numbers and signatures are its own) and queues the bytes; once
per pass of its event loop the queue goes to the worker in one write, and the worker
sends each datagram from the socket the vehicles know.  The worker decides nothing.

Nothing of the worker can block the control loop: the pipe towards the worker is
written without blocking (what the pipe does not take waits in memory, up to
:data:`MAX_BACKLOG_BYTES`; past that the oldest waiting sends are dropped and counted,
as a full socket buffer drops datagrams).  A worker that dies is seen at once (its
process sentinel is readable in the control loop's selector): the network counts as
silent, so the show holds; its sends go straight out of the socket from the control
loop meanwhile (never a silent stop of a network's setpoints), a new worker is started
on the same socket, and the datagrams that waited in the socket are read by it (the
socket never closed: nothing between is lost but time).

The wire: worker to control loop, a ``multiprocessing`` pipe carrying one pickled
batch per message (:func:`encode_batch` / :func:`decode_batch`), sent as soon as the
socket is empty, or :data:`BATCH_WAIT_S` after its first datagram while more keep
coming, or at :data:`MAX_BATCH` datagrams; control loop to worker, a pipe of frames
(a 4-byte length, then a pickled list of (bytes, address)).

A control loop that falls behind (the pipe towards it full) is not fed a queue: what
arrives meanwhile waits in a :class:`Conflator`, where a newer state message of a
vehicle replaces the older one (kept as its header and CRC, so that every packet's
number is still judged), and goes as one batch once the pipe is taken.  The loop's
work then stays bounded by the fleet, and what it decides on is the newest state,
never seconds-old positions (at 1,000 vehicles on two cores, the queue grew to a
minute and every vehicle read as silent).
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import select
import socket
import struct
import sys
import time
import zlib
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.codec import DatagramParser, new_codec
from groundctl.link.signing import SigningConfig, new_guard
from groundctl.link.transport import read_datagram

log = logging.getLogger(__name__)

Address = tuple[str, int]

#: Datagrams per batch at most.
MAX_BATCH = 512
#: A batch waits for more datagrams no longer than this after its first, s: at most
#: 250 batches a second per network for the control loop to date (each a look at a
#: dry-run's shared clock: at 1,000 vehicles, thousands a second starved the
#: simulator's processes of its lock).
BATCH_WAIT_S = 0.004
#: How often an idle worker looks whether the ground station is still there, s.
PARENT_CHECK_S = 0.25
#: Sends waiting for a worker that does not take them, bytes at most (a second of a
#: 254-vehicle network's setpoints and LED colours is about 0.4 MB).
MAX_BACKLOG_BYTES = 4 * 1024 * 1024
#: Reads of the pipe from a worker per call of :meth:`LinkWorker.drain` at most (each at
#: most a pipe's worth, 64 KB): a worker that writes as fast as the control loop reads
#: must not keep it in one call while its ticks wait; the rest is read on the next pass.
MAX_READS_PER_DRAIN = 4
_FRAME = struct.Struct("<I")

#: ``--link-workers auto`` moves the receive path into workers for fleets this large:
#: below, a worker's batching and rebuilding cost more than the parsing they save the
#: control loop (measured: ``benchmarks/bench_flight.py load``).
WORKERS_FROM = 100

LINK_WORKER_MODES = ("auto", "on", "off")


def use_workers(mode: str, vehicles: int) -> bool:
    """Whether ``--link-workers MODE`` means link workers for a fleet of ``vehicles``."""
    if mode not in LINK_WORKER_MODES:
        raise ValueError(f"--link-workers must be one of {', '.join(LINK_WORKER_MODES)}, "
                         f"got {mode!r}")
    return mode == "on" or (mode == "auto" and vehicles >= WORKERS_FROM)


_HEADER = ("msgId", "incompat_flags", "compat_flags", "mlen", "seq", "srcSystem",
           "srcComponent")

#: A message as the worker passes it on: (message id, header, attributes), or for a
#: message superseded while the control loop was behind (:class:`Conflator`) the CRC-32
#: of its bytes in place of its attributes.
PackedMessage = tuple[int, tuple[int, ...], dict[str, Any] | int]
_SEQ, _SRC_SYSTEM, _SRC_COMPONENT = (_HEADER.index(k) for k in ("seq", "srcSystem",
                                                                 "srcComponent"))

#: Messages that say only what a vehicle's state is now (a position, a battery, a
#: wind): of two waiting for a control loop that is behind, from the same sender and
#: component, only the newer is worth acting on.  Every answer, text, command and
#: HEARTBEAT (a mode or arming change is an event, and needs its second) goes on whole.
CONFLATED: frozenset[int] = frozenset({
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_VFR_HUD,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT, mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS,
    mavlink.MAVLINK_MSG_ID_WIND, mavlink.MAVLINK_MSG_ID_WIND_COV,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, mavlink.MAVLINK_MSG_ID_VIBRATION,
})
#: Messages a worker keeps for a control loop that does not take them, at most (the
#: conflated ones stand for one each); past that the oldest datagrams go, counted.
MAX_CONFLATOR_MESSAGES = 400_000


class Datagram(NamedTuple):
    """What one datagram held, as the worker passes it on.  A named tuple, not a frozen
    dataclass: the control loop unpickles one per datagram, thousands a second, and a
    frozen dataclass's ``__init__`` was a fifth of that."""

    address: Address
    """Who sent it."""
    arrived: float
    """When it arrived, ``time.monotonic()`` seconds (the kernel's stamp where it
    gives one)."""
    messages: Sequence[PackedMessage]
    """Its well-formed (and correctly signed) messages, packed (:func:`pack_message`),
    those superseded while the control loop was behind as their CRC only."""
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
    if isinstance(fields, int):
        raise ValueError("a superseded message has only its header")
    cls = mavlink.mavlink_map[msg_id]
    msg: mavlink.MAVLink_message = cls.__new__(cls)
    vars(msg).update(fields)
    msg._header = mavlink.MAVLink_header(*header)  # (_HEADER is its arguments' order)
    return msg


@dataclass(frozen=True, slots=True)
class Superseded:
    """What the control loop knows of a message the :class:`Conflator` replaced by a
    newer one: its header and the CRC-32 of its bytes."""

    msg_id: int
    header: tuple[int, ...]
    crc: int

    @property
    def system(self) -> int:
        return self.header[_SRC_SYSTEM]

    @property
    def component(self) -> int:
        return self.header[_SRC_COMPONENT]

    @property
    def seq(self) -> int:
        return self.header[_SEQ]

    @property
    def kind(self) -> str:
        """Its type's name, as ``get_type()`` says it."""
        return str(mavlink.mavlink_map[self.msg_id].msgname)


def unpack(packed: PackedMessage) -> mavlink.MAVLink_message | Superseded:
    """The message ``packed`` stands for, or what is known of it if it was superseded."""
    msg_id, header, fields = packed
    if isinstance(fields, int):
        return Superseded(msg_id, header, fields)
    return unpack_message(packed)


class Conflator:
    """Datagrams waiting while the control loop has not taken the last batch (the pipe
    towards it is full: it is behind).  A state message (:data:`CONFLATED`) replaces
    the one of the same sender, system, component and type still waiting, which is
    kept in its place as its header and CRC only: the control loop counts it heard and
    takes its sequence number (loss, reordering and a second sender's numbers are
    judged on every packet, as without conflation) without acting on what it said.
    So a loop that falls behind catches up on the newest state instead of working
    through seconds of stale positions, and its work per batch stays bounded by the
    fleet, not by how far behind it is."""

    def __init__(self, limit: int = MAX_CONFLATOR_MESSAGES) -> None:
        self.limit = limit
        self.datagrams: list[Datagram] = []
        self._latest: dict[tuple[Address, int, int, int], tuple[int, int]] = {}
        self._messages = 0
        self.superseded = 0
        """Messages replaced by newer ones so far."""
        self.dropped = 0
        """Datagrams dropped past :attr:`limit`."""

    def __len__(self) -> int:
        return len(self.datagrams)

    @property
    def oldest(self) -> float | None:
        """When the oldest datagram waiting arrived (``time.monotonic()``)."""
        return self.datagrams[0].arrived if self.datagrams else None

    def add(self, batch: list[Datagram]) -> None:
        for d in batch:
            i = len(self.datagrams)
            messages = list(d.messages)
            for j, (msg_id, header, fields) in enumerate(messages):
                if msg_id not in CONFLATED or isinstance(fields, int):
                    continue
                key = (d.address, header[_SRC_SYSTEM], header[_SRC_COMPONENT], msg_id)
                old = self._latest.get(key)
                if old is not None:
                    older = self.datagrams[old[0]].messages
                    o_id, o_header, o_fields = older[old[1]]
                    assert isinstance(o_fields, dict) and isinstance(older, list)
                    older[old[1]] = (o_id, o_header, zlib.crc32(o_fields["_msgbuf"]))
                    self.superseded += 1
                self._latest[key] = (i, j)
            self.datagrams.append(d._replace(messages=messages))
            self._messages += len(messages)
        if self._messages > self.limit:
            self._shed()

    def _shed(self) -> None:
        """Drop the oldest half (a control loop stopped for many seconds)."""
        keep = len(self.datagrams) // 2
        self.dropped += len(self.datagrams) - keep
        rest = self.take()[-keep:] if keep else []
        self.add(rest)

    def take(self) -> list[Datagram]:
        out = self.datagrams
        self.datagrams = []
        self._latest = {}
        self._messages = 0
        return out


def encode_batch(datagrams: list[Datagram], errors: int = 0) -> bytes:
    """A batch as bytes for the pipe, with the socket errors the worker met since the
    last one."""
    return pickle.dumps((errors, datagrams), protocol=pickle.HIGHEST_PROTOCOL)


def decode_batch(data: bytes) -> tuple[int, list[Datagram]]:
    """The (socket errors, datagrams) :func:`encode_batch` encoded."""
    errors, datagrams = pickle.loads(data)
    return errors, datagrams


def encode_frame(payload: bytes) -> bytes:
    """``payload`` framed for a pipe: its length (4 bytes), then itself."""
    return _FRAME.pack(len(payload)) + payload


def encode_sends(sends: list[tuple[bytes, Address]]) -> bytes:
    """One frame of sends for the worker."""
    return encode_frame(pickle.dumps(sends, protocol=pickle.HIGHEST_PROTOCOL))


class FrameReader:
    """One end of a pipe of frames: bytes in as the pipe gives them, whole payloads out."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[bytes]:
        self._buf += data
        out = []
        start = 0
        while len(self._buf) - start >= _FRAME.size:
            (n,) = _FRAME.unpack_from(self._buf, start)
            if len(self._buf) - start < _FRAME.size + n:
                break
            out.append(bytes(self._buf[start + _FRAME.size:start + _FRAME.size + n]))
            start += _FRAME.size + n
        del self._buf[:start]
        return out


class FrameWriter:
    """The other end: frames queued and written without ever blocking (the pipe takes
    what it can; the rest waits here, up to ``limit`` bytes, past which the oldest frames
    not begun are dropped and their ``count``s returned)."""

    def __init__(self, fd: int, limit: int) -> None:
        self.fd = fd
        self.limit = limit
        self._frames: deque[tuple[bytes, list[Any]]] = deque()
        self._bytes = 0
        self._written = 0

    @property
    def waiting(self) -> int:
        """Bytes not written yet."""
        return self._bytes - self._written

    def put(self, frame: bytes, items: list[Any]) -> int:
        """Queue ``frame`` (the encoding of ``items``) and write what the pipe takes;
        returns how many items were dropped to stay within the limit."""
        self._frames.append((frame, items))
        self._bytes += len(frame)
        dropped = 0
        while self._bytes > self.limit and len(self._frames) > 1:
            k = 1 if self._written else 0  # never the frame half written
            old, lost = self._frames[k]
            del self._frames[k]
            self._bytes -= len(old)
            dropped += len(lost)
        self.write()
        return dropped

    def write(self) -> None:
        """Write what the pipe takes now; raises OSError once the reader is gone."""
        while self._frames:
            frame, _ = self._frames[0]
            try:
                n = os.write(self.fd, memoryview(frame)[self._written:])
            except (BlockingIOError, InterruptedError):
                return
            self._written += n
            if self._written < len(frame):
                return
            self._frames.popleft()
            self._bytes -= len(frame)
            self._written = 0

    def take(self) -> list[Any]:
        """Every frame not fully written, and forget them (the reader is gone)."""
        items = [item for _, its in self._frames for item in its]
        self._frames.clear()
        self._bytes = self._written = 0
        return items


@dataclass(frozen=True)
class WorkerSetup:
    """What a link worker needs besides its socket and its pipes."""

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
    clock: Any = None
    """A dry-run's :class:`~groundctl.clock.PacedClock`, this worker's participant view
    (None: a real flight, nothing to pace): see :class:`Pacer`."""


#: A worker reading datagrams older than this (real s) is behind its socket.
HOLD_AFTER_S = 0.02
#: While it holds a paced clock, it says how far it got no more often than this (real
#: s of arrivals): each say is a look at the clock's lock, shared with the simulator.
PACER_STEP_S = 0.005


class Pacer:
    """A link worker's part in a paced dry-run (:class:`~groundctl.clock.PacedClock`):
    telemetry that arrived and has not reached the control loop holds the rehearsal's
    clock where it arrived, as a late simulator or ground-station tick does.  Without
    it a machine too busy for the fleet (1,000 vehicles on two cores) let the simulator
    run on while the workers fell behind their sockets, and the kernel dropped
    thousands of datagrams a second: the loss bursts read as second senders, and no
    vehicle was believed.  With it the rehearsal slows instead, which is what pacing
    promises: what the ground station sees is the flight's, not the machine's."""

    def __init__(self, clock: Any) -> None:
        self.clock = clock
        self.holding = False
        self._said = -float("inf")

    def done_up_to(self, arrived: float | None) -> None:
        """Everything that arrived before ``arrived`` (``time.monotonic()``) reached the
        control loop and the worker is behind after it; None: it is caught up."""
        if arrived is None:
            if self.holding:
                self.clock.idle_until(float("inf"))
                self.holding = False
            return
        if self.holding and arrived - self._said < PACER_STEP_S:
            return
        self.clock.idle_until(self.clock.at_wall(arrived))
        self.holding = True
        self._said = arrived


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
                data, address, arrived = read_datagram(sock, self.setup.stamped)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:
                self.errors += 1  # ICMP from a vehicle that went away: read on
                continue
            except OSError:
                self.errors += 1
                break
            result = self._parser(address).feed(data)
            out.append(Datagram(address, arrived,
                                tuple(pack_message(m) for m in result.messages),
                                tuple(result.bad), tuple(result.refused_signatures),
                                result.unknown))
        return out

    def send(self, sends: list[tuple[bytes, Address]]) -> None:
        """Send each datagram; never blocks (a full socket buffer drops it, as the
        network would)."""
        for data, addr in sends:
            try:
                self.sock.sendto(data, addr)
            except OSError:
                self.errors += 1


def _alive(pid: int) -> bool:
    """Whether process ``pid`` is still there (the worker's parent is the fork server,
    not the ground station: ``os.getppid`` cannot tell)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def serve(sock: socket.socket, conn: Any, sends: Any, setup: WorkerSetup) -> None:
    """The worker process's body: read, batch, pass on, until the pipe or the ground
    station goes away."""
    from groundctl.processes import settle_helper

    settle_helper()
    sock.setblocking(False)
    receiver = Receiver(sock, setup)
    frames = FrameReader()
    out_fd = sends.fileno()
    in_fd = conn.fileno()
    os.set_blocking(in_fd, False)
    # One frame at a time towards the ground station (a new one only once the last is
    # wholly in the pipe): what arrives behind it waits in the Conflator, bounded there.
    towards = FrameWriter(in_fd, sys.maxsize)
    poller = select.poll()
    poller.register(sock.fileno(), select.POLLIN)
    poller.register(out_fd, select.POLLIN)
    watching_in = False
    reported = 0
    conflator = Conflator()
    pacer = None if setup.clock is None else Pacer(setup.clock)
    frame_since: float | None = None  # arrival of the first datagram of the frame begun

    def pace(batch: list[Datagram]) -> None:
        """Say how far the telemetry got (a paced dry-run only)."""
        nonlocal frame_since
        if pacer is None:
            return
        if not towards.waiting:
            frame_since = None
        pending = [t for t in (frame_since, conflator.oldest) if t is not None]
        if pending:
            pacer.done_up_to(min(pending))  # not handed on yet
        elif batch and time.monotonic() - batch[-1].arrived > HOLD_AFTER_S:
            pacer.done_up_to(batch[-1].arrived)  # handed on, but the socket holds more
        else:
            pacer.done_up_to(None)

    def pass_on(batch: list[Datagram]) -> int:
        """Frame what waited and ``batch`` for the ground station; returns the errors
        reported so far.  Never waits for it: what its pipe does not take waits here."""
        receiver.errors += conflator.dropped
        conflator.dropped = 0
        nonlocal frame_since
        batch = conflator.take() + batch
        towards.put(encode_frame(encode_batch(batch, receiver.errors - reported)), batch)
        if towards.waiting and batch:
            frame_since = batch[0].arrived
        return receiver.errors

    def take_sends() -> bool:
        """Send what the ground station queued; False once it closed the pipe."""
        try:
            data = os.read(out_fd, 1 << 20)
        except (BlockingIOError, InterruptedError):
            return True
        if not data:
            return False
        for payload in frames.feed(data):
            receiver.send(pickle.loads(payload))
        return True

    try:
        while True:
            # The pipe towards the ground station watched only while frames wait for it.
            if towards.waiting and not watching_in:
                poller.register(in_fd, select.POLLOUT)
                watching_in = True
            elif not towards.waiting and watching_in:
                poller.unregister(in_fd)
                watching_in = False
            ready = dict(poller.poll(PARENT_CHECK_S * 1000.0))
            if not ready:
                if not _alive(setup.parent_pid):
                    return  # (its end of the sends pipe closing says so too)
                pace([])
                continue
            if out_fd in ready and not take_sends():
                return
            if in_fd in ready:
                towards.write()
                if not towards.waiting and (len(conflator) or conflator.dropped):
                    reported = pass_on([])  # taken: what waited goes now, as one batch
                pace([])
            if sock.fileno() not in ready:
                continue
            batch = receiver.read()
            first = time.monotonic()
            while len(batch) < MAX_BATCH:
                left = BATCH_WAIT_S - (time.monotonic() - first)
                if left <= 0.0:
                    break
                more = dict(poller.poll(left * 1000.0))
                if not more:
                    break
                if out_fd in more and not take_sends():
                    return
                if sock.fileno() in more:
                    batch.extend(receiver.read(MAX_BATCH - len(batch)))
            if towards.waiting:
                # Behind: the batch waits with the others, the newest state of each
                # vehicle replacing the older (never a queue of stale positions).
                conflator.add(batch)
            elif batch or receiver.errors != reported:
                reported = pass_on(batch)
            pace(batch)
    except (BrokenPipeError, EOFError, OSError):
        return  # the ground station closed its end
    finally:
        with contextlib.suppress(OSError):
            conn.close()


class LinkWorker:
    """The ground station's handle on one network's worker: starts it on a duplicate of
    the network's socket, reads its batches, queues its sends, sees it die, starts
    another."""

    def __init__(self, sock: socket.socket, setup: WorkerSetup,
                 on_batch: Callable[[list[Datagram]], None],
                 on_death: Callable[[int | None], None],
                 on_errors: Callable[[int], None] = lambda n: None,
                 direct: Callable[[bytes, Address], None] | None = None) -> None:
        """``direct(data, address)`` sends from the socket itself while no worker runs
        (the transport's own send; default: a plain sendto, errors to ``on_errors``)."""
        import asyncio

        self._sock = sock
        self._direct = direct or self._sendto
        self.setup = setup
        self._on_batch = on_batch
        self._on_death = on_death
        self._on_errors = on_errors
        self._loop = asyncio.get_running_loop()
        self._proc: Any = None
        self._conn: Any = None  # the worker's batches (read without blocking)
        self._batches = FrameReader()
        self._sends: Any = None  # our end of the sends pipe (written without blocking)
        self._writer: FrameWriter | None = None
        self._outbox: list[tuple[bytes, Address]] = []
        self._flush_due = False
        self._writing = False
        self.starts = 0
        """How many worker processes were started (1 + restarts)."""
        self.batches = 0
        """Batches read from the worker."""
        self.dropped = 0
        """Sends dropped because the worker did not take them (MAX_BACKLOG_BYTES)."""
        self.direct = 0
        """Sends that went straight out of the socket (no worker running)."""
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
        child_sends, parent_sends = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=serve, args=(self._sock, child, child_sends, self.setup),
                           name=f"groundctl-link{self.setup.network + 1}", daemon=True)
        proc.start()
        child.close()
        child_sends.close()
        os.set_blocking(parent_sends.fileno(), False)
        os.set_blocking(parent.fileno(), False)
        self._proc, self._conn, self._sends = proc, parent, parent_sends
        self._batches = FrameReader()
        self._writer = FrameWriter(parent_sends.fileno(), MAX_BACKLOG_BYTES)
        self.starts += 1
        self._loop.add_reader(parent.fileno(), self.drain)
        self._loop.add_reader(proc.sentinel, self._died)

    # -- receiving -----------------------------------------------------------------------

    def drain(self) -> int:
        """Hand on the batches waiting in the pipe, :data:`MAX_READS_PER_DRAIN` reads at
        most (the rest on the next pass); returns how many datagrams.  Never waits: a
        batch the pipe holds only part of is completed on the next call."""
        count = 0
        for _ in range(MAX_READS_PER_DRAIN):
            if self._conn is None:
                break
            try:
                data = os.read(self._conn.fileno(), 1 << 20)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                data = b""
            if not data:
                self._close_pipe()  # it died or is dying: its sentinel says so next
                break
            datagrams: list[Datagram] = []
            for payload in self._batches.feed(data):
                errors, batch = decode_batch(payload)
                self.batches += 1
                datagrams += batch
                if errors:
                    self._on_errors(errors)
            if datagrams:  # every batch of this read handed on (and dated) at once
                count += len(datagrams)
                self._on_batch(datagrams)
        return count

    # -- sending -------------------------------------------------------------------------

    def send(self, data: bytes, addr: Address) -> None:
        """Queue one datagram; it leaves with the others queued in this pass of the event
        loop.  Straight out of the socket while no worker runs."""
        if self._sends is None:
            self._send_now(data, addr)
            return
        self._outbox.append((data, addr))
        if not self._flush_due:
            self._flush_due = True
            self._loop.call_soon(self.flush)

    def _sendto(self, data: bytes, addr: Address) -> None:
        try:
            self._sock.sendto(data, addr)
        except OSError:
            self._on_errors(1)

    def _send_now(self, data: bytes, addr: Address) -> None:
        self.direct += 1
        self._direct(data, addr)

    def flush(self) -> None:
        """Hand the queued sends to the worker (what the pipe does not take waits)."""
        self._flush_due = False
        if not self._outbox:
            return
        sends, self._outbox = self._outbox, []
        writer = self._writer
        if writer is None:
            for data, addr in sends:
                self._send_now(data, addr)
            return
        try:
            self.dropped += writer.put(encode_sends(sends), sends)
        except OSError:
            return  # the worker is gone: its sentinel says so, and _died sends these
        self._watch_writer()

    def _write(self) -> None:
        if self._writer is not None:
            with contextlib.suppress(OSError):  # gone: its sentinel says so
                self._writer.write()
        self._watch_writer()

    def _watch_writer(self) -> None:
        writer = self._writer
        if writer is None:
            return
        if writer.waiting and not self._writing:
            self._loop.add_writer(writer.fd, self._write)
            self._writing = True
        elif not writer.waiting and self._writing:
            self._loop.remove_writer(writer.fd)
            self._writing = False

    # -- its life ------------------------------------------------------------------------

    def _close_pipe(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._conn.fileno())
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def _unwatch(self) -> None:
        self._close_pipe()
        if self._sends is not None:
            if self._writing and self._writer is not None:
                with contextlib.suppress(Exception):
                    self._loop.remove_writer(self._writer.fd)
                self._writing = False
            with contextlib.suppress(OSError):
                self._sends.close()
            self._sends = None
        if self._proc is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._proc.sentinel)

    def _orphans(self) -> None:
        """Sends the worker may not have taken go straight out (those of every frame the
        pipe held: a repeated setpoint or command is harmless, a missing one is not)."""
        waiting = (self._writer.take() if self._writer is not None else []) + self._outbox
        self._writer = None
        self._outbox = []
        for data, addr in waiting:
            self._send_now(data, addr)

    def _died(self) -> None:
        self.drain()  # what it passed on before it died
        proc = self._proc
        self._unwatch()
        self._orphans()
        proc.join(0.5)
        self._proc = None
        if not self.closed:
            self._on_death(proc.exitcode)

    def close(self) -> None:
        """Read what is left, send what is queued, then stop the worker."""
        self.closed = True
        self.drain()
        proc = self._proc
        self._unwatch()
        self._orphans()
        self._proc = None
        if proc is not None:
            proc.kill()
            proc.join(1.0)
