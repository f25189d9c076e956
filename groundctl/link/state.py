"""What the ground station knows about one vehicle, updated by a pure :func:`apply`.

:func:`apply` takes a decoded message and the time it arrived and updates a
:class:`VehicleState`; it returns the notable changes (mode changed, armed,
STATUSTEXT...) so the caller can log them.  No I/O here.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour, decode_mode
from groundctl.link.quality import SequenceTracker
from groundctl.link.timesync import TimesyncEstimator, TimesyncSample

Vec3 = tuple[float, float, float]

#: Two position samples further apart than this on the vehicle's own clock mean its
#: stream stopped (it streams at 10 Hz), s.
STREAM_GAP_S = 0.5


@dataclass(frozen=True)
class GlobalPosition:
    """GLOBAL_POSITION_INT, in SI units."""

    lat_deg: float
    """Latitude, degrees."""
    lon_deg: float
    """Longitude, degrees."""
    alt_m: float
    """Altitude above mean sea level, metres."""
    relative_alt_m: float
    """Altitude above home, metres."""
    vel_ned: Vec3
    """Ground speed north, east, down, m/s."""
    heading_deg: float | None
    """Heading, degrees, or None when unknown."""


@dataclass(frozen=True)
class GeoPoint:
    """A geodetic point (EKF origin, home)."""

    lat_deg: float
    """Latitude, degrees."""
    lon_deg: float
    """Longitude, degrees."""
    alt_m: float
    """Altitude above mean sea level, metres."""


@dataclass(frozen=True)
class StatusText:
    """A STATUSTEXT line from the vehicle."""

    text: str
    """The text, as sent."""
    severity: int
    """MAV_SEVERITY (0 emergency .. 7 debug)."""
    at: float
    """Our time when it arrived."""


@dataclass(frozen=True)
class StateChange:
    """A notable change worth an event-log line."""

    event: str
    """Event name: ``mode_changed``, ``armed``, ``disarmed``, ``statustext``, ..."""
    fields: dict[str, Any]
    """Event details."""


@dataclass
class VehicleState:
    """Everything known about one vehicle.  Fields are None until first reported."""

    system_id: int
    """MAVLink system id."""
    flavour: Flavour | None = None
    """Autopilot family from HEARTBEAT.autopilot."""
    vehicle_type: int | None = None
    """HEARTBEAT.type (MAV_TYPE)."""
    mode: str = "UNKNOWN"
    """Flight mode name decoded the way the flavour encodes it."""
    armed: bool = False
    """MAV_MODE_FLAG_SAFETY_ARMED from HEARTBEAT.base_mode."""
    system_status: int | None = None
    """HEARTBEAT.system_status (MAV_STATE)."""
    position_ned: Vec3 | None = None
    """LOCAL_POSITION_NED x, y, z in metres from the EKF origin."""
    velocity_ned: Vec3 | None = None
    """LOCAL_POSITION_NED vx, vy, vz in m/s."""
    local_time_boot_ms: int | None = None
    """time_boot_ms of the last LOCAL_POSITION_NED."""
    stream_gaps: int = 0
    """Silences in its own position stream: consecutive LOCAL_POSITION_NED further apart
    than STREAM_GAP_S on the *vehicle's* clock.  Our own stalls never count here (their
    packets waited in our socket, they were not missing)."""
    last_stream_gap_s: float = 0.0
    """The length of the last such silence, s."""
    global_position: GlobalPosition | None = None
    """Last GLOBAL_POSITION_INT."""
    battery_remaining_pct: float | None = None
    """Remaining battery, percent (SYS_STATUS or BATTERY_STATUS)."""
    battery_voltage_v: float | None = None
    """Battery voltage, volts."""
    throttle_pct: float | None = None
    """VFR_HUD.throttle: the motors' output, percent (what it hovers at says how much
    thrust it has left: :mod:`groundctl.execute.authority`)."""
    prearm_ok: bool | None = None
    """SYS_STATUS pre-arm check bit: True passing, False failing, None not reported."""
    gps_fix_type: int | None = None
    """GPS_RAW_INT.fix_type (GPS_FIX_TYPE; 3 = 3D fix)."""
    gps_satellites: int | None = None
    """GPS_RAW_INT.satellites_visible."""
    ekf_origin: GeoPoint | None = None
    """GPS_GLOBAL_ORIGIN: where the vehicle's local NED frame is anchored."""
    home: GeoPoint | None = None
    """HOME_POSITION."""
    first_heard: float | None = None
    """Our time of the first packet."""
    last_heard: float | None = None
    """Our time of the last packet."""
    last_heartbeat: float | None = None
    """Our time of the last autopilot HEARTBEAT."""
    lost: bool = False
    """Silent for longer than the link timeout (set by the link, cleared by any packet)."""
    packets: int = 0
    """Packets received from this vehicle."""
    bad_packets: int = 0
    """Malformed or rejected packets attributed to this vehicle's address."""
    quality: SequenceTracker = field(default_factory=SequenceTracker)
    """Sequence-number based loss estimate."""
    timesync: TimesyncEstimator = field(default_factory=TimesyncEstimator)
    """Clock offset and RTT from TIMESYNC."""
    statustexts: deque[StatusText] = field(default_factory=lambda: deque(maxlen=20))
    """The most recent STATUSTEXTs, oldest first (chunked ones reassembled)."""
    text_chunks: dict[int, _Chunks] = field(default_factory=dict)
    """Chunked STATUSTEXTs being reassembled, by MAVLink 2 ``id``."""
    params: dict[str, float] = field(default_factory=dict)
    """Parameter values the vehicle reported (PARAM_VALUE), by name."""
    acks: deque[mavlink.MAVLink_command_ack_message] = field(
        default_factory=lambda: deque(maxlen=20)
    )
    """The most recent COMMAND_ACKs, oldest first."""

    @property
    def loss_ratio(self) -> float:
        """Fraction of this vehicle's packets lost on the way (sequence gaps)."""
        return self.quality.loss_ratio

    @property
    def rtt_s(self) -> float | None:
        """Latest TIMESYNC round-trip time in seconds."""
        return self.timesync.rtt_s

    @property
    def median_rtt_s(self) -> float | None:
        """Median TIMESYNC round trip over the recent window: one stall of ours (a late
        answer) does not move it."""
        return self.timesync.median_rtt_s

    @property
    def clock_offset_s(self) -> float | None:
        """Vehicle boot clock minus our clock, seconds (best TIMESYNC sample)."""
        return self.timesync.offset_s

    @property
    def last_statustext(self) -> StatusText | None:
        return self.statustexts[-1] if self.statustexts else None

    def vehicle_time_boot_ms(self, now: float) -> int | None:
        """The vehicle's time_boot_ms at our time ``now``, from TIMESYNC, if known."""
        t = self.timesync.vehicle_time_s(now)
        return None if t is None else max(int(t * 1000), 0)

    def silent_for(self, now: float) -> float:
        """Seconds since the last packet (infinite if never heard)."""
        return float("inf") if self.last_heard is None else now - self.last_heard


