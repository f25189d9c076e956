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

The sequence is one class, :class:`ShowSequence`, built in layers, one module each
(each layer derives from the one before it)::

    types      the actions, phases, constants, SequenceConfig, VehicleRun, StreamRequest
    lifecycle  the table (phase, event) -> phase every phase change goes through
    state      SequenceState: the fields, the show clock and its holds, the show's phase
    spots      who is streamed, the one path each follows, where each lands
    returns    the land-all return
    columns    the last resort: straight down, one column at a time
    leaves     ways out of the show mid-flight (land-one, off its plan, battery)
    commands   the operator's commands
    lost       lost, heard again, off its plan (stranded), given up
    failsafes  refused commands, autopilot failsafes (retaken or respected), batteries
    spares     a spare sent into a vacated track: asked for, armed, joining, joined
    core       ShowSequence: start, and each update drives every vehicle's lifecycle

Beside the layers, :mod:`.policies` holds judgements as pure functions of a vehicle's
view (a low battery, a flight mode the vehicle left), which the layers carry out.
"""

from __future__ import annotations

# Every public name the module had before it became a package stays importable from here.
from groundctl.execute.sequence.core import ShowSequence
from groundctl.execute.sequence.types import (
    AIRBORNE_M,
    CLIMB_SEEN_M,
    COLUMN_MARGIN_M,
    COLUMN_WAIT_S,
    FENCE_NOTICE_S,
    FLEET_HOLDS,
    GROUND_CLEARANCE_M,
    HOLD_APART_MAX_M,
    HOVER_BEFORE_SHOW_S,
    LINK_FAILSAFE_GAP_S,
    LOW_BATTERY_FLEET,
    MAX_LATE_LEAVES,
    MAX_REPLANS,
    MAX_RETAKES,
    OFF_PLAN_WINDOW_S,
    RETAKE_WINDOW_S,
    SILENCE_GAP_S,
    STARVED_WINDOW_S,
    STRANDED_LAND_ALL,
    Action,
    Arm,
    Command,
    Disarm,
    Kill,
    Land,
    Notice,
    SequenceConfig,
    SetMode,
    ShowPhase,
    StreamRequest,
    Takeoff,
    VehiclePhase,
    VehicleRun,
)

__all__ = [
    "AIRBORNE_M",
    "CLIMB_SEEN_M",
    "COLUMN_MARGIN_M",
    "COLUMN_WAIT_S",
    "FENCE_NOTICE_S",
    "FLEET_HOLDS",
    "GROUND_CLEARANCE_M",
    "HOLD_APART_MAX_M",
    "HOVER_BEFORE_SHOW_S",
    "LINK_FAILSAFE_GAP_S",
    "LOW_BATTERY_FLEET",
    "MAX_LATE_LEAVES",
    "MAX_REPLANS",
    "MAX_RETAKES",
    "OFF_PLAN_WINDOW_S",
    "RETAKE_WINDOW_S",
    "SILENCE_GAP_S",
    "STARVED_WINDOW_S",
    "STRANDED_LAND_ALL",
    "Action",
    "Arm",
    "Command",
    "Disarm",
    "Kill",
    "Land",
    "Notice",
    "SequenceConfig",
    "SetMode",
    "ShowPhase",
    "ShowSequence",
    "StreamRequest",
    "Takeoff",
    "VehiclePhase",
    "VehicleRun",
]
