"""A command refused or unanswered: whether it matters (a stale answer, or its effect
already seen), and if so whether to send it again or give the vehicle up.  A refused
takeoff is judged by the climb, not by the answer: without signing anyone can send a
refusal, and an autopilot refuses a repeat of a takeoff it is already spooling up for."""

from __future__ import annotations

import enum

from groundctl.execute.sequence.types import (
    _LAND_MODES,
    AIRBORNE_M,
    CLIMB_SEEN_M,
    Command,
    Land,
    Takeoff,
    VehicleRun,
)


class Refused(enum.Enum):
    """What a refusal (or a command without effect) asks for."""

    STALE = "stale"
    """The answer is to a command the vehicle has moved on from."""
    DONE = "done"
    """Its effect is already there (a climb, a land mode): only the answer was lost."""
    JUDGE_LATER = "judge_later"
    """A refused takeoff: judged by the climb once it has had the time to lift off."""
    RETRY = "retry"
    """Send it again after a while."""
    GIVE_UP = "give_up"
    """Out of attempts: the vehicle is given up."""


def climbing(v: VehicleRun) -> bool:
    """Whether its telemetry says it is taking off (or flying)."""
    alt = v.altitude
    if alt is None:
        return False
    return alt > AIRBORNE_M or (v.takeoff_from is not None
                                and alt - v.takeoff_from >= CLIMB_SEEN_M)


def refused(v: VehicleRun | None, command: Command, max_attempts: int) -> Refused:
    """What ``command``, refused or without effect, asks of vehicle ``v``."""
    if v is None or v.pending != command:
        return Refused.STALE
    if isinstance(command, Takeoff):
        # Climbing already: the first NAV_TAKEOFF was accepted but its ACK lost, and the
        # autopilot refuses a repeat in flight.  Its effect is what counts.
        return Refused.DONE if climbing(v) else Refused.JUDGE_LATER
    if isinstance(command, Land) and v.mode in _LAND_MODES:
        # In its land mode already: the LAND was carried out and only its ACK was lost
        # (half the packets lost, say).  Counting the timeouts gave a vehicle that went
        # on to land up as "land failed 3 times".
        return Refused.DONE
    return _again(v, max_attempts)


def _again(v: VehicleRun, max_attempts: int) -> Refused:
    """Sent again, or given up once ``max_attempts`` sends had no effect."""
    return Refused.GIVE_UP if v.attempts >= max_attempts else Refused.RETRY


def takeoff_verdict(v: VehicleRun, max_attempts: int) -> Refused:
    """The verdict on a refused takeoff once the time to lift off has passed: climbing,
    the refusal was not the vehicle's last word (a forged ACK, or its answer to a repeat)
    and its takeoff goes on (DONE); still on the ground, RETRY or GIVE_UP."""
    return Refused.DONE if climbing(v) else _again(v, max_attempts)
