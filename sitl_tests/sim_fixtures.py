"""A small ground-station peer and fleet factories for the simulator tests.

The peer is a real UDP socket on 127.0.0.1 (port 0: tests run in parallel)
with its own pymavlink codec; it records everything it receives so a test can
wait for a message and then look at what came before it.  No mocks: the
vehicles under test are the simulator's, over loopback UDP.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import ManualClock, ScaledClock
from groundctl.link.flavours import Flavour, mode_request
from groundctl.sim import SimConfig, SimFleet

Msg = mavlink.MAVLink_message

#: Short boot delays for tests (the real SITL figures are 20 s and 40 s).
FAST_BOOT = {"ekf_origin_delay_s": 0.5, "ready_delay_s": 1.0}


@dataclass
class Received:
    """One message as the peer got it."""

    wall: float
    msg: Msg
    consumed: bool = False


@dataclass
class GcsPeer:
    """A ground station on loopback UDP with a pymavlink codec of its own."""

    sysid: int = 255
    compid: int = 190
    signing_key: bytes | None = None
    pump: Callable[[], None] | None = None
    """Called between receive attempts (steps a ManualClock fleet); None: wall-clock waits."""
    history: list[Received] = field(default_factory=list)
    addrs: dict[int, tuple[str, int]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # Big receive buffer: a ManualClock test may run many simulated seconds between reads.
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.mav = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=self.compid)
        self.mav.robust_parsing = True
        if self.signing_key is not None:
            self.mav.signing.secret_key = self.signing_key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)

    @property
    def address(self) -> tuple[str, int]:
        """Where vehicles should send (pass as ``SimConfig.gcs``)."""
        host, port = self.sock.getsockname()
        return host, port

    def close(self) -> None:
        self.sock.close()

    # -- sending ------------------------------------------------------------------------------

    def send(self, msg: Msg, sysid: int = 1, raw: bytes | None = None) -> None:
        """Encode and send ``msg`` (or ``raw`` bytes) to vehicle ``sysid``."""
        data = raw if raw is not None else msg.pack(self.mav)
        if raw is None:
            self.mav.seq = (self.mav.seq + 1) % 256
        self.sock.sendto(data, self.addrs[sysid])

    def heartbeat(self, sysid: int = 1) -> None:
        self.send(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3), sysid)

    def command_long(self, sysid: int, command: int, *params: float,
                     timeout: float = 5.0) -> Msg:
        """Send COMMAND_LONG and return its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mavlink.MAVLink_command_long_message(sysid, 1, command, 0, *p), sysid)
        return self.wait("COMMAND_ACK", sysid,
                         lambda m: m.command == command, timeout=timeout)

    def set_mode(self, sysid: int, flavour: Flavour, name: str, timeout: float = 5.0) -> Msg:
        req = mode_request(flavour, name)
        return self.command_long(sysid, mavlink.MAV_CMD_DO_SET_MODE, req.param1, req.param2,
                                 req.param3, timeout=timeout)

    def arm(self, sysid: int, arm: bool = True, timeout: float = 5.0) -> Msg:
        return self.command_long(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                 1.0 if arm else 0.0, timeout=timeout)

    def set_interval(self, sysid: int, msgid: int, hz: float) -> Msg:
        return self.command_long(sysid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msgid,
                                 1e6 / hz if hz > 0 else -1)

    def setpoint_local(self, sysid: int, type_mask: int, pos: tuple[float, float, float] = (
            0, 0, 0), vel: tuple[float, float, float] = (0, 0, 0),
            acc: tuple[float, float, float] = (0, 0, 0),
            frame: int = mavlink.MAV_FRAME_LOCAL_NED) -> None:
        self.send(mavlink.MAVLink_set_position_target_local_ned_message(
            0, sysid, 1, frame, type_mask, *pos, *vel, *acc, 0.0, 0.0), sysid)

    # -- receiving ----------------------------------------------------------------------------

    def _recv(self, block: float) -> None:
        if block > 0:
            self.sock.settimeout(block)
        else:
            self.sock.setblocking(False)
        try:
            while True:
                data, addr = self.sock.recvfrom(65535)
                now = time.monotonic()
                msgs = self.mav.parse_buffer(data) or []
                for m in msgs:
                    if m.get_type() == "BAD_DATA":
                        continue
                    self.addrs.setdefault(m.get_srcSystem(), addr)
                    self.addrs[m.get_srcSystem()] = addr
                    self.history.append(Received(now, m))
                self.sock.setblocking(False)
        except (BlockingIOError, TimeoutError):
            pass
        finally:
            self.sock.setblocking(False)

    def poll(self, seconds: float = 0.0) -> None:
        """Receive for ``seconds`` (wall, or pump steps with a ManualClock fleet)."""
        end = time.monotonic() + seconds
        while True:
            if self.pump is not None:
                self.pump()
                self._recv(0)
            else:
                self._recv(min(0.02, max(0.0, end - time.monotonic())))
            if time.monotonic() >= end:
                return

    def find(self, mtype: str, sysid: int | None = None,
             cond: Callable[[Msg], bool] | None = None, consume: bool = True) -> Msg | None:
        """The first unconsumed received message that matches, or None."""
        for r in self.history:
            m = r.msg
            if r.consumed or m.get_type() != mtype:
                continue
            if sysid is not None and m.get_srcSystem() != sysid:
                continue
            if cond is not None and not cond(m):
                continue
            r.consumed = consume
            return m
        return None

    def wait(self, mtype: str, sysid: int | None = None,
             cond: Callable[[Msg], bool] | None = None, timeout: float = 5.0,
             steps: int = 100_000) -> Msg:
        """Wait for a matching message (wall ``timeout``, or ``steps`` pumps)."""
        end = time.monotonic() + timeout
        for _ in range(steps):
            m = self.find(mtype, sysid, cond)
            if m is not None:
                return m
            if time.monotonic() > end:
                break
            if self.pump is not None:
                self.pump()
                self._recv(0)
            else:
                self._recv(0.02)
        raise AssertionError(f"no {mtype} from {sysid} within {timeout} s")

    def all(self, mtype: str, sysid: int | None = None) -> list[Msg]:
        """Every received message of a type (consumed or not)."""
        return [r.msg for r in self.history if r.msg.get_type() == mtype
                and (sysid is None or r.msg.get_srcSystem() == sysid)]

    def clear(self) -> None:
        """Forget what was received so far (reading what is already queued first)."""
        self._recv(0)
        self.history.clear()


