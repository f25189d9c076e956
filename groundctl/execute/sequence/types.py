"""The sequence's vocabulary: the actions it returns (:class:`SetMode` ...
:class:`Notice`), where a vehicle and the show are (:class:`VehiclePhase`,
:class:`ShowPhase`), its tolerances (:class:`SequenceConfig`) and constants, one
vehicle's progress (:class:`VehicleRun`) and what the driver streams each tick
(:class:`StreamRequest`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from groundctl.execute.leaving import Join, Leave
from groundctl.execute.paths import Path, PathClocks, PathKind
from groundctl.execute.showclock import ShowClock
from groundctl.link.flavours import Flavour
from groundctl.plan.plan import Plan
from groundctl.plan.trajectory import Trajectories

# -- actions -----------------------------------------------------------------------------


@dataclass(frozen=True)
class SetMode:
    """Switch ``sysid`` to ``mode`` (a name :func:`~groundctl.link.flavours.mode_request`
    knows)."""

    sysid: int
    """MAVLink system id."""
    mode: str
    """Mode name."""


@dataclass(frozen=True)
class Arm:
    """Arm ``sysid`` (never forced)."""

    sysid: int
    """MAVLink system id."""


@dataclass(frozen=True)
class Takeoff:
    """MAV_CMD_NAV_TAKEOFF to ``alt_m`` above home."""

    sysid: int
    """MAVLink system id."""
    alt_m: float
    """Altitude above home, m."""


@dataclass(frozen=True)
class Land:
    """Land where it is, in the flavour's land mode."""

    sysid: int
    """MAVLink system id."""


@dataclass(frozen=True)
class Disarm:
    """Disarm on the ground (not forced: the autopilot refuses it in flight)."""

    sysid: int
    """MAVLink system id."""


@dataclass(frozen=True)
class Kill:
    """Force-disarm in flight: the motors stop and the drone falls."""

    sysid: int
    """MAVLink system id."""


@dataclass(frozen=True)
class Notice:
    """Something the operator must see (a lost vehicle, a refused command)."""

    sysid: int | None
    """The vehicle concerned, or None for the whole show."""
    text: str
    """The message, naming the vehicle, what happened and why."""
    kind: str = field(default="", compare=False)
    """What happened, the same for every vehicle it happens to (``lost``, ``landed``...):
    the driver folds many notices of one kind in one update into one line."""
    summary: str = field(default="", compare=False)
    """The text for a folded line, after the list of vehicles (``landed``)."""


Action = SetMode | Arm | Takeoff | Land | Disarm | Kill | Notice
Command = SetMode | Arm | Takeoff | Land | Disarm | Kill


class VehiclePhase(enum.StrEnum):
    """Where one vehicle is in the sequence."""

    PREFLIGHT = "preflight"
    ARMING = "arming"
    TAKEOFF = "takeoff"
    READY = "ready"
    JOINING = "joining"
    SHOW = "show"
    LEAVING = "leaving"
    RETURNING = "returning"
    LANDING = "landing"
    LANDED = "landed"
    LOST = "lost"
    FAILED = "failed"
    KILLED = "killed"


class ShowPhase(enum.StrEnum):
    """Where the show as a whole is."""

    PREFLIGHT = "preflight"
    ARMING = "arming"
    TAKEOFF = "takeoff"
    SHOW = "show"
    LANDING = "landing"
    LANDED = "landed"


#: Above this height above home a vehicle is taking off (or flying), m.
AIRBORNE_M = 0.5
#: A hold point is moved at most this many separation limits to clear the others.
HOLD_APART_MAX_M = 2.0
#: Hold points are held apart by the separation limit plus this, m (the guard's margin).
HOLD_APART_MARGIN_M = 0.1
#: Risen this far since its takeoff was sent, a vehicle is climbing (whatever its height
#: above home), m: well above an EKF's altitude noise on the ground.
CLIMB_SEEN_M = 0.2

#: Phases a vehicle never leaves: it is down (seen disarmed) or given up.  LOST is not
#: one of them: a silent vehicle may still be airborne.
_DONE = {VehiclePhase.LANDED, VehiclePhase.FAILED, VehiclePhase.KILLED}
#: Phases the per-vehicle update does not advance (LOST waits to be heard again).
_IDLE = _DONE | {VehiclePhase.LOST, VehiclePhase.PREFLIGHT}
_STREAMED = {VehiclePhase.READY, VehiclePhase.JOINING, VehiclePhase.SHOW,
             VehiclePhase.LEAVING, VehiclePhase.RETURNING}
