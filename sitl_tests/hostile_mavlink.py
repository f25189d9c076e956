"""Hostile MAVLink against a flying dry-run, and what it changed.

A seeded generator of hostile datagrams (:class:`Hostile`) sent at the ground
station of a real dry-run (:func:`fly_fuzzed`: the quick show against the
simulator over loopback UDP, exactly as ``groundctl dry-run`` flies it), while
a watcher compares what the ground station believes about every vehicle with
the simulator's truth.  Every MAVLink byte is pymavlink's; every datagram goes
to 127.0.0.0/8 only (checked before each send).

Kinds of datagram:

* ``random``: random bytes; ``truncated``: a valid packet cut short; ``bitflip``:
  a valid packet with a few bits flipped;
* ``spoofed``: a valid packet under a vehicle's system id (HEARTBEAT with another
  mode or disarmed, EKF origin, home, positions, battery, landed state, ACKs,
  STATUSTEXT, TIMESYNC, parameters) from a port of the attacker's own;
* ``forged``: the same from the vehicle's own address and port (a raw socket: needs
  CAP_NET_RAW, skipped otherwise), numbered either at random or as the vehicle's
  next packet (learnt by sniffing the loopback, also a raw socket);
* ``wrong_key``: signed with a key that is not the fleet's, timestamps now or ahead;
* ``replay``: a genuine packet of a vehicle sniffed earlier, sent again (from its
  own address or another);
* ``stray``: HEARTBEATs of system ids that are not in the show.

Used by ``benchmarks/fuzz_mavlink.py`` (the figures) and
``sitl_tests/test_fuzz_mavlink.py`` (a small seeded run).
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import math
import socket
import struct
import time
import traceback
from collections import Counter, deque
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.execute.frames import enu_to_show, ned_to_show, show_to_enu
from groundctl.flight.dryrun import DryRunOptions, fly_dry_run
from groundctl.flight.runner import ShowRunner
from groundctl.link.flavours import COPTER_MODES, Flavour
from groundctl.link.signing import signing_timestamp
from groundctl.plan.plan import Plan
from groundctl.sim.process import SimProcess

Address = tuple[str, int]

LOOPBACK = ipaddress.ip_network("127.0.0.0/8")

#: The fleet's key in the signed runs (any 32 bytes: it is a test).
FLEET_KEY = bytes(range(100, 132))

KINDS = ("random", "truncated", "bitflip", "spoofed", "forged", "wrong_key", "replay", "stray")
#: How often each kind is drawn (forged/replay fall back to spoofed without raw sockets).
WEIGHTS = (0.10, 0.08, 0.10, 0.22, 0.26, 0.10, 0.09, 0.05)


def _check_loopback(addr: Address) -> None:
    if ipaddress.ip_address(addr[0]) not in LOOPBACK:
        raise ValueError(f"refusing to send to {addr[0]}: loopback (127.0.0.0/8) only")


@cache
def quick_plan() -> Plan:
    """The bundled 9-drone quick show, planned once per process."""
    from groundctl.plan.planner import plan_show
    from groundctl.show.loader import load_show

    show = Path(__file__).resolve().parents[1] / "shows" / "quick.toml"
    return plan_show(load_show(show), workers=1).plan


class RawUdp:
    """UDP datagrams with a forged source address and port, on loopback only."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    @classmethod
    def open(cls) -> RawUdp | None:
        """A raw IPv4 socket, or None where this process may not open one (not root)."""
        try:
            return cls(socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW))
        except OSError:
            return None

    def send(self, data: bytes, src: Address, dst: Address) -> None:
        _check_loopback(src)
        _check_loopback(dst)
        # IPv4 header (the kernel fills in length, id and checksum) + UDP header with
        # checksum 0 (none: allowed over IPv4).
        ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 0, 0, 0, 64, socket.IPPROTO_UDP, 0,
                         socket.inet_aton(src[0]), socket.inet_aton(dst[0]))
        udp = struct.pack("!HHHH", src[1], dst[1], 8 + len(data), 0)
        with contextlib.suppress(OSError):
            self.sock.sendto(ip + udp + data, (dst[0], 0))

    def close(self) -> None:
        self.sock.close()


