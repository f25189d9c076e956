"""What the ground station knows about one vehicle, updated by a pure :func:`apply`.

:func:`apply` takes a decoded message and the time it arrived and updates a
:class:`VehicleState`; it returns the notable changes (mode changed, armed,
STATUSTEXT, link conflicts...) so the caller can log them.  No I/O here.

The fields are what the ground station *believes*: a report that contradicts the
vehicle's own stream changes nothing, and a mode, arming, landed state, battery
level, EKF origin or home that would end its show unasked is believed only once a
second report confirms it (:mod:`groundctl.link.trust` has the rules).
"""

from __future__ import annotations

import math
import operator
import zlib
from collections import deque
from collections.abc import Collection
from dataclasses import dataclass, field, replace
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour, decode_mode
from groundctl.link.quality import SequenceTracker
from groundctl.link.timesync import TimesyncEstimator, TimesyncSample
from groundctl.link.trust import (
    BATTERY_STEP_PCT,
    CONFIRM_PACKETS,
    CONFIRM_PACKETS_IN_STEP,
    DISARM_BALLISTIC_S,
    DISARM_FALL_MS,
    EXPECT_S,
    GROUND_FRESH_S,
    GROUND_HEIGHT_M,
    GROUND_SPEED_MS,
    HOME_UNDER_M,
    LANDING_MODES,
    ORIGIN_TOLERANCE_M,
    PAIR_WINDOW_S,
    HeartbeatClaim,
    QuickClaim,
    Sample,
    Seq,
    Trust,
    metres_per_degree,
    origin_error_m,
)

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
    local_received_at: float | None = None
    """Our time the last LOCAL_POSITION_NED arrived (the kernel's stamp, on our clock)."""
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
    throttle_at: float | None = None
    """Our time of that VFR_HUD."""
    wind_ned: Vec3 | None = None
    """The vehicle's own wind estimate, NED m/s (where the air moves to): ArduPilot's
    WIND, PX4's WIND_COV."""
    wind_at: float | None = None
    """Our time of that estimate."""
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
    landed_state: int | None = None
    """EXTENDED_SYS_STATE.landed_state (MAV_LANDED_STATE), where the vehicle sends it."""
    link_conflicts: int = 0
    """Packets under this system id that contradicted the vehicle's own stream (a second
    sender: two packets with one sequence number, a jump back, a position off its track,
    a mode or disarm reported once and contradicted, an EKF origin its positions deny).
    Counted, never acted on."""
    last_conflict: str | None = None
    """Why the last link conflict was one."""
    bad_signatures: int = 0
    """Packets under this system id refused by signing (wrong key, replayed timestamp,
    unsigned): counted, never acted on."""
    trust: Trust = field(default_factory=Trust, repr=False)
    """The bookkeeping behind what is believed (pending reports, numberings)."""

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

    def wind_speed(self, now: float, max_age_s: float) -> float | None:
        """Horizontal speed of its own wind estimate, m/s; None without one this fresh."""
        if self.wind_ned is None or self.wind_at is None or now - self.wind_at > max_age_s:
            return None
        return math.hypot(self.wind_ned[0], self.wind_ned[1])

    def silent_for(self, now: float) -> float:
        """Seconds since the last packet (infinite if never heard)."""
        return float("inf") if self.last_heard is None else now - self.last_heard


#: A wind estimate this strong or more is not one (no multirotor flies in it), m/s.
MAX_WIND_MPS = 100.0


def _is_autopilot_heartbeat(msg: mavlink.MAVLink_heartbeat_message) -> bool:
    # Gimbals, cameras and companion computers send HEARTBEATs too, under the
    # same system id; only the autopilot's carries the vehicle's mode and
    # armed state.
    return (
        msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID
        and msg.type not in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
    )


#: Messages read from a packet that does not fit the vehicle's stream (a link
#: conflict) or from a component other than its autopilot: nothing they say changes
#: what the ground station believes, but their text is worth showing.
_FROM_ANYONE = frozenset({"STATUSTEXT"})
#: Every message type whose report may wait for confirmation.
_ALL_KINDS = frozenset({"HEARTBEAT", "SYS_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION",
                        "GPS_GLOBAL_ORIGIN"})


