"""The flight sequence as a pure state machine: observe, decide, return actions.

Written once without I/O, h11 style.  A thin async driver, every tick::

    actions = seq.update(now, fleet.vehicles)    # observe telemetry, advance
    for a in actions: perform a (SetMode -> fleet.set_mode, Arm -> arm, Takeoff ->
        takeoff, Land -> land, Disarm -> disarm, Kill -> disarm(force=True),
        Notice -> console and event log), and on CommandRefused/CommandTimeout
        call seq.command_failed(a, reason, now)
    guard: seq.hold_for / stop_for / release (the driver's own lag, a fleet-wide
        silence, safety responses), seq.take_out, seq.land_all
    req = seq.stream_request(now)                 # whom to send setpoints, and the
                                                  # one path each follows (req.paths)
    send SetpointStream.at(now, offsets, paths=req.paths, clocks=req.clocks(plan))
        rows for req.sysids, and LED colours

The show clock (:attr:`ShowSequence.clock`, :mod:`groundctl.execute.showclock`)
holds by braking along the plan, for reasons (``operator``, ``stall``,
``overload``, ``silence``, ``safety``, ``land-all``); the show runs only when none
is left.  A LOST vehicle is never done: silence is not "down".

Streaming is not an action: :meth:`ShowSequence.stream_request` is the one
source of truth for who gets setpoints each tick, so a start/stop event can
never be missed or applied twice.  What each streamed vehicle follows is one
:class:`~groundctl.execute.paths.Path` (its plan, a hold point, its way out,
the land-all return, its landing point), decided in one place,
:meth:`ShowSequence.path`, from where the vehicle is in the sequence: every
operator command and safety response changes where a vehicle is, and with it
its path; the stream, the guard, the return planner and the MPC only read it.

Operator commands (:meth:`ShowSequence.hold`, ``resume``, ``land_all`` (every
vehicle to its landing slot, then down), ``land_one`` (one vehicle to its
slot, then down; mid-show it flies on to its next formation and leaves from
there on a way out planned around the others: :attr:`ShowSequence.leave_needed`,
``set_leave``, ``leave_failed``, phase LEAVING), ``land_here`` (one vehicle
straight down), ``kill``) return actions the same way; bad operator input
comes back as a :class:`Notice`, never an exception.

Per vehicle: ARMING (ArduPilot: GUIDED, then arm; PX4: arm) -> TAKEOFF
(NAV_TAKEOFF, wait until within ``takeoff_tolerance_m`` of the takeoff
altitude; PX4 then gets setpoints for ``offboard_lead_s`` before OFFBOARD,
because PX4 refuses OFFBOARD without a setpoint stream) -> READY -> SHOW ->
RETURNING (to the point above its landing spot, where the plan ends) -> LANDING (land
mode) -> LANDED (disarmed).  ArduCopter's guided takeoff needs GUIDED before
arming, which is why the order differs.  Every step waits for its effect in
telemetry (mode, armed, altitude), not just for the command's ACK; a step is
re-sent after a refusal or ``step_timeout_s`` without effect, up to
``max_attempts`` times, keeping the last reason.  A refused takeoff is judged by
the vehicle's climb, not by the ACK: without signing anyone can send a refusal,
and an autopilot refuses a repeat of a takeoff it is already spooling up for, so
it is re-sent (or given up) only ``takeoff_retry_after_s`` later -- longer than
any spool-up -- and not at all if the vehicle climbs meanwhile.

A vehicle whose link is lost is marked LOST and reported; the show goes on
for the others.  It is still streamed what it would have flown (its plan,
then its landing point): the plan is collision-free, so if our packets still
reach it (a link lost one way only, or our own receive path stalling) that is
the one place guaranteed to be out of everyone's way, whereas a vehicle left
without setpoints hovers where it is, in the others' paths.  If it is heard
again it rejoins where the sequence is, unless it is more than
``rejoin_tolerance_m`` off its plan (its autopilot flew on along the last
setpoint for GUID_TIMEOUT, which the runner sets to 1 s on ArduPilot, then held
it while the show flew on; PX4's offboard-loss failsafe held it; the same check
follows any silence over SILENCE_GAP_S, lost or not): then snapping back would
be a dash across the formation, so it holds where it is and leaves the show on
a way out planned from there.  If it hears
nothing, its own failsafe is in charge; a vehicle whose autopilot leaves its
flight mode by itself (failsafe or pilot) is out of the show and never fought
over.  A vehicle that fails to arm stays on its slot: if that puts
it in a neighbour's takeoff or landing path the whole show is aborted.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

import numpy as np

from groundctl.execute.frames import show_positions
from groundctl.execute.leaving import (
    LEAVE_LEAD_S,
    Leave,
    free_spots,
    landing_candidates,
    leave_duration,
    leave_time,
)
from groundctl.execute.paths import (
    Path,
    PathClocks,
    PathKind,
    position_on_show_clock,
    sample_paths,
)
from groundctl.execute.preflight import remaining_plan_conflicts
from groundctl.execute.showclock import ShowClock, brake_ramp
from groundctl.execute.spread import spread_apart
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState
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
#: Risen this far since its takeoff was sent, a vehicle is climbing (whatever its height
#: above home), m: well above an EKF's altitude noise on the ground.
CLIMB_SEEN_M = 0.2

#: Phases a vehicle never leaves: it is down (seen disarmed) or given up.  LOST is not
#: one of them: a silent vehicle may still be airborne.
_DONE = {VehiclePhase.LANDED, VehiclePhase.FAILED, VehiclePhase.KILLED}
#: Phases the per-vehicle update does not advance (LOST waits to be heard again).
_IDLE = _DONE | {VehiclePhase.LOST, VehiclePhase.PREFLIGHT}
_STREAMED = {VehiclePhase.READY, VehiclePhase.SHOW, VehiclePhase.LEAVING,
             VehiclePhase.RETURNING}
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


def _fence_acted(state: VehicleState, now: float) -> bool:
    """The vehicle's own fence fired: ArduPilot's "Fence Breached", PX4's "Geofence ..."."""
    st = state.last_statustext
    return st is not None and "fence" in st.text.lower() and now - st.at <= FENCE_NOTICE_S


#: This share of the fleet (at least two) below the battery threshold lands everyone.
LOW_BATTERY_FLEET = 0.1
#: A way out planned too late this many times is given up (no retry storm).
MAX_LATE_LEAVES = 3
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
    ready_at: float | None = None
    """Our time it became READY (hovering at its first point's column, before the show)."""
    returning_since: float | None = None
    """Our time it started returning to its landing point."""
    landing_point: tuple[float, float, float] | None = None
    """Where it descends from when not the plan's landing spot (a return re-assigned it)."""
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
    starved_at: float | None = None
    """Our time its setpoints resumed after we had sent it none for LINK_FAILSAFE_GAP_S
    or more (our own loop starved: a PX4 vehicle then drops into its offboard-loss
    failsafe without any silence of the link)."""


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