class Sniffer:
    """Copies of the vehicles' datagrams to the ground station (a raw IPPROTO_UDP socket
    sees every UDP datagram the host receives): what a sniffing attacker learns."""

    def __init__(self, sock: socket.socket, gcs_port: int, vehicles: dict[int, int]) -> None:
        self.sock = sock
        self.gcs_port = gcs_port
        self.by_port = vehicles
        self.ours: deque[bytes] = deque(maxlen=512)
        self.genuine: dict[int, deque[bytes]] = {s: deque(maxlen=64) for s in vehicles.values()}
        """System id -> its recent genuine datagrams (to replay)."""
        self.next_seq: dict[tuple[int, int], int] = {}
        self._rx = mavlink.MAVLink(None)
        self._rx.robust_parsing = True

    @classmethod
    def open(cls, gcs_port: int, vehicles: dict[int, Address]) -> Sniffer | None:
        try:
            sock = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_UDP)
        except OSError:
            return None
        sock.setblocking(False)
        return cls(sock, gcs_port, {a[1]: s for s, a in vehicles.items()})

    def poll(self) -> None:
        for _ in range(2000):
            try:
                packet = self.sock.recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            ihl = (packet[0] & 0x0F) * 4
            sport, dport = struct.unpack("!HH", packet[ihl:ihl + 4])
            payload = packet[ihl + 8:]
            sysid = self.by_port.get(sport)
            if dport != self.gcs_port or sysid is None or payload in self.ours:
                continue
            self.genuine[sysid].append(payload)
            self._rx.buf, self._rx.buf_index = bytearray(), 0
            self._rx.expected_length = mavlink.HEADER_LEN_V1 + 2
            for msg in self._rx.parse_buffer(payload) or []:
                if not isinstance(msg, mavlink.MAVLink_bad_data):
                    h = msg.get_header()
                    self.next_seq[(h.srcSystem, h.srcComponent)] = (h.seq + 1) % 256

    def close(self) -> None:
        self.sock.close()


@dataclass
class Target:
    """The flight under attack."""

    gcs: Address
    """The ground station's socket."""
    vehicles: dict[int, Address]
    """System id -> the vehicle's socket."""
    origins: dict[int, tuple[float, float, float]]
    """System id -> its true EKF origin (lat, lon, alt)."""


