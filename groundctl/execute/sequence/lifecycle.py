"""One vehicle's lifecycle as one table: (phase, event) -> phase, and nothing else.

The sequence's layers decide *when* something happens to a vehicle and what to send
it; every change of its phase goes through :func:`step` with the :class:`Event` that
caused it, so the whole lifecycle reads here, in one place, and a change the table
does not list is a bug that stops at once (:class:`~groundctl.errors.LifecycleError`)
instead of leaving a vehicle in a phase nobody planned for.  Side effects (commands,
notices, paths) stay with the callers, as in h11's ``_state.py``.

A lost vehicle keeps the phase it was lost in (``VehicleRun.lost_from``: what it is
still streamed as), and the sequence moves that phase on with the same table while it
is silent (the show ends, a land-all, a way out begins).  Two targets are a memory,
not a phase (:data:`PREVIOUS`): heard again, a vehicle goes back to the phase it was
lost in; when no land-all return can be planned, to the phase the land-all took it
out of.

The table, by phase (``*`` marks the ways down that are not landing on a spot)::

    preflight  start -> arming            stand_down -> landed
    arming     armed -> takeoff           stand_down -> landed      give_up -> failed
    takeoff    up -> ready                land* -> landing          give_up -> failed
    ready      show_starts -> show        show_ends -> returning    return -> returning
               not_at_start -> returning  joins -> joining
    joining    joined -> show             show_ends -> returning    return -> returning
    show       leaves -> leaving          stranded -> leaving       show_ends -> returning
               return -> returning
    leaving    show_ends -> returning     return -> returning       arrived -> landing
    returning  arrived -> landing         last_resort -> leaving
               return_failed -> PREVIOUS (ready, joining, show or leaving)
    landing    disarmed -> landed         give_up -> failed
    lost       heard_again -> PREVIOUS (the phase it was lost in)    stranded -> leaving
               land* -> landing
    failed     alive -> show              stranded -> leaving       land* -> landing
    landed, killed: none

A spare that takes over a track runs through the same table from preflight: it arms,
takes off over its pad, is ready, and joins (``joins``: it flies its way in, dark) until
it is on the track's plan (``joined``).

and from every phase in the air (ready, joining, show, leaving, returning): ``land*``
(straight down where it is), ``taken_over`` (its autopilot left the flight mode) ->
landing, ``fell`` (disarmed in the air) and ``give_up`` -> failed; from arming,
takeoff, landing and every phase in the air: ``lost`` -> lost; from every phase:
``kill`` -> killed.
"""

from __future__ import annotations

import enum
from typing import Final

from groundctl.errors import LifecycleError
from groundctl.execute.sequence.types import VehiclePhase

P = VehiclePhase


class Event(enum.StrEnum):
    """What happened to a vehicle, as far as its phase is concerned."""

    START = "start"
    """Pre-flight passed: arm it (ArduPilot: GUIDED first)."""
    ARMED = "armed"
    """Seen armed: take off."""
    UP = "up"
    """At its takeoff altitude in the flight mode: ready for the show."""
    SHOW_STARTS = "show_starts"
    """The show clock starts (or, for a vehicle ready but silent then, is running)."""
    JOINS = "joins"
    """A spare ready over its pad flies its way into a track (:attr:`VehicleRun.join`)."""
    JOINED = "joined"
    """A joining spare is on the track's plan (the way in's end): it flies the show."""
    NOT_AT_START = "not_at_start"
    """Could not reach its first plan point in time: back down its own column."""
    SHOW_ENDS = "show_ends"
    """The plan's end: back over its landing point."""
    RETURN = "return"
    """Land-all or land-one: to its landing point, then down."""
    RETURN_FAILED = "return_failed"
    """No land-all return could be planned: back to what it was doing."""
    LEAVES = "leaves"
    """Its way out begins (its planned instant on the show clock)."""
    STRANDED = "stranded"
    """Off its plan mid-show: it holds where it is, then leaves on a way out."""
    LAST_RESORT = "last_resort"
    """No return and drones off their plans: it holds, to land straight down."""
    ARRIVED = "arrived"
    """Over its landing point (or at the end of its way out): land."""
    LAND = "land"
    """Straight down where it is (land-here, a timeout, a clear column, a battery)."""
    STAND_DOWN = "stand_down"
    """Never took off: nothing to land."""
    DISARMED = "disarmed"
    """Seen disarmed after landing: down."""
    TAKEN_OVER = "taken_over"
    """Its autopilot left the flight mode by itself: out of the show, it lands."""
    FELL = "fell"
    """Disarmed in the air: a crash or a motor failure."""
    ALIVE = "alive"
    """Given up as fallen, it is armed in the air on its plan after all."""
    GIVE_UP = "give_up"
    """A step failed too often: given up."""
    LOST = "lost"
    """Its link is lost."""
    HEARD_AGAIN = "heard_again"
    """Its link is back."""
    KILL = "kill"
    """The operator stopped its motors."""