def wait_until(pred: Callable[[], bool], timeout: float = 10.0, what: str = "condition") -> None:
    """Poll ``pred`` every 10 ms of wall time."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.01)
    raise AssertionError(f"{what} not reached within {timeout} s")


@contextlib.contextmanager
def running_fleet(count: int = 1, flavour: Flavour = Flavour.ARDUPILOT, speed: float = 10.0,
                  peer: GcsPeer | None = None, **config: object) -> Iterator[tuple[SimFleet,
                                                                                   GcsPeer]]:
    """A started fleet on a ScaledClock and a ground-station peer that heard every vehicle."""
    peer = peer or GcsPeer()
    opts: dict[str, object] = {**FAST_BOOT, **config}
    cfg = SimConfig(count=count, flavour=flavour, gcs=peer.address, **opts)  # type: ignore[arg-type]
    fleet = SimFleet(cfg, ScaledClock(speed))
    try:
        fleet.start()
        for sid in fleet.sysids:
            peer.wait("HEARTBEAT", sid, timeout=5.0)
        yield fleet, peer
    finally:
        fleet.stop()
        peer.close()


@contextlib.contextmanager
def manual_fleet(count: int = 1, flavour: Flavour = Flavour.ARDUPILOT,
                 peer: GcsPeer | None = None, **config: object) -> Iterator[tuple[SimFleet,
                                                                                  GcsPeer]]:
    """A fleet on a ManualClock; the peer's waits step it one physics tick at a time."""
    peer = peer or GcsPeer()
    opts: dict[str, object] = {**FAST_BOOT, **config}
    cfg = SimConfig(count=count, flavour=flavour, gcs=peer.address, **opts)  # type: ignore[arg-type]
    fleet = SimFleet(cfg, ManualClock())
    peer.pump = lambda: fleet.step(fleet.dt)
    try:
        for sid in fleet.sysids:
            peer.wait("HEARTBEAT", sid, steps=200)
        yield fleet, peer
    finally:
        fleet.stop()
        peer.close()


def ready_and_flying(fleet: SimFleet, peer: GcsPeer, sysid: int = 1, alt: float = 5.0,
                     timeout: float = 20.0) -> None:
    """ArduPilot: wait until armable, GUIDED, arm, NAV_TAKEOFF to ``alt`` and wait there."""
    wait_until(lambda: fleet.time > fleet.config.ready_delay_s + 0.1, timeout, "ready")
    assert peer.set_mode(sysid, Flavour.ARDUPILOT, "GUIDED").result == 0
    assert peer.arm(sysid).result == 0
    ack = peer.command_long(sysid, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt)
    assert ack.result == 0
    home_z = fleet.vehicles[fleet.sysids.index(sysid)].home_enu[2]
    wait_until(lambda: fleet.state(sysid).position[2] - home_z > alt - 0.15, timeout, "takeoff")