class Hostile:
    """Seeded hostile datagrams for one :class:`Target`."""

    def __init__(self, rng: np.random.Generator, target: Target, raw: RawUdp | None,
                 sniffer: Sniffer | None) -> None:
        self.rng = rng
        self.target = target
        self.raw = raw
        self.sniffer = sniffer
        self.sent: Counter[str] = Counter()
        self.ports = []
        for _ in range(4):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            s.setblocking(False)
            self.ports.append(s)
        self.codecs: dict[tuple[int, int], mavlink.MAVLink] = {}
        self.ids = sorted(target.vehicles)

    def close(self) -> None:
        for s in self.ports:
            s.close()

    def total(self) -> int:
        """Datagrams sent so far."""
        return sum(self.sent.values())

    # -- packets --------------------------------------------------------------------------

    def _codec(self, sysid: int, comp: int) -> mavlink.MAVLink:
        mav = self.codecs.get((sysid, comp))
        if mav is None:
            mav = self.codecs[(sysid, comp)] = mavlink.MAVLink(None, srcSystem=sysid,
                                                              srcComponent=comp)
            mav.seq = int(self.rng.integers(256))
        return mav

    def _pack(self, msg: mavlink.MAVLink_message, sysid: int, comp: int = 1, *,
              predicted: bool = False, key: bytes | None = None) -> bytes:
        mav = self._codec(sysid, comp)
        if predicted and self.sniffer is not None:
            mav.seq = self.sniffer.next_seq.get((sysid, comp), mav.seq)
        if key is not None:
            mav.signing.secret_key = key
            mav.signing.sign_outgoing = True
            mav.signing.link_id = int(self.rng.integers(3))
            ahead = float(self.rng.choice([0.0, 5.0, 3600.0]))
            mav.signing.timestamp = signing_timestamp(time.time() + ahead)
        else:
            mav.signing.sign_outgoing = False
        data = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        return data

    def _message(self, sysid: int) -> mavlink.MAVLink_message:
        """A valid message of a random kind, with hostile contents, as vehicle ``sysid``."""
        r = self.rng
        m = mavlink
        kind = int(r.integers(13))
        now_ms = int(r.integers(0, 600_000))
        origin = self.target.origins.get(sysid, (47.0, 8.0, 400.0))
        if kind <= 2:  # the commonest forgery: another mode, or disarmed
            base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if r.random() < 0.5:
                base |= m.MAV_MODE_FLAG_SAFETY_ARMED
            mode = int(r.choice([COPTER_MODES["LOITER"], COPTER_MODES["LAND"],
                                 COPTER_MODES["RTL"], COPTER_MODES["GUIDED"],
                                 COPTER_MODES["STABILIZE"], int(r.integers(0, 1 << 31))]))
            autopilot = int(r.choice([m.MAV_AUTOPILOT_ARDUPILOTMEGA, m.MAV_AUTOPILOT_PX4,
                                      m.MAV_AUTOPILOT_GENERIC]))
            return m.MAVLink_heartbeat_message(m.MAV_TYPE_QUADROTOR, autopilot, base, mode,
                                               int(r.integers(0, 9)), 3)
        if kind == 3:
            off = r.normal(0, 200, 3)
            lat, lon, alt = pymap3d.ned2geodetic(*off, *origin)
            return m.MAVLink_gps_global_origin_message(round(float(lat) * 1e7),
                                                       round(float(lon) * 1e7),
                                                       round(float(alt) * 1000), now_ms * 1000)
        if kind == 4:
            x, y, z = (float(v) for v in r.normal(0, 30, 3))
            return m.MAVLink_home_position_message(
                round((origin[0] + x / 111e3) * 1e7), round((origin[1] + y / 75e3) * 1e7),
                round((origin[2] - z) * 1000), x, y, z, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0)
        if kind == 5:
            p = [float(v) for v in r.normal(0, 40, 3)]
            v = [float(u) for u in r.normal(0, 5, 3)]
            if r.random() < 0.1:
                p[0] = math.nan
            return m.MAVLink_local_position_ned_message(now_ms, *p, *v)
        if kind == 6:
            lat, lon, alt = pymap3d.ned2geodetic(*r.normal(0, 40, 3), *origin)
            return m.MAVLink_global_position_int_message(
                now_ms, round(float(lat) * 1e7), round(float(lon) * 1e7),
                round(float(alt) * 1000), int(r.integers(-5000, 30000)),
                *(int(u) for u in r.integers(-500, 500, 3)), int(r.integers(0, 36000)))
        if kind == 7:
            return m.MAVLink_sys_status_message(0, 0, 0, 0, 11000, 0, int(r.integers(0, 30)),
                                                0, 0, 0, 0, 0, 0)
        if kind == 8:
            return m.MAVLink_extended_sys_state_message(0, int(r.integers(0, 5)))
        if kind == 9:
            cmd = int(r.choice([m.MAV_CMD_DO_SET_MODE, m.MAV_CMD_COMPONENT_ARM_DISARM,
                                m.MAV_CMD_NAV_TAKEOFF, m.MAV_CMD_SET_MESSAGE_INTERVAL]))
            return m.MAVLink_command_ack_message(cmd, int(r.integers(0, 6)), 0, 0, 255, 190)
        if kind == 10:
            text = bytes(r.integers(32, 127, int(r.integers(1, 50))).astype(np.uint8))
            return m.MAVLink_statustext_message(int(r.integers(0, 8)), text,
                                                int(r.integers(0, 3)), int(r.integers(0, 3)))
        if kind == 11:
            return m.MAVLink_timesync_message(int(r.integers(0, 1 << 62)),
                                              int(r.integers(0, 1 << 62)))
        return m.MAVLink_param_value_message(b"GUID_TIMEOUT", float(r.normal(5, 5)),
                                             m.MAV_PARAM_TYPE_REAL32, 500, 1)

    # -- sending ----------------------------------------------------------------------------

    def _other_port(self) -> socket.socket:
        return self.ports[int(self.rng.integers(len(self.ports)))]

    def _send_from_port(self, data: bytes) -> None:
        _check_loopback(self.target.gcs)
        with contextlib.suppress(OSError):
            self._other_port().sendto(data, self.target.gcs)

    def _send_forged(self, data: bytes, sysid: int) -> None:
        assert self.raw is not None
        if self.sniffer is not None:
            self.sniffer.ours.append(data)
        self.raw.send(data, self.target.vehicles[sysid], self.target.gcs)

    def one(self) -> str:
        """Send one hostile datagram; returns its kind."""
        r = self.rng
        kind = str(r.choice(KINDS, p=WEIGHTS))
        if kind in ("forged", "replay") and self.raw is None:
            kind = "spoofed"
        if kind == "replay" and (self.sniffer is None
                                 or not any(self.sniffer.genuine.values())):
            kind = "forged"
        sysid = int(r.choice(self.ids))
        comp = 1 if r.random() < 0.9 else int(r.integers(0, 256))
        if kind == "random":
            data = bytes(r.integers(0, 256, int(r.integers(0, 300))).astype(np.uint8))
            if r.random() < 0.5:
                data = bytes([0xFD]) + data  # a MAVLink 2 start: the parser reads further
            self._maybe_forged(data, sysid)
        elif kind == "truncated":
            data = self._pack(self._message(sysid), sysid, comp)
            self._maybe_forged(data[:int(r.integers(1, len(data)))], sysid)
        elif kind == "bitflip":
            buf = bytearray(self._pack(self._message(sysid), sysid, comp))
            for _ in range(int(r.integers(1, 9))):
                i = int(r.integers(len(buf)))
                buf[i] ^= 1 << int(r.integers(8))
            self._maybe_forged(bytes(buf), sysid)
        elif kind == "spoofed":
            self._send_from_port(self._pack(self._message(sysid), sysid, comp))
        elif kind == "forged":
            data = self._pack(self._message(sysid), sysid, comp, predicted=r.random() < 0.6)
            self._send_forged(data, sysid)
        elif kind == "wrong_key":
            key = bytes(r.integers(0, 256, 32).astype(np.uint8))
            data = self._pack(self._message(sysid), sysid, comp, predicted=True, key=key)
            self._maybe_forged(data, sysid)
        elif kind == "replay":
            assert self.sniffer is not None
            pools = [(s, q) for s, q in self.sniffer.genuine.items() if q]
            owner, pool = pools[int(r.integers(len(pools)))]
            data = pool[int(r.integers(len(pool)))]
            if r.random() < 0.7:
                self._send_forged(data, owner)
            else:
                self._send_from_port(data)
        else:  # stray system ids, from a port of their own
            stray = int(r.choice([77, 120, 200, 254]))
            hb = mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0, mavlink.MAV_STATE_STANDBY, 3)
            self._send_from_port(self._pack(hb, stray, 1))
        self.sent[kind] += 1
        return kind

    def _maybe_forged(self, data: bytes, sysid: int) -> None:
        if self.raw is not None and self.rng.random() < 0.5:
            self._send_forged(data, sysid)
        else:
            self._send_from_port(data)