def apply(state: VehicleState, msg: mavlink.MAVLink_message, now: float) -> list[StateChange]:
    """Update ``state`` from ``msg`` received at ``now``; returns notable changes.

    What the message says is believed only as far as :mod:`groundctl.link.trust`
    allows: a packet that contradicts the vehicle's own stream is counted as a link
    conflict (a ``link_conflict`` change) and not acted on, and
    ``state.trust.last_trusted`` says whether this one was (the link routes ACKs and
    answers TIMESYNC only for packets it trusts).
    """
    changes: list[StateChange] = []
    header = msg.get_header()
    comp = header.srcComponent
    trust = state.trust
    buf = msg.get_msgbuf()
    kind = msg.get_type()
    verdict = _received(state, comp, header.seq,
                        zlib.crc32(buf) if buf else zlib.crc32(str(msg).encode()), kind,
                        now, changes)
    if verdict is Seq.DUPLICATE:
        trust.last_trusted = False  # the same bytes again: already acted on
        return changes
    if verdict in (Seq.CONFLICT, Seq.HELD):
        trust.last_trusted = False
        if kind == "HEARTBEAT" and _is_autopilot_heartbeat(msg) \
                and comp == trust.autopilot_component:
            state.last_heartbeat = now  # it may be the vehicle's own: it is alive
        if kind in _FROM_ANYONE:
            _HANDLERS[kind](state, msg, now, changes)
        return changes
    trust.last_trusted = True
    if kind == "HEARTBEAT":
        _heartbeat(state, msg, now, changes)
        return changes
    if trust.quick is not None:
        _settle_quick(state, now, changes)
    if trust.autopilot_component is not None and comp != trust.autopilot_component \
            and kind not in _FROM_ANYONE:
        # Only the autopilot speaks for the vehicle's state: a packet under another
        # component id has its own numbering, which no stream of the autopilot's
        # could contradict.
        trust.last_trusted = False
        return changes
    handler = _HANDLERS.get(kind)
    if handler is not None:
        handler(state, msg, now, changes)
    if trust.quick is not None:
        _settle_quick(state, now, changes)
    return changes


def _received(state: VehicleState, comp: int, seq: int, digest: int, kind: str,
              now: float, changes: list[StateChange]) -> Seq:
    """What every packet of ``state``'s vehicle does, whatever it says: it is heard, it
    is counted (loss, reordering), its number ``seq`` of component ``comp`` is judged
    against the component's numbering (``digest``: its bytes' CRC-32), and a number
    that contradicts it is a conflict."""
    state.packets += 1
    if state.first_heard is None:
        state.first_heard = now
    state.last_heard = now
    numbering = state.trust.sequence(comp)
    verdict = numbering.check(seq, digest, kind, now)
    # Loss is counted on the vehicle's own numbering only.  A packet far from it (held)
    # or under a number already used (a conflict) may be a forger's, whose numbering of
    # its own would read as gaps: spoofed origins in pre-flight read as 36-46 % loss
    # and failed every vehicle's link check.  A held packet the numbering reaches or
    # goes on from is counted then; a new numbering starts the count afresh.
    if verdict is Seq.RESTART:
        state.quality.restart(comp)
    if numbering.placed:  # rare: most packets come in their place
        newest = seq if numbering.newest is None else numbering.newest
        for number in sorted(numbering.placed, key=lambda n: -((newest - n) % 256)):
            state.quality.update(comp, number)  # along the ring, the oldest first
        numbering.placed.clear()
    if verdict is not Seq.HELD and verdict is not Seq.CONFLICT:
        state.quality.update(comp, seq)
    for why, kinds in numbering.blame:
        _conflict(state, f"component {comp}: {why}", changes, kinds)
    numbering.blame.clear()
    if verdict is Seq.CONFLICT:
        _conflict(state, f"component {comp}: {numbering.reason}", changes,
                  numbering.suspects)
    elif verdict is Seq.RESTART:
        # A second numbering took over (or the vehicle rebooted without a silence):
        # nothing waiting for confirmation can be told apart from a forger's.
        _conflict(state, f"component {comp}: {numbering.reason}", changes, _ALL_KINDS)
    return verdict


