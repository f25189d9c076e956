"""The vehicle left its flight mode by itself: a failsafe of its own reacting to losing
us (an offboard- or GCS-loss failsafe: hold, land or return where it is) is taken back,
since the ground station knows where everyone is; a pilot, its fence or a battery
failsafe is respected, and the vehicle is out of the show."""

from __future__ import annotations

import enum
from collections.abc import Collection

from groundctl.execute.sequence.types import (
    _LINK_FAILSAFE_MODES,
    FENCE_NOTICE_S,
    LINK_FAILSAFE_GAP_S,
    MAX_RETAKES,
    RETAKE_WINDOW_S,
    STARVED_WINDOW_S,
    VehicleRun,
)
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState


class ModeLeft(enum.Enum):
    """What to do about a vehicle found out of its flight mode."""

    RETAKE = "retake"
    """A link-loss failsafe of ours to undo: back into the flight mode."""
    RESPECT = "respect"
    """A pilot, a fence or another failsafe: out of the show, its autopilot in charge."""


def fence_acted(state: VehicleState, at: float) -> bool:
    """The vehicle's own fence fired (ArduPilot's "Fence Breached", PX4's "Geofence ...")
    within :data:`FENCE_NOTICE_S` before ``at``."""
    st = state.last_statustext
    return st is not None and "fence" in st.text.lower() and at - st.at <= FENCE_NOTICE_S


def _battery_fine(state: VehicleState, minimum: float | None) -> bool:
    battery = state.battery_remaining_pct
    return battery is None or minimum is None or battery >= minimum


def retake_goes_on(v: VehicleRun, state: VehicleState, battery_min: float | None) -> bool:
    """A retake under way goes on, until its own attempts run out, even once the silence
    that explained it is over: while the vehicle is still in the failsafe mode it was
    being taken back from (or PX4's hold moved on to its land), and its battery is fine
    (a battery failsafe is never fought)."""
    if v.retaking is None or fence_acted(state, v.sent_at):
        return False
    if not _battery_fine(state, battery_min):
        return False
    return state.mode == v.retaking or (
        v.flavour is Flavour.PX4 and v.retaking == "AUTO.LOITER"
        and state.mode == "AUTO.LAND")


def link_failsafe(v: VehicleRun, state: VehicleState, now: float, battery_min: float | None,
                  holds: Collection[str]) -> bool:
    """Whether a mode change looks like the vehicle's own reaction to losing us, as
    opposed to a pilot or a battery failsafe: it came while the whole fleet was silent
    (or our loop stalled: ``holds``) or right after a silence of its own, and its
    battery is fine."""
    if state.mode not in _LINK_FAILSAFE_MODES[v.flavour]:
        return False
    if v.retakes >= MAX_RETAKES or fence_acted(state, now):
        return False
    if not _battery_fine(state, battery_min):
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
    return own_silence or starved or bool(set(holds) & {"stall", "silence"})


def mode_left(v: VehicleRun, state: VehicleState, now: float, battery_min: float | None,
              holds: Collection[str]) -> ModeLeft:
    """Take it back, or respect what its autopilot (or pilot) did.  A retake under way
    goes on (until its own attempts run out) even once the silence that explained it is
    over or it was the last one allowed."""
    if retake_goes_on(v, state, battery_min) or link_failsafe(v, state, now, battery_min,
                                                              holds):
        return ModeLeft.RETAKE
    return ModeLeft.RESPECT