# -- the watcher -------------------------------------------------------------------------


#: A believed value must have been true within this long (the confirmation of a genuine
#: change takes up to two HEARTBEAT periods), s of the flight's clock.
TRUTH_WINDOW_S = 4.0
#: A believed position further than this from the simulator's estimate is not its, m.
POSITION_LIMIT_M = 3.0


@dataclass
class Watch:
    """Believed state against the simulator's truth, sampled through the flight.

    A *violation* is a belief that changed to a value the simulator did not have in the
    last TRUTH_WINDOW_S (a mode, arming or battery level), or an EKF origin or position
    off the truth: a state a spoofed packet changed.  A belief that lags the truth (a
    genuine change not believed yet) is not one: it is measured as *staleness*.
    """

    history: dict[int, deque[tuple[float, str, bool, float]]] = field(default_factory=dict)
    violations: dict[tuple[int, str], str] = field(default_factory=dict)
    believed: dict[tuple[int, str], object] = field(default_factory=dict)
    behind_since: dict[tuple[int, str], float] = field(default_factory=dict)
    stale_s: dict[str, float] = field(default_factory=dict)
    """Field -> the longest a belief lagged the truth, s of the flight's clock."""
    samples: int = 0

    def sample(self, runner: ShowRunner, sim: SimProcess,
               origins: dict[int, tuple[float, float, float]]) -> bool:
        """One comparison; returns whether any vehicle is armed (truth)."""
        now = runner.clock.now()
        truth = {s.sysid: s for s in sim.call("snapshot")}
        plan = runner.plan
        for sysid, t in truth.items():
            h = self.history.setdefault(sysid, deque())
            h.append((now, t.mode, t.armed, t.battery * 100.0))
            while h and h[0][0] < now - TRUTH_WINDOW_S:
                h.popleft()
        self.samples += 1
        for sysid, state in runner.link.vehicles.items():
            t = truth.get(sysid)
            past = self.history.get(sysid)
            if t is None or not past:
                continue
            h = past
            self._changed(sysid, "mode", state.mode, now, t.mode,
                          state.mode == "UNKNOWN" or state.mode in {m for _, m, _, _ in h})
            self._changed(sysid, "armed", state.armed, now, t.armed,
                          state.armed in {a for _, _, a, _ in h})
            pct = state.battery_remaining_pct
            if pct is not None:
                self._changed(sysid, "battery", round(pct), now, None,
                              min(abs(pct - b) for _, _, _, b in h) <= 5.0)
            o = state.ekf_origin
            if o is not None:
                err = float(np.linalg.norm(pymap3d.geodetic2ned(
                    o.lat_deg, o.lon_deg, o.alt_m, *origins[sysid])))
                if err > 1.0:
                    self._flag(sysid, "origin", f"believed an origin {err:.1f} m off")
                if state.position_ned is not None and state.silent_for(now) < 0.5:
                    here = ned_to_show(plan.origin, o, np.array(state.position_ned))
                    est = enu_to_show(plan.origin, np.array(t.estimated_position))
                    d = float(np.linalg.norm(np.ravel(here) - np.ravel(est)))
                    if d > POSITION_LIMIT_M:
                        self._flag(sysid, "position", f"believed a position {d:.1f} m off")
        return any(t.armed for t in truth.values())

    def _changed(self, sysid: int, what: str, value: object, now: float, true_now: object,
                 was_true: bool) -> None:
        key = (sysid, what)
        before = self.believed.get(key)
        self.believed[key] = value
        if before is not None and value != before and not was_true:
            self._flag(sysid, what, f"belief changed to {value!r}, never true in the last "
                                    f"{TRUTH_WINDOW_S:.0f} s")
        if true_now is None:
            return
        if value == true_now:
            since = self.behind_since.pop(key, None)
            if since is not None:
                self.stale_s[what] = max(self.stale_s.get(what, 0.0), now - since)
        else:
            self.behind_since.setdefault(key, now)

    def _flag(self, sysid: int, what: str, text: str) -> None:
        self.violations.setdefault((sysid, what), f"vehicle {sysid}: {what}: {text}")


