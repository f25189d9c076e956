"""FleetLink: the asyncio MAVLink endpoint for a whole fleet.

One UDP socket per MAVLink network serves every vehicle of that network (one network,
one socket, unless several are given: :mod:`groundctl.vehicleid`).  Vehicles are
told apart by vehicle id, their system id on their network's socket; each one's
address is learnt from its first packet (or given by a fleet file).  Everything above
the wire (the vehicles' states, commands, listeners, events) is keyed by vehicle id;
only the packets carry the system id, translated here on the way in and out.  The
protocol logic lives in pure modules (:mod:`.state`, :mod:`.command`,
:mod:`.timesync`, :mod:`.messages`); this module only routes bytes between them and
the sockets, and runs the periodic duties: ground
station HEARTBEAT, TIMESYNC requests, lost-vehicle detection.

Anything odd on the wire (garbage, a truncated or badly signed packet, an
unexpected system id, a known vehicle talking from a new address, a packet that
contradicts the vehicle's own stream) is counted, logged and ignored; it never
raises out of the receive path.  A fleet file's address pins its vehicle: only
packets from that address (or host, ``host:*``) speak for that system id.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import ipaddress
import logging
import math
import os
import socket
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import Clock
from groundctl.errors import LinkError
from groundctl.link import messages
from groundctl.link.codec import (
    GCS_COMPONENT_ID,
    GCS_SYSTEM_ID,
    DatagramParser,
    Encoder,
    new_codec,
)
from groundctl.link.command import CommandExchange
from groundctl.link.flavours import Flavour, mode_from_set_mode, mode_request
from groundctl.link.fleetfile import Endpoint
from groundctl.link.messages import FORCE_MAGIC
from groundctl.link.signing import SigningConfig, new_guard
from groundctl.link.state import (
    StateChange,
    VehicleState,
    account,
    apply,
    expect,
    expire_chunks,
    unexpect,
)
from groundctl.link.timesync import answer as timesync_answer
from groundctl.link.transport import Received, UdpTransport
from groundctl.link.trust import EXPECT_S, Trust
from groundctl.link.worker import (
    Datagram,
    LinkWorker,
    Superseded,
    WorkerSetup,
    unpack,
)
from groundctl.record.events import EventSink
from groundctl.record.tlog import TlogWriter
from groundctl.vehicleid import (
    MAX_NETWORKS,
    NETWORK_STRIDE,
    VehicleId,
    network_index,
    sysid_of,
)

log = logging.getLogger(__name__)

Address = tuple[str, int]
Vec3 = Sequence[float]

#: A link worker that died again is restarted after this, s (real time).
WORKER_RESTART_S = 1.0

#: Telemetry a show needs, in Hz, for :meth:`FleetLink.request_streams`.  The local
#: position at the setpoint rate (the guard, MPC and the monitor fly by it); the global
#: position only for the height above home, a fall and the cross-check of the local one,
#: at 2 Hz (5 until session 36: three datagrams a vehicle a second that a 1,000-drone
#: link receives, parses and records for nothing).
DEFAULT_STREAMS: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 2.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,  # throttle: each vehicle's thrust authority
}
#: Each autopilot's own wind estimate (the show's wind limit), streamed at 1 Hz.
WIND_MESSAGE = {Flavour.ARDUPILOT: mavlink.MAVLINK_MSG_ID_WIND,
                Flavour.PX4: mavlink.MAVLINK_MSG_ID_WIND_COV}



@dataclass
class LinkStats:
    """Link-wide counters (per-vehicle ones live in :class:`VehicleState`)."""

    datagrams: int = 0
    """Datagrams received."""
    packets: int = 0
    """Well-formed packets received (including ignored ones)."""
    bad_packets: int = 0
    """Malformed, truncated or badly signed pieces."""
    unknown_system_packets: int = 0
    """Packets from system ids outside ``expected_ids``."""
    unknown_messages: int = 0
    """Well-formed packets of messages our dialect does not know, ignored."""
    address_conflicts: int = 0
    """Packets from a known system id arriving from an unexpected address (or from
    anywhere but the address a fleet file pins it to)."""
    link_conflicts: int = 0
    """Packets that contradicted their vehicle's own stream (see
    :attr:`VehicleState.link_conflicts`), not acted on."""
    bad_signatures: int = 0
    """Packets refused by signing (unsigned, wrong signature, replayed), not acted on."""
    foreign_packets: int = 0
    """Packets from other ground stations (or our own system id), ignored."""
    sent: int = 0
    """Packets sent."""
    socket_errors: int = 0
    """Errors the socket reported (ICMP unreachable, send failures)."""
    commands_refused: int = 0
    """COMMAND_LONG exchanges a vehicle answered with a refusal (every ``command_refused``
    event; pre-flight requests included)."""
    commands_timed_out: int = 0
    """COMMAND_LONG exchanges never answered after every retry (``command_timeout`` events)."""
    superseded: int = 0
    """State messages a link worker replaced by newer ones while the control loop was
    behind (counted heard and numbered, not acted on)."""
    worker_deaths: int = 0
    """Receive workers that died (each restarted; ``link_worker_died`` events)."""


def _log_worthy(count: int) -> bool:
    # Log the 1st, 2nd, 4th, 8th... occurrence: a flood of garbage must not
    # flood the event log, yet its existence and scale stay visible.
    return count & (count - 1) == 0


class FleetLink:
    """MAVLink link to a fleet over one UDP socket.

    ``listen`` is the local (host, port) to bind; port 0 picks a free one
    (see :attr:`local_address`).  ``endpoints`` lists vehicles at known
    addresses (a fleet file): each is contacted there first, and only packets
    from that address (or, for an endpoint without a port, from that host) speak
    for its system id; packets under its id from anywhere else are address
    conflicts.  ``expected_ids``, when given, restricts the fleet: other system
    ids are counted and ignored.  All times (timeouts, periods) are in
    seconds of ``clock``.
    """

    def __init__(
        self,
        listen: Address | Sequence[Address] = ("0.0.0.0", 14550),
        *,
        clock: Clock,
        endpoints: Iterable[Endpoint] = (),
        expected_ids: Iterable[int] | None = None,
        system_id: int = GCS_SYSTEM_ID,
        component_id: int = GCS_COMPONENT_ID,
        signing_key: bytes | None = None,
        signing_keys: Sequence[bytes | None] | None = None,
        signing_link_id: int = 0,
        allow_unsigned: bool = False,
        tlog: TlogWriter | Sequence[TlogWriter | None] | None = None,
        events: EventSink | None = None,
        lost_timeout: float = 3.0,
        fleet_silence: float = 1.0,
        heartbeat_period: float = 1.0,
        timesync_period: float = 1.0,
        tick: float = 0.05,
        allow_address_change: bool = False,
        command_reason_grace: float = 0.2,
        wall: Callable[[], float] = time.time,
        link_workers: bool = False,
        worker_clocks: Sequence[Any] | None = None,
    ) -> None:
        if not lost_timeout > 0:
            raise ValueError(f"`lost_timeout` must be positive, got {lost_timeout}")
        if not heartbeat_period > 0:
            raise ValueError(f"`heartbeat_period` must be positive, got {heartbeat_period}")
        if timesync_period < 0:
            raise ValueError(f"`timesync_period` must be non-negative, got {timesync_period}")
        if not tick > 0:
            raise ValueError(f"`tick` must be positive, got {tick}")
        listens: list[Address] = ([listen] if _is_address(listen)  # type: ignore[list-item]
                                  else list(listen))  # type: ignore[arg-type]
        if not 1 <= len(listens) <= MAX_NETWORKS:
            raise ValueError(f"`listen` must name 1..{MAX_NETWORKS} networks, got "
                             f"{len(listens)}")
        self.listens = listens
        """Where each network's socket binds, in network order."""
        self.listen = listens[0]
        self.clock = clock
        real_s = clock.wall_interval(1.0)  # 0: a clock real time does not move
        self._speed = 1.0 / real_s if real_s > 0 else 1.0
        """Clock seconds a real second (a dry-run's pace), for the tlog's stamps."""
        self.endpoints = list(endpoints)
        self.expected_ids = None if expected_ids is None else frozenset(expected_ids)
        self.system_id = system_id
        self.component_id = component_id
        self.signing = (
            None if signing_key is None
            else SigningConfig(signing_key, signing_link_id, allow_unsigned)
        )  # fmt: skip
        tlogs = list(tlog) if isinstance(tlog, Sequence) else [tlog]
        if len(tlogs) == 1:
            tlogs *= len(listens)
        elif len(tlogs) != len(listens):
            raise ValueError(f"{len(tlogs)} tlogs for {len(listens)} networks")
        self._tlogs: list[TlogWriter | None] = tlogs
        self.tlog = tlogs[0]
        self.events = events
        self.lost_timeout = lost_timeout
        self.fleet_silence = fleet_silence
        self.heartbeat_period = heartbeat_period
        self.timesync_period = timesync_period
        self.tick = tick
        self.allow_address_change = allow_address_change
        self.command_reason_grace = command_reason_grace
        self._wall = wall
        new_codec(system_id, component_id)  # validates the ids now, not on first packet

        self.vehicles: dict[int, VehicleState] = {}
        """Vehicles heard from, by system id."""
        self.stats = LinkStats()
        self._addresses: dict[int, Address] = {
            e.system_id: e.address for e in self.endpoints if e.address is not None}
        self._pins: dict[int, tuple[str, int | None]] = {
            e.system_id: (_resolve(e.host), e.port) for e in self.endpoints}
        if signing_keys is not None and len(signing_keys) != len(listens):
            raise ValueError(f"{len(signing_keys)} signing keys for {len(listens)} networks")
        self._signings: list[SigningConfig | None] = (
            [self.signing] * len(listens) if signing_keys is None
            else [None if k is None else SigningConfig(k, signing_link_id, allow_unsigned)
                  for k in signing_keys])
        """Each network's signing (its own key, or ``signing_key`` for all)."""
        self._guards = [None if s is None else new_guard(s, wall) for s in self._signings]
        self._bad_signatures: dict[int, int] = {}
        self._parsers: dict[tuple[int, Address], DatagramParser] = {}
        self._encoders: dict[int, Encoder] = {}
        self._bad_by_address: dict[Address, int] = {}
        self._conflicts_by_id: dict[int, int] = {}
        self._unknown_ids: dict[int, int] = {}
        self._exchanges: dict[tuple[int, int], tuple[CommandExchange, asyncio.Event]] = {}
        self._listeners: dict[int, list[Callable[[mavlink.MAVLink_message, float], None]]] = {}
        self._command_locks: dict[tuple[int, int], asyncio.Lock] = {}
        self._heard = asyncio.Event()
        self.last_packet_at: float | None = None
        """Our time of the last well-formed packet from any vehicle of the fleet."""
        self.fleet_silent = False
        """Nobody has been heard for ``fleet_silence`` s: the link (or we) went quiet."""
        self._fleet_back_at = -math.inf
        self.silence_ids: set[int] | None = None
        """The vehicles a fleet-wide silence is judged over (the executor sets those in
        the air: a drone on the ground still talking must not hide a cut of the rest);
        None: every vehicle."""
        self._transports: list[UdpTransport] = []
        self._task: asyncio.Task[None] | None = None
        self.local_address: Address | None = None
        """The first network's bound (host, port), once started."""
        self.local_addresses: list[Address] = []
        """Every network's bound (host, port), in network order, once started."""
        self._last_by_network: list[float | None] = [None] * len(listens)
        self._back_by_network: list[float] = [-math.inf] * len(listens)
        self.link_workers = link_workers
        """Each network's socket work (reads, parsing, signatures, the send system calls)
        runs in a process of its own (:mod:`groundctl.link.worker`); False: in this one."""
        self._workers: list[LinkWorker] = []
        if worker_clocks is not None and len(worker_clocks) != len(listens):
            raise ValueError(f"{len(worker_clocks)} worker clocks for {len(listens)} networks")
        self._worker_clocks = list(worker_clocks) if worker_clocks is not None \
            else [None] * len(listens)
        """Each network's worker's view of a dry-run's paced clock (its telemetry holds
        the rehearsal: :class:`~groundctl.link.worker.Pacer`), or None."""
        self._worker_down: list[bool] = [False] * len(listens)
        self._restarts: list[asyncio.TimerHandle | None] = [None] * len(listens)

    # -- lifecycle -------------------------------------------------------

    async def start(self) -> None:
        """Bind the socket and start the periodic duties."""
        if self._transports:
            raise LinkError("link already started")
        try:
            for k, listen in enumerate(self.listens):
                transport = UdpTransport(functools.partial(self._on_datagrams, network=k),
                                         self._on_socket_error)
                self._transports.append(transport)
                self.local_addresses.append(await transport.open(listen))
        except BaseException:
            for transport in self._transports:
                transport.close()
            self._transports, self.local_addresses = [], []
            raise
        self.local_address = self.local_addresses[0]
        if self.link_workers:
            self._start_workers()
        self._task = asyncio.create_task(self._run_periodic(), name="fleetlink-periodic")
        for k, (host, port) in enumerate(self.local_addresses):
            extra = {"network": k + 1} if len(self.local_addresses) > 1 else {}
            self._emit("link_started", address=f"{host}:{port}", **extra)

    async def close(self) -> None:
        """Stop, close the socket, flush the tlog and the event sink (the caller closes them)."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        for handle in self._restarts:
            if handle is not None:
                handle.cancel()
        for worker in self._workers:
            worker.close()
        self._workers = []
        if self._transports:
            for transport in self._transports:
                transport.close()
            self._transports = []
            self._emit("link_closed", **{k: v for k, v in vars(self.stats).items()})
        for tlog in self._tlogs:
            if tlog is not None:
                tlog.flush()
        flush = getattr(self.events, "flush", None)
        if callable(flush):
            flush()

    async def __aenter__(self) -> FleetLink:
        await self.start()
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.close()

    # -- receive path ----------------------------------------------------

    def _parser(self, addr: Address, network: int = 0) -> DatagramParser:
        parser = self._parsers.get((network, addr))
        if parser is None:
            parser = DatagramParser(
                new_codec(self.system_id, self.component_id, self._signings[network],
                          self._wall, self._guards[network])
            )
            self._parsers[(network, addr)] = parser
        return parser

    def _on_socket_error(self, exc: Exception) -> None:
        self.stats.socket_errors += 1
        log.debug("socket error: %s", exc)

    def _on_datagrams(self, batch: list[Received], network: int = 0) -> None:
        """A drain's datagrams, each dated when it arrived, not when our busy loop read
        it: one look at the clock for the batch (a paced clock's is a lock and a read of
        shared memory)."""
        times, stamps = self._dated([arrived for _, _, arrived in batch], network)
        for (data, addr, _), at, stamp in zip(batch, times, stamps, strict=True):
            try:
                self._on_datagram(data, addr, at, network, stamp)
            except Exception:  # a bug in a handler must cost one datagram, not the batch
                log.exception("error handling datagram from %s:%s", addr[0], addr[1])

    def _dated(self, arrived: list[float], network: int
               ) -> tuple[list[float], list[float | None]]:
        """When each datagram that arrived at ``arrived`` (``time.monotonic()``) did so,
        on our clock (one reading of it for the batch) and on the network's tlog's
        (Unix time, one reading of its stamp for the batch: a backlog is stamped when
        each packet arrived, not as the loop got to it; None without a tlog)."""
        wall = time.monotonic()
        now, times = self.clock.dated([max(wall - a, 0.0) for a in arrived])
        tlog = self._tlogs[network]
        if tlog is None:
            return times, [None] * len(times)
        base = tlog.stamp()
        return times, [base - (now - t) / self._speed for t in times]

    def _on_datagram(self, data: bytes, addr: Address, now: float, network: int = 0,
                     stamp: float | None = None) -> None:
        """One datagram, arrived at ``now`` on our clock (``stamp`` on the tlog's)."""
        result = self._parser(addr, network).feed(data)
        self._on_parsed(addr, now, network, result.messages, result.bad,
                        result.refused_signatures, result.unknown, stamp)

    def _on_parsed(self, addr: Address, now: float, network: int,
                   messages: Iterable[mavlink.MAVLink_message | Superseded],
                   bad: Iterable[str], refused_signatures: Iterable[int],
                   unknown: int, stamp: float | None = None) -> None:
        """One datagram's content, parsed here or by the network's link worker (whose
        :class:`Superseded` entries stand for state messages a newer one replaced while
        this loop was behind).  The tlog stamps each packet ``stamp``, when it arrived
        (:meth:`_dated`): a busy loop that read a backlog at once wrote it under one
        stamp, and a replay dating the vehicles' clocks by those stamps tracked them
        centimetres off the monitor's figures."""
        self.stats.datagrams += 1
        for reason in bad:
            self._bad_packet(addr, reason)
        offset = network * NETWORK_STRIDE
        for sysid in refused_signatures:
            self._bad_signature(VehicleId(offset + sysid), addr)
        self.stats.unknown_messages += unknown
        tlog = self._tlogs[network]
        for msg in messages:
            self.stats.packets += 1
            if isinstance(msg, Superseded):
                self.stats.superseded += 1
                self._superseded(msg, addr, now, network)
                continue
            if tlog is not None:
                tlog.write(msg.get_msgbuf(), stamp)
            try:
                self._handle(msg, addr, now, network)
            except Exception:  # a bug here must cost one packet, not the link
                log.exception("error handling %s from %s:%s", msg.get_type(), *addr)

    # -- link workers ------------------------------------------------------

    @property
    def worker_pids(self) -> list[int]:
        """The running link workers' process ids (none without workers)."""
        return [w.pid for w in self._workers if w.pid is not None]

    def _start_workers(self) -> None:
        for k, transport in enumerate(self._transports):
            sock = transport.pause_reading()
            setup = WorkerSetup(k, self.system_id, self.component_id, self._signings[k],
                                transport.stamped, os.getpid(), self._worker_clocks[k])
            worker = LinkWorker(sock, setup, functools.partial(self._on_batch, k),
                                functools.partial(self._worker_died, k),
                                self._on_worker_errors, direct=transport.send)
            self._workers.append(worker)
            worker.start()

    def _on_batch(self, network: int, batch: list[Datagram]) -> None:
        """A link worker's batch: each datagram dated on our clock as it arrived, then
        handled as if read here.  A restarted worker's first batch ends its network's
        silence (then heard again as any silent network is)."""
        self._worker_down[network] = False
        times, stamps = self._dated([d.arrived for d in batch], network)
        for datagram, at, stamp in zip(batch, times, stamps, strict=True):
            try:
                messages = [unpack(m) for m in datagram.messages]
            except Exception as exc:  # a worker of another version, a bug: one datagram
                self._bad_packet(datagram.address, f"unreadable from the worker: {exc}")
                continue
            self._on_parsed(datagram.address, at, network, messages, datagram.bad,
                            datagram.refused_signatures, datagram.unknown, stamp)

    def _on_worker_errors(self, count: int) -> None:
        self.stats.socket_errors += count

    def _worker_died(self, network: int, exitcode: int | None) -> None:
        """Seen at once: the network counts as silent (``fleet_silent`` at once: the show
        holds) until a new worker on the same socket passes its vehicles on again;
        restarted at once, then after WORKER_RESTART_S if it keeps dying."""
        self.stats.worker_deaths += 1
        self._worker_down[network] = True
        clock = self._worker_clocks[network]
        if clock is not None:
            clock.idle_until(math.inf)  # it holds a paced clock no more (a new one may)
        self._emit("link_worker_died", network=network + 1, exit_code=exitcode)
        log.warning("network %d: the link worker died (exit code %s); restarting it",
                    network + 1, exitcode)
        self.check_lost(self.clock.now())  # fleet_silent now, not at the next check
        worker = self._workers[network]
        delay = 0.0 if worker.starts <= 1 else WORKER_RESTART_S
        self._restarts[network] = asyncio.get_running_loop().call_later(
            delay, self._restart_worker, network)

    def _restart_worker(self, network: int) -> None:
        self._restarts[network] = None
        worker = self._workers[network]
        if worker.closed:
            return
        try:
            worker.start()
        except Exception as exc:  # cannot fork: the network stays silent, say so
            log.error("network %d: cannot restart the link worker: %s", network + 1, exc)
            self._emit("link_worker_failed", network=network + 1, reason=str(exc))
            self._restarts[network] = asyncio.get_running_loop().call_later(
                WORKER_RESTART_S, self._restart_worker, network)
            return
        self._emit("link_worker_restarted", network=network + 1, pid=worker.pid,
                   starts=worker.starts)

    def _bad_packet(self, addr: Address, reason: str) -> None:
        self.stats.bad_packets += 1
        for sysid, known in self._addresses.items():
            if known == addr and sysid in self.vehicles:
                self.vehicles[sysid].bad_packets += 1
        n = self._bad_by_address.get(addr, 0) + 1
        self._bad_by_address[addr] = n
        log.debug("bad packet from %s:%s: %s", addr[0], addr[1], reason)
        if _log_worthy(n):
            self._emit("bad_packet", address=f"{addr[0]}:{addr[1]}", reason=reason, count=n)

    def _bad_signature(self, sysid: int, addr: Address) -> None:
        # Counted against the system id the packet claims, and nothing else: a refused
        # packet is not heard from anyone, so it changes no state at all.
        self.stats.bad_signatures += 1
        n = self._bad_signatures.get(sysid, 0) + 1
        self._bad_signatures[sysid] = n
        state = self.vehicles.get(sysid)
        if state is not None:
            state.bad_signatures = n
        if _log_worthy(n):
            self._emit("bad_signature", system_id=sysid, address=f"{addr[0]}:{addr[1]}",
                       count=n)

    def _handle(self, msg: mavlink.MAVLink_message, addr: Address, now: float,
                network: int = 0) -> None:
        src = msg.get_srcSystem()
        kind = msg.get_type()
        if src == self.system_id or (kind == "HEARTBEAT" and msg.type == mavlink.MAV_TYPE_GCS):
            self.stats.foreign_packets += 1
            return
        key = network * NETWORK_STRIDE + src
        state = self.vehicles.get(key)
        # (A known vehicle's id is its state's: no new VehicleId a packet.)
        sysid = VehicleId(key) if state is None else state.system_id
        if self.expected_ids is not None and sysid not in self.expected_ids:
            self.stats.unknown_system_packets += 1
            n = self._unknown_ids.get(sysid, 0) + 1
            self._unknown_ids[sysid] = n
            if _log_worthy(n):
                log.warning("ignoring unknown system id %d from %s:%s", sysid, *addr)
                self._emit("unknown_vehicle", system_id=sysid, address=f"{addr[0]}:{addr[1]}",
                           count=n)
            return
        if not self._accept_address(sysid, addr):
            return

        if state is None:
            state = self.vehicles[sysid] = VehicleState(sysid)
            state.bad_signatures = self._bad_signatures.get(sysid, 0)
            self._emit("vehicle_appeared", system_id=sysid, address=f"{addr[0]}:{addr[1]}")
        if state.lost:
            state.lost = False
            self._emit("vehicle_found", system_id=sysid,
                       silent_for_s=round(state.silent_for(now), 3))
        self.last_packet_at = now
        self._last_by_network[network] = now
        changes = apply(state, msg, now)
        if changes:
            self._emit_changes(sysid, changes)
        self._heard.set()

        if not state.trust.last_trusted and kind != "STATUSTEXT":
            return  # not believed: no answer, no ACK taken from it
        listeners = self._listeners.get(sysid)
        if listeners:
            for listener in tuple(listeners):
                listener(msg, now)  # protocol clients (parameters, fence upload)
        if kind == "TIMESYNC":
            reply = timesync_answer(msg.tc1, msg.ts1, now)
            if reply is not None:
                self._send(sysid, messages.timesync(*reply))
        elif kind == "STATUSTEXT":
            for text in (c.fields["text"] for c in changes if c.event == "statustext"):
                for (target, _), (exchange, wake) in self._exchanges.items():
                    if target == sysid:
                        exchange.note_statustext(text, now)
                        wake.set()
        elif kind == "COMMAND_ACK":
            entry = self._exchanges.get((sysid, msg.command))
            if entry is not None and entry[0].matches(msg, self.system_id):
                entry[0].receive(msg, now)
                entry[1].set()

    def _superseded(self, entry: Superseded, addr: Address, now: float,
                    network: int) -> None:
        """A packet heard and numbered, its content replaced by a newer one (the worker's
        conflation): judged only as far as its number goes (:func:`account`)."""
        state = self.vehicles.get(network * NETWORK_STRIDE + entry.system)
        if state is None or entry.system == self.system_id \
                or self._addresses.get(state.system_id) != addr:
            return  # not one of ours (its newer one, handled whole, says what it is)
        sysid = state.system_id
        self.last_packet_at = now
        self._last_by_network[network] = now
        self._emit_changes(sysid, account(state, entry.component, entry.seq, entry.crc,
                                          entry.kind, now))

    def _emit_changes(self, sysid: int, changes: list[StateChange]) -> None:
        for change in changes:
            if change.event == "link_conflict":
                self.stats.link_conflicts += 1
                if not _log_worthy(int(change.fields["count"])):
                    continue  # a flood must not flood the event log
                log.warning("vehicle %d: link conflict: %s", sysid, change.fields["reason"])
            self._emit(change.event, system_id=sysid, **change.fields)

    def _accept_address(self, sysid: int, addr: Address) -> bool:
        known = self._addresses.get(sysid)
        pin = self._pins.get(sysid)
        if pin is not None and not (addr[0] == pin[0] and pin[1] in (None, addr[1])):
            # The fleet file says where this vehicle talks from: nobody else speaks for
            # it, whoever comes first (a stray or spoofed HEARTBEAT must not win it).
            where = f"{pin[0]}:{'*' if pin[1] is None else pin[1]}"
            return self._address_conflict(sysid, addr, where)
        if known == addr:
            return True
        if known is None:
            # First packet: learn the address (for a host-only fleet entry, the port).
            self._addresses[sysid] = addr
            if pin is not None and pin[1] is None:
                self._emit("address_learnt", system_id=sysid, address=f"{addr[0]}:{addr[1]}",
                           configured=f"{pin[0]}:*")
            return True
        if self.allow_address_change:
            self._addresses[sysid] = addr
            state = self.vehicles.get(sysid)
            if state is not None:
                # A new sender (the vehicle rebooted onto a new port, as the operator
                # allows): its numbering and tracks start afresh, not as a conflict.
                state.trust = Trust()
            self._emit("address_changed", system_id=sysid, old=f"{known[0]}:{known[1]}",
                       new=f"{addr[0]}:{addr[1]}")
            return True
        # Someone else claims this system id (a duplicate id, a spoofer, or a
        # vehicle that rebooted onto a new port): never hijack the vehicle.
        return self._address_conflict(sysid, addr, f"{known[0]}:{known[1]}")

    def _address_conflict(self, sysid: int, addr: Address, known: str) -> bool:
        self.stats.address_conflicts += 1
        n = self._conflicts_by_id.get(sysid, 0) + 1
        self._conflicts_by_id[sysid] = n
        if _log_worthy(n):
            log.warning("vehicle %d: ignoring packets from %s:%s (known at %s)",
                        sysid, addr[0], addr[1], known)
            self._emit("address_conflict", system_id=sysid, address=f"{addr[0]}:{addr[1]}",
                       known=known, count=n)
        return False

    # -- send path -------------------------------------------------------

    def _encoder(self, sysid: int) -> Encoder:
        enc = self._encoders.get(sysid)
        if enc is None:
            enc = Encoder(new_codec(self.system_id, self.component_id,
                                    self._signings[network_index(sysid)], self._wall))
            self._encoders[sysid] = enc
        return enc

    def _send(self, sysid: int, msg: mavlink.MAVLink_message) -> None:
        addr = self._addresses.get(sysid)
        if addr is None:
            raise LinkError(f"vehicle {sysid}: address unknown (never heard from it)")
        if not self._transports:
            raise LinkError("link is not open: call `await link.start()` first")
        network = network_index(sysid)
        if network and getattr(msg, "target_system", 0) == sysid:
            msg.target_system = sysid_of(sysid)  # on the wire: its network's system id
        data = self._encoder(sysid).encode(msg)
        if self._workers:
            self._workers[network].send(data, addr)
        else:
            self._transports[network].send(data, addr)
        self.stats.sent += 1
        tlog = self._tlogs[network]
        if tlog is not None:
            tlog.write(data)

    def address_of(self, sysid: int) -> Address | None:
        """Where packets for vehicle ``sysid`` go, if known."""
        return self._addresses.get(sysid)

    def pin(self, addresses: Mapping[int, Address]) -> None:
        """Pin vehicles to the addresses they talk from once the link is up (a dry-run
        knows its simulated vehicles' ports only after it has bound its own, for the
        simulator to send to), as a fleet file pins them before: from now on a packet
        claiming one of them from anywhere else is an address conflict.  An address
        learnt before from elsewhere -- a stranger that sent to our port first, such as
        another simulator on the same machine -- is forgotten, with all that was heard
        from it.  Call it before the flight uses the vehicles."""
        for sysid, addr in addresses.items():
            self._pins[sysid] = addr
            known = self._addresses.get(sysid)
            if known is not None and known != addr:
                del self._addresses[sysid]
                self.vehicles.pop(sysid, None)
                self._emit("address_forgotten", system_id=sysid,
                           address=f"{known[0]}:{known[1]}", pinned=f"{addr[0]}:{addr[1]}")

    # -- periodic duties -------------------------------------------------

    async def _run_periodic(self) -> None:
        next_heartbeat = -math.inf
        next_timesync = -math.inf
        while True:
            now = self.clock.now()
            try:
                if now >= next_heartbeat:
                    next_heartbeat = now + self.heartbeat_period
                    self._broadcast(messages.gcs_heartbeat())
                if self.timesync_period > 0 and now >= next_timesync:
                    next_timesync = now + self.timesync_period
                    for sysid, state in self.vehicles.items():
                        if not state.lost:
                            # Stamped as it leaves, not at the top of this duty: a request
                            # that left later than its stamp said reads as that much
                            # offset (half its delay), and at 1,000 vehicles the last
                            # leaves a whole loop after the first.
                            self._send(sysid, messages.timesync(
                                0, state.timesync.request(self.clock.now())))
                self.check_lost(now)
            except LinkError as exc:
                log.warning("periodic duty failed: %s", exc)
            await asyncio.sleep(max(self.clock.wall_interval(self.tick), 0.001))

    def _broadcast(self, msg: mavlink.MAVLink_message) -> None:
        # One copy per vehicle: each vehicle's stream has its own sequence numbers.
        for sysid in list(self._addresses):
            self._send(sysid, msg)

    def drain(self) -> int:
        """Read every datagram waiting in the socket now; returns how many.

        Called before anything is decided from the vehicles' states: after a stall
        of our own loop the socket holds their packets, and they are not silent.
        """
        if self._workers:
            return sum(w.drain() for w in self._workers)
        return sum(t.drain() for t in self._transports)

    def fleet_silent_for(self, now: float) -> float:
        """Seconds since any vehicle of :attr:`silence_ids` (default: any) was heard
        (infinite before the first packet).  Vehicles already marked lost do not count:
        their silence is their own, judged one by one (one drone lost for good, the last
        still streamed after the others landed, read as the whole fleet silent).

        With several networks, the longest of their silences: a network whose link is
        cut (a radio, a cable) is silent however well the others are heard, and that
        says nothing about any one of its vehicles."""
        return self._fleet_silence_of(self._network_silences(now))

    def network_silent_for(self, network: int, now: float) -> float:
        """Seconds since network ``network`` (from 0) was heard, as
        :meth:`fleet_silent_for` judges it (infinite while its link worker is down)."""
        if self.silence_ids is None:
            return self._heard_silence(network, now)  # no pass over the fleet needed
        return self._network_silences(now)[0][network]

    def _heard_silence(self, network: int, now: float) -> float:
        """Seconds since anything was heard on ``network`` (infinite while its link
        worker is down, or before its first packet)."""
        if self._worker_down[network]:
            return math.inf  # its link worker died: nothing of it is heard
        last = self._last_by_network[network]
        return math.inf if last is None else now - last

    def _fleet_silence_of(self, silences: tuple[list[float], list[bool]]) -> float:
        """The fleet's silence from its networks' (:meth:`_network_silences`): the
        longest among the networks any vehicle was heard on."""
        each, known = silences
        if len(each) == 1:
            return each[0]
        return max((s for s, k in zip(each, known, strict=True) if k), default=0.0)

    def _network_silences(self, now: float) -> tuple[list[float], list[bool]]:
        """Every network's silence (:meth:`network_silent_for`) and whether any vehicle
        was heard on it, from one pass over the fleet: at 1,000 vehicles a pass per
        network, three times a periodic duty, was a tenth of the control loop."""
        n = len(self.listens)
        known = [n == 1] * n
        judged = [False] * n
        latest = [-math.inf] * n
        ids = self.silence_ids
        if ids is not None or n > 1:
            for sysid, state in self.vehicles.items():
                k = sysid // NETWORK_STRIDE
                if k >= n:
                    continue  # (only a test's hand-made state: the link keys what it hears)
                known[k] = True
                if ids is None or state.lost or sysid not in ids:
                    continue
                judged[k] = True
                heard = state.last_heard
                if heard is not None and heard > latest[k]:
                    latest[k] = heard
        each = []
        for k in range(n):
            if ids is None or self._worker_down[k]:
                each.append(self._heard_silence(k, now))
            else:  # (nobody to judge a fleet-wide silence by: not silent)
                each.append(now - latest[k] if judged[k] else 0.0)
        return each, known

    def check_lost(self, now: float) -> list[int]:
        """Mark vehicles silent for longer than ``lost_timeout``; returns newly lost ids.

        Silence must be the vehicle's own: the socket is drained first (our own stall
        leaves its packets waiting there), and while the whole fleet is silent (a cut
        of the whole link, the receive path stopped) nobody is marked lost, since
        that says nothing about any one vehicle: the ``fleet_silent`` flag is set
        instead and the executor holds the show.  With several networks the same holds
        network by network: the vehicles of a silent network (or one just heard again)
        are not marked lost, and ``fleet_silent`` is set while any network is silent.
        """
        self.drain()
        for sysid, state in self.vehicles.items():
            if state.text_chunks:  # (most have none: no call a vehicle a duty)
                for change in expire_chunks(state, now):
                    self._emit(change.event, system_id=sysid, **change.fields)
        silences = self._network_silences(now)
        fleet = self._fleet_silence_of(silences)
        silent = fleet > self.fleet_silence and bool(self.vehicles)
        if silent != self.fleet_silent:
            self.fleet_silent = silent
            self._emit("fleet_silent" if silent else "fleet_heard",
                       silent_for_s=round(min(fleet, 1e9), 3))
            if not silent:
                self._fleet_back_at = now
        if silent or now - self._fleet_back_at < self.fleet_silence:
            # Silent, or just back: the rest of the fleet's packets are on their way.
            return []
        quiet: set[int] = set()
        if len(self.listens) > 1:
            for k in range(len(self.listens)):
                if silences[0][k] > self.fleet_silence:
                    quiet.add(k)
                    self._back_by_network[k] = math.inf
                elif self._back_by_network[k] == math.inf:
                    self._back_by_network[k] = now
                if now - self._back_by_network[k] < self.fleet_silence:
                    quiet.add(k)
        newly = []
        timeout = self.lost_timeout
        for sysid, state in self.vehicles.items():
            heard = state.last_heard  # (state.silent_for, inline: every vehicle, 20 Hz)
            if not state.lost and (heard is None or now - heard > timeout) \
                    and network_index(sysid) not in quiet:
                state.lost = True
                newly.append(sysid)
                self._emit("vehicle_lost", system_id=sysid,
                           silent_for_s=round(state.silent_for(now), 3))
        return newly

    def _emit(self, event: str, **fields: Any) -> None:
        log.info("%s %s", event, fields)
        if self.events is not None:
            try:
                self.events.emit(event, **fields)
            except Exception:  # a broken sink must not break the link
                log.exception("event sink failed on %s", event)

    # -- waiting ---------------------------------------------------------

    async def wait_for_vehicles(
        self, ids: Iterable[int] | int, timeout: float = 10.0
    ) -> dict[int, VehicleState]:
        """Wait until the given system ids (or this many vehicles) sent an autopilot HEARTBEAT.

        Raises :class:`LinkError` naming the missing vehicles after ``timeout``.
        """
        want_count = ids if isinstance(ids, int) else None
        want_ids = None if isinstance(ids, int) else set(ids)
        deadline = self.clock.now() + timeout

        def ready() -> dict[int, VehicleState]:
            return {s: v for s, v in self.vehicles.items() if v.last_heartbeat is not None}

        while True:
            have = ready()
            if want_ids is not None and want_ids <= set(have):
                return {s: have[s] for s in sorted(want_ids)}
            if want_count is not None and len(have) >= want_count:
                return have
            remaining = deadline - self.clock.now()
            if remaining <= 0:
                heard = sorted(have)
                if want_ids is not None:
                    missing = sorted(want_ids - set(have))
                    raise LinkError(f"no HEARTBEAT from vehicles {missing} within {timeout} s "
                                    f"(heard from {heard})")
                raise LinkError(f"only {len(heard)} of {want_count} vehicles sent a HEARTBEAT "
                                f"within {timeout} s (heard from {heard})")
            self._heard.clear()
            wait = min(max(self.clock.wall_interval(remaining), 0.001), 0.1)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._heard.wait(), wait)

    # -- commands ----------------------------------------------------------

    async def command_long(
        self,
        sysid: int,
        command: int,
        *params: float,
        timeout: float = 1.0,
        retries: int = 2,
        target_component: int = 1,
        poll: bool = False,
    ) -> mavlink.MAVLink_command_ack_message:
        """Send COMMAND_LONG and wait for its ACCEPTED ACK.

        Resends after ``timeout`` up to ``retries`` times; raises
        :class:`CommandRefused` (with the vehicle's STATUSTEXT as reason) or
        :class:`CommandTimeout`.  Commands with the same number to the same
        vehicle run one after the other: an ACK names only the command.

        ``poll``: a question asked again until the vehicle can answer it (pre-flight's
        GPS_GLOBAL_ORIGIN and HOME_POSITION before its EKF has them, which ArduPilot
        refuses): its refusal or silence is the expected "not yet", raised but neither
        counted among the flight's refused or timed-out commands nor an event (1,000
        vehicles asked every 2 s made 19,500 of the 47,000 events of a dry-run).
        """
        if retries < 0:
            raise ValueError(f"`retries` must be non-negative, got {retries}")
        key = (sysid, command)
        lock = self._command_locks.setdefault(key, asyncio.Lock())
        async with lock:
            exchange = CommandExchange(
                sysid, command, params, timeout=timeout, attempts=retries + 1,
                reason_grace=self.command_reason_grace, target_component=target_component,
            )  # fmt: skip
            wake = asyncio.Event()
            self._exchanges[key] = (exchange, wake)
            self._expect(sysid, command, params, timeout * (retries + 1) + EXPECT_S)
            try:
                for msg in exchange.start(self.clock.now()):
                    self._send(sysid, msg)
                while not exchange.done:
                    remaining = exchange.deadline - self.clock.now()
                    if remaining > 0:
                        wait = max(self.clock.wall_interval(remaining), 0.001)
                        with contextlib.suppress(TimeoutError):
                            await asyncio.wait_for(wake.wait(), wait)
                    wake.clear()
                    for msg in exchange.poll(self.clock.now()):
                        self._send(sysid, msg)
            finally:
                del self._exchanges[key]
        if exchange.error is not None:
            event = "command_refused" if exchange.ack is not None else "command_timeout"
            if exchange.ack is not None:
                self._unexpect(sysid, command, params)
            if poll:
                raise exchange.error
            if exchange.ack is not None:
                self.stats.commands_refused += 1
            else:
                self.stats.commands_timed_out += 1
            self._emit(event, system_id=sysid, command=exchange.name, error=str(exchange.error))
            raise exchange.error
        return exchange.result()

    def _expect(self, sysid: int, command: int, params: Sequence[float], for_s: float) -> None:
        """What this command asks the vehicle for is believed at once when its HEARTBEAT
        reports it (see :func:`groundctl.link.state.expect`)."""
        state = self.vehicles.get(sysid)
        if state is None or state.flavour is None:
            return
        now = self.clock.now()
        p = [*params, 0.0, 0.0, 0.0][:3]
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            name = mode_from_set_mode(state.flavour, p[1], p[2])
            if name is not None:
                expect(state, now, mode=name, for_s=for_s)
        elif command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            expect(state, now, armed=p[0] == 1, for_s=for_s)
        elif command == mavlink.MAV_CMD_NAV_TAKEOFF and state.flavour is Flavour.PX4:
            # PX4 takes off in AUTO.TAKEOFF and hovers in AUTO.LOITER once there.
            for name in ("AUTO.TAKEOFF", "AUTO.LOITER"):
                expect(state, now, mode=name, for_s=for_s)

    def _unexpect(self, sysid: int, command: int, params: Sequence[float]) -> None:
        state = self.vehicles.get(sysid)
        if state is None or state.flavour is None:
            return
        p = [*params, 0.0, 0.0, 0.0][:3]
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            unexpect(state, mode=mode_from_set_mode(state.flavour, p[1], p[2]))
        elif command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            unexpect(state, armed=p[0] == 1)

    def _flavour(self, sysid: int) -> Flavour:
        state = self.vehicles.get(sysid)
        if state is None or state.flavour is None:
            raise LinkError(f"vehicle {sysid}: autopilot unknown (no HEARTBEAT yet)")
        return state.flavour

    async def set_mode(self, sysid: int, name: str, **kw: Any) -> None:
        """Switch vehicle ``sysid`` to mode ``name`` (``GUIDED``, ``OFFBOARD``, ``LAND``...)."""
        req = mode_request(self._flavour(sysid), name)
        await self.command_long(sysid, mavlink.MAV_CMD_DO_SET_MODE,
                                req.param1, req.param2, req.param3, **kw)

    async def arm(self, sysid: int, force: bool = False, **kw: Any) -> None:
        """Arm; ``force`` overrides the pre-arm checks (never in a show)."""
        await self.command_long(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                1, FORCE_MAGIC if force else 0, **kw)

    async def disarm(self, sysid: int, force: bool = False, **kw: Any) -> None:
        """Disarm; ``force`` disarms even in flight (an emergency stop)."""
        await self.command_long(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                0, FORCE_MAGIC if force else 0, **kw)

    async def takeoff(self, sysid: int, alt_m: float, **kw: Any) -> None:
        """MAV_CMD_NAV_TAKEOFF to ``alt_m`` metres above home.

        ArduPilot reads param7 as altitude above home; PX4 reads it as AMSL
        and takes NaN latitude/longitude/yaw as "here", so for PX4 the home
        altitude is added.
        """
        if self._flavour(sysid) is Flavour.PX4:
            home = self.vehicles[sysid].home
            if home is None:
                raise LinkError(f"vehicle {sysid}: PX4 takeoff needs HOME_POSITION first")
            nan = math.nan
            await self.command_long(sysid, mavlink.MAV_CMD_NAV_TAKEOFF,
                                    -1, 0, 0, nan, nan, nan, home.alt_m + alt_m, **kw)
        else:
            await self.command_long(sysid, mavlink.MAV_CMD_NAV_TAKEOFF,
                                    0, 0, 0, 0, 0, 0, alt_m, **kw)

    async def land(self, sysid: int, **kw: Any) -> None:
        """Land where the vehicle is, via the flavour's land mode."""
        name = "LAND" if self._flavour(sysid) is Flavour.ARDUPILOT else "AUTO.LAND"
        await self.set_mode(sysid, name, **kw)

    async def request_message(self, sysid: int, msg_id: int, **kw: Any) -> None:
        """MAV_CMD_REQUEST_MESSAGE: have the vehicle send ``msg_id`` once."""
        await self.command_long(sysid, mavlink.MAV_CMD_REQUEST_MESSAGE, msg_id, **kw)

    async def set_message_interval(self, sysid: int, msg_id: int, hz: float, **kw: Any) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: stream ``msg_id`` at ``hz`` (0 stops it)."""
        await self.command_long(sysid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                msg_id, messages.message_interval_us(hz), **kw)

    async def request_streams(
        self, sysid: int, rates: Mapping[int, float] | None = None, **kw: Any
    ) -> None:
        """Ask for every stream in ``rates`` (message id -> Hz; default :data:`DEFAULT_STREAMS`
        and the flavour's wind estimate, :data:`WIND_MESSAGE`: a vehicle that refuses it
        (or never answers) flies, its wind unknown, said in the log)."""
        for msg_id, hz in (DEFAULT_STREAMS if rates is None else rates).items():
            await self.set_message_interval(sysid, msg_id, hz, **kw)
        state = self.vehicles.get(sysid)
        flavour = state.flavour if state is not None else None
        wind = WIND_MESSAGE.get(flavour) if rates is None and flavour is not None else None
        if wind is not None:
            try:
                await self.set_message_interval(sysid, wind, 1.0, **kw)
            except LinkError as exc:
                log.info("vehicle %s does not stream its wind estimate: %s", sysid, exc)

    # -- streaming senders (non-blocking, fire and forget) -------------------

    def send_position_target_local_ned(
        self,
        sysid: int,
        time_boot_ms: int,
        pos_ned: Vec3,
        vel_ned: Vec3 | None = None,
        acc_ned: Vec3 | None = None,
        yaw: float | None = None,
        yaw_rate: float | None = None,
    ) -> None:
        """SET_POSITION_TARGET_LOCAL_NED to vehicle ``sysid`` (type_mask from what is given)."""
        self._send(sysid, messages.position_target_local_ned(
            sysid, time_boot_ms, pos_ned, vel_ned, acc_ned, yaw, yaw_rate))

    def send_position_target_global_int(
        self,
        sysid: int,
        time_boot_ms: int,
        lat_deg: float,
        lon_deg: float,
        alt_m: float,
        vel_ned: Vec3 | None = None,
        acc_ned: Vec3 | None = None,
        yaw: float | None = None,
        yaw_rate: float | None = None,
        frame: int = mavlink.MAV_FRAME_GLOBAL_INT,
    ) -> None:
        """SET_POSITION_TARGET_GLOBAL_INT to vehicle ``sysid``."""
        self._send(sysid, messages.position_target_global_int(
            sysid, time_boot_ms, lat_deg, lon_deg, alt_m, vel_ned, acc_ned, yaw, yaw_rate, frame))

    def send_led_rgb(self, sysid: int, r: int, g: int, b: int,
                     blink_hz: int | None = None) -> None:
        """LED_CONTROL colour to ``sysid``; 0 sends a broadcast copy to every vehicle."""
        msg = messages.led_rgb(sysid, r, g, b, blink_hz)
        if sysid == 0:
            self._broadcast(msg)
        else:
            self._send(sysid, msg)

    async def set_param(self, sysid: int, name: str, value: float, *, timeout: float = 1.0,
                        attempts: int = 3) -> bool:
        """Set a float parameter on ``sysid``: PARAM_SET until its PARAM_VALUE echoes the
        value (``timeout`` seconds of the link's clock per attempt); True if confirmed."""
        state = self.vehicles.get(sysid)
        if state is None:
            raise LinkError(f"vehicle {sysid} has not been heard")
        for _ in range(attempts):
            state.params.pop(name, None)
            self._send(sysid, messages.param_set(sysid, name, value))
            deadline = self.clock.now() + timeout
            while self.clock.now() < deadline:
                got = state.params.get(name)
                if got is not None and math.isclose(got, value, rel_tol=1e-6, abs_tol=1e-6):
                    self._emit("param_set", system_id=sysid, name=name, value=value)
                    return True
                await asyncio.sleep(self.clock.wall_interval(0.02))
        return False

    def subscribe(self, sysid: int, listener: Callable[[mavlink.MAVLink_message, float], None]
               ) -> Callable[[], None]:
        """Call ``listener(msg, now)`` with every trusted message from ``sysid`` (a protocol
        client: parameters, fence upload); returns the function that stops it."""
        self._listeners.setdefault(sysid, []).append(listener)

        def stop() -> None:
            with contextlib.suppress(KeyError, ValueError):
                self._listeners[sysid].remove(listener)
        return stop

    def send_message(self, sysid: int, msg: mavlink.MAVLink_message) -> None:
        """Send any message object to vehicle ``sysid`` (escape hatch)."""
        self._send(sysid, msg)


def _is_address(value: object) -> bool:
    """Whether ``value`` is one (host, port) rather than a list of them."""
    return isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], str)


def _resolve(host: str) -> str:
    """A fleet file's host as packets will show it: an IP literal as it is, a name
    resolved once (IPv4), or the name itself if it does not resolve."""
    try:
        return str(ipaddress.ip_address(host))
    except ValueError:
        pass
    try:
        return socket.gethostbyname(host)
    except OSError:
        log.warning("fleet file host %r does not resolve: no packet can match it", host)
        return host
