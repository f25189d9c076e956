"""What the link believes: each report checked against the vehicle's own stream (no I/O).

Without MAVLink signing anybody on the network can send packets under a vehicle's
system id, even from its own address (a raw socket forges the source).  A ground
station cannot tell such a packet from the vehicle's by looking at it, but it can
refuse to believe what contradicts the stream that vehicle has been sending:

* **sequence numbers** (:class:`SequenceCheck`).  Every component numbers its packets
  0..255 per link and wraps (MAVLink serialization; pymavlink tracks them per
  (system, component)).  Loss leaves gaps forward; a jittery link delivers a few
  packets late, into a gap; a duplicating one repeats a packet byte for byte.  A
  second sender under the same ids cannot fit into one numbering: two *different*
  packets with one number is a link conflict; a packet far from the numbering (a step
  ahead of more than :data:`MAX_STEP`, or a step back that is not a reordering: deeper
  than :data:`REORDER_DEPTH`, or more than :data:`MAX_LATE_RUN` late in a row) is held
  back, not acted on, and is a conflict once the vehicle's numbering goes on without
  it (unless the stream was silent before it: an outage, a reboot).  Of two packets
  with one number, which was forged is unknown, but what each carried is: every report
  of those kinds still waiting for confirmation is forgotten.  (The vehicle's own
  packet with the forged packet's number always arrives, unless lost.)
* **motion** (:class:`MotionCheck`).  Consecutive position samples must agree with
  the velocities they report, within what a multirotor can do, on a vehicle clock
  that does not run ahead of ours.  The first track, and a jump (a GPS glitch, an EKF
  reset, a reboot), are believed once a run of samples following each other spans
  :data:`JUMP_CONFIRM_S`; a sample that the next one contradicts (it continues the
  old track) was not the vehicle's.  A sample that continues both the old track and
  the run that left it contradicts neither: the two met again (an impact stops a
  falling drone faster than any manoeuvre, and the next sample on the ground fits the
  fall too).
* **the EKF origin and home** (:func:`origin_error_m`) must agree with the vehicle's
  own local and global positions: an origin that does not is not its origin.
* **reports that end a show or hold a vehicle back** (a mode nobody asked for, a
  disarm in the air, a battery level, the landed state, home) are believed from a
  second agreeing report at least :data:`CONFIRM_GAP_S` later with no conflict of
  their kind in between (:class:`Candidates`); the real vehicle streams at 10 Hz or
  more meanwhile, so a forged report is contradicted before it can be confirmed.
  That needs the vehicle's own HEARTBEAT in between, which a lossy radio, a starved
  ground station (its socket full) or a stalled vehicle can drop: so a **disarm in
  the air** also needs the vehicle's own motion to agree.  A disarmed multirotor
  falls; one that still holds its height :data:`DISARM_BALLISTIC_S` after the claim
  refutes it, and the claim is confirmed only by a HEARTBEAT that finds the vehicle
  falling (:data:`DISARM_FALL_MS`) or down (on the ground, or landed by its own
  report).  Measured: the first rule alone let one forged pair through in a busy
  run of the nine-vehicle dry-run (vehicle 5 dropped from the show while it hovered).
  What the executor asked for (the mode it commanded, arming, disarming) and a
  disarm of a vehicle standing on the ground in a landing mode end nothing by
  surprise: they are believed without the second HEARTBEAT, once
  :data:`CONFIRM_PACKETS_IN_STEP` more packets of the vehicle have arrived with no
  conflict over a HEARTBEAT (0.2 s at its stream rates; :data:`CONFIRM_PACKETS` if
  it came after a gap in the numbering).  The first
  HEARTBEAT is believed as it stands (nothing can contradict it yet); a later one
  corrects it by the same rule.

None of this authenticates anything: an attacker who can silence the vehicle (or
who speaks for one that is silent) is believed.  That needs signing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection
from dataclasses import dataclass, field, replace
from enum import Enum

from groundctl import wgs84
from groundctl.link.flavours import Flavour

Vec3 = tuple[float, float, float]

#: Packets of one numbering that may arrive behind the newest: a jittery link reorders
#: a burst (an autopilot sends its telemetry in bursts: PX4 at 10 ms jitter reorders 9
#: deep), a second sender's numbering is anywhere in the ring.
REORDER_DEPTH = 32
#: Forward steps up to this are losses (step - 1 packets lost); further ones are far.
MAX_STEP = 12
#: A component silent this long (our clock, s) may come back anywhere in its numbering:
#: an outage or a reboot, not a second sender.
SILENCE_S = 0.5
#: ... but no more than this many in a row.  Counted in packets, not seconds: our own
#: stalls (the socket holds a backlog) must not read as a second sender.
MAX_LATE_RUN = 12
#: A report is confirmed only after this many further packets of the vehicle: by then a
#: forged packet numbered up to MAX_STEP ahead has met the vehicle's own of its number.
CONFIRM_PACKETS = MAX_STEP + 2
#: ... or this many, for one that came numbered exactly as the vehicle's next packet: a
#: forgery numbered so meets the vehicle's own packet of that number at once.
CONFIRM_PACKETS_IN_STEP = 4
#: Forward steps up to this are losses; more is read as a step back (MAVLink's ring
#: is 256 long, so half of it is the most either way).
SEQ_WINDOW = 128
#: A stream going on from packets held far ahead of the numbering for this long (our
#: clock, s) is a new numbering; sooner it may be a burst the link reordered (the
#: simulator's 50 ms of jitter on parameter and fence bursts: 185 "conflicts" a flight).
REORDER_S = 0.3
#: Packets held far from the numbering at once, at most (the oldest is blamed).
MAX_HELD = 16

#: A show-ending report is confirmed by a second one at least this much later (our
#: clock, s): long enough for the vehicle's own stream to have spoken in between.
CONFIRM_GAP_S = 0.5
#: A position jump is believed once samples continuing from it span this long (s).
JUMP_CONFIRM_S = 0.25
#: What the executor asked for stays expected this long after the command was sent (s).
EXPECT_S = 8.0

#: Position samples: error allowed against the reported velocities, m.
POSITION_TOLERANCE_M = 0.5
#: Velocity change allowed beyond MAX_ACCEL_MS2 * dt, m/s.
VELOCITY_TOLERANCE_MS = 1.0
#: The most a multirotor accelerates (a hard manoeuvre, a strong gust), m/s^2.
MAX_ACCEL_MS2 = 25.0
#: The vehicle's clock may run ahead of ours between two samples by this much (our own
#: receive jitter: the earlier sample may have waited in a queue), s.
CLOCK_SLACK_S = 1.0

#: A disarmed multirotor falls: this long after a disarm (free fall from a 3 m/s climb
#: is past 1.9 m/s down by then), a vehicle in the air that descends slower than
#: DISARM_FALL_MS (or climbs) was not disarmed.
DISARM_BALLISTIC_S = 0.5
DISARM_FALL_MS = 1.0

#: "On the ground" for a disarm in a landing mode: height above home, m, and vertical
#: speed, m/s, in a GLOBAL_POSITION_INT at most GROUND_FRESH_S old.
GROUND_HEIGHT_M = 0.5
GROUND_SPEED_MS = 0.3
GROUND_FRESH_S = 1.0

#: Battery reports further apart than this (percentage points) need a second report.
BATTERY_STEP_PCT = 5.0

#: EKF origin / home against the positions: tolerance, m, plus this fraction of the
#: distance from the origin (the autopilots' flat-earth offsets differ a little).
ORIGIN_TOLERANCE_M = 1.0
ORIGIN_TOLERANCE_FRACTION = 0.01
#: A home this close to where a disarmed vehicle stands is where it stands, m (GPS
#: drift since home was set, a vehicle nudged on its slot).
HOME_UNDER_M = 2.0
#: A local and a global sample this far apart on the vehicle's clock still pair, s.
PAIR_WINDOW_S = 0.3

#: Modes a vehicle lands in (as the link decodes them): a disarm on the ground in one
#: of these is the landing ending.
LANDING_MODES = frozenset({"LAND", "AUTO.LAND", "AUTO.PRECLAND", "RTL", "AUTO.RTL",
                           "SMART_RTL"})


class Seq(Enum):
    """How a packet's sequence number fits its component's numbering."""

    FIRST = "first"
    """The first packet of this component."""
    NEXT = "next"
    """Ahead of the newest (maybe after a gap: loss), or the first after a silence."""
    LATE = "late"
    """A little behind the newest, into a gap: a reordering link."""
    DUPLICATE = "duplicate"
    """The same bytes under a number already received: a duplicating link."""
    CONFLICT = "conflict"
    """Another packet had this number: a second sender under this system and component."""
    HELD = "held"
    """Far from the numbering: held back (not acted on) until the next packet shows whether
    the numbering goes on from it (a restart) or from before it (someone else's)."""
    RESTART = "restart"
    """The numbering went on from a held packet: a new numbering (a reboot without a
    silence, or a second sender that took over); counted as a conflict."""


#: A slot two different packets claimed: whatever comes under that number conflicts.
_CONTESTED = -1


@dataclass
class SequenceCheck:
    """One component's numbering: which numbers arrived, and what they carried.

    ``slots[n]`` holds a digest of the packet received with number ``n`` since the
    numbering last passed ``n`` (moving forward clears the slots it moves over), so a
    slot behind the newest is filled only by a packet of this lap of the ring.  Nothing
    else ever clears a slot: a forger must not be able to make the link forget which
    numbers the vehicle has used -- except the vehicle's own silence of ``SILENCE_S``
    (an outage, a reboot), after which the old lap is stale.
    """

    newest: int | None = None
    """The furthest number along the ring."""
    newest_at: float = -math.inf
    """Our time of the last packet that fitted."""
    slots: list[int | None] = field(default_factory=lambda: [None] * 256)
    """Digest of the packet received under each number in this lap (None: none yet)."""
    kinds: list[str] = field(default_factory=lambda: [""] * 256)
    """The message type each of those packets carried."""
    late_run: int = 0
    """Late packets since the newest."""
    step: int = 0
    """How far the last packet moved the numbering (1: the very next number; 0: it did
    not move it forward as the vehicle's own next packet does)."""
    held: list[tuple[int, int, str, float]] = field(default_factory=list)
    """Packets far from the numbering, held (never acted on): (number, digest, type, our
    time).  One ahead of the numbering waits for it to get there (a jittery link sends
    a burst out of order); one the numbering passes was the vehicle's own, early; one
    that does not fit (behind, beyond the window, or another packet under its number)
    is blamed."""
    reason: str = ""
    """Why the last packet was a conflict (or a restart)."""
    suspects: frozenset[str] = frozenset()
    """The message types the last conflict involved (either packet may be the forged)."""
    blame: list[tuple[str, frozenset[str]]] = field(default_factory=list)
    """Set by :meth:`check` when held packets turned out not to be the vehicle's: why,
    and the type of each (one conflict each).  The caller counts them and clears it."""
    placed: list[int] = field(default_factory=list)
    """Set by :meth:`check` when held packets turned out to be the vehicle's own (the
    numbering got to them, or went on from them): their numbers, in arrival order.  The
    caller counts them as received and clears it."""

    def check(self, seq: int, digest: int, kind: str = "", at: float = 0.0) -> Seq:
        """Account for packet number ``seq`` of type ``kind`` whose bytes hash to
        ``digest``, arrived at our time ``at``."""
        self.step = 0
        if self.newest is None:
            self._put(seq, digest, kind)
            self.newest, self.newest_at = seq, at
            return Seq.FIRST
        if at - self.newest_at >= SILENCE_S:
            # Back after a silence of its own (an outage, a reboot): its numbering may
            # come back anywhere, and the lap it left is stale -- a number it used
            # before the silence is not a second sender's (measured: after a 5 s link
            # cut, every vehicle "conflicted" with its own old packets, was not
            # believed, and two came within 0.56 m).
            self.held = []
            self.slots = [None] * 256
            self.kinds = [""] * 256
            self._put(seq, digest, kind)
            self.newest, self.newest_at, self.late_run = seq, at, 0
            return Seq.NEXT
        verdict = self._fit(seq, digest, kind)
        if verdict is not Seq.HELD:
            if verdict is not Seq.CONFLICT:
                self.newest_at = at
            self._settle_held()
            return verdict
        # Far from the numbering.  A stream going on from held packets for REORDER_S
        # with the old numbering silent meanwhile is a new numbering (a reboot without a
        # silence of SILENCE_S, or a second sender that took over); sooner, it may be a
        # burst reordered by the link, and the numbering may yet get there.
        chain = [h for h in self.held if 0 < (seq - h[0]) % 256 <= MAX_STEP]
        # ... and only while the old numbering is quiet: with the vehicle's own packets
        # still coming, a stream beside them is a second sender's, never a restart.
        if chain and at - min(h[3] for h in chain) >= REORDER_S \
                and at - self.newest_at >= REORDER_S:
            first = min(chain, key=lambda h: h[3])
            self.reason = (f"numbering moved from {self.newest} to {first[0]} (a reboot, or "
                           "a second sender)")
            for h in chain:
                self._put(h[0], h[1], h[2])
                self.placed.append(h[0])
            self.held = [h for h in self.held if h not in chain]
            self._put(seq, digest, kind)
            self.newest, self.newest_at, self.late_run = seq, at, 0
            self._settle_held()
            return Seq.RESTART
        self.held.append((seq, digest, kind, at))
        if len(self.held) > MAX_HELD:
            self._blame(self.held.pop(0))
        return Seq.HELD

    def _settle_held(self) -> None:
        """After the numbering moved: each held packet it passed was the vehicle's own
        (early), each still ahead within the window waits, the rest are blamed."""
        assert self.newest is not None
        keep = []
        for h in self.held:
            number, digest, kind, _ = h
            behind = (self.newest - number) % 256
            if behind <= MAX_STEP:  # the numbering got there (or just past it)
                old = self.slots[number]
                if old is None:
                    self._put(number, digest, kind)  # early, and now in its place
                    self.placed.append(number)
                elif old != digest:
                    self.slots[number] = _CONTESTED
                    self._blame(h, f"two different packets numbered {number}")
                continue
            if 0 < (number - self.newest) % 256 <= SEQ_WINDOW:
                keep.append(h)  # still ahead: the numbering may get there
                continue
            self._blame(h)
        self.held = keep

    def _blame(self, h: tuple[int, int, str, float], why: str | None = None) -> None:
        """Held packet ``h`` was not the vehicle's: one conflict (see :attr:`blame`)."""
        self.blame.append((why or f"packet numbered {h[0]} does not fit the numbering "
                                  f"(at {self.newest})", frozenset({h[2]} - {""})))

    def _fit(self, seq: int, digest: int, kind: str) -> Seq:
        """Where ``seq`` falls against the newest (HELD: far from it)."""
        assert self.newest is not None
        step = (seq - self.newest) % 256
        if 0 < step <= SEQ_WINDOW:
            if step > MAX_STEP:
                return Seq.HELD
            for k in range(1, step + 1):
                self.slots[(self.newest + k) % 256] = None
            self._put(seq, digest, kind)
            self.newest, self.late_run, self.step = seq, 0, step
            return Seq.NEXT
        old = self.slots[seq]
        if old is not None:
            if old == digest:
                return Seq.DUPLICATE
            self.reason = f"two different packets numbered {seq}"
            self.suspects = frozenset({kind, self.kinds[seq]} - {""})
            self.slots[seq] = _CONTESTED
            return Seq.CONFLICT
        depth = (self.newest - seq) % 256
        if depth <= REORDER_DEPTH and self.late_run < MAX_LATE_RUN:
            self._put(seq, digest, kind)
            self.late_run += 1
            return Seq.LATE
        return Seq.HELD

    def _put(self, seq: int, digest: int, kind: str) -> None:
        self.slots[seq] = digest
        self.kinds[seq] = kind


@dataclass(frozen=True)
class Sample:
    """One position report on the vehicle's clock."""

    t: float
    """The vehicle's time_boot_ms, in seconds."""
    pos: Vec3
    """Position in a local Cartesian frame (NED), m."""
    vel: Vec3
    """Velocity in the same axes, m/s."""
    at: float
    """Our time of arrival, s."""
    payload: object = field(default=None, compare=False)
    """What the caller keeps with it (the decoded report)."""


def _norm(x: float, y: float, z: float) -> float:
    return math.sqrt(x * x + y * y + z * z)


def follows(a: Sample, b: Sample) -> bool:
    """Whether ``b`` can be the vehicle's next sample after ``a``: later on its clock, its
    clock not ahead of ours, its position where ``a``'s and its own velocities lead
    within what a multirotor can do."""
    dt = b.t - a.t
    if dt <= 0.0 or dt > (b.at - a.at) + CLOCK_SLACK_S:
        return False
    reach = 0.5 * MAX_ACCEL_MS2 * dt * dt
    ex = b.pos[0] - a.pos[0] - 0.5 * (a.vel[0] + b.vel[0]) * dt
    ey = b.pos[1] - a.pos[1] - 0.5 * (a.vel[1] + b.vel[1]) * dt
    ez = b.pos[2] - a.pos[2] - 0.5 * (a.vel[2] + b.vel[2]) * dt
    if _norm(ex, ey, ez) > POSITION_TOLERANCE_M + reach:
        return False
    dv = _norm(b.vel[0] - a.vel[0], b.vel[1] - a.vel[1], b.vel[2] - a.vel[2])
    return dv <= VELOCITY_TOLERANCE_MS + MAX_ACCEL_MS2 * dt


#: Runs of samples kept apart while a jump (or the first track) waits for its proof.
MAX_CHAINS = 4
#: A sample up to this much older than the believed one that fits before it arrived
#: late (reordered), s of the vehicle's clock.
LATE_SAMPLE_S = 1.0


@dataclass
class MotionCheck:
    """One position stream (LOCAL_POSITION_NED or GLOBAL_POSITION_INT) of one vehicle."""

    ref: Sample | None = None
    """The last sample believed."""
    chains: list[list[Sample]] = field(default_factory=list)
    """Runs of samples that do not follow :attr:`ref` but follow each other (the first
    track, a jump, or someone else's samples): one is believed once it spans
    JUMP_CONFIRM_S; all are forgotten (a conflict) when the believed track goes on."""

    def offer(self, s: Sample) -> tuple[list[Sample], str | None]:
        """The samples to believe now (in order) and, if ``s`` contradicts what came
        before, why."""
        ref = self.ref
        if ref is not None:
            if s.t == ref.t and s.pos == ref.pos:
                return [], None  # the same report again (a resend, a request answered)
            if 0.0 < ref.t - s.t <= LATE_SAMPLE_S and follows(s, replace(ref, at=s.at)):
                return [], None  # overtaken on the way (a reordering link): stale, not false
            if follows(ref, s):
                conflict = None
                # A sample both tracks lead to is no second sender: the two met again
                # (an impact: the first sample on the ground stopped faster than a
                # multirotor can brake, and the next one fits both it and the fall).
                if self.chains and not any(follows(c[-1], s) for c in self.chains):
                    far = max(self._jump(c[0]) for c in self.chains)
                    conflict = (f"position samples {far:.1f} m off the track, which went on "
                                "(another sender)")
                self.chains = []
                self.ref = s
                return [s], conflict
        for chain in self.chains:
            if follows(chain[-1], s):
                chain.append(s)
                if s.at - chain[0].at >= JUMP_CONFIRM_S:
                    self.chains = []
                    self.ref = s
                    return chain, None
                return [], None
        self.chains = [*self.chains[-(MAX_CHAINS - 1):], [s]]
        return [], None

    def _jump(self, s: Sample) -> float:
        if self.ref is None:
            return 0.0
        r = self.ref.pos
        return _norm(s.pos[0] - r[0], s.pos[1] - r[1], s.pos[2] - r[2])

    def forget_pending(self) -> None:
        """Drop the unconfirmed runs."""
        self.chains = []


def metres_per_degree(lat_deg: float) -> tuple[float, float]:
    """(north, east) metres per degree of latitude and longitude at ``lat_deg`` (WGS-84)."""
    phi = math.radians(lat_deg)
    s2 = math.sin(phi) ** 2
    m = wgs84.A * (1 - wgs84.E2) / (1 - wgs84.E2 * s2) ** 1.5
    n = wgs84.A / math.sqrt(1 - wgs84.E2 * s2)
    return math.radians(1.0) * m, math.radians(1.0) * n * math.cos(phi)


def origin_error_m(origin: tuple[float, float, float], point: tuple[float, float, float],
                   ned: Vec3) -> tuple[float, float, float]:
    """How far ``origin`` (lat, lon, alt) is from where ``point`` (lat, lon, alt) and its
    local NED offset ``ned`` put it: (horizontal m, vertical m, allowed horizontal m).

    The allowance grows with the offset: ArduPilot offsets locations on a sphere, PX4
    on its own projection, and neither is exactly this ellipsoid's tangent plane.
    """
    north_m, east_m = metres_per_degree(point[0])
    dn = (point[0] - origin[0]) * north_m - ned[0]
    de = (point[1] - origin[1]) * east_m - ned[1]
    dz = (point[2] - origin[2]) + ned[2]  # NED z is down: alt = origin alt - z
    offset = math.hypot(ned[0], ned[1])
    return (math.hypot(dn, de), abs(dz),
            ORIGIN_TOLERANCE_M + ORIGIN_TOLERANCE_FRACTION * offset)


@dataclass(frozen=True)
class HeartbeatClaim:
    """What one autopilot HEARTBEAT says the vehicle is."""

    flavour: Flavour | None
    """The autopilot family."""
    mode: str
    """The decoded mode."""
    armed: bool
    """MAV_MODE_FLAG_SAFETY_ARMED."""

    def describe(self) -> str:
        return f"{self.mode}, {'armed' if self.armed else 'disarmed'}"


@dataclass(frozen=True)
class QuickClaim:
    """A HEARTBEAT claim believable without a second HEARTBEAT, waiting for packets."""

    claim: HeartbeatClaim
    """What it says."""
    vehicle_type: int
    """Its HEARTBEAT.type."""
    system_status: int
    """Its HEARTBEAT.system_status."""
    due: int
    """The vehicle's packet count at which it is believed (if nothing contradicts it)."""


@dataclass
class Pending:
    """A report not believed yet: the first of the two a confirmation needs."""

    value: object
    """What it says."""
    at: float
    """Our time it arrived, s."""
    packets: int = 0
    """The vehicle's packets received by then."""


#: Different reports of one kind waiting for confirmation at once (the vehicle's own
#: and a forger's: a forged report in between must not displace the vehicle's).
MAX_CANDIDATES = 4


@dataclass
class Candidates:
    """Reports of one kind not believed yet; one is, once reported again (agreeing) at
    least CONFIRM_GAP_S after it first was."""

    items: list[Pending] = field(default_factory=list)
    """The first report of each distinct value, oldest first."""

    def offer(self, value: object, now: float, same: Callable[[object, object], bool],
              packets: int) -> bool:
        """Account for report ``value``, arrived at ``now`` as the vehicle's ``packets``-th
        packet; True when it is confirmed (and all are dropped)."""
        c = self._find(value, same)
        if c is None:
            self._add(value, now, packets)
            return False
        if now - c.at >= CONFIRM_GAP_S and packets - c.packets >= CONFIRM_PACKETS:
            self.items = []
            return True
        return False

    def note(self, value: object, now: float, same: Callable[[object, object], bool],
             packets: int) -> None:
        """Account for report ``value`` without confirming it: it becomes a candidate if it
        is not one yet (a later :meth:`offer` may confirm it)."""
        if self._find(value, same) is None:
            self._add(value, now, packets)

    def _find(self, value: object, same: Callable[[object, object], bool]) -> Pending | None:
        return next((c for c in self.items if same(c.value, value)), None)

    def _add(self, value: object, now: float, packets: int) -> None:
        self.items = [*self.items[-(MAX_CANDIDATES - 1):], Pending(value, now, packets)]

    def first(self) -> Pending | None:
        return self.items[0] if self.items else None

    def clear(self) -> None:
        self.items = []

    def __bool__(self) -> bool:
        return bool(self.items)


@dataclass
class Expected:
    """What the executor asked this vehicle for: such a change is believed at once."""

    modes: dict[str, float] = field(default_factory=dict)
    """Mode name -> until when (our clock) it is expected."""
    armed: tuple[bool, float] | None = None
    """(armed state, until when) after an ARM/DISARM command."""

    def mode(self, name: str, now: float) -> bool:
        until = self.modes.get(name)
        return until is not None and now <= until

    def arming(self, armed: bool, now: float) -> bool:
        return self.armed is not None and self.armed[0] is armed and now <= self.armed[1]


@dataclass
class Trust:
    """Per-vehicle bookkeeping behind the believed state (see the module docstring)."""

    sequences: dict[int, SequenceCheck] = field(default_factory=dict)
    """Numbering per component id."""
    autopilot_component: int | None = None
    """The component whose HEARTBEAT speaks for the vehicle's mode and arming (and whose
    telemetry speaks for its state)."""
    heartbeat_seen: bool = False
    """An autopilot HEARTBEAT was believed already (the first one is taken as it is)."""
    heartbeat: Candidates = field(default_factory=Candidates)
    """HEARTBEAT claims (:class:`HeartbeatClaim`) that differ from the believed one."""
    quick: QuickClaim | None = None
    """A HEARTBEAT claim that needs no second HEARTBEAT (asked for, or a landing's end),
    waiting for CONFIRM_PACKETS more packets."""
    landed_state: Candidates = field(default_factory=Candidates)
    """EXTENDED_SYS_STATE landed states that differ from the believed one."""
    battery: Candidates = field(default_factory=Candidates)
    """Battery percentages not believed yet (the first, or far from the believed one)."""
    origin: tuple[float, float, float] | None = None
    """A GPS_GLOBAL_ORIGIN (lat, lon, alt) waiting for positions to be checked against."""
    home: Candidates = field(default_factory=Candidates)
    """HOME_POSITIONs (lat, lon, alt) waiting for a second report."""
    local: MotionCheck = field(default_factory=MotionCheck)
    """LOCAL_POSITION_NED."""
    global_: MotionCheck = field(default_factory=MotionCheck)
    """GLOBAL_POSITION_INT, in metres around :attr:`global_ref`."""
    global_ref: tuple[float, float, float, float] | None = None
    """(lat, lon, north m/deg, east m/deg) the global samples are measured from."""
    global_raw: tuple[float, float, float, float] | None = None
    """The last believed GLOBAL_POSITION_INT: (vehicle time s, lat, lon, alt)."""
    global_at: float | None = None
    """Our time of the last believed GLOBAL_POSITION_INT."""
    landed_at: float | None = None
    """Our time of the last EXTENDED_SYS_STATE agreeing with the believed landed state."""
    expected: Expected = field(default_factory=Expected)
    """What the executor asked for."""
    last_trusted: bool = True
    """Whether the last packet fitted the stream (a conflicting one is not acted on)."""

    def sequence(self, component: int) -> SequenceCheck:
        check = self.sequences.get(component)
        if check is None:
            check = self.sequences[component] = SequenceCheck()
        return check

    def forget(self, kinds: Collection[str]) -> None:
        """A conflict involving messages of these types: what such messages said and is
        still waiting for confirmation is not believed any more (it may be the forger's)."""
        for kind in kinds:
            if kind == "HEARTBEAT":
                self.heartbeat.clear()
                self.quick = None
            elif kind in ("SYS_STATUS", "BATTERY_STATUS"):
                self.battery.clear()
            elif kind == "EXTENDED_SYS_STATE":
                self.landed_state.clear()
            elif kind == "HOME_POSITION":
                self.home.clear()
            elif kind == "GPS_GLOBAL_ORIGIN":
                self.origin = None