_LAND_MODES = {"LAND", "AUTO.LAND"}  # ArduCopter's and PX4's, as decoded by the link
#: A vehicle counts as off its plan only if it is farther than the rejoin tolerance
#: from every point its plan passed in this last stretch of show time, s.
OFF_PLAN_WINDOW_S = 0.5
#: Silence longer than this (telemetry streams at 10 Hz), s, even if too short to mark
#: the vehicle lost, means it may have flown on without us: its position is checked.
SILENCE_GAP_S = 0.5
#: Holds of the whole fleet for what the vehicles did not do (our stall or overload, a
#: fleet-wide silence): while one is in force, a vehicle's own gap is not its fault.
FLEET_HOLDS = frozenset({"stall", "overload", "silence"})
#: Modes an autopilot's link-loss failsafe puts a vehicle in (hold, land, return), as
#: decoded by the link; a vehicle found in one after a silence is taken back.
_LINK_FAILSAFE_MODES = {
    Flavour.ARDUPILOT: frozenset({"LOITER", "BRAKE", "LAND", "RTL", "SMART_RTL"}),
    Flavour.PX4: frozenset({"AUTO.LOITER", "AUTO.LAND", "AUTO.RTL"}),
}
#: This many vehicles holding off their plans at once (a fleet-wide link loss or stall
#: stopped them short of the plan) and the whole fleet lands on one joint return planned
#: from where everyone hovers: their ways out, planned one at a time through a show that
#: flies on, each take the others for drones on their plans (measured: a 5 s cut of a
#: PX4 fleet's link on a busy machine stranded five at once; two came 1.30 m apart).
STRANDED_LAND_ALL = 2
#: The last resort lands a drone straight down only if no drone on the ground is within
#: this of where it lands, m (drones are under half a metre across; the separation limit
#: is for drones in the air).
GROUND_CLEARANCE_M = 1.0
#: ... and only if every drone in the air below it is this much farther than the limit
#: sideways, m: a descent takes 10-20 s, and a wind that stranded drones moves them.
COLUMN_MARGIN_M = 1.0
#: A drone held this long with a drone below it says so (it keeps waiting), s.
COLUMN_WAIT_S = 30.0
#: Returns planned again because a landing spot was taken (then: nearest free spot).
MAX_REPLANS = 2
#: A vehicle is taken back from a link-loss failsafe at most this many times.
MAX_RETAKES = 2
#: ... if the failsafe comes within this long of its own silence ending, s ...
RETAKE_WINDOW_S = 10.0
#: ... and that silence was at least this long (PX4's COM_OF_LOSS_T default), s.
LINK_FAILSAFE_GAP_S = 1.0
#: A PX4 vehicle found in a failsafe mode this soon after we resumed the setpoints we had
#: not sent it for LINK_FAILSAFE_GAP_S is taken back (its HEARTBEAT says so within about
#: a second, and it is confirmed by the next), s.
STARVED_WINDOW_S = 3.0
#: A vehicle that said its own fence was breached this recently is never taken back from
#: the mode its fence put it in (it is not a link-loss failsafe), s.
FENCE_NOTICE_S = 10.0


#: This share of the fleet (at least two) below the battery threshold lands everyone.
LOW_BATTERY_FLEET = 0.1
#: The track of a spare waiting in the air before it takes one over (its run exists from
#: the start: it takes off with the fleet and hovers at its standby point).
NO_TRACK = -1
#: A way out planned too late this many times is given up (no retry storm).
MAX_LATE_LEAVES = 3
#: ... and each time it leaves at least this much show time later than it could, doubled
#: each time, s (more time to plan it).
LATE_LEAVE_S = 4.0
#: The mode each autopilot flies our setpoints in.
_FLIGHT_MODE = {Flavour.ARDUPILOT: "GUIDED", Flavour.PX4: "OFFBOARD"}
#: Where a vehicle that lost our setpoints waits (PX4's offboard-loss failsafe: Hold).
_HOLD_MODE = {Flavour.ARDUPILOT: "GUIDED", Flavour.PX4: "AUTO.LOITER"}