def account(state: VehicleState, comp: int, seq: int, digest: int, kind: str,
            now: float) -> list[StateChange]:
    """A packet known only by its header and CRC: a state message the link worker
    replaced by a newer one of the same kind while the control loop was behind
    (:class:`~groundctl.link.worker.Conflator`).  It was heard and it is numbered
    (its number judged as any packet's: a second sender's shows), but what it said is
    superseded: nothing is acted on.  Returns notable changes (conflicts)."""
    changes: list[StateChange] = []
    _received(state, comp, seq, digest, kind, now, changes)
    return changes


def expect(state: VehicleState, now: float, *, mode: str | None = None,
           armed: bool | None = None, for_s: float = EXPECT_S) -> None:
    """The executor asked vehicle ``state`` for ``mode`` (or to arm / disarm) at ``now``:
    when its HEARTBEAT reports it within ``for_s`` it is believed at once."""
    if mode is not None:
        state.trust.expected.modes[mode] = now + for_s
    if armed is not None:
        state.trust.expected.armed = (armed, now + for_s)


def unexpect(state: VehicleState, *, mode: str | None = None,
             armed: bool | None = None) -> None:
    """The vehicle refused what was asked: nothing of it is expected any more."""
    if mode is not None:
        state.trust.expected.modes.pop(mode, None)
    exp = state.trust.expected.armed
    if armed is not None and exp is not None and exp[0] is armed:
        state.trust.expected.armed = None


def _conflict(state: VehicleState, reason: str, changes: list[StateChange],
              kinds: Collection[str] = ()) -> None:
    """Count a link conflict; what messages of ``kinds`` said and is still waiting for
    confirmation is forgotten (one of the two packets was not the vehicle's)."""
    state.link_conflicts += 1
    state.last_conflict = reason
    state.trust.forget(kinds)
    changes.append(StateChange("link_conflict", {"reason": reason,
                                                 "count": state.link_conflicts}))


