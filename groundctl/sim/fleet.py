"""The simulated fleet: physics + one MAVLink endpoint and UDP socket per vehicle + the loop.

Two ways to drive it:

* real time (scaled): ``SimFleet(config, ScaledClock(speed)).start()`` runs a
  background thread that owns the sockets; ``stop()`` joins it and closes
  them.  ``with SimFleet(...) as fleet:`` does both.
* deterministic: with a :class:`~groundctl.clock.ManualClock`, call
  :meth:`SimFleet.step` / :meth:`SimFleet.run_until` from the test's thread;
  the clock is advanced one physics tick at a time and sockets are polled
  without blocking.

Per physics tick: read every socket (link faults may drop, delay or duplicate
each datagram), hand due packets to their vehicle, apply scheduled faults,
step the physics, run every vehicle's timers, send what they produced
(through the link faults again).  Everything is in simulated time, so with
speed K the whole fleet, streams and timeouts included, runs K times faster.
"""

from __future__ import annotations

import contextlib
import heapq
import logging
import math
import selectors
import socket
import threading
import time
from collections.abc import Callable, Sequence
from types import TracebackType

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import HELD_POLL_S, Clock, ManualClock, ScaledClock
from groundctl.errors import SimulatorError
from groundctl.link.flavours import Flavour
from groundctl.sim.ardupilot import ArduPilotVehicle
from groundctl.sim.codec import VehicleCodec
from groundctl.sim.config import SimConfig
from groundctl.sim.faults import FaultEvent, FaultKind, Jitter, LinkFaults
from groundctl.sim.frames import FleetFrames
from groundctl.sim.physics import FleetPhysics
from groundctl.sim.px4 import PX4Vehicle
from groundctl.sim.state import VehicleState
from groundctl.sim.vehicle import Vehicle

log = logging.getLogger(__name__)

#: Largest number of physics ticks run in one go when the loop falls behind; beyond
#: that the loop is not keeping real time and skips ahead (counted in ``overruns``).
MAX_CATCHUP_TICKS = 25