@dataclass(frozen=True)
class SequenceConfig:
    """Tolerances and timeouts of the sequence."""

    takeoff_tolerance_m: float = 0.3
    """Takeoff is done within this of the takeoff altitude, m."""
    arrive_tolerance_m: float = 0.5
    """A returning vehicle is over its landing slot within this, m."""
    max_attempts: int = 3
    """Times a step (mode, arm, takeoff, land) is tried before giving up."""
    retry_after_s: float = 1.0
    """Pause before re-sending a refused command, s."""
    takeoff_retry_after_s: float = 4.0
    """Pause before a refused takeoff is re-sent or given up, s: longer than an
    autopilot's spool-up before lift-off (2.6 s measured on ArduCopter SITL), so a
    vehicle that took off after all -- the refusal forged, or the answer to a repeat of
    an accepted takeoff whose ACK was lost -- is seen climbing first (then it is not
    re-sent: the climb is what counts)."""
    step_timeout_s: float = 5.0
    """A mode or arm step with no effect in telemetry after this is re-sent, s."""
    takeoff_timeout_s: float = 60.0
    """A takeoff that has not reached altitude after this has failed, s."""
    offboard_lead_s: float = 1.0
    """PX4: setpoints stream this long before OFFBOARD is requested, s."""
    start_tolerance_m: float = 0.15
    """The show clock starts once every ready vehicle is this close to its first plan point."""
    settle_timeout_s: float = 10.0
    """...or once they have been ready this long, whatever their distance, s."""
    hover_before_show_s: float = 0.0
    """...and never before each of them has hovered ready this long, s (the flight's
    runner asks for :data:`HOVER_BEFORE_SHOW_S`)."""
    rejoin_tolerance_m: float = 1.0
    """A vehicle heard again mid-show rejoins its plan if it is this close to it, m;
    farther, it holds where it is and leaves the show on a planned way out."""
    exclude_tolerance_m: float = 1.0
    """After ``settle_timeout_s`` a ready vehicle still farther than this from its first
    plan point is landed on its own slot rather than started (the exclusion check
    applies: an unsafe exclusion aborts the show)."""
    brake_accel: float | None = None
    """Deceleration used to brake the fleet along its paths on hold, m/s^2 (None: half
    the plan's acceleration limit)."""
    land_battery_pct: float | None = None
    """A vehicle in the show below this battery leaves it on a way out and lands; below
    half of it, it lands where it is (None: the plan's ``limits.land_battery_pct``)."""
    return_timeout_s: float = 30.0
    """A returning vehicle not over its landing point this long after its return should
    have ended lands where it is, s."""


#: What a flight hovers ready before its show starts, s: each vehicle's hover throttle,
#: which says how much thrust it has (a weak motor, a tired battery:
#: :mod:`groundctl.execute.authority`), is then known before its path asks anything of
#: it, and the MPC flies a weak one from the first second (VFR_HUD comes at 4 Hz and the
#: estimate wants 8 readings; without the hover, a weak vehicle fell behind its first
#: climb before it was known).
HOVER_BEFORE_SHOW_S = 3.0