def _is_autopilot_heartbeat(msg: mavlink.MAVLink_heartbeat_message) -> bool:
    # Gimbals, cameras and companion computers send HEARTBEATs too, under the
    # same system id; only the autopilot's carries the vehicle's mode and
    # armed state.
    return (
        msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID
        and msg.type not in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
    )


def apply(state: VehicleState, msg: mavlink.MAVLink_message, now: float) -> list[StateChange]:
    """Update ``state`` from ``msg`` received at ``now``; returns notable changes."""
    changes: list[StateChange] = []
    state.packets += 1
    if state.first_heard is None:
        state.first_heard = now
    state.last_heard = now
    header = msg.get_header()
    state.quality.update(header.srcComponent, header.seq)

    kind = msg.get_type()
    handler = _HANDLERS.get(kind)
    if handler is not None:
        handler(state, msg, now, changes)
    return changes


def _heartbeat(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    if not _is_autopilot_heartbeat(msg):
        return
    state.last_heartbeat = now
    flavour = Flavour.from_heartbeat(msg.autopilot)
    if flavour is not state.flavour:
        state.flavour = flavour
        changes.append(StateChange("flavour", {"flavour": str(flavour) if flavour else None}))
    state.vehicle_type = msg.type
    state.system_status = msg.system_status
    mode = decode_mode(flavour, msg.base_mode, msg.custom_mode)
    if mode != state.mode:
        changes.append(StateChange("mode_changed", {"old": state.mode, "new": mode}))
        state.mode = mode
    armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
    if armed != state.armed:
        state.armed = armed
        changes.append(StateChange("armed" if armed else "disarmed", {}))


def _local_position(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    prev = state.local_time_boot_ms
    if prev is not None and msg.time_boot_ms > prev:
        gap = (msg.time_boot_ms - prev) / 1000.0
        if gap > STREAM_GAP_S:
            state.stream_gaps += 1
            state.last_stream_gap_s = gap
    state.position_ned = (msg.x, msg.y, msg.z)
    state.velocity_ned = (msg.vx, msg.vy, msg.vz)
    state.local_time_boot_ms = msg.time_boot_ms


def _global_position(
    state: VehicleState, msg: Any, now: float, changes: list[StateChange]
) -> None:
    state.global_position = GlobalPosition(
        lat_deg=msg.lat / 1e7,
        lon_deg=msg.lon / 1e7,
        alt_m=msg.alt / 1000.0,
        relative_alt_m=msg.relative_alt / 1000.0,
        vel_ned=(msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0),
        heading_deg=None if msg.hdg == 65535 else msg.hdg / 100.0,
    )


def _sys_status(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    if msg.onboard_control_sensors_present & prearm:
        ok = bool(msg.onboard_control_sensors_health & prearm)
        if ok is not state.prearm_ok:
            changes.append(StateChange("prearm", {"ok": ok}))
        state.prearm_ok = ok
    # -1 and UINT16_MAX mean "not measured": keep what BATTERY_STATUS may have said.
    if msg.battery_remaining >= 0:
        state.battery_remaining_pct = float(msg.battery_remaining)
    if msg.voltage_battery != 65535:
        state.battery_voltage_v = msg.voltage_battery / 1000.0


def _battery_status(
    state: VehicleState, msg: Any, now: float, changes: list[StateChange]
) -> None:
    if msg.id != 0:
        return  # only the first (main) battery
    if msg.battery_remaining >= 0:
        state.battery_remaining_pct = float(msg.battery_remaining)
    cells = [v for v in msg.voltages if v != 65535]
    if cells:
        state.battery_voltage_v = sum(cells) / 1000.0


def _gps_raw(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    state.gps_fix_type = msg.fix_type
    state.gps_satellites = None if msg.satellites_visible == 255 else msg.satellites_visible


def _origin(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    origin = GeoPoint(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
    if origin != state.ekf_origin:
        state.ekf_origin = origin
        changes.append(StateChange("ekf_origin", {"lat": origin.lat_deg, "lon": origin.lon_deg,
                                                  "alt": origin.alt_m}))


def _home(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    home = GeoPoint(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
    if home != state.home:
        state.home = home
        changes.append(StateChange("home", {"lat": home.lat_deg, "lon": home.lon_deg,
                                            "alt": home.alt_m}))


#: STATUSTEXT's text field, bytes: a chunk this long may be followed by more.
STATUSTEXT_CHUNK = 50
#: A chunked STATUSTEXT still incomplete after this long is taken as it stands, s.
STATUSTEXT_CHUNK_TIMEOUT_S = 1.0


@dataclass
class _Chunks:
    """A chunked STATUSTEXT being reassembled (MAVLink 2 ``id`` / ``chunk_seq``)."""

    severity: int
    parts: list[str]
    next_seq: int
    started: float
    gap: bool = False


def _text_line(state: VehicleState, text: str, severity: int, now: float,
               changes: list[StateChange]) -> None:
    state.statustexts.append(StatusText(text, severity, now))
    changes.append(StateChange("statustext", {"text": text, "severity": severity}))


def _flush_chunks(state: VehicleState, now: float, changes: list[StateChange], *,
                  older_than: float | None = None, keep: int | None = None,
                  cut: bool = True) -> None:
    """Emit the chunked texts that will not be completed (all but ``keep``, or those
    started before ``older_than``).  ``cut``: each is marked " [...]" as cut short (timed
    out, or a plain text came after it); otherwise only where a chunk was lost (a new
    chunked text began: PX4 sends no empty final chunk after an exactly full one)."""
    for cid in [c for c, ch in state.text_chunks.items()
                if c != keep and (older_than is None or ch.started < older_than)]:
        ch = state.text_chunks.pop(cid)
        mark = " [...]" if cut or ch.gap else ""
        _text_line(state, "".join(ch.parts) + mark, ch.severity, now, changes)


def expire_chunks(state: VehicleState, now: float) -> list[StateChange]:
    """Chunked STATUSTEXTs still incomplete after STATUSTEXT_CHUNK_TIMEOUT_S, emitted as
    they stand (the link calls this every tick: nothing else may arrive to end them)."""
    changes: list[StateChange] = []
    if state.text_chunks:
        _flush_chunks(state, now, changes, older_than=now - STATUSTEXT_CHUNK_TIMEOUT_S)
    return changes


def _statustext(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    raw = msg.text
    text = raw.decode("utf-8", "replace") if isinstance(raw, bytes) else str(raw)
    text = text.split("\0", 1)[0]
    severity = int(msg.severity)
    cid, seq = int(getattr(msg, "id", 0) or 0), int(getattr(msg, "chunk_seq", 0) or 0)
    _flush_chunks(state, now, changes, older_than=now - STATUSTEXT_CHUNK_TIMEOUT_S)
    if cid == 0:  # not chunked: the whole text (any chunked one pending ended before it)
        _flush_chunks(state, now, changes)
        _text_line(state, text, severity, now, changes)
        return
    ch = state.text_chunks.get(cid)
    if ch is None:
        ch = state.text_chunks[cid] = _Chunks(severity, [], 0, now)
        _flush_chunks(state, now, changes, keep=cid, cut=False)  # a new text began
    if seq != ch.next_seq:
        ch.gap = True  # a chunk was lost (or came twice): say so where it was
        if seq < ch.next_seq:
            return
        ch.parts.append(" [...] ")
    ch.parts.append(text)
    ch.next_seq = seq + 1
    if len(text.encode("utf-8")) < STATUSTEXT_CHUNK:  # a short (or empty) chunk ends it
        del state.text_chunks[cid]
        _text_line(state, "".join(ch.parts), ch.severity, now, changes)


def _param_value(state: VehicleState, msg: Any, now: float,
                 changes: list[StateChange]) -> None:
    raw = msg.param_id
    name = (raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw))
    name = name.split("\0", 1)[0]
    if name and math.isfinite(float(msg.param_value)):
        state.params[name] = float(msg.param_value)


def _vfr_hud(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    if 0 <= msg.throttle <= 100:
        state.throttle_pct = float(msg.throttle)


def _ack(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    state.acks.append(msg)


def _timesync(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    sample: TimesyncSample | None = state.timesync.receive(msg.tc1, msg.ts1, now)
    del sample  # the estimator keeps it; nothing notable to log per sample


_HANDLERS = {
    "HEARTBEAT": _heartbeat,
    "LOCAL_POSITION_NED": _local_position,
    "GLOBAL_POSITION_INT": _global_position,
    "SYS_STATUS": _sys_status,
    "BATTERY_STATUS": _battery_status,
    "GPS_RAW_INT": _gps_raw,
    "GPS_GLOBAL_ORIGIN": _origin,
    "HOME_POSITION": _home,
    "STATUSTEXT": _statustext,
    "COMMAND_ACK": _ack,
    "TIMESYNC": _timesync,
    "PARAM_VALUE": _param_value,
    "VFR_HUD": _vfr_hud,
}