class Tracebacks(logging.Handler):
    """Every log record that carries a traceback (``log.exception``), and every error."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info or record.levelno >= logging.ERROR:
            self.records.append(self.format(record))


@dataclass
class FuzzResult:
    """What one fuzzed flight gave."""

    sent: Counter[str]
    """Datagrams sent, by kind."""
    airborne: int
    """Of them, sent while some vehicle was armed (the simulator's truth)."""
    raw: bool
    """Forged-source and sniffing kinds were possible (a raw socket opened)."""
    signed: bool
    """The fleet used MAVLink signing."""
    report: dict[str, Any]
    """The dry-run's report."""
    error: str | None
    """The error that ended the flight early, if one did."""
    crashes: list[str]
    """Ground-station exceptions that escaped, a simulator that died, drones that crashed."""
    tracebacks: list[str]
    """Log records with a traceback (or at ERROR) during the flight."""
    violations: list[str]
    """Vehicles whose believed state was never true (a spoofed packet changed it)."""
    stale_s: dict[str, float]
    """Field -> the longest the belief lagged the truth (genuine changes believed late)."""
    link: dict[str, int]
    """The link's counters (bad packets, conflicts, bad signatures...)."""
    conflicts: dict[int, int]
    """Link conflicts per vehicle."""
    wall_s: float
    """Wall time of the flight."""

    @property
    def total(self) -> int:
        return sum(self.sent.values())

    @property
    def unsafe(self) -> bool:
        return not self.report.get("safe", False)


def fly_fuzzed(*, count: int, seed: int = 0, speed: float = 2.0, signed: bool = False,
               flavour: Flavour = Flavour.ARDUPILOT, use_raw: bool = True,
               record_dir: Path | None = None) -> FuzzResult:
    """Fly the quick show with ``count`` hostile datagrams spread over the flight
    (recorded into ``record_dir`` when given: tlog, events, report)."""
    plan = quick_plan()
    rng = np.random.default_rng(seed)
    raw = RawUdp.open() if use_raw else None
    watch = Watch()
    handler = Tracebacks()
    crashes: list[str] = []
    hostile_box: list[Hostile] = []
    runners: list[ShowRunner] = []
    airborne = [0]
    origins = _true_origins(plan)
    # Spread over pre-flight, takeoff and the show (about 10 simulated seconds before
    # it); what is left of the count goes on through the landing.
    rate = count / ((plan.duration + 10.0) / speed)

    harness: list[str] = []

    async def attack(runner: ShowRunner, sim: SimProcess) -> None:
        try:
            await _attack(runner, sim)
        except asyncio.CancelledError:
            raise
        except Exception:  # the harness's own bug: say so, it is not the ground station's
            harness.append(traceback.format_exc())
            raise

    async def _attack(runner: ShowRunner, sim: SimProcess) -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(
            lambda _loop, ctx: handler.records.append(f"asyncio: {ctx.get('message')} "
                                                      f"{ctx.get('exception')!r}"))
        link = runner.link
        ids = list(range(1, plan.drones + 1))
        while any(link.address_of(s) is None for s in ids):
            await asyncio.sleep(0.01)
        assert link.local_address is not None
        vehicles: dict[int, Address] = {}
        for s in ids:
            addr = link.address_of(s)
            assert addr is not None
            vehicles[s] = addr
        target = Target(link.local_address, vehicles, origins)
        sniffer = Sniffer.open(target.gcs[1], target.vehicles) if raw is not None else None
        hostile = Hostile(rng, target, raw, sniffer)
        hostile_box.append(hostile)
        start = time.monotonic()
        next_watch = 0.0
        flying = False
        try:
            while hostile.total() < count:
                if sniffer is not None:
                    sniffer.poll()
                due = min(int((time.monotonic() - start) * rate) + 1, count) - hostile.total()
                for _ in range(max(0, min(due, 40))):
                    hostile.one()
                    airborne[0] += flying
                if time.monotonic() >= next_watch:
                    next_watch = time.monotonic() + 0.1
                    flying = watch.sample(runner, sim, origins)
                await asyncio.sleep(0.005)
            while True:  # keep watching until the flight ends (this task is cancelled)
                await asyncio.sleep(0.1)
                watch.sample(runner, sim, origins)
        finally:
            hostile.close()
            if sniffer is not None:
                sniffer.close()

    root = logging.getLogger()
    root.addHandler(handler)
    old_level = root.level
    root.setLevel(logging.DEBUG)
    for noisy in ("groundctl", "asyncio"):
        logging.getLogger(noisy).setLevel(logging.DEBUG)
    t0 = time.monotonic()
    try:
        options = DryRunOptions(speed=speed, ekf_origin_delay_s=1.0, ready_delay_s=2.0,
                                seed=seed, flavour=flavour, record_dir=record_dir,
                                signing_key=FLEET_KEY if signed else None)
        try:
            result = asyncio.run(fly_dry_run(plan, options, during=attack,
                                             on_runner=runners.append))
        except Exception as exc:  # an exception escaping the dry-run is a crash
            crashes.append("".join(traceback.format_exception(exc)))
            raise_report: dict[str, Any] = {"safe": False, "unsafe_reasons": [repr(exc)]}
            return FuzzResult(Counter(), 0, raw is not None, signed, raise_report, repr(exc),
                              crashes, handler.records, [], {}, {}, {},
                              time.monotonic() - t0)
    finally:
        root.removeHandler(handler)
        root.setLevel(old_level)
        if raw is not None:
            raw.close()
    report = result.report
    sim = report.get("simulator", {})
    if sim.get("crashed"):
        crashes.append(f"simulated vehicles crashed: {sim['crashed']}")
    if sim.get("error"):
        crashes.append(f"simulator: {sim['error']}")
    if harness:
        raise RuntimeError("the fuzz harness failed:\n" + "\n".join(harness))
    sent = hostile_box[0].sent if hostile_box else Counter()
    link = report.get("link", {})
    return FuzzResult(sent, airborne[0], raw is not None, signed, report,
                      None if result.error is None else str(result.error), crashes,
                      handler.records, sorted(watch.violations.values()),
                      {k: round(v, 2) for k, v in sorted(watch.stale_s.items())},
                      {k: v for k, v in link.items() if isinstance(v, int)},
                      {s: getattr(v, "link_conflicts", 0)
                       for s, v in sorted(runners[0].link.vehicles.items())} if runners else {},
                      time.monotonic() - t0)


def _true_origins(plan: Plan) -> dict[int, tuple[float, float, float]]:
    """Each simulated vehicle's EKF origin: where it stands at boot (the dry-run's
    default), as the simulator computes it."""
    enu = show_to_enu(plan.origin, plan.home)
    o = plan.origin
    out = {}
    for i, (e, n, u) in enumerate(enu):
        lat, lon, alt = pymap3d.enu2geodetic(e, n, u, o.lat, o.lon, o.alt)
        out[i + 1] = (float(lat), float(lon), float(alt))
    return out