@dataclass
class VehicleRun:
    """One vehicle's progress through the sequence."""

    sysid: int
    """MAVLink system id."""
    track: int
    """The plan track it flies."""
    flavour: Flavour
    """Its autopilot family."""
    phase: VehiclePhase = VehiclePhase.PREFLIGHT
    """Where it is."""
    pending: Command | None = None
    """The command of the current step, awaiting its effect."""
    sent_at: float = 0.0
    """Our time the pending command was last sent."""
    attempts: int = 0
    """Sends of the pending command so far."""
    retry_at: float | None = None
    """When to re-send the pending command after a refusal."""
    stream_since: float | None = None
    """Our time setpoints started flowing to it."""
    reason: str | None = None
    """The last refusal or failure reason."""
    lost_from: VehiclePhase | None = None
    """While LOST: the phase it was lost in (what it is still streamed as)."""
    altitude: float | None = None
    """Last altitude above home seen in telemetry, m."""
    mode: str | None = None
    """Last flight mode seen in telemetry."""
    column_since: float | None = None
    """When the last resort made it hold to descend in its column (None: it did not)."""
    column: bool = False
    """Sent straight down by the last resort."""
    column_waited: bool = False
    """Said it has waited long to descend."""
    never_flew: bool = False
    """Given up before it took off (arming refused): it stands on its slot."""
    takeoff_from: float | None = None
    """Its altitude above home when its takeoff was first sent, m (None: unknown)."""
    leave_at: float | None = None
    """Land-one mid-show: the show time it is to leave at (its way out being planned)."""
    leave: Leave | None = None
    """Its planned way out of the show, once there is one."""
    hold_point: tuple[float, float, float] | None = None
    """Heard again off its plan: where it hovers (show frame) until its way out begins."""
    gap_seen: int = 0
    """Its telemetry's own silences (gaps on the vehicle's clock) already looked at."""
    started_at: float | None = None
    """Our time it was told to arm (its takeoff's start: mode, arm, spool-up, climb)."""
    ready_at: float | None = None
    """Our time it became READY (hovering at its first point's column, before the show)."""
    returning_since: float | None = None
    """Our time it started returning to its landing point."""
    landing_point: tuple[float, float, float] | None = None
    """Where it descends from when not the plan's landing spot (a return re-assigned it)."""
    land_from: tuple[float, float] | None = None
    """Where it was (show frame, east and north) when told to land, its position heard
    then: its autopilot's land mode brakes and descends there (over where it stops: within
    a metre at show speeds), so it is where the ground station sent it down.  None: not
    landing, or its position was not known whenever it was told."""
    battery_low: bool = False
    """Its battery fell below the show's threshold (it has been told to land)."""
    leave_late: int = 0
    """Ways out that were planned too late for their instant."""
    battery_critical: bool = False
    """Its battery fell below half the threshold (it has been landed where it is)."""
    before_return: VehiclePhase | None = None
    """The phase land-all took it out of (restored if no return can be planned)."""
    retaking: str | None = None
    """The failsafe mode it is being taken back from, while that is under way."""
    retakes: int = 0
    """Times it was taken back from a link-loss failsafe."""
    fell: bool = False
    """Given up as disarmed in the air (a crash, a motor failure, or a report that was
    wrong: see :meth:`ShowSequence._armed_again`)."""
    gap_at: float | None = None
    """Our time its own telemetry last came back from a silence."""
    streamed_at: float | None = None
    """Our time setpoints were last sent to it (:meth:`ShowSequence.streamed`)."""
    join: Join | None = None
    """A spare taking over ``track``: its way in, flown on the show clock (it arms and
    climbs from its pad before, and is on the track's plan from ``join.until``)."""
    pad: int | None = None
    """A spare: the index of the pad it stood on (:attr:`~groundctl.plan.plan.SparePlan.pads`)."""
    replaced_by: int | None = None
    """The spare that took over its track (its system id): from then on it is not the
    track's drone, and where it lands is an obstacle like any drone down elsewhere."""
    starved_at: float | None = None
    """Our time its setpoints resumed after we had sent it none for LINK_FAILSAFE_GAP_S
    or more (our own loop starved: a PX4 vehicle then drops into its offboard-loss
    failsafe without any silence of the link)."""

    @property
    def standing_by(self) -> bool:
        """A spare (in the air or on its pad) not sent into any track."""
        return self.pad is not None and self.join is None


@dataclass(frozen=True)
class StreamRequest:
    """What the driver streams this tick: who, and the one path each follows."""

    show_time: float
    """Plan time now (for the monitor), s."""
    moving: bool
    """False while the show clock is stopped or not started."""
    sysids: frozenset[int]
    """Vehicles to send setpoints to."""
    clock: ShowClock | None = None
    """The show clock: the stream samples it each vehicle's lead ahead (braking included)."""
    ended: bool = False
    """The show is over: the plan is sampled at ``show_time`` without feed-forward."""
    paths: dict[int, Path] = field(default_factory=dict)
    """The path each streamed vehicle follows (system id -> Path)."""
    returns: Trajectories | None = None
    """The land-all return's trajectories while one is flown, or None."""
    return_clock: ShowClock | None = None
    """The return's own clock (held with the show's)."""

    def clocks(self, plan: Plan) -> PathClocks:
        """What :func:`~groundctl.execute.paths.sample_paths` samples these paths on."""
        return PathClocks(plan, self.clock, self.show_time, self.ended, self.returns,
                          self.return_clock)

    # Views of the paths by kind (for the monitor, the guard and tests).
    @property
    def fixed(self) -> dict[int, tuple[float, float, float]]:
        """Vehicles holding a show-frame point now (a hold, a landing point)."""
        out = {}
        for s, p in self.paths.items():
            point = p.fixed_at(self.show_time) if p.kind is not PathKind.RETURN else None
            if point is not None:
                out[s] = point
        return out

    @property
    def follow(self) -> dict[int, int]:
        """Vehicles flying the return: system id -> row."""
        return {s: p.row for s, p in self.paths.items()
                if p.kind is PathKind.RETURN and p.row is not None}

    @property
    def leaves(self) -> dict[int, Leave]:
        """Vehicles with a way out they fly (not holding before it): system id -> Leave."""
        fixed = self.fixed
        return {s: p.leave for s, p in self.paths.items()
                if p.kind is PathKind.WAY_OUT and p.leave is not None and s not in fixed}

    @property
    def follow_trajectories(self) -> Trajectories | None:
        return self.returns if self.follow else None


def _describe(command: Command) -> str:
    if isinstance(command, SetMode):
        return f"mode {command.mode}"
    if isinstance(command, Takeoff):
        return "takeoff"
    return type(command).__name__.lower()