def _heartbeat(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    if not _is_autopilot_heartbeat(msg):
        return
    trust = state.trust
    comp = msg.get_srcComponent()
    pinned = trust.autopilot_component
    if pinned is None or (comp == mavlink.MAV_COMP_ID_AUTOPILOT1 and pinned != comp):
        # MAVLink's autopilot is component 1: a first HEARTBEAT under another
        # component (a forged one, first) must not lock the real autopilot out.
        if pinned is not None:
            _conflict(state, f"autopilot HEARTBEATs from components {pinned} and {comp}: "
                             f"following component {comp}", changes)
        trust.autopilot_component = comp
    elif comp != pinned:
        _conflict(state, f"a second autopilot (component {comp}) speaks for this vehicle "
                         f"(its autopilot is component {pinned})", changes)
        trust.last_trusted = False
        return
    state.last_heartbeat = now
    flavour = Flavour.from_heartbeat(msg.autopilot)
    claim = HeartbeatClaim(flavour, decode_mode(flavour, msg.base_mode, msg.custom_mode),
                           bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
    if not trust.heartbeat_seen:
        trust.heartbeat_seen = True  # nothing to contradict yet: the first is believed
        _believe_heartbeat(state, claim, msg.type, msg.system_status, changes)
        return
    believed = HeartbeatClaim(state.flavour, state.mode, state.armed)
    if claim == believed:
        state.vehicle_type, state.system_status = msg.type, msg.system_status
        pending = trust.heartbeat.first()
        said = trust.quick.claim if trust.quick is not None else \
            pending.value if pending is not None else None
        if isinstance(said, HeartbeatClaim):
            trust.heartbeat.clear()
            trust.quick = None
            _conflict(state, f"one HEARTBEAT said {said.describe()}, the next "
                             f"{claim.describe()} again", changes)
        return
    if _disarm_in_the_air(state, claim, believed, now) and _holds_height(state, now):
        # Not confirmed by a HEARTBEAT alone: wait for one that finds it falling or down
        # (and _global_position refutes it if the vehicle holds its height meanwhile).
        trust.heartbeat.note(claim, now, operator.eq, state.packets)
    elif trust.heartbeat.offer(claim, now, operator.eq, state.packets):
        trust.quick = None
        _believe_heartbeat(state, claim, msg.type, msg.system_status, changes)
    elif (trust.quick is None or trust.quick.claim != claim) \
            and _believable_without_second(state, claim, believed, now):
        step = trust.sequence(comp).step
        wait = CONFIRM_PACKETS_IN_STEP if step == 1 else CONFIRM_PACKETS
        trust.quick = QuickClaim(claim, msg.type, msg.system_status, state.packets + wait)


def _settle_quick(state: VehicleState, now: float, changes: list[StateChange]) -> None:
    """A claim that needs no second HEARTBEAT is believed once a few more packets of
    the vehicle came with no conflict over a HEARTBEAT (a forged one would have met
    the vehicle's own numbering by then), if it still holds."""
    trust = state.trust
    q = trust.quick
    assert q is not None
    if state.packets < q.due:
        return
    trust.quick = None
    believed = HeartbeatClaim(state.flavour, state.mode, state.armed)
    if q.claim != believed and _believable_without_second(state, q.claim, believed, now):
        trust.heartbeat.clear()
        _believe_heartbeat(state, q.claim, q.vehicle_type, q.system_status, changes)


def _believable_without_second(state: VehicleState, claim: HeartbeatClaim,
                               believed: HeartbeatClaim, now: float) -> bool:
    """A change the executor asked for, or a disarm standing on the ground after a
    landing: nothing ends by surprise, so it needs no second HEARTBEAT."""
    exp = state.trust.expected
    if claim.flavour is not believed.flavour:
        return False
    if claim.mode != believed.mode and not exp.mode(claim.mode, now):
        return False
    if claim.armed != believed.armed and not exp.arming(claim.armed, now):
        return not claim.armed and claim.mode in LANDING_MODES and _on_ground(state, now)
    return True


def _disarm_in_the_air(state: VehicleState, claim: HeartbeatClaim,
                       believed: HeartbeatClaim, now: float) -> bool:
    """``claim`` disarms a vehicle believed armed, and nobody asked for it."""
    return believed.armed and not claim.armed \
        and not state.trust.expected.arming(False, now)


def _holds_height(state: VehicleState, now: float) -> bool:
    """The vehicle's own believed global position, fresh, says it is in the air and
    neither falls nor stands on the ground: not what a disarmed multirotor does.  (Only
    the global position has a height above home; with none fresh there is nothing to
    tell by.)"""
    trust = state.trust
    gp = state.global_position
    if gp is None or trust.global_at is None or now - trust.global_at > GROUND_FRESH_S:
        return False
    return _in_the_air(state, gp.relative_alt_m, now) and gp.vel_ned[2] < DISARM_FALL_MS


def _in_the_air(state: VehicleState, height_m: float, now: float) -> bool:
    """Above the ground by ``height_m`` (above home) and not landed by its own report."""
    return height_m > GROUND_HEIGHT_M and not _landed_by_report(state, now)


def _landed_by_report(state: VehicleState, now: float) -> bool:
    """Its own EXTENDED_SYS_STATE, believed and fresh, says it is on the ground."""
    trust = state.trust
    return (state.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
            and trust.landed_at is not None and now - trust.landed_at <= 2 * GROUND_FRESH_S)


def _on_ground(state: VehicleState, now: float) -> bool:
    """The vehicle's own believed telemetry says it stands on the ground, now."""
    trust = state.trust
    gp = state.global_position
    if gp is not None and trust.global_at is not None and now - trust.global_at <= \
            GROUND_FRESH_S and gp.relative_alt_m <= GROUND_HEIGHT_M \
            and abs(gp.vel_ned[2]) <= GROUND_SPEED_MS:
        return True
    return _landed_by_report(state, now)


def _believe_heartbeat(state: VehicleState, claim: HeartbeatClaim, vehicle_type: int,
                       system_status: int, changes: list[StateChange]) -> None:
    flavour = claim.flavour
    if flavour is not state.flavour:
        state.flavour = flavour
        changes.append(StateChange("flavour", {"flavour": str(flavour) if flavour else None}))
    state.vehicle_type = vehicle_type
    state.system_status = system_status
    exp = state.trust.expected
    if claim.mode != state.mode:
        changes.append(StateChange("mode_changed", {"old": state.mode, "new": claim.mode}))
        state.mode = claim.mode
    exp.modes.pop(claim.mode, None)
    if claim.armed != state.armed:
        state.armed = claim.armed
        changes.append(StateChange("armed" if claim.armed else "disarmed", {}))
    if exp.armed is not None and exp.armed[0] is claim.armed:
        exp.armed = None


def _local_position(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    trust = state.trust
    sample = Sample(msg.time_boot_ms / 1000.0, (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz),
                    now)
    believed, conflict = trust.local.offer(sample)
    if conflict is not None:
        _conflict(state, f"LOCAL_POSITION_NED: {conflict}", changes)
    for s in believed:
        ms = round(s.t * 1000.0)
        prev = state.local_time_boot_ms
        if prev is not None and ms > prev:
            gap = (ms - prev) / 1000.0
            if gap > STREAM_GAP_S:
                state.stream_gaps += 1
                state.last_stream_gap_s = gap
        state.position_ned = s.pos
        state.velocity_ned = s.vel
        state.local_time_boot_ms = ms
        state.local_received_at = s.at
    if believed and trust.origin is not None:
        _settle_origin(state, changes)


def _global_position(
    state: VehicleState, msg: Any, now: float, changes: list[StateChange]
) -> None:
    trust = state.trust
    lat, lon, alt = msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0
    if not (abs(lat) <= 90.0 and abs(lon) <= 180.0):
        _conflict(state, f"GLOBAL_POSITION_INT at latitude {lat}, longitude {lon}", changes)
        return
    if trust.global_ref is None:
        trust.global_ref = (lat, lon, *metres_per_degree(lat))
    lat0, lon0, north_m, east_m = trust.global_ref
    here = GlobalPosition(
        lat_deg=lat,
        lon_deg=lon,
        alt_m=alt,
        relative_alt_m=msg.relative_alt / 1000.0,
        vel_ned=(msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0),
        heading_deg=None if msg.hdg == 65535 else msg.hdg / 100.0,
    )
    t = msg.time_boot_ms / 1000.0
    sample = Sample(t, ((lat - lat0) * north_m, (lon - lon0) * east_m, -alt), here.vel_ned, now,
                    payload=(here, t))
    believed, conflict = trust.global_.offer(sample)
    if conflict is not None:
        _conflict(state, f"GLOBAL_POSITION_INT: {conflict}", changes)
    if not believed:
        return
    last = believed[-1]
    payload = last.payload
    assert isinstance(payload, tuple)
    gp: GlobalPosition = payload[0]
    t_last: float = payload[1]
    state.global_position = gp
    trust.global_raw = (t_last, gp.lat_deg, gp.lon_deg, gp.alt_m)
    trust.global_at = now
    # Measure the next samples around this one (metres per degree change with latitude).
    trust.global_ref = (gp.lat_deg, gp.lon_deg, *metres_per_degree(gp.lat_deg))
    trust.global_.ref = replace(last, pos=(0.0, 0.0, -gp.alt_m))
    vz_down = gp.vel_ned[2]
    if state.armed and vz_down < DISARM_FALL_MS and _in_the_air(state, gp.relative_alt_m, now) \
            and any(isinstance(p.value, HeartbeatClaim) and not p.value.armed
                    and now - p.at >= DISARM_BALLISTIC_S for p in trust.heartbeat.items):
        # A disarmed multirotor falls: this one holds its height in the air.
        motion = f"climbs at {-vz_down:.1f} m/s" if vz_down < 0.0 else \
            f"descends at {vz_down:.1f} m/s"
        _conflict(state, f"HEARTBEAT said disarmed while it {motion}, "
                         f"{gp.relative_alt_m:.1f} m up", changes, ("HEARTBEAT",))
    if trust.origin is not None:
        _settle_origin(state, changes)


def _sys_status(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    if msg.onboard_control_sensors_present & prearm:
        ok = bool(msg.onboard_control_sensors_health & prearm)
        if ok is not state.prearm_ok:
            changes.append(StateChange("prearm", {"ok": ok}))
        state.prearm_ok = ok
    # -1 and UINT16_MAX mean "not measured": keep what BATTERY_STATUS may have said.
    if msg.battery_remaining >= 0:
        _battery(state, float(msg.battery_remaining), now, changes)
    if msg.voltage_battery != 65535:
        state.battery_voltage_v = msg.voltage_battery / 1000.0


def _battery_status(
    state: VehicleState, msg: Any, now: float, changes: list[StateChange]
) -> None:
    if msg.id != 0:
        return  # only the first (main) battery
    if msg.battery_remaining >= 0:
        _battery(state, float(msg.battery_remaining), now, changes)
    cells = [v for v in msg.voltages if v != 65535]
    if cells:
        state.battery_voltage_v = sum(cells) / 1000.0


def _battery(state: VehicleState, pct: float, now: float, changes: list[StateChange]) -> None:
    """A battery level: the first, and one far from the believed level (a low one sends
    the vehicle home, or keeps it on the ground), is believed from a second report."""
    trust = state.trust
    believed = state.battery_remaining_pct
    if believed is not None and abs(pct - believed) <= BATTERY_STEP_PCT:
        state.battery_remaining_pct = pct
        pending = trust.battery.first()
        if pending is not None and isinstance(pending.value, float):
            # Reported once far off, then the believed level again: not the vehicle's.
            trust.battery.clear()
            _conflict(state, f"battery {pending.value:.0f} % in one report, {pct:.0f} % "
                             "around it", changes)
        return
    if trust.battery.offer(pct, now, _same_battery, state.packets):
        state.battery_remaining_pct = pct


def _same_battery(a: object, b: object) -> bool:
    return isinstance(a, float) and isinstance(b, float) and abs(a - b) <= BATTERY_STEP_PCT


def _gps_raw(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    state.gps_fix_type = msg.fix_type
    state.gps_satellites = None if msg.satellites_visible == 255 else msg.satellites_visible


def _extended_sys_state(state: VehicleState, msg: Any, now: float,
                        changes: list[StateChange]) -> None:
    trust = state.trust
    value = int(msg.landed_state)
    if value == state.landed_state:
        trust.landed_at = now
        return
    if trust.landed_state.offer(value, now, operator.eq, state.packets):
        changes.append(StateChange("landed_state", {"state": value}))
        state.landed_state, trust.landed_at = value, now


def _origin(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    # Believed once the vehicle's own positions agree with it (see _settle_origin).
    state.trust.origin = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
    _settle_origin(state, changes)


def _settle_origin(state: VehicleState, changes: list[StateChange]) -> None:
    """Check the pending EKF origin against a believed local and global position pair
    close in time: where the global position minus the local offset puts the origin."""
    trust = state.trust
    claim, local, raw = trust.origin, trust.local.ref, trust.global_raw
    if claim is None or local is None or raw is None:
        return
    t, lat, lon, alt = raw
    dt = t - local.t
    if abs(dt) > PAIR_WINDOW_S:
        return  # wait for a closer pair
    ned = (local.pos[0] + local.vel[0] * dt, local.pos[1] + local.vel[1] * dt,
           local.pos[2] + local.vel[2] * dt)
    trust.origin = None
    horizontal, vertical, allowed = origin_error_m(claim, (lat, lon, alt), ned)
    if not (horizontal <= allowed and vertical <= allowed):
        _conflict(state, f"EKF origin {claim[0]:.7f}, {claim[1]:.7f}, {claim[2]:.1f} m is "
                         f"{horizontal:.1f} m across and {vertical:.1f} m up or down from "
                         "where its own positions put it", changes)
        return
    origin = GeoPoint(*claim)
    if origin != state.ekf_origin:
        state.ekf_origin = origin
        changes.append(StateChange("ekf_origin", {"lat": origin.lat_deg, "lon": origin.lon_deg,
                                                  "alt": origin.alt_m}))


def _home(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    """HOME_POSITION: refused where it says where it is in the local frame (ArduPilot
    and PX4 both do) and the EKF origin puts that elsewhere; believed at once where
    it also lies under the disarmed vehicle (both set home where it stands, at boot
    and at arming); otherwise from a second agreeing report."""
    trust = state.trust
    claim = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
    local = (float(msg.x), float(msg.y), float(msg.z))
    origin = state.ekf_origin
    checked = False
    if origin is not None and any(local):
        horizontal, vertical, allowed = origin_error_m(
            (origin.lat_deg, origin.lon_deg, origin.alt_m), claim, local)
        if not (horizontal <= allowed and vertical <= allowed):
            _conflict(state, f"home is {horizontal:.1f} m across and {vertical:.1f} m up or "
                             "down from where its own local position puts it", changes,
                      ("HOME_POSITION",))
            return
        checked = True
    home = state.home
    if home is not None and _near(claim, (home.lat_deg, home.lon_deg, home.alt_m)):
        return
    gp = state.global_position
    under = checked and not state.armed and gp is not None and trust.global_at is not None \
        and now - trust.global_at <= GROUND_FRESH_S \
        and _near(claim, (gp.lat_deg, gp.lon_deg, gp.alt_m), HOME_UNDER_M)
    if under or trust.home.offer(claim, now, _near_claims, state.packets):
        trust.home.clear()
        _believe_home(state, claim, changes)


def _near_claims(a: object, b: object) -> bool:
    return isinstance(a, tuple) and isinstance(b, tuple) and _near(a, b)


def _near(a: tuple[float, float, float], b: tuple[float, float, float],
          within_m: float = ORIGIN_TOLERANCE_M) -> bool:
    north_m, east_m = metres_per_degree(a[0])
    return math.hypot((a[0] - b[0]) * north_m, (a[1] - b[1]) * east_m) <= within_m \
        and abs(a[2] - b[2]) <= within_m


def _believe_home(state: VehicleState, claim: tuple[float, float, float],
                  changes: list[StateChange]) -> None:
    home = GeoPoint(*claim)
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
        state.throttle_at = now


def _wind(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    # ArduPilot's WIND: the direction the wind comes *from* (degrees), the whole
    # vector's length (GCS_MAVLINK::send_wind: wind.length()) and its vertical part.
    speed, direction = float(msg.speed), math.radians(float(msg.direction))
    down = float(msg.speed_z)
    down = down if math.isfinite(down) else 0.0
    if math.isfinite(speed) and math.isfinite(direction) and 0.0 <= speed < MAX_WIND_MPS:
        flat = math.sqrt(max(speed * speed - down * down, 0.0))
        state.wind_ned = (-flat * math.cos(direction), -flat * math.sin(direction), down)
        state.wind_at = now


def _wind_cov(state: VehicleState, msg: Any, now: float, changes: list[StateChange]) -> None:
    # PX4's WIND_COV: the air's velocity, north and east (NaN while it has no estimate).
    north, east, down = float(msg.wind_x), float(msg.wind_y), float(msg.wind_z)
    if math.isfinite(north) and math.isfinite(east) \
            and math.hypot(north, east) < MAX_WIND_MPS:
        state.wind_ned = (north, east, down if math.isfinite(down) else 0.0)
        state.wind_at = now


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
    "EXTENDED_SYS_STATE": _extended_sys_state,
    "STATUSTEXT": _statustext,
    "COMMAND_ACK": _ack,
    "TIMESYNC": _timesync,
    "PARAM_VALUE": _param_value,
    "VFR_HUD": _vfr_hud,
    "WIND": _wind,
    "WIND_COV": _wind_cov,
}