class SimFleet:
    """N simulated vehicles on loopback UDP, driven by an injected clock.

    Sockets are bound on construction, so :attr:`ports` is known before
    :meth:`start`.  All public methods are thread-safe.

    ``boot_text``: each vehicle first sends its autopilot's boot text as raw
    datagrams (ArduPilot SITL prints "Init ArduCopter ..." on its MAVLink port
    before MAVLink starts; PX4 has none), which a ground station must count as
    bad packets and ignore.
    """

    def __init__(self, config: SimConfig, clock: Clock | None = None, *,
                 boot_text: bool | None = None) -> None:
        self.config = config
        boot_text = config.boot_text if boot_text is None else boot_text
        self.boot_text = boot_text
        """Whether the vehicles send their boot text before MAVLink."""
        self._boot_text_due = boot_text
        self.clock: Clock = clock if clock is not None else ScaledClock(1.0)
        self.dt = 1.0 / config.physics_rate_hz
        # (a third stream, not a longer first one: adding it left the others' draws as
        # they were)
        seeds = np.random.SeedSequence(config.seed).spawn(3)
        self._link_rng = np.random.default_rng(seeds[1])
        homes = config.homes_enu()
        self.frames = FleetFrames.build(
            config.origin, homes,
            list(config.ekf_origins) if config.ekf_origins is not None else None)
        self.physics = FleetPhysics(homes, config.resolved_dynamics(),
                                    np.random.default_rng(seeds[0]), config.wind,
                                    config.gust_std, config.gps_noise_m,
                                    np.random.default_rng(seeds[2]))
        self.sysids = config.sysids()
        self.t = self.clock.now()
        self.boot_time = self.t
        # A dry-run's paced clock waits for this fleet from the moment it has vehicles,
        # not from its loop's first report: it ran free meanwhile, and on a busy machine at
        # x60 the fleet's first heartbeats then came seconds of clock behind it (seven
        # vehicles "lost" before the flight began, silent 3 s that were 50 ms of wall).
        self.clock.idle_until(self.t)
        unix = time.time()
        cls: type[Vehicle] = (ArduPilotVehicle if config.flavour is Flavour.ARDUPILOT
                              else PX4Vehicle)
        local = config.local_ids()  # on the wire; self.sysids names them (vehicle ids)
        self.vehicles: list[Vehicle] = [
            cls(i, sid, config, self.physics, self.frames, self.boot_time, unix)
            for i, sid in enumerate(local)]
        self.codecs = [VehicleCodec(sid, config.signing_key) for sid in local]
        self._links: list[LinkFaults] = [config.link_faults] * config.count
        # Each link direction's wandering queueing delay: (to the vehicle, from it).
        self._jitter = [(Jitter(), Jitter()) for _ in range(config.count)]
        # ... and when its last delayed datagram is due, on the clock: the jitter keeps
        # each direction first in, first out in the link's own time base, and a due time
        # rounded a hair earlier in the clock's would let a datagram overtake the one
        # before it (bursts sent back to back on a busy machine: 3 in 1,700 reordered).
        self._last_due = [[-math.inf, -math.inf] for _ in range(config.count)]
        self._gcs: list[tuple[str, int]] = [config.gcs_of(i) for i in range(config.count)]
        self._lock = threading.RLock()
        self._inbox: list[tuple[float, int, int, bytes, tuple[str, int]]] = []
        # Messages that arrived, to be acted on once the physics gets there: (arrival on the
        # clock, order, vehicle index, messages).
        self._arrived: list[tuple[float, int, int, list[mavlink.MAVLink_message]]] = []
        self._outbox: list[tuple[float, int, int, bytes]] = []
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = 0
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self.overruns = 0
        """Times the loop fell more than MAX_CATCHUP_TICKS behind and skipped ahead."""
        self.max_lag = 0.0
        """Largest delay (simulated s) between the clock and the physics seen by the loop."""
        self.send_errors = 0
        """Datagrams the OS refused to send."""
        self._sockets: list[socket.socket] = []
        self._selector = selectors.DefaultSelector()
        self._closed = False
        try:
            for i in range(config.count):
                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self._sockets.append(sock)
                sock.setblocking(False)
                port = config.base_port + i if config.base_port else 0
                sock.bind((config.bind_host, port))
                self._selector.register(sock, selectors.EVENT_READ, i)
        except OSError as exc:
            self.close()
            raise SimulatorError(
                f"cannot bind vehicle socket {len(self._sockets)} on "
                f"{config.bind_host}:{config.base_port or 0}: {exc}") from exc

    # -- facts --------------------------------------------------------------------------------

    @property
    def ports(self) -> list[int]:
        """UDP port of each vehicle's socket, in vehicle order."""
        return [s.getsockname()[1] for s in self._sockets]

    @property
    def addresses(self) -> dict[int, tuple[str, int]]:
        """System id -> (host, port) of the vehicle's socket."""
        return {sid: s.getsockname() for sid, s in zip(self.sysids, self._sockets, strict=True)}

    @property
    def time(self) -> float:
        """Simulated seconds since the fleet booted (as far as the physics got)."""
        return self.t - self.boot_time

    def snapshot(self) -> list[VehicleState]:
        """Every vehicle's state now, as frozen values (safe from any thread)."""
        with self._lock:
            ph = self.physics
            out = []
            for i, v in enumerate(self.vehicles):
                c = self.codecs[i].counters
                out.append(VehicleState(
                    sysid=self.sysids[i], port=self._sockets[i].getsockname()[1],
                    time=self.time,
                    position=_t3(ph.pos[i]), velocity=_t3(ph.ground_vel[i]),
                    estimated_position=_t3(ph.est_pos[i]), armed=v.armed, mode=v.mode,
                    landed=bool(ph.on_ground[i]), crashed=bool(ph.crashed[i]), led=v.led,
                    led_blink_hz=v.led_blink_hz,
                    battery=float(ph.battery[i]),
                    gcs_address=self._gcs[i], packets_in=c.packets_in,
                    packets_out=c.packets_out, bad_packets=c.bad_packets,
                    rejected_signature=c.rejected_signature,
                    setpoints_dropped=v.setpoints_dropped))
            return out

    def truth(self) -> tuple[np.ndarray, list[tuple[tuple[int, int, int], float | None]]]:
        """What only the simulator knows, cheaply (no snapshot objects), in vehicle order.

        The (count, 3) true show-frame ENU positions (a copy), and each LED's colour
        with the clock time it last changed (None: never set).
        """
        with self._lock:
            return (self.physics.pos.copy(),
                    [(v.led, v.led_changed_at) for v in self.vehicles])

    def rtk_stats(self) -> dict[int, dict[str, int]]:
        """System id -> RTCM frames received intact / bad, distinct frames, fix type now."""
        with self._lock:
            return {sid: {**v.rtk.stats(), "fix_type": v.gps_fix(self.t)}
                    for sid, v in zip(self.sysids, self.vehicles, strict=True)}

    def state(self, sysid: int) -> VehicleState:
        """Snapshot of the (first) vehicle with system id ``sysid``."""
        i = int(self._indices(sysid)[0])
        return self.snapshot()[i]

    def _indices(self, sysid: int | None) -> np.ndarray:
        if sysid is None:
            return np.arange(len(self.vehicles))
        idx = np.flatnonzero(np.asarray(self.sysids) == sysid)
        if idx.size == 0:
            raise SimulatorError(f"no simulated vehicle has system id {sysid}; "
                                 f"the fleet has {self.sysids[0]}..{self.sysids[-1]}")
        return idx

    # -- faults -------------------------------------------------------------------------------

    def set_link_faults(self, faults: LinkFaults, sysid: int | None = None) -> None:
        """Apply ``faults`` to one vehicle's link (or every vehicle's)."""
        with self._lock:
            for i in self._indices(sysid):
                self._links[i] = faults

    def link_faults(self, sysid: int) -> LinkFaults:
        """The link faults currently applied to vehicle ``sysid``."""
        return self._links[int(self._indices(sysid)[0])]

    def cut_link(self, sysid: int | None = None, at: float | None = None,
                 restore_at: float | None = None) -> None:
        """Cut the link both ways at simulated time ``at`` (None: now) until ``restore_at``."""
        with self._lock:
            start = self.time if at is None else at
            for i in self._indices(sysid):
                old = self._links[i]
                self._links[i] = LinkFaults(old.loss, old.latency_ms, old.jitter_ms,
                                            old.duplicate, start, restore_at)

    def inject(self, event: FaultEvent) -> None:
        """Schedule a physical fault (applied at ``event.at``, simulated s since boot)."""
        with self._lock:
            idx = self._indices(event.sysid)
            self._add_timer(self.boot_time + event.at, lambda: self._apply(event, idx))

    def gps_glitch(self, offset: Sequence[float], sysid: int | None = None,
                   at: float | None = None, duration: float | None = None) -> None:
        """The position estimate jumps by ``offset`` (ENU m); the vehicle flies off by -offset."""
        self.inject(FaultEvent(FaultKind.GPS_GLITCH, self._at(at), sysid, _v3(offset), duration))

    def refuse_arming(self, sysid: int | None = None, times: int = 1,
                      reason: str = "PreArm: Gyros inconsistent") -> None:
        """The next ``times`` arm commands are refused with ``reason`` (an arming-time check
        that SYS_STATUS's pre-arm bit did not show, as real autopilots have)."""
        with self._lock:
            for i in self._indices(sysid):
                self.vehicles[int(i)].arm_refusals.extend([reason] * times)

    def lose_acks(self, command: int, sysid: int | None = None, times: int = 1) -> None:
        """The next ``times`` COMMAND_ACKs for ``command`` are lost on the way: the
        command is carried out (or refused), its answer never arrives."""
        with self._lock:
            for i in self._indices(sysid):
                lost = self.vehicles[int(i)].lost_acks
                lost[command] = lost.get(command, 0) + times

    def motor_failure(self, sysid: int | None = None, at: float | None = None) -> None:
        """Thrust lost: the vehicle falls (and is disarmed by its crash check on impact)."""
        self.inject(FaultEvent(FaultKind.MOTOR_FAILURE, self._at(at), sysid))

    def low_battery(self, remaining: float = 0.1, sysid: int | None = None,
                    at: float | None = None) -> None:
        """The battery drops to ``remaining`` (fraction) at once."""
        self.inject(FaultEvent(FaultKind.LOW_BATTERY, self._at(at), sysid, value=remaining))

    def gust(self, wind: Sequence[float], duration: float, sysid: int | None = None,
             at: float | None = None) -> None:
        """Extra wind ``wind`` (ENU m/s) for ``duration`` s."""
        self.inject(FaultEvent(FaultKind.GUST, self._at(at), sysid, _v3(wind), duration))

    def push(self, offset: Sequence[float], sysid: int | None = None, at: float | None = None,
             duration: float = 1.0) -> None:
        """Displace the vehicle by ``offset`` (ENU m) over ``duration`` s."""
        self.inject(FaultEvent(FaultKind.PUSH, self._at(at), sysid, _v3(offset), duration))

    def weaken(self, factor: float, sysid: int | None = None, at: float | None = None) -> None:
        """Scale the vehicle's speed and acceleration authority by ``factor`` (0, 1]."""
        self.inject(FaultEvent(FaultKind.WEAK, self._at(at), sysid, value=factor))

    def _at(self, at: float | None) -> float:
        return self.time if at is None else float(at)

    def _add_timer(self, when: float, fn: Callable[[], None]) -> None:
        self._seq += 1
        heapq.heappush(self._timers, (when, self._seq, fn))

    def _apply(self, ev: FaultEvent, idx: np.ndarray) -> None:
        ph = self.physics
        vec = np.asarray(ev.vector, dtype=float)
        if ev.kind is FaultKind.MOTOR_FAILURE:
            ph.motor_failed[idx] = True
        elif ev.kind is FaultKind.LOW_BATTERY:
            ph.battery[idx] = np.minimum(ph.battery[idx], ev.value)
        elif ev.kind is FaultKind.WEAK:
            ph.authority[idx] = ev.value
        elif ev.kind is FaultKind.PUSH:
            # Carried, not flown: moved at vector / duration for ``duration`` whatever its
            # autopilot does (which sees its position error grow and fights it back).
            duration = ev.duration or 1.0
            rate = vec / duration
            ph.carry[idx] += rate

            def release(rate: np.ndarray = rate) -> None:
                ph.carry[idx] -= rate
            self._add_timer(self.boot_time + ev.at + duration, release)
        else:
            target = ph.glitch if ev.kind is FaultKind.GPS_GLITCH else ph.gust_extra
            target[idx] += vec
            if ev.duration is not None:
                end = self.boot_time + ev.at + ev.duration

                def undo(target: np.ndarray = target) -> None:
                    target[idx] -= vec
                self._add_timer(end, undo)

    # -- lifecycle ----------------------------------------------------------------------------

    def start(self) -> SimFleet:
        """Run the fleet in a background thread until :meth:`stop`."""
        if isinstance(self.clock, ManualClock):
            raise SimulatorError("a fleet on a ManualClock is driven by step()/run_until(), "
                                 "not start()")
        if self._closed:
            raise SimulatorError("this fleet was stopped; build a new one")
        if self._thread is not None:
            raise SimulatorError("the fleet is already running")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="groundctl-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the loop thread (if running), close every socket; idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        self.close()
        if self._error is not None:
            err, self._error = self._error, None
            raise SimulatorError(f"the simulator loop failed: {err!r}") from err

    def close(self) -> None:
        """Close the sockets (the fleet cannot run afterwards)."""
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(OSError, RuntimeError, KeyError):
            self._selector.close()
        for sock in self._sockets:
            sock.close()

    @property
    def running(self) -> bool:
        """Whether the background loop is alive."""
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> SimFleet:
        if not isinstance(self.clock, ManualClock):
            self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    # -- deterministic driving ----------------------------------------------------------------

    def step(self, dt: float) -> None:
        """Advance ``dt`` simulated seconds now, in this thread (ManualClock fleets)."""
        if dt < 0:
            raise ValueError("`dt` must be non-negative")
        if self.running:
            raise SimulatorError("step() while the background loop runs; stop() it first")
        if self._closed:
            raise SimulatorError("this fleet was stopped; build a new one")
        target = self.t + dt
        with self._lock:
            while self.t + self.dt <= target + 1e-9:
                # The step reads what arrived up to its start, then the clock moves on to
                # its end (a message sent before step() is in it, not the next one).
                self._tick()
                if isinstance(self.clock, ManualClock):
                    self.clock.advance(max(0.0, self.t - self.clock.now()))

    def run_until(self, t: float) -> None:
        """Advance until simulated time ``t`` (seconds since boot)."""
        self.step(max(0.0, t - self.time))

    # -- the loop -----------------------------------------------------------------------------

    def _run(self) -> None:
        held = math.nan
        try:
            while not self._stop.is_set():
                now = self.clock.now()
                with self._lock:
                    behind = int((now - self.t) / self.dt)
                    if behind > MAX_CATCHUP_TICKS:
                        self.overruns += 1
                        self.t = now - MAX_CATCHUP_TICKS * self.dt
                    while self.t + self.dt <= now:
                        self._tick()
                    self.max_lag = max(self.max_lag, self.clock.now() - self.t - self.dt)
                # Nothing to do before the next physics tick (a paced dry-run clock waits
                # for us no further than that).
                self.clock.idle_until(self.t + self.dt)
                now = self.clock.now()
                wait = self.clock.wall_interval(self.t + self.dt - now)
                if now == held:
                    # The clock has not moved since the last look: a paced clock waits
                    # for someone else.  No polling it at the physics rate meanwhile.
                    wait = max(wait, HELD_POLL_S)
                held = now
                if wait > 0:
                    if self._selector.select(wait):
                        # Packets arrived between ticks: answer now rather than at the
                        # next tick.
                        with self._lock:
                            self._receive(self.t)
                else:
                    # Behind: let the other threads (the parent's calls: truth, faults) have
                    # the lock between catch-ups; CPython's locks are not fair, and a loop
                    # that takes its lock straight back starved them for seconds.
                    time.sleep(0)
        except Exception as exc:  # pragma: no cover - reported by stop()
            log.exception("simulator loop failed")
            self._error = exc
        finally:
            self.clock.idle_until(math.inf)

    def _tick(self) -> None:
        now = self.t
        if self._boot_text_due:
            self._boot_text_due = False
            for i, v in enumerate(self.vehicles):
                for line in v.boot_lines():
                    self._queue(i, line, now)
        self._receive(now)
        while self._timers and self._timers[0][0] <= now:
            heapq.heappop(self._timers)[2]()
        self.physics.step(self.dt)
        self.t = now = now + self.dt
        for i, v in enumerate(self.vehicles):
            out = v.tick(now)
            if out:
                self._send(i, out, now)
        self._flush_outbox(now)

    def _receive(self, now: float) -> None:
        # A datagram's latency runs from when it really arrived: when the physics
        # lags the clock (a loaded machine), stamping it with the physics time
        # would shorten the latency by the lag (and the link's queue, first in first
        # out, is kept in the same time as the delivery is scheduled in).
        read_at = max(now, self.clock.now())
        rel = read_at - self.boot_time
        # What the link delayed, as it arrives on the clock (not as the physics gets there:
        # a TIMESYNC answer must not wait for a lagging physics).
        while self._inbox and self._inbox[0][0] <= read_at:
            due, _, i, data, addr = heapq.heappop(self._inbox)
            self._deliver(i, data, addr, now, due, read_at)
        for key, _ in self._selector.select(0):
            i = key.data
            sock = self._sockets[i]
            link = self._links[i]
            while True:
                try:
                    data, addr = sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    break  # e.g. an ICMP error reported on the socket: nothing to read
                for delay in link.deliveries(rel, self._link_rng, self._jitter[i][0]):
                    due = self._last_due[i][0] = max(read_at + delay, self._last_due[i][0])
                    if due <= read_at:
                        self._deliver(i, data, addr, now, read_at, read_at)
                    else:
                        self._seq += 1
                        heapq.heappush(self._inbox, (due, self._seq, i, data, addr))
        # Acted on in the order they arrived, from the first step at or after arrival.
        while self._arrived and self._arrived[0][0] <= now:
            arrived, _, i, msgs = heapq.heappop(self._arrived)
            self._handle(i, msgs, now, age=max(now - arrived, 0.0))

    def _deliver(self, i: int, data: bytes, addr: tuple[str, int], now: float,
                 arrived: float, read_at: float) -> None:
        """Datagram ``data`` reached vehicle ``i`` at clock time ``arrived`` and is read at
        ``read_at``; the physics is at ``now``.

        The vehicle's own clock never lags: a TIMESYNC request is answered at once, with
        the clock's time as it is read (the physics' last step was up to a step and the
        physics' lag behind: read as the ground station's clock offset, it dated every
        sample carried to "now" that much wrong).  The rest is acted on from the first
        physics step at or after its arrival, never before: a message arrives between two
        steps, and the physics lags a clock that ran on (a busy machine).  A setpoint taken
        at the step before flew the vehicle ahead of its plan (by up to a step; on a busy
        machine by the whole lag: the dry-run at x60 140-190 ms ahead, and MPC set off by
        it), and its response to setpoints read as negative (issue 33)."""
        msgs = self.codecs[i].decode(data)
        if not msgs:
            return
        # Like a real autopilot's UDP link: reply to whoever last talked to us.
        self._gcs[i] = addr
        timesync = [m for m in msgs if m.get_type() == "TIMESYNC"]
        if timesync:
            self._handle(i, timesync, read_at)
            msgs = [m for m in msgs if m.get_type() != "TIMESYNC"]
            if not msgs:
                return
        self._seq += 1
        heapq.heappush(self._arrived, (arrived, self._seq, i, msgs))

    def _handle(self, i: int, msgs: list[mavlink.MAVLink_message], now: float,
                age: float = 0.0) -> None:
        """Vehicle ``i`` acts on ``msgs`` at physics time ``now``; they arrived ``age``
        seconds before (between two physics steps)."""
        vehicle = self.vehicles[i]
        for msg in msgs:
            out = vehicle.handle(msg, now, age)
            if out:
                self._send(i, out, now)

    def _send(self, i: int, msgs: list[mavlink.MAVLink_message], now: float) -> None:
        codec = self.codecs[i]
        for msg in msgs:
            self._queue(i, codec.encode(msg), now)

    def _queue(self, i: int, data: bytes, now: float) -> None:
        """Send one datagram of vehicle ``i`` through its link faults."""
        link = self._links[i]
        if link.is_clean:
            self._sendto(i, data)
            return
        # The link's delay runs from when the datagram really leaves, on the clock, and its
        # queue (first in, first out) is kept in that time too: a physics lagging the clock
        # shortened the latency by the lag (a TIMESYNC answer came back sooner than the link
        # allows), and a physics catching up let later datagrams overtake earlier ones.
        left = max(now, self.clock.now())
        for delay in link.deliveries(left - self.boot_time, self._link_rng,
                                     self._jitter[i][1]):
            due = self._last_due[i][1] = max(left + delay, self._last_due[i][1])
            if due <= left:
                # Not ahead of what is due and still waits for the step's end (first in,
                # first out: those of this vehicle all are, when nothing is later).  A
                # burst answered between steps overtook them: 31 parameters behind the
                # next 24, read as a second sender's packets on a busy machine.
                self._flush_outbox(left)
                self._sendto(i, data)
            else:
                self._seq += 1
                heapq.heappush(self._outbox, (due, self._seq, i, data))

    def _flush_outbox(self, now: float) -> None:
        """Send what the link delayed and is due on the clock (not on the physics, which
        may lag it)."""
        if not self._outbox:
            return
        due = max(now, self.clock.now())
        while self._outbox and self._outbox[0][0] <= due:
            _, _, i, data = heapq.heappop(self._outbox)
            self._sendto(i, data)

    def _sendto(self, i: int, data: bytes) -> None:
        try:
            self._sockets[i].sendto(data, self._gcs[i])
        except OSError:
            self.send_errors += 1


def _t3(a: np.ndarray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _v3(v: Sequence[float]) -> tuple[float, float, float]:
    if len(v) != 3:
        raise ValueError(f"expected 3 components (east, north, up), got {len(v)}")
    return (float(v[0]), float(v[1]), float(v[2]))