class _Previous:
    """The target that is a memory: the phase the vehicle was in before."""

    def __repr__(self) -> str:
        return "PREVIOUS"


#: A target that is where the vehicle was before (given to :func:`step`).
PREVIOUS: Final = _Previous()

_IN_AIR = (P.READY, P.JOINING, P.SHOW, P.LEAVING, P.RETURNING)
_CAN_BE_LOST = (P.ARMING, P.TAKEOFF, *_IN_AIR, P.LANDING)

#: The lifecycle: for each phase, the events that move a vehicle out of it and where to.
TRANSITIONS: Final[dict[VehiclePhase, dict[Event, VehiclePhase | _Previous]]] = {
    P.PREFLIGHT: {Event.START: P.ARMING, Event.STAND_DOWN: P.LANDED},
    P.ARMING: {Event.ARMED: P.TAKEOFF, Event.STAND_DOWN: P.LANDED,
               Event.GIVE_UP: P.FAILED},
    P.TAKEOFF: {Event.UP: P.READY, Event.LAND: P.LANDING, Event.GIVE_UP: P.FAILED},
    P.READY: {Event.SHOW_STARTS: P.SHOW, Event.SHOW_ENDS: P.RETURNING,
              Event.RETURN: P.RETURNING, Event.NOT_AT_START: P.RETURNING,
              Event.JOINS: P.JOINING},
    P.JOINING: {Event.JOINED: P.SHOW, Event.SHOW_ENDS: P.RETURNING,
                Event.RETURN: P.RETURNING},
    P.SHOW: {Event.LEAVES: P.LEAVING, Event.STRANDED: P.LEAVING,
             Event.SHOW_ENDS: P.RETURNING, Event.RETURN: P.RETURNING},
    P.LEAVING: {Event.SHOW_ENDS: P.RETURNING, Event.RETURN: P.RETURNING,
                Event.ARRIVED: P.LANDING},
    P.RETURNING: {Event.ARRIVED: P.LANDING, Event.LAST_RESORT: P.LEAVING,
                  Event.RETURN_FAILED: PREVIOUS},
    P.LANDING: {Event.DISARMED: P.LANDED, Event.GIVE_UP: P.FAILED},
    P.LOST: {Event.HEARD_AGAIN: PREVIOUS, Event.STRANDED: P.LEAVING, Event.LAND: P.LANDING},
    P.FAILED: {Event.ALIVE: P.SHOW, Event.STRANDED: P.LEAVING, Event.LAND: P.LANDING},
    P.LANDED: {},
    P.KILLED: {},
}
for _phase in _IN_AIR:
    TRANSITIONS[_phase].update({Event.LAND: P.LANDING, Event.TAKEN_OVER: P.LANDING,
                                Event.FELL: P.FAILED, Event.GIVE_UP: P.FAILED})
for _phase in _CAN_BE_LOST:
    TRANSITIONS[_phase][Event.LOST] = P.LOST
for _exits in TRANSITIONS.values():
    _exits[Event.KILL] = P.KILLED

#: The phases a PREVIOUS target may go back to, by event.
RESUMABLE: Final[dict[Event, frozenset[VehiclePhase]]] = {
    Event.HEARD_AGAIN: frozenset(_CAN_BE_LOST),
    Event.RETURN_FAILED: frozenset((P.READY, P.JOINING, P.SHOW, P.LEAVING)),
}


def step(phase: VehiclePhase, event: Event,
         previous: VehiclePhase | None = None) -> VehiclePhase:
    """The phase a vehicle in ``phase`` moves to on ``event``; ``previous`` is where it
    was before, for the events whose target is :data:`PREVIOUS`.

    Raises :class:`~groundctl.errors.LifecycleError` for a pair the table does not list
    (or a ``previous`` it cannot go back to): a bug, never an operator's mistake.
    """
    target = TRANSITIONS[phase].get(event)
    if target is None:
        raise LifecycleError(str(phase), str(event))
    if isinstance(target, _Previous):
        if previous is None or previous not in RESUMABLE[event]:
            raise LifecycleError(str(phase), str(event),
                                 f"cannot go back to {previous}")
        return previous
    return target