class ShowSequence:
    """The whole show's flight sequence; see the module docstring for the protocol."""

    def __init__(self, plan: Plan, tracks: Mapping[int, int], flavours: Mapping[int, Flavour],
                 config: SequenceConfig | None = None,
                 grounded_tracks: Collection[int] = ()) -> None:
        """``tracks`` maps system id -> plan track for every vehicle that flies;
        ``grounded_tracks`` are tracks whose (excluded) drone stays on its slot."""
        missing = sorted(set(tracks) - set(flavours))
        if missing:
            raise ValueError(f"`flavours` has no autopilot for vehicle(s) {missing}")
        if len(set(tracks.values())) != len(tracks):
            raise ValueError("`tracks` gives one track to two vehicles")
        self.plan = plan
        self.config = config or SequenceConfig()
        self.vehicles: dict[int, VehicleRun] = {
            sysid: VehicleRun(sysid, track, flavours[sysid])
            for sysid, track in sorted(tracks.items())}
        self.grounded_tracks: set[int] = set(grounded_tracks)
        self.aborted: str | None = None
        """Why the show was called off before it could be flown (None: it was not)."""
        self._slots = plan.landing_hover  # where each track's descent starts
        self._home_hover = plan.home + np.array([0.0, 0.0, plan.takeoff_altitude])
        self._first = plan.trajectories.evaluate(0.0)[0]  # where each track's show starts
        self._ready_since: float | None = None
        self._return_wanted = False  # a return plan is needed (land-all, blocked spots)
        self._return: tuple[Trajectories, dict[int, int]] | None = None
        self._return_clock: ShowClock | None = None
        self._started = False
        self._ended = False
        self._columns = False  # the last resort: landing straight down, column by column
        self._stopped_at: float | None = None  # show time at which land_all stopped the show
        brake = self.config.brake_accel or 0.5 * plan.limits.max_accel
        speeds = np.linalg.norm(plan.trajectories.vel, axis=-1)
        self.clock = ShowClock(brake_ramp(float(speeds.max(initial=0.0)), brake))
        """The show clock (braking holds; see :mod:`groundctl.execute.showclock`)."""
        self._pre_start_hold = False  # the operator held before the show clock started
        self._replans = 0  # returns planned again for blocked landing spots
        self._after_return = False  # a new return starts from the landing points
        self._battery = (self.config.land_battery_pct if self.config.land_battery_pct
                         is not None else plan.limits.land_battery_pct)
        # This update's show-frame positions (one vectorised conversion per update).
        self._positions: dict[int, np.ndarray | None] = {}

    # -- clock -----------------------------------------------------------------------
    @property
    def started_at(self) -> float | None:
        """Our time of show time 0, None before the show clock started."""
        return self.clock.started_at

    @property
    def paused(self) -> bool:
        """The show is held (braking or stopped) for any reason."""
        return self.clock.held or self._pre_start_hold

    @property
    def holds(self) -> set[str]:
        """Why the show is held (``operator``, ``overload``, ``stall``, ``silence``...)."""
        return set(self.clock.holds) | ({"operator"} if self._pre_start_hold else set())

    def show_time(self, now: float) -> float:
        """The show clock: 0 before the start, braking to a stop while held, capped at the
        duration (and at where land-all stopped it)."""
        t = min(max(self.clock.show_time(now), 0.0), self.plan.duration)
        return t if self._stopped_at is None else min(t, self._stopped_at)

    def show_time_of(self, when: float) -> float | None:
        """The show time at our (past) time ``when``; None before the show clock started."""
        t0 = self.clock.started_at
        if t0 is None or when < t0:
            return None
        return self.clock.show_time(when)

    @property
    def clock_state(self) -> tuple[int, ...]:
        """Each clock's (show, then return) :attr:`~ShowClock.revision`.  When it changes
        (held, released, put back after a stall, a return set off), what was predicted on
        the clocks as they were (MPC trajectories, a weak vehicle's lead) no longer
        holds: its neighbours brake, stop or set off where it was not expected."""
        return tuple(c.revision for c in self._clocks())

    def _clocks(self) -> list[ShowClock]:
        return [self.clock] + ([self._return_clock] if self._return_clock is not None else [])

    def hold_for(self, reason: str, now: float) -> bool:
        """Brake every clock (show and return) to a stop for ``reason``; True if newly held.

        Used by the driver for what the sequence cannot see itself: its own overload, a
        fleet-wide silence, a safety response.
        """
        fresh = False
        for clock in self._clocks():
            fresh |= clock.hold(now, reason)
        return fresh

    def stop_for(self, reason: str, now: float, show_time: float, rate: float = 0.0) -> None:
        """Re-synchronise the show clock to ``show_time`` and brake from ``rate`` (the
        driver stalled: its drones flew on stale setpoints, and :meth:`fit_show_time`
        found where along the plan they are)."""
        if self._ended or self.started_at is None:
            self.hold_for(reason, now)
            return
        self.clock.stop_at(now, min(max(show_time, 0.0), self.plan.duration), reason, rate)

    def fit_show_time(self, lo: float, hi: float, positions: Mapping[int, np.ndarray],
                      velocities: Mapping[int, np.ndarray]) -> tuple[float, float]:
        """The show time in [``lo``, ``hi``] at which the plan best matches where the
        drones flying the show are (least median distance), and their speed along the
        plan there as a clock rate (0 standing .. 1 at the plan's speed)."""
        rows = [(v.track, positions[s], velocities.get(s)) for s, v in self.vehicles.items()
                if v.phase is VehiclePhase.SHOW and s in positions]
        lo, hi = max(lo, 0.0), min(max(hi, lo), self.plan.duration)
        if not rows or hi <= lo:
            return lo, 0.0
        tracks = np.array([r[0] for r in rows])
        here = np.array([r[1] for r in rows])
        times = np.linspace(lo, hi, max(int((hi - lo) / 0.05) + 1, 2))
        path = self.plan.trajectories.evaluate(times, tracks)[0]  # (drones, times, 3)
        cost = np.median(np.linalg.norm(path - here[:, None, :], axis=2), axis=0)
        best = float(times[int(np.argmin(cost))])
        plan_vel = self.plan.trajectories.evaluate(best, tracks)[1]
        ratios = [float(np.dot(v, pv) / np.dot(pv, pv))
                  for (_, _, v), pv in zip(rows, plan_vel, strict=True)
                  if v is not None and float(np.dot(pv, pv)) > 0.09]
        rate = float(np.clip(np.median(ratios), 0.0, 1.0)) if ratios else 0.0
        return best, rate

    def release(self, reason: str, now: float) -> bool:
        """Drop the hold ``reason``; the clocks ramp back up once no hold is left."""
        resumed = False
        for clock in self._clocks():
            resumed |= clock.release(now, reason)
        return resumed

    def commanded_all(self, req: StreamRequest, now: float) -> dict[int, np.ndarray]:
        """Where every streamed vehicle's path puts it at ``now`` (show frame), from this
        tick's request: one vectorised evaluation for the whole fleet."""
        ids = list(req.paths)
        if not ids:
            return {}
        pos, _, _ = sample_paths([req.paths[s] for s in ids], np.full(len(ids), now),
                                 req.clocks(self.plan))
        return dict(zip(ids, pos, strict=True))

    @property
    def phase(self) -> ShowPhase:
        """LANDED only once every vehicle is down or given up; a lost vehicle may still be
        airborne, so the show is not over while one is lost."""
        phases = {v.phase for v in self.vehicles.values()}
        lost = bool(self.lost)
        if not self._started:
            return ShowPhase.PREFLIGHT
        if VehiclePhase.ARMING in phases:
            return ShowPhase.ARMING
        if phases & {VehiclePhase.TAKEOFF, VehiclePhase.READY}:
            return ShowPhase.TAKEOFF
        if VehiclePhase.SHOW in phases:
            return ShowPhase.SHOW
        if lost or phases & {VehiclePhase.LEAVING, VehiclePhase.RETURNING,
                             VehiclePhase.LANDING}:
            return ShowPhase.LANDING
        return ShowPhase.LANDED

    @property
    def lost(self) -> list[int]:
        """System ids of the vehicles lost now that may be airborne (silent after their
        takeoff was sent; one lost while arming never left its slot)."""
        return [s for s, v in self.vehicles.items() if v.phase is VehiclePhase.LOST
                and v.lost_from not in (VehiclePhase.PREFLIGHT, VehiclePhase.ARMING)]

    @property
    def settled(self) -> bool:
        """Every vehicle not lost is down or given up: only lost ones keep the flight open."""
        return all(v.phase in _DONE or v.phase is VehiclePhase.LOST
                   for v in self.vehicles.values())

    # -- driver interface ------------------------------------------------------------
    def start(self, now: float) -> list[Action]:
        """Begin arming every vehicle (pre-flight checks have passed)."""
        if self._started or self._ended:
            return [Notice(None, "the sequence has already started or been stopped")]
        self._started = True
        actions: list[Action] = []
        for v in self.vehicles.values():
            v.phase = VehiclePhase.ARMING
            first: Command = SetMode(v.sysid, "GUIDED") if v.flavour is Flavour.ARDUPILOT \
                else Arm(v.sysid)
            actions.append(self._send(v, first, now))
        return actions

    def update(self, now: float, states: Mapping[int, VehicleState]) -> list[Action]:
        """Advance every vehicle from its telemetry; returns the actions to perform."""
        actions: list[Action] = []
        self._positions = show_positions(self.plan.origin, states)
        # Losses first: one may abort the show, and then nobody should be
        # told to arm or take off in the same breath.
        for v in self.vehicles.values():
            state = states.get(v.sysid)
            if v.phase is VehiclePhase.LOST and state is not None and not state.lost:
                actions += self._rejoin(v, now, state)
                continue
            if v.phase in _IDLE:
                continue
            if state is None or state.lost:
                actions += self._lose(v, now, state)
        for v in self.vehicles.values():
            if v.phase in _IDLE:
                continue
            actions += self._advance(v, states[v.sysid], now)
        for v in self.vehicles.values():
            state = states.get(v.sysid)
            if v.fell and v.phase is VehiclePhase.FAILED and state is not None:
                actions += self._armed_again(v, state, now)
        actions += self._land_all_if_stranded(now)
        actions += self._descend_columns(now)
        actions += self._maybe_start_show(now, states)
        actions += self._begin_leaves(now)
        if self.started_at is not None and not self._ended \
                and self.clock.show_time(now) >= self.plan.duration:
            self._ended = True
            for v in self.vehicles.values():
                if v.phase is VehiclePhase.SHOW or (v.phase is VehiclePhase.LEAVING
                                                    and v.leave is None):
                    v.phase, v.returning_since = VehiclePhase.RETURNING, now
                if v.lost_from is VehiclePhase.SHOW or (v.lost_from is VehiclePhase.LEAVING
                                                         and v.leave is None):
                    v.lost_from = VehiclePhase.RETURNING
            actions.append(Notice(None, "show finished: returning to the landing slots"))
        return actions

    # -- landing spots ---------------------------------------------------------------------
    def down_positions(self, asking: VehicleRun | None = None) -> list[np.ndarray]:
        """Show-frame positions of the drones that are down, descending or given up
        somewhere the plan did not put them (land-here, a crash, a failsafe landing, a
        drone that never took off), from this update's telemetry (else their slot):
        obstacles for every landing.  A drone descending over its own landing point is
        not one: landing points are separated by the plan."""
        # Excluded drones, and drones that never took off, stand on their slots (not the
        # one ``asking``: a drone sent back to its own slot does not block itself).
        out: list[np.ndarray] = [self.plan.home[t] for t in sorted(self.grounded_tracks)
                                 if asking is None or t != asking.track]
        for v in self.vehicles.values():
            if v is asking:
                continue
            if v.phase in (VehiclePhase.LANDING, VehiclePhase.LANDED, VehiclePhase.FAILED,
                           VehiclePhase.KILLED) or (v.phase is VehiclePhase.LOST
                                                    and v.lost_from is VehiclePhase.LANDING):
                pos = self._positions.get(v.sysid)
                if pos is None or (v.track in self.grounded_tracks and v.phase
                                   is not VehiclePhase.FAILED):
                    continue
                spot = self._landing_point(v)
                if v.phase is not VehiclePhase.FAILED and v.phase is not VehiclePhase.KILLED \
                        and float(np.hypot(*(pos[:2] - spot[:2]))) \
                        <= self.config.arrive_tolerance_m:
                    continue  # down on its own landing point, as planned
                out.append(np.asarray(pos, dtype=float))
        return out

    def landing_positions(self) -> list[np.ndarray]:
        """Show-frame positions of the drones descending (LANDING) now."""
        out = []
        for v in self.vehicles.values():
            pos = self._positions.get(v.sysid)
            if v.phase is VehiclePhase.LANDING and pos is not None:
                out.append(np.asarray(pos, dtype=float))
        return out

    def reserved_spots(self, returning: Collection[int]) -> list[np.ndarray]:
        """Landing points of the vehicles outside ``returning`` (system ids) that are
        landing, or will land, on them: nobody else may be sent there."""
        out = []
        for v in self.vehicles.values():
            if v.sysid in returning or v.phase in (VehiclePhase.FAILED, VehiclePhase.KILLED,
                                                   VehiclePhase.PREFLIGHT):
                continue
            if v.track in self.grounded_tracks and v.landing_point is None:
                continue  # standing on its slot: in down_positions
            pos = self._positions.get(v.sysid)
            spot = self._landing_point(v)
            if v.phase in (VehiclePhase.LANDING, VehiclePhase.LANDED) and pos is not None \
                    and float(np.hypot(*(pos[:2] - spot[:2]))) > self.config.arrive_tolerance_m:
                continue  # down elsewhere: in down_positions, its spot is free
            out.append(spot)
        return out

    def spot_blocked(self, v: VehicleRun) -> bool:
        """Whether the column under ``v``'s landing point comes within the separation
        limit of a drone that is down or descending."""
        point = np.asarray(self._landing_point(v), dtype=float)[None, :]
        down = np.array(self.down_positions(v)).reshape(-1, 3)
        return len(free_spots(self.plan, point, down=down)) == 0

    def command_failed(self, command: Command, reason: str, now: float) -> list[Action]:
        """A command was refused or timed out; retry it later or give the vehicle up."""
        v = self.vehicles.get(command.sysid)
        if v is None or v.pending != command:
            return []  # a stale answer: the vehicle has moved on
        if isinstance(command, Takeoff):
            if self._climbing(v):
                # Climbing already: the first NAV_TAKEOFF was accepted but its ACK lost,
                # and the autopilot refuses a repeat in flight.  Its effect is what counts.
                return []
            # Judged once the vehicle has had the time to lift off (_retake_off).
            v.reason = reason
            v.retry_at = now + self.config.takeoff_retry_after_s
            return []
        if isinstance(command, Land) and v.mode in _LAND_MODES:
            # In its land mode already: the LAND was carried out and only its ACK was
            # lost (half the packets lost, say).  Its effect is what counts: counting the
            # timeouts gave a vehicle that went on to land up as "land failed 3 times".
            return []
        v.reason = reason
        if v.attempts >= self.config.max_attempts:
            return self._give_up(v, f"{_describe(command)} failed {v.attempts} times: {reason}",
                                 now)
        v.retry_at = now + self.config.retry_after_s
        return []

    def streamed(self, sysids: Collection[int], now: float) -> None:
        """The driver sent setpoints to ``sysids`` at ``now``: a vehicle that had had none
        for LINK_FAILSAFE_GAP_S (our loop starved) may be in its offboard-loss failsafe
        for our doing, and is taken back from it (:meth:`_link_failsafe`)."""
        for sysid in sysids:
            v = self.vehicles.get(sysid)
            if v is None:
                continue
            if v.streamed_at is not None and now - v.streamed_at >= LINK_FAILSAFE_GAP_S:
                v.starved_at = now
            v.streamed_at = now

    def stream_request(self, now: float) -> StreamRequest:
        """Whom to send setpoints to this tick, and the path each follows."""
        sysids = frozenset(v.sysid for v in self.vehicles.values()
                           if self.streamed_as(v) in _STREAMED
                           or (v.phase is VehiclePhase.TAKEOFF and v.stream_since is not None))
        paths: dict[int, Path] = {}
        for sysid in sysids:
            path = self.path(sysid, now)
            if path is not None:
                paths[sysid] = path
        flying_return = any(p.kind is PathKind.RETURN for p in paths.values())
        moving = self.started_at is not None and not self._ended and self.clock.at(now).moving
        # After land-all the show clock is still braking: keep sampling it (with its
        # feed-forward) until it is at rest.
        braking = self._ended and self.started_at is not None and self.clock.at(now).rate > 0 \
            and self.clock.show_time(now) < self.plan.duration
        return StreamRequest(self.show_time(now), moving, sysids,
                             self.clock if self.started_at is not None else None,
                             self.started_at is None or (self._ended and not braking),
                             paths, self._return[0] if flying_return and self._return else None,
                             self._return_clock if flying_return else None)

    def path(self, sysid: int, now: float) -> Path | None:
        """The one path vehicle ``sysid`` follows now (None: it is not streamed).

        The only place that decides it, from where the vehicle is in the sequence:
        returning, it flies the land-all return while there is one (else it holds over
        its landing point, or, while a return is awaited, brakes on what it flew); held
        off its plan, its point (then its way out); leaving, its way out; else its plan.
        """
        v = self.vehicles.get(sysid)
        if v is None:
            return None
        phase = self.streamed_as(v)
        if phase not in _STREAMED and not (v.phase is VehiclePhase.TAKEOFF
                                           and v.stream_since is not None):
            return None
        if phase is VehiclePhase.RETURNING:
            if self._return is not None and self._return_clock is not None:
                traj, rows = self._return
                if sysid in rows and self._return_clock.show_time(now) < traj.end:
                    return Path(PathKind.RETURN, "the land-all return", v.track,
                                row=rows[sysid])
            if not (self._return_wanted and self._return is None and v.landing_point is None):
                point = tuple(float(x) for x in self._landing_point(v))
                return Path(PathKind.LANDING_POINT, "over its landing spot", v.track,
                            point=point)  # type: ignore[arg-type]
        if v.leave is not None:
            return Path(PathKind.WAY_OUT, "its way out of the show", v.track,
                        point=v.hold_point, leave=v.leave)
        if v.hold_point is not None:
            return Path(PathKind.HOLD, "holding off its plan until its way out", v.track,
                        point=v.hold_point)
        return Path(PathKind.PLAN, "the show plan", v.track)

    # -- land-all return ---------------------------------------------------------------
    @property
    def return_needed(self) -> list[tuple[int, int]] | None:
        """(system id, track) of the vehicles needing a return plan, if one is awaited.

        After :meth:`land_all` interrupts the show, straight lines home could
        cross; the driver plans a return (from the frozen plan points at
        :meth:`show_time`) and hands it over with :meth:`set_return`, or calls
        :meth:`return_failed`.
        """
        if not self._return_wanted or self._return is not None:
            return None
        return [(v.sysid, v.track) for v in self.vehicles.values()
                if self.streamed_as(v) is VehiclePhase.RETURNING]

    def return_start(self, sysid: int, now: float) -> np.ndarray:
        """Where vehicle ``sysid`` starts its return from (show frame): where its path is
        when the braking show clock stops (its plan, its way out, the point it holds)."""
        v = self.vehicles[sysid]
        path = self.path(sysid, now)
        if self._after_return or path is None or not path.on_show_clock:
            return np.asarray(self._landing_point(v), dtype=float)  # hovering over it
        t = min(self.clock.stop_time(now) if self.started_at is not None else 0.0,
                self.plan.duration)
        if self._stopped_at is not None:
            t = min(t, self._stopped_at)
        return position_on_show_clock(path, self.plan, t)

    def set_return(self, trajectories: Trajectories, sysids: list[int], now: float,
                   goals: np.ndarray | None = None) -> list[Action]:
        """Fly ``trajectories`` (row i for ``sysids[i]``) once the fleet has braked to a
        stop, then land; ``goals`` (n, 3) are the landing points it ends over when a
        return re-assigned them (blocked spots)."""
        if self._return is not None:
            return []
        self._return = (trajectories, {s: i for i, s in enumerate(sysids)})
        clock = ShowClock(self.clock.default_ramp_s)
        clock.start(max(now, self.clock.rest_at()) if self.started_at is not None else now)
        for reason in self.clock.holds & FLEET_HOLDS:  # the ground station's own trouble
            clock.hold(now, reason)
        self._return_clock = clock
        if goals is not None:
            for row, sysid in enumerate(sysids):
                v = self.vehicles[sysid]
                point = tuple(float(x) for x in goals[row])
                v.landing_point = None if np.allclose(point, self._slots[v.track]) \
                    else point  # type: ignore[assignment]
        for sysid in sysids:
            self.vehicles[sysid].returning_since = now
        return [Notice(None, f"flying the {trajectories.end:.1f} s return to the landing "
                             "points")]

    def return_failed(self, reason: str, now: float | None = None) -> list[Action]:
        """No return plan.  Interrupted mid-show, the show itself is the one way home known
        to be collision-free: it flies on to its end (ramping up from the hold), where
        every drone is over its landing spot, and lands from there.  Otherwise (spots
        re-planned after the show) each flies straight to its landing point, loudly."""
        interrupted = self._stopped_at is not None and self._stopped_at < self.plan.duration \
            and not self._after_return and now is not None
        if interrupted and now is not None and any(
                v.hold_point is not None and v.before_return is VehiclePhase.LEAVING
                for v in self.vehicles.values()):
            # Drones off their plans hover where they were stopped: the show flying on
            # is not known to be clear of them (and they would be stranded again at
            # once: land-all, no return, the show again -- the livelock).  Where each
            # holds is read while the return is still awaited (then every path is where
            # it braked, not the landing spot a failed return falls back to).
            return self._land_in_columns(reason, now)
        self._return_wanted = False
        if not interrupted:
            return [Notice(None, f"no collision-free return could be planned ({reason}); "
                                 "flying straight to the landing points: watch the fleet")]
        assert now is not None
        self._ended, self._stopped_at = False, None
        for v in self.vehicles.values():
            if v.phase is VehiclePhase.RETURNING and v.before_return is not None:
                v.phase = v.before_return
                if v.phase is VehiclePhase.READY:
                    v.phase = VehiclePhase.SHOW
            elif v.phase is VehiclePhase.LOST and v.lost_from is VehiclePhase.RETURNING \
                    and v.before_return is not None:
                v.lost_from = v.before_return
            v.before_return = None
        self.release("land-all", now)
        return [Notice(None, f"no collision-free return could be planned ({reason}): the "
                             "show flies on to its end, the one way known to be clear, and "
                             "every drone lands from there")]

    # -- the last resort: straight down, one column at a time ------------------------------
    @property
    def in_columns(self) -> bool:
        """The fleet is landing by the last resort (:meth:`_land_in_columns`)."""
        return self._columns

    def _land_in_columns(self, reason: str, now: float) -> list[Action]:
        """No collision-free return, and drones off their plans: every airborne drone
        holds where its path stopped, and they go straight down one column at a time
        (:meth:`_descend_columns`).  It always exists and plans nothing: nothing more
        can fail, and a stop signal meanwhile changes nothing (:meth:`land_all`)."""
        # Where each path stopped, read before anything changes (return_start).
        starts = {v.sysid: self.return_start(v.sysid, now) for v in self.vehicles.values()
                  if self.streamed_as(v) is VehiclePhase.RETURNING}
        off = [v.sysid for v in self.vehicles.values()
               if v.hold_point is not None and v.before_return is VehiclePhase.LEAVING]
        points = self._held_apart({s: (float(p[0]), float(p[1]), float(p[2]))
                                    for s, p in starts.items()}, now)
        self._columns = True
        self._return_wanted = False
        for v in self.vehicles.values():
            if v.sysid not in points:
                continue
            v.hold_point = points[v.sysid]
            v.column_since = now
            v.leave, v.leave_at, v.before_return = None, None, None
            if v.phase is VehiclePhase.LOST:
                v.lost_from = VehiclePhase.LEAVING
            else:
                v.phase = VehiclePhase.LEAVING
        actions: list[Action] = [Notice(
            None, f"no collision-free return could be planned ({reason}) and "
                  f"{'vehicles' if len(off) != 1 else 'vehicle'} "
                  f"{', '.join(str(s) for s in off)} {'are' if len(off) != 1 else 'is'} off "
                  "the plan: every drone holds where it is and they land straight down, one "
                  "column at a time (the lowest first; nobody descends with a drone below it)",
            "land_in_columns")]
        return actions + self._descend_columns(now)

    def _held_apart(self, points: Mapping[int, tuple[float, float, float]], now: float
                    ) -> dict[int, tuple[float, float, float]]:
        """``points`` (system id -> where it would hold) pushed sideways until each is the
        separation limit from the others and from every other drone in the air (where it
        holds, or is and will hover once the braking show clock stops): the wind or a
        fault may have pushed them together
        (:func:`~groundctl.execute.spread.spread_apart`)."""
        others: list[tuple[float, ...]] = []
        for u in self.vehicles.values():
            if u.sysid in points or u.phase in _DONE or u.never_flew:
                continue
            pos = self._positions.get(u.sysid)
            if pos is None or pos[2] <= AIRBORNE_M:
                continue
            if u.hold_point is not None:
                others.append(u.hold_point)
                continue
            # Where it is, and where it will hover once the braking clock stops.
            others += [tuple(pos), tuple(self.return_start(u.sysid, now))]
        ids = list(points)
        if not ids:
            return {}
        pts = np.array([points[s] for s in ids] + others, dtype=float).reshape(-1, 3)
        movable = np.arange(len(pts)) < len(ids)
        limit = self.plan.limits.min_separation
        spread = spread_apart(pts, movable, limit, HOLD_APART_MAX_M * limit)
        return {s: (float(p[0]), float(p[1]), float(p[2]))
                for s, p in zip(ids, spread[:len(ids)], strict=True)}

    def _descend_columns(self, now: float) -> list[Action]:
        """Send down each held drone whose column is clear (no airborne drone within the
        separation limit below it, no drone on the ground within
        :data:`GROUND_CLEARANCE_M` of where it lands); re-checked every update, so a
        drone waits while another drifts under it."""
        if not self._columns:
            return []
        waiting = [v for v in self.vehicles.values()
                   if v.phase is VehiclePhase.LEAVING and v.hold_point is not None
                   and v.pending is None]
        actions: list[Action] = []
        for v in sorted(waiting, key=lambda u: self._height(u)):
            # Only drones below count: one above is left behind by the descent.
            if not self._column_clear(v, ground_m=GROUND_CLEARANCE_M, above_m=0.0,
                                      margin_m=COLUMN_MARGIN_M):
                if v.column_since is not None and now - v.column_since >= COLUMN_WAIT_S \
                        and not v.column_waited:
                    v.column_waited = True
                    actions.append(Notice(
                        v.sysid, f"vehicle {v.sysid} has waited {COLUMN_WAIT_S:.0f} s to "
                                 "descend: a drone is below it (lost, or still landing); it "
                                 f"holds (land-here {v.sysid} brings it straight down now)",
                        "column_blocked", "waiting to descend: a drone below it"))
                continue
            v.column = True
            v.phase, v.reason = VehiclePhase.LANDING, "landed by the last resort (columns)"
            actions += [Notice(v.sysid, f"vehicle {v.sysid}: its column is clear: landing "
                                        "straight down", "column_landing",
                               "landing straight down (last resort)"),
                        self._send(v, Land(v.sysid), now)]
            # The ones above it wait for it: their columns are rechecked next update.
        return actions

    def _height(self, v: VehicleRun) -> float:
        pos = self._positions.get(v.sysid)
        if pos is not None:
            return float(pos[2])
        return v.hold_point[2] if v.hold_point is not None else math.inf

    # -- land-one mid-show: a way out -------------------------------------------------------
    @property
    def leave_needed(self) -> list[tuple[int, int, float, tuple[float, float, float] | None]]:
        """(system id, track, show time, start) of each vehicle whose way out awaits
        planning; start is None for its plan point at that time (land-one), or where it
        hovers (heard again off its plan).

        The driver plans it (around the others as they will fly, and
        :attr:`leaves`) and hands it over with :meth:`set_leave`, or calls
        :meth:`leave_failed`.
        """
        if self._ended:
            return []
        return [(v.sysid, v.track, v.leave_at, v.hold_point) for v in self.vehicles.values()
                if v.leave_at is not None and v.leave is None and self._awaits_leave(v)]

    def _awaits_leave(self, v: VehicleRun) -> bool:
        phase = self.streamed_as(v)
        return phase is VehiclePhase.SHOW or (phase is VehiclePhase.LEAVING
                                              and v.hold_point is not None)

    @property
    def leaves(self) -> dict[int, Leave]:
        """Planned ways out by *track* (obstacles for the next one, starts for a return)."""
        return {v.track: v.leave for v in self.vehicles.values() if v.leave is not None}

    def set_leave(self, sysid: int, leave: Leave, now: float) -> list[Action]:
        """Fly ``leave`` from its show time on, then land."""
        v = self.vehicles.get(sysid)
        if v is None or v.leave_at is None or v.leave is not None or self._ended \
                or not self._awaits_leave(v) or leave.held != (v.hold_point is not None):
            return []  # overtaken: landed, lost, stranded meanwhile, or the show ended
        if self.show_time(now) > leave.at:
            return self.leave_late(sysid, "its way out was ready too late", now)
        v.leave = leave
        return [Notice(sysid, f"way out for vehicle {sysid} planned: from show time "
                              f"{leave.at:.1f} s, {leave.trajectory.end:.1f} s to its landing "
                              "spot")]

    @property
    def ended(self) -> bool:
        """The show is over (its end reached, or land-all)."""
        return self._ended

    def leave_late(self, sysid: int, reason: str, now: float) -> list[Action]:
        """Its way out could not be planned before its instant: the next instant, a bounded
        number of times, then as :meth:`leave_failed`."""
        v = self.vehicles.get(sysid)
        if v is None or v.leave is not None or v.leave_at is None:
            return []
        v.leave_late += 1
        if v.leave_late >= MAX_LATE_LEAVES:
            return self.leave_failed(sysid, f"{reason}; {v.leave_late} times", now)
        v.leave_at = (self._hold_leave_time(v, now) if v.hold_point is not None
                      else leave_time(self.plan, v.track, self.show_time(now)))
        if v.leave_at is None:
            return self.leave_failed(sysid, f"{reason}; no formation left to leave from", now)
        return [Notice(sysid, f"vehicle {sysid}: {reason}; leaving at show time "
                              f"{v.leave_at:.1f} s instead", "leave_late",
                       "way out not planned in time: leaving later")]

    def leave_failed(self, sysid: int, reason: str, now: float) -> list[Action]:
        """No safe way out: it flies on with the show and lands at the end, loudly."""
        v = self.vehicles.get(sysid)
        if v is None or v.leave is not None:
            return []
        v.leave_at = None
        if v.hold_point is not None and v.phase is VehiclePhase.LEAVING:
            v.phase = VehiclePhase.LANDING
            return [Notice(sysid, f"no safe way out of the show for vehicle {sysid} ({reason}); "
                                  "landing it where it holds"),
                    self._send(v, Land(sysid), now)]
        return [Notice(sysid, f"no safe way out of the show for vehicle {sysid} ({reason}); it "
                              f"flies on and lands with the others (land-here {sysid} brings "
                              "it straight down now)")]

    # -- operator --------------------------------------------------------------------
    def hold(self, now: float) -> list[Action]:
        """Brake the show to a stop: every drone decelerates along its own trajectory and
        hovers on it (the plan keeps them apart at every instant)."""
        if "operator" in self.holds:
            return [Notice(None, "already holding")]
        if self.started_at is None:
            self._pre_start_hold = True
            return [Notice(None, "holding: the show clock will not start until resume")]
        self.hold_for("operator", now)
        return [Notice(None, f"holding: braking along the plan, stopped at show time "
                             f"{min(self.clock.stop_time(now), self.plan.duration):.1f} s")]

    def resume(self, now: float) -> list[Action]:
        """Run the show clock again (ramping up) from where it was held."""
        if self._pre_start_hold:
            self._pre_start_hold = False
            return [Notice(None, "resumed: the show starts once the fleet is ready")]
        if "operator" not in self.holds:
            return [Notice(None, "not holding: nothing to resume")]
        self.release("operator", now)
        others = sorted(self.holds)
        if others:
            return [Notice(None, f"operator hold released; still holding for {', '.join(others)}")]
        return [Notice(None, f"resuming at show time {self.show_time(now):.1f} s")]

    def land_all(self, now: float) -> list[Action]:
        """Every vehicle back to its landing slot and down; the show is over."""
        if self._columns:
            return [Notice(None, "already landing every vehicle, one column at a time")]
        if self._stopped_at is None:
            interrupted = self.started_at is not None and not self._ended \
                and self.clock.show_time(now) < self.plan.duration
            self._pre_start_hold = False
            self.release("operator", now)
            self.hold_for("land-all", now)
            self._stopped_at = min(self.clock.stop_time(now), self.plan.duration)
            # Interrupted mid-show: the way home needs planning (see return_needed).
            self._return_wanted = self._return_wanted or interrupted
        self._ended = True
        actions: list[Action] = [Notice(None, "landing all vehicles")]
        for v in self.vehicles.values():
            actions += self._land(v, now)
        return actions

    def land_one(self, sysid: int, now: float) -> list[Action]:
        """Vehicle ``sysid`` back to its landing slot and down; the others go on.

        Mid-show it first flies on to the next instant it rests on a formation and
        leaves from there on a way out planned around the others (see
        :attr:`leave_needed`); a straight line home would cut through the show.
        """
        v = self.vehicles.get(sysid)
        if v is None:
            return [Notice(None, f"no vehicle {sysid} in this show")]
        if self._columns:
            return [Notice(sysid, f"every vehicle lands straight down, one column at a time; "
                                  f"land-here {sysid} brings it down now")]
        if self.streamed_as(v) is VehiclePhase.SHOW and not self._ended:
            if v.leave_at is not None:
                return [Notice(sysid, f"vehicle {sysid} already leaves the show at show time "
                                      f"{v.leave_at:.1f} s")]
            at = leave_time(self.plan, v.track, self.show_time(now))
            if at is None:
                return [Notice(sysid, f"vehicle {sysid}: no formation left to leave the show "
                                      "from; it lands with the others at the end (land-here "
                                      f"{sysid} brings it straight down now)")]
            v.leave_at = at
            return [Notice(sysid, f"vehicle {sysid} leaves the show at show time {at:.1f} s, "
                                  "on a way out planned around the others")]
        return [Notice(sysid, f"landing vehicle {sysid}"), *self._land(v, now)]

    def land_here(self, sysid: int, now: float) -> list[Action]:
        """Vehicle ``sysid`` straight down where it is (not over its slot); the others go on.

        For a drone that misbehaves: it stops following the plan at once, so
        the operator must know the column below it is clear.
        """
        v = self.vehicles.get(sysid)
        if v is None:
            return [Notice(None, f"no vehicle {sysid} in this show")]
        if v.phase in _DONE or v.phase is VehiclePhase.LANDING:
            return [Notice(sysid, f"vehicle {sysid} is already {v.phase}")]
        if v.phase in (VehiclePhase.PREFLIGHT, VehiclePhase.ARMING):
            return [Notice(sysid, f"landing vehicle {sysid} here"), *self._land(v, now)]
        v.phase = VehiclePhase.LANDING
        return [Notice(sysid, f"landing vehicle {sysid} where it is"),
                self._send(v, Land(sysid), now)]

    def kill(self, sysid: int, now: float, confirm: bool = False) -> list[Action]:
        """Stop ``sysid``'s motors in flight; needs ``confirm`` because the drone falls."""
        v = self.vehicles.get(sysid)
        if v is None:
            return [Notice(None, f"no vehicle {sysid} in this show")]
        if not confirm:
            return [Notice(sysid, f"kill vehicle {sysid} not sent: it stops the motors and "
                                  "the drone falls; confirm to kill")]
        v.phase, v.pending = VehiclePhase.KILLED, None
        return [Kill(sysid), Notice(sysid, f"vehicle {sysid} killed by the operator")]

    # -- internals -------------------------------------------------------------------
    def _send(self, v: VehicleRun, command: Command, now: float) -> Command:
        if command != v.pending:
            v.attempts = 0
        v.pending, v.sent_at, v.retry_at = command, now, None
        v.attempts += 1
        return command

    def _land(self, v: VehicleRun, now: float) -> list[Action]:
        if v.phase is VehiclePhase.PREFLIGHT:
            v.phase = VehiclePhase.LANDED
            return []
        if v.phase is VehiclePhase.ARMING:
            # Still on the ground (takeoff was never sent): nothing to land, but
            # it may already be armed.
            v.phase, v.pending = VehiclePhase.LANDED, None
            return [Disarm(v.sysid), Notice(v.sysid, f"vehicle {v.sysid} stood down on the ground")]
        if v.phase in (VehiclePhase.ARMING, VehiclePhase.TAKEOFF):
            v.phase = VehiclePhase.LANDING
            return [self._send(v, Land(v.sysid), now)]
        if v.leave is None:
            v.leave_at = None  # a way out not planned yet: the landing replaces it
        if v.phase in (VehiclePhase.READY, VehiclePhase.SHOW, VehiclePhase.LEAVING):
            v.before_return = v.phase
            v.phase, v.pending = VehiclePhase.RETURNING, None
        if v.phase is VehiclePhase.LOST and v.lost_from in (
                VehiclePhase.READY, VehiclePhase.SHOW, VehiclePhase.LEAVING):
            v.before_return = v.lost_from
            v.lost_from = VehiclePhase.RETURNING
        return []

    @staticmethod
    def streamed_as(v: VehicleRun) -> VehiclePhase:
        """Its phase, or for a lost vehicle the phase it was lost in (what it is streamed)."""
        return v.lost_from if v.phase is VehiclePhase.LOST and v.lost_from else v.phase

    def _lose(self, v: VehicleRun, now: float, state: VehicleState | None) -> list[Action]:
        silent = "never heard" if state is None else f"silent for {state.silent_for(now):.1f} s"
        was = v.phase
        v.phase, v.pending, v.reason = VehiclePhase.LOST, None, f"link lost ({silent})"
        v.lost_from, v.retaking = was, None
        still = ("still streamed its plan in case it hears us, otherwise its failsafe is in "
                 "charge" if was in _STREAMED else "its failsafe is in charge")
        actions: list[Action] = [
            Notice(v.sysid, f"vehicle {v.sysid} lost during {was} ({silent}); {still}; "
                            "the show goes on", "lost", f"lost during {was}; {still}")]
        if was is VehiclePhase.ARMING:
            actions += self._left_on_slot(v, now)
        return actions

    def _rejoin(self, v: VehicleRun, now: float, state: VehicleState) -> list[Action]:
        assert v.lost_from is not None
        v.gap_seen, v.gap_at = state.stream_gaps, now  # this silence is handled here
        if v.lost_from in (VehiclePhase.ARMING, VehiclePhase.TAKEOFF):
            # Lost before the show and counted as standing on its slot meanwhile: it
            # does not join a show planned without it; it stands down.
            v.phase, v.lost_from = v.lost_from, None
            return [Notice(v.sysid, f"vehicle {v.sysid} heard again before the show: "
                                    "standing it down", "heard_again", "heard again: "
                                    "standing down"), *self._land(v, now)]
        off = self._off_plan(v, now)
        if off is not None and v.lost_from is VehiclePhase.SHOW:
            v.lost_from = None
            return self._strand(v, off, now, "heard again")
        v.phase, v.lost_from, v.reason = v.lost_from, None, None
        if v.phase is VehiclePhase.READY and self.started_at is not None:
            v.phase = VehiclePhase.SHOW if not self._ended else VehiclePhase.RETURNING
        if v.phase is VehiclePhase.LANDING:
            return self._rejoin_landing(v, state, now)
        return [Notice(v.sysid, f"vehicle {v.sysid} heard again: back in the sequence "
                                f"({v.phase})", "heard_again", f"heard again ({v.phase})")]

    def _rejoin_landing(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        """Heard again after being lost while landing: what it does now decides what is
        still needed.  Disarmed: down (the next update counts it landed).  In its land
        mode: descending.  Still in our flight mode (or PX4's Hold, where losing its
        setpoints put it): the LAND was lost in the silence, so send it again.  Any other
        mode: its failsafe or a pilot has it, and we do not fight them."""
        if not state.armed:
            doing = "down and disarmed"
        elif state.mode in _LAND_MODES:
            doing = "landing"
        elif state.mode in (_FLIGHT_MODE[v.flavour], _HOLD_MODE[v.flavour]):
            return [Notice(v.sysid, f"vehicle {v.sysid} heard again still in {state.mode}: "
                                    "its LAND was lost, sending it again", "heard_again",
                           f"heard again in {state.mode}: LAND re-sent"),
                    self._send(v, Land(v.sysid), now)]
        else:
            doing = f"in {state.mode} (its failsafe or a pilot)"
        return [Notice(v.sysid, f"vehicle {v.sysid} heard again: {doing}", "heard_again",
                       f"heard again: {doing}")]

    def _off_plan(self, v: VehicleRun, now: float
                  ) -> tuple[float, tuple[float, float, float]] | None:
        """(distance, position) if a vehicle is mid-show farther than
        ``rejoin_tolerance_m`` from its plan over the last ``OFF_PLAN_WINDOW_S`` (so a
        late telemetry sample or a lagging autopilot does not count); None otherwise."""
        pos = self._positions.get(v.sysid)
        if self.started_at is None or self._ended or pos is None:
            return None
        t = self.show_time(now)
        recent = np.linspace(max(t - OFF_PLAN_WINDOW_S, 0.0), t, 6)
        path = self.plan.trajectories.evaluate(recent, np.array([v.track]))[0][0]
        distance = float(np.linalg.norm(path - pos, axis=1).min())
        if distance <= self.config.rejoin_tolerance_m:
            return None
        return distance, (float(pos[0]), float(pos[1]), float(pos[2]))

    def _strand(self, v: VehicleRun, off: tuple[float, tuple[float, float, float]],
                now: float, how: str) -> list[Action]:
        """Off its plan mid-show (its autopilot held the last setpoint through a link drop,
        say): snapping back would be a dash across the formation.  Hold where it is,
        then leave the show on a way out planned from there."""
        distance, here = off
        v.phase, v.reason = VehiclePhase.LEAVING, f"{how} {distance:.1f} m off its plan"
        v.hold_point, v.leave = self._held_apart({v.sysid: here}, now)[v.sysid], None
        v.leave_at = self._hold_leave_time(v, now)
        if v.leave_at is None:
            return [Notice(v.sysid, f"vehicle {v.sysid} {how} {distance:.1f} m off its plan: "
                                    "holding where it is until the show ends, then to its "
                                    "landing spot", "stranded", "off its plan: holding "
                                    "where it is until the show ends")]
        return [Notice(v.sysid, f"vehicle {v.sysid} {how} {distance:.1f} m off its plan: "
                                "holding where it is, then leaving the show on a way out "
                                "planned from there", "stranded", "off its plan: holding, "
                                "then leaving on a way out")]

    def _armed_again(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        """Given up as disarmed in the air, but its own telemetry says it is armed, in the
        air, in the flight mode: the disarm it was given up for was not real (believed
        from reports the link could not check).  Left alone it would hover where it was
        with nobody in charge while the show flies past: it holds there and leaves on a
        way out, as a vehicle heard again off its plan does; after the show, it lands."""
        altitude = self._altitude(state)
        if not state.armed or state.lost or altitude is None or altitude <= AIRBORNE_M \
                or state.mode != _FLIGHT_MODE[v.flavour]:
            return []
        v.fell, v.reason = False, None
        pos = self._positions.get(v.sysid)
        if self._ended or self.started_at is None or pos is None:
            v.phase = VehiclePhase.LANDING
            return [Notice(v.sysid, f"vehicle {v.sysid} is armed in the air after all: "
                                    "landing it where it is"), self._send(v, Land(v.sysid), now)]
        off = self._off_plan(v, now)
        if off is None:
            v.phase = VehiclePhase.SHOW
            return [Notice(v.sysid, f"vehicle {v.sysid} is armed in the air after all, on its "
                                    "plan: back in the show")]
        return self._strand(v, off, now, "armed in the air after all,")

    def _land_all_if_stranded(self, now: float) -> list[Action]:
        """Land the whole fleet when STRANDED_LAND_ALL or more hold off their plans."""
        if self._ended:
            return []
        stranded = sorted(v.sysid for v in self.vehicles.values()
                          if v.hold_point is not None
                          and self.streamed_as(v) is VehiclePhase.LEAVING)
        if len(stranded) < STRANDED_LAND_ALL:
            return []
        names = ", ".join(str(s) for s in stranded)
        return [Notice(None, f"vehicles {names} are off their plans at once: landing the whole "
                             "fleet on one collision-free return planned from where each "
                             "hovers", "stranded_land_all"), *self.land_all(now)]

    def take_out(self, sysid: int, now: float, distance: float,
                 why: str = "taken out of the show") -> list[Action]:
        """Take a vehicle off its path out of the show from where it is (the guard's
        response): it holds there and leaves on a way out planned from there, or lands
        there if there is none."""
        v = self.vehicles.get(sysid)
        pos = self._positions.get(sysid)
        if v is None or v.phase is not VehiclePhase.SHOW or pos is None or self._ended:
            return []
        here = (float(pos[0]), float(pos[1]), float(pos[2]))
        return self._strand(v, (distance, here), now, why)

    def _hold_leave_time(self, v: VehicleRun, now: float) -> float | None:
        """When a vehicle holding off its plan leaves: LEAVE_LEAD_S from now, if its way out
        ends before the plan does (a way out runs on the show clock, which stops there).
        None: it holds until the show ends and then returns with the others."""
        assert v.hold_point is not None
        at = self.show_time(now) + LEAVE_LEAD_S
        if at + leave_duration(self.plan, v.track, at, np.asarray(v.hold_point)) \
                > self.plan.duration:
            return None
        return at

    def _give_up(self, v: VehicleRun, why: str, now: float) -> list[Action]:
        was, v.reason, v.pending = v.phase, why, None
        v.phase = VehiclePhase.FAILED
        if was is VehiclePhase.LANDING:
            return [Notice(v.sysid, f"vehicle {v.sysid}: {why}; land it by hand")]
        actions: list[Action] = [Notice(v.sysid, f"vehicle {v.sysid}: {why}")]
        if was is not VehiclePhase.ARMING:
            # In the air (or may be): bring it down where it is, straight below.
            v.phase = VehiclePhase.LANDING
            actions.append(self._send(v, Land(v.sysid), now))
            if was is VehiclePhase.TAKEOFF:
                # Straight below is its own takeoff spot, which may be where another
                # drone lands: the same obstacle as a drone that never took off.
                actions += self._left_on_slot(v, now)
            return actions
        v.never_flew = True
        return actions + self._left_on_slot(v, now)

    def _left_on_slot(self, v: VehicleRun, now: float) -> list[Action]:
        # A drone that never took off stands on its slot: an obstacle for its
        # neighbours' takeoff and landing.  If it is in their way, stop the show.
        self.grounded_tracks.add(v.track)
        flying = {u.track for u in self.vehicles.values() if u.phase not in _DONE}
        conflicts = [c for c in remaining_plan_conflicts(self.plan, self.grounded_tracks)
                     if c.track in flying]
        if not conflicts or self._ended:
            return []
        self.aborted = f"vehicle {v.sysid} stays on its slot and {conflicts[0]}"
        return [Notice(None, f"aborting the show: {conflicts[0]}"), *self.land_all(now)]

    def _taken_over(self, v: VehicleRun, state: VehicleState) -> list[Action]:
        """The vehicle left its flight mode by itself: a failsafe (offboard or GCS loss,
        battery, geofence) or a pilot took over.  It is out of the show, and we do not
        fight its autopilot for it: no more setpoints, and it counts as down once it has
        disarmed wherever its own mode brings it."""
        was = v.phase
        v.phase, v.pending, v.leave_at = VehiclePhase.LANDING, None, None
        v.retaking = None
        v.reason = f"left {_FLIGHT_MODE[v.flavour]} for {state.mode} during {was}"
        return [Notice(v.sysid, f"vehicle {v.sysid} switched to {state.mode} by itself "
                                f"(failsafe or pilot) during {was}: out of the show, its "
                                "autopilot is in charge until it is down")]

    def _link_failsafe(self, v: VehicleRun, state: VehicleState, now: float) -> bool:
        """Whether a mode change looks like the vehicle's own reaction to losing us (an
        offboard- or GCS-loss failsafe: hold, land or return where it was), as opposed to
        a pilot or a battery failsafe: it came while the whole fleet was silent or right
        after a silence of its own, and its battery is fine."""
        if state.mode not in _LINK_FAILSAFE_MODES[v.flavour]:
            return False
        if v.retakes >= MAX_RETAKES or _fence_acted(state, now):
            return False
        battery = state.battery_remaining_pct
        if battery is not None and self._battery is not None and battery < self._battery:
            return False
        own_silence = state.last_stream_gap_s >= LINK_FAILSAFE_GAP_S and (
            state.stream_gaps > v.gap_seen
            or (v.gap_at is not None and now - v.gap_at <= RETAKE_WINDOW_S))
        # Our own stall starves it of setpoints without any gap in its telemetry: the
        # hold says so while it lasts, and the setpoints we did not send say so after
        # (or now, on the first tick after the stall, before any is sent again).  Only
        # PX4 leaves its flight mode for want of setpoints (ArduPilot's GUIDED holds).
        starved = v.flavour is Flavour.PX4 and (
            (v.starved_at is not None and now - v.starved_at <= STARVED_WINDOW_S)
            or (v.streamed_at is not None and now - v.streamed_at >= LINK_FAILSAFE_GAP_S))
        return own_silence or starved or bool(self.holds & {"stall", "silence"})

    def _retake_goes_on(self, v: VehicleRun, state: VehicleState) -> bool:
        """A retake under way goes on, until its own attempts run out, even once the silence
        that explained it is over: while the vehicle is still in the failsafe mode it was
        being taken back from (or PX4's hold moved on to its land), and its battery is
        fine (a battery failsafe is never fought)."""
        if v.retaking is None or _fence_acted(state, v.sent_at):
            return False
        battery = state.battery_remaining_pct
        if battery is not None and self._battery is not None and battery < self._battery:
            return False
        return state.mode == v.retaking or (
            v.flavour is Flavour.PX4 and v.retaking == "AUTO.LOITER"
            and state.mode == "AUTO.LAND")

    def _retake(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        """Back in touch after a link loss that tripped its failsafe (a hold, or a blind
        descent or return through the formation): the ground station knows where everyone
        is and takes it back into its flight mode, setpoints already flowing."""
        flight = _FLIGHT_MODE[v.flavour]
        if v.retaking is not None:
            if now - v.sent_at < self.config.step_timeout_s:
                return []
            if v.attempts >= self.config.max_attempts:
                v.retaking = None
                return self._taken_over(v, state)  # it will not come back: its autopilot's
            return [self._send(v, SetMode(v.sysid, flight), now)]
        v.retakes += 1
        v.retaking = state.mode
        actions: list[Action] = [
            Notice(v.sysid, f"vehicle {v.sysid} went to {state.mode} on its own after the "
                            f"link loss: taking it back into {flight}", "retaking",
                   f"in a link-loss failsafe: taking it back into {flight}")]
        if v.phase is VehiclePhase.SHOW and (off := self._off_plan(v, now)) is not None:
            # Its failsafe stopped it short of the plan: back in the flight mode it must
            # not dash to catch up; it holds where it is and leaves on a way out.
            actions += self._strand(v, off, now, "taken back")
        return [*actions, self._send(v, SetMode(v.sysid, flight), now)]

    def _climbing(self, v: VehicleRun) -> bool:
        """Whether its telemetry says it is taking off (or flying)."""
        alt = v.altitude
        if alt is None:
            return False
        return alt > AIRBORNE_M or (v.takeoff_from is not None
                                    and alt - v.takeoff_from >= CLIMB_SEEN_M)

    def _retake_off(self, v: VehicleRun, cmd: Takeoff, now: float) -> list[Action]:
        """``takeoff_retry_after_s`` after a refused takeoff: climbing, the refusal was
        not the vehicle's last word (a forged ACK, or its answer to a repeat of a
        takeoff it had accepted) and its takeoff goes on; still on the ground, it is
        re-sent, or given up after ``max_attempts``."""
        if self._climbing(v):
            return self._refusal_overruled(v)
        v.retry_at = None
        if v.attempts >= self.config.max_attempts:
            return self._give_up(v, f"{_describe(cmd)} failed {v.attempts} times: "
                                    f"{v.reason}", now)
        return [self._send(v, cmd, now)]

    @staticmethod
    def _refusal_overruled(v: VehicleRun) -> list[Action]:
        """Its takeoff was refused, but it climbs: the refusal is dropped, not retried."""
        why, v.reason, v.retry_at = v.reason, None, None
        return [Notice(v.sysid, f"vehicle {v.sysid} climbs although its takeoff was "
                                f"refused ({why}): its takeoff goes on",
                       "takeoff_refusal_overruled",
                       "climbing although the takeoff was refused: it goes on")]

    def _altitude(self, state: VehicleState) -> float | None:
        if state.global_position is not None:
            return state.global_position.relative_alt_m
        return None

    def _advance(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        cfg = self.config
        v.altitude = self._altitude(state)
        v.mode = state.mode
        # Streamed phases fly our setpoints, so must be in the flight mode.
        if v.retaking is not None and state.mode == _FLIGHT_MODE[v.flavour]:
            v.retaking, v.pending = None, None
            return [Notice(v.sysid, f"vehicle {v.sysid} back in {state.mode}: in the sequence "
                                    f"again ({v.phase})", "retaken",
                           f"back in {state.mode} after its link-loss failsafe")]
        if v.phase in _STREAMED and state.mode is not None \
                and state.mode not in (_FLIGHT_MODE[v.flavour], "UNKNOWN"):
            if self._retake_goes_on(v, state) or self._link_failsafe(v, state, now):
                # A retake under way goes on (until its own attempts run out) even once
                # the silence that explained it is over or it was the last one allowed.
                return self._retake(v, state, now)
            return self._taken_over(v, state)
        if v.phase in _STREAMED and not state.armed and state.last_heartbeat is not None:
            # Disarmed while flying our setpoints: a crash, a motor failure, a pilot's
            # kill switch.  It is down where it fell: out of the show at once, and an
            # obstacle for every landing from now on (down_positions).
            was = v.phase
            v.phase, v.pending, v.leave_at = VehiclePhase.FAILED, None, None
            v.reason, v.fell = f"disarmed during {was} (crash or motor failure)", True
            text = state.last_statustext.text if state.last_statustext is not None else ""
            return [Notice(v.sysid, f"vehicle {v.sysid} disarmed in the air during {was}"
                                    + (f" ('{text}')" if text else "")
                                    + ": out of the show; where it fell is kept clear",
                           "crashed", "disarmed in the air: out of the show")]
        if state.stream_gaps > v.gap_seen:
            # Its own telemetry (on its own clock) stopped for a while: it may have flown
            # on without us.  Our own stalls never show here (the packets were queued,
            # not missing), and a fleet-wide silence holds the whole show instead.
            v.gap_seen, v.gap_at = state.stream_gaps, now
            gap = state.last_stream_gap_s
            if v.phase is VehiclePhase.SHOW and not self.holds & FLEET_HOLDS \
                    and (off := self._off_plan(v, now)) is not None:
                return self._strand(v, off, now, f"heard again after {gap:.1f} s,")
        pct = state.battery_remaining_pct
        if self._battery is not None and pct is not None and v.phase in _STREAMED:
            if pct < self._battery / 2 and not v.battery_critical:
                return self._battery_landing(v, state, now)
            if v.phase is VehiclePhase.SHOW and not v.battery_low and pct < self._battery:
                return self._battery_landing(v, state, now)
        cmd = v.pending
        if v.retry_at is not None and now >= v.retry_at and cmd is not None:
            if isinstance(cmd, Takeoff):
                return self._retake_off(v, cmd, now)
            return [self._send(v, cmd, now)]
        if isinstance(cmd, SetMode) and cmd.mode == "GUIDED":
            if state.mode == "GUIDED":
                return [self._send(v, Arm(v.sysid), now)]
        elif isinstance(cmd, Arm):
            if state.armed:
                v.phase, v.takeoff_from = VehiclePhase.TAKEOFF, v.altitude
                return [self._send(v, Takeoff(v.sysid, self.plan.takeoff_altitude), now)]
        elif isinstance(cmd, Takeoff):
            alt = v.altitude
            if alt is not None and abs(alt - cmd.alt_m) <= cfg.takeoff_tolerance_m:
                # Up before a refusal's verdict was due: the climb overrules it too.
                notices = self._refusal_overruled(v) if v.retry_at is not None else []
                v.stream_since = now
                v.pending = None
                if v.flavour is Flavour.ARDUPILOT:
                    v.phase = VehiclePhase.READY  # already in GUIDED since before arming
                    v.ready_at = now
                return notices
            if now - v.sent_at >= cfg.takeoff_timeout_s:
                return self._give_up(v, f"takeoff did not reach {cmd.alt_m:.1f} m within "
                                        f"{cfg.takeoff_timeout_s:.0f} s", now)
            return []
        elif cmd is None and v.phase is VehiclePhase.TAKEOFF and v.stream_since is not None:
            # PX4 rejects OFFBOARD unless setpoints are already arriving.
            if now - v.stream_since >= cfg.offboard_lead_s:
                return [self._send(v, SetMode(v.sysid, "OFFBOARD"), now)]
            return []
        elif isinstance(cmd, SetMode) and cmd.mode == "OFFBOARD":
            if state.mode == "OFFBOARD":
                v.phase, v.pending, v.ready_at = VehiclePhase.READY, None, now
                return []
        elif v.phase is VehiclePhase.RETURNING:
            return self._returning(v, state, now)
        elif v.phase is VehiclePhase.LEAVING:
            return self._leaving(v, state, now)
        elif isinstance(cmd, Land) or v.phase is VehiclePhase.LANDING:
            if not state.armed:
                v.phase, v.pending = VehiclePhase.LANDED, None
                return [Notice(v.sysid, f"vehicle {v.sysid} landed", "landed", "landed")]
            if state.mode in _LAND_MODES:
                return []  # descending: that takes as long as it takes
        if cmd is not None and now - v.sent_at >= cfg.step_timeout_s and v.retry_at is None:
            return self.command_failed(cmd, f"no effect after {cfg.step_timeout_s:.0f} s", now)
        return []

    def _landing_point(self, v: VehicleRun) -> np.ndarray:
        """Where ``v`` descends from.

        Once the show has started, above the plan's landing spot (or the spot a
        return re-assigned it, when that one was blocked).  Before (an abort
        during takeoff), straight back down its own takeoff column: the plan's
        landing spot may be another drone's takeoff spot, and that drone may
        still be standing on it (the very reason for the abort).
        """
        if v.landing_point is not None:
            return np.asarray(v.landing_point, dtype=float)
        if self.started_at is None:
            return self._home_hover[v.track]
        return self._slots[v.track]

    def _settled(self, v: VehicleRun) -> bool:
        return self._start_distance(v) <= self.config.start_tolerance_m

    def _returning(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        pos = self._positions.get(v.sysid)
        if pos is None:
            return []
        if v.returning_since is None:
            v.returning_since = now
        if self._return_wanted and self._return is None:
            v.returning_since = now  # waiting for a return plan (bounded by the driver)
            return []
        if self._return is not None and self._return_clock is not None \
                and self._return_clock.show_time(now) < self._return[0].end:
            return []  # still flying the return
        if self.paused and self.holds - {"land-all"}:
            v.returning_since = now  # held: the time to reach its spot does not run
        if np.linalg.norm(pos - self._landing_point(v)) <= self.config.arrive_tolerance_m:
            if self._ended and self.spot_blocked(v):
                return self._blocked(v, now)
            v.phase = VehiclePhase.LANDING
            return [self._send(v, Land(v.sysid), now)]
        if now - v.returning_since > self.config.return_timeout_s:
            v.phase, v.reason = VehiclePhase.LANDING, (
                f"did not reach its landing point within {self.config.return_timeout_s:.0f} s "
                f"({float(np.linalg.norm(pos - self._landing_point(v))):.1f} m away)")
            return [Notice(v.sysid, f"vehicle {v.sysid} {v.reason}: landing where it is",
                           "land_here_timeout", "did not reach its landing point: landing "
                                                "where it is"),
                    self._send(v, Land(v.sysid), now)]
        return []

    def _blocked(self, v: VehicleRun, now: float) -> list[Action]:
        """Over its landing point, but a drone came down under it (land-here, a failsafe,
        a crash): descending now would land on it.  Once every return in flight is over,
        a new one re-assigns the spots from where the drones hover, a bounded number of
        times; after that the drone moves to the nearest free spot and lands there."""
        if self._replans < MAX_REPLANS:
            self._replans += 1
            self._return_wanted, self._return, self._return_clock = True, None, None
            self._after_return = True
            return [Notice(v.sysid, f"vehicle {v.sysid}: its landing spot is taken by a drone "
                                    "that is down; planning new spots", "spot_taken",
                           "landing spot taken by a drone that is down: planning new spots")]
        spot = self.nearest_free_spot(v)
        if spot is None:
            v.phase, v.reason = VehiclePhase.LANDING, "no free landing spot left"
            return [Notice(v.sysid, f"vehicle {v.sysid}: no free landing spot left: landing "
                                    "where it is; watch it"), self._send(v, Land(v.sysid), now)]
        v.landing_point, v.returning_since = spot, now
        return [Notice(v.sysid, f"vehicle {v.sysid}: its landing spot is taken; moving to the "
                                f"nearest free spot ({spot[0]:.1f}, {spot[1]:.1f}) to land")]

    def nearest_free_spot(self, v: VehicleRun) -> tuple[float, float, float] | None:
        """The closest landing candidate (plan landing spots, then takeoff slots) clear of
        every drone down and every spot someone else lands on."""
        candidates = landing_candidates(self.plan)
        down = np.array(self.down_positions(v)).reshape(-1, 3)
        reserved = np.array(self.reserved_spots({v.sysid})).reshape(-1, 3)
        free = candidates[free_spots(self.plan, candidates, reserved, down)]
        if not len(free):
            return None
        best = free[np.argmin(np.linalg.norm(free - self._landing_point(v), axis=1))]
        return (float(best[0]), float(best[1]), float(best[2]))

    def _leaving(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        if v.leave is None:
            return []  # holding where it was heard again, its way out being planned
        if self.show_time(now) < v.leave.until:
            return []
        return self._returning(v, state, now)

    def _begin_leaves(self, now: float) -> list[Action]:
        if self.started_at is None or self._ended:
            return []
        t = self.show_time(now)
        actions: list[Action] = []
        for v in self.vehicles.values():
            if v.leave is None or t < v.leave.at:
                continue
            if v.phase is VehiclePhase.SHOW:
                v.phase = VehiclePhase.LEAVING
                actions.append(Notice(v.sysid, f"vehicle {v.sysid} leaves the show"))
            elif v.phase is VehiclePhase.LOST and v.lost_from is VehiclePhase.SHOW:
                v.lost_from = VehiclePhase.LEAVING
        return actions

    def _battery_landing(self, v: VehicleRun, state: VehicleState,
                         now: float) -> list[Action]:
        assert self._battery is not None and state.battery_remaining_pct is not None
        v.battery_low = True
        pct = state.battery_remaining_pct
        low = [u for u in self.vehicles.values() if u.battery_low and u.phase in _STREAMED]
        if not self._ended and len(low) >= max(2, math.ceil(LOW_BATTERY_FLEET * len(
                self.vehicles))):
            # The batteries are running out across the fleet: one planned return for all,
            # not a way out (or a descent in place) each.
            v.reason = f"battery {pct:.0f} %"
            return [Notice(None, f"batteries low across the fleet ({len(low)} vehicles below "
                                 f"{self._battery:.0f} %): landing every vehicle"),
                    *self.land_all(now)]
        if pct < self._battery / 2 and self._column_clear(v):
            v.battery_critical = True
            v.phase, v.reason = VehiclePhase.LANDING, f"battery {pct:.0f} % (critical)"
            v.leave_at = None
            return [Notice(v.sysid, f"vehicle {v.sysid}: battery {pct:.0f} % is below half "
                                    f"the show's {self._battery:.0f} %: landing where it is "
                                    "(nobody below it)", "battery_critical",
                           "battery critical: landing where it is"),
                    self._send(v, Land(v.sysid), now)]
        if v.phase is not VehiclePhase.SHOW:
            return []  # already leaving or returning: that is the fastest safe way down
        v.reason = f"battery {pct:.0f} % (minimum {self._battery:.0f} %)"
        actions: list[Action] = [Notice(
            v.sysid, f"vehicle {v.sysid}: battery {pct:.0f} % is below the show's "
                     f"{self._battery:.0f} %: it leaves the show", "battery_low",
            "battery low: leaving the show")]
        return actions + self.land_one(v.sysid, now)

    def _column_clear(self, v: VehicleRun, ground_m: float | None = None,
                      above_m: float | None = None, margin_m: float = 0.0) -> bool:
        """Whether no other drone is within the separation limit, horizontally, of the
        column below ``v`` (descending there would not pass through anyone), counting
        drones up to ``above_m`` (default: the limit) above it, and ``margin_m`` beyond
        the limit sideways.  With ``ground_m``, drones down on the ground (and the slots
        of those that never flew) count only within that distance of where ``v`` lands:
        a landed drone is not flying into anyone."""
        here = self._positions.get(v.sysid)
        if here is None:
            return False
        limit = self.plan.limits.min_separation
        above = limit if above_m is None else above_m
        others: list[tuple[np.ndarray, bool]] = []  # (position, down on the ground)
        for u in self.vehicles.values():
            pos = self._positions.get(u.sysid)
            if u is v or pos is None or u.phase in (VehiclePhase.PREFLIGHT,):
                continue
            # Down is what telemetry says, not the phase: a FAILED drone may be airborne.
            others.append((pos, u.phase in _DONE and float(pos[2]) <= AIRBORNE_M))
        if ground_m is not None:  # excluded drones, and those never airborne, on slots
            others += [(self.plan.home[t], True) for t in self.grounded_tracks
                       if t != v.track]
        for pos, down in others:
            reach = ground_m if ground_m is not None and down else limit + margin_m
            if pos[2] < here[2] + above and float(np.hypot(*(pos[:2] - here[:2]))) < reach:
                return False
        return True

    def _maybe_start_show(self, now: float, states: Mapping[int, VehicleState]) -> list[Action]:
        if self.started_at is not None or self._ended or not self._started or self.paused:
            return []
        phases = [v.phase for v in self.vehicles.values()]
        if any(p in (VehiclePhase.ARMING, VehiclePhase.TAKEOFF) for p in phases):
            return []
        ready = [v for v in self.vehicles.values() if v.phase is VehiclePhase.READY]
        if not ready:
            return []
        # Takeoff ends within takeoff_tolerance_m of the altitude; starting the
        # clock before the fleet has settled on the plan's first points would
        # put that whole offset into the first seconds of the show.
        if self._ready_since is None:
            self._ready_since = now
        if any(v.ready_at is not None and now - v.ready_at < self.config.hover_before_show_s
               for v in ready):
            return []
        if now - self._ready_since < self.config.settle_timeout_s \
                and not all(self._settled(v) for v in ready):
            return []
        # A vehicle that could not get to its first point in that time does not start
        # the show off its plan: it goes back down its own column (an exclusion, with
        # the exclusion's safety check: if the others need its slot clear, no show).
        actions: list[Action] = []
        far = [v for v in ready if self._start_distance(v) > self.config.exclude_tolerance_m]
        for v in far:
            d = self._start_distance(v)
            v.reason = (
                f"{d:.1f} m from its first plan point after "
                f"{self.config.settle_timeout_s:.0f} s (tolerance "
                f"{self.config.exclude_tolerance_m:.1f} m)")
            # Back over its own takeoff slot, then down there (the exclusion check below
            # says whether the others can fly the show with it standing on it).
            v.phase, v.pending, v.returning_since = VehiclePhase.RETURNING, None, now
            v.landing_point = tuple(float(x) for x in self._home_hover[v.track])  # type: ignore[assignment]
            actions += [Notice(v.sysid, f"vehicle {v.sysid} is {v.reason}: landing it on its "
                                        "slot instead of starting it", "start_excluded",
                               "could not reach its first plan point: landing on its slot"),
                        *self._left_on_slot(v, now)]
        if self._ended:
            return actions  # the exclusion left the show unsafe: aborted
        ready = [v for v in ready if v not in far]
        if not ready:
            return actions
        self.clock.start(now)
        for v in ready:
            v.phase = VehiclePhase.SHOW
        return [*actions, Notice(None, f"show started with {len(ready)} vehicle(s)")]

    def _start_distance(self, v: VehicleRun) -> float:
        pos = self._positions.get(v.sysid)
        return math.inf if pos is None else float(np.linalg.norm(pos - self._first[v.track]))


def _describe(command: Command) -> str:
    if isinstance(command, SetMode):
        return f"mode {command.mode}"
    if isinstance(command, Takeoff):
        return "takeoff"
    return type(command).__name__.lower()
