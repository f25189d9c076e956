"""The vehicle lifecycle table (groundctl/execute/sequence/lifecycle.py), without a fleet:
what it allows, what it refuses, that its docstring says what the table holds, and that
every phase can be reached and left for the ground."""

from __future__ import annotations

import re
from collections import deque

import pytest

from groundctl.errors import FlightError, LifecycleError
from groundctl.execute.sequence import VehiclePhase as P
from groundctl.execute.sequence import lifecycle
from groundctl.execute.sequence.lifecycle import PREVIOUS, RESUMABLE, TRANSITIONS, Event, step

_ENDS = {P.LANDED, P.KILLED}


def _targets(phase: P, event: Event) -> set[P]:
    target = TRANSITIONS[phase][event]
    return set(RESUMABLE[event]) if target is PREVIOUS else {target}  # type: ignore[arg-type]


def _reachable(start: P) -> set[P]:
    seen, todo = {start}, deque([start])
    while todo:
        phase = todo.popleft()
        for event in TRANSITIONS[phase]:
            for nxt in _targets(phase, event) - seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def test_a_show_flown_as_planned() -> None:
    phase = P.PREFLIGHT
    walk = [Event.START, Event.ARMED, Event.UP, Event.SHOW_STARTS, Event.SHOW_ENDS,
            Event.ARRIVED, Event.DISARMED]
    seen = [phase]
    for event in walk:
        phase = step(phase, event)
        seen.append(phase)
    assert seen == [P.PREFLIGHT, P.ARMING, P.TAKEOFF, P.READY, P.SHOW, P.RETURNING,
                    P.LANDING, P.LANDED]


def test_lost_and_heard_again_goes_back_to_where_it_was() -> None:
    assert step(P.SHOW, Event.LOST) is P.LOST
    assert step(P.LOST, Event.HEARD_AGAIN, P.SHOW) is P.SHOW
    assert step(P.LOST, Event.HEARD_AGAIN, P.LANDING) is P.LANDING
    # While it is silent its own phase moves on with the show, by the same table.
    assert step(P.SHOW, Event.SHOW_ENDS) is P.RETURNING


def test_a_failed_return_resumes_what_the_land_all_interrupted() -> None:
    assert step(P.SHOW, Event.RETURN) is P.RETURNING
    assert step(P.RETURNING, Event.RETURN_FAILED, P.SHOW) is P.SHOW
    assert step(P.RETURNING, Event.RETURN_FAILED, P.LEAVING) is P.LEAVING


@pytest.mark.parametrize(("phase", "event", "previous"), [
    (P.LANDED, Event.ARMED, None),          # down is down
    (P.PREFLIGHT, Event.SHOW_STARTS, None),  # no show before takeoff
    (P.SHOW, Event.DISARMED, None),         # disarmed in the air is FELL, not landed
    (P.LOST, Event.LOST, None),
    (P.LOST, Event.HEARD_AGAIN, None),      # back to where? the caller must say
    (P.LOST, Event.HEARD_AGAIN, P.LANDED),  # never lost once down
    (P.RETURNING, Event.RETURN_FAILED, P.LANDING),
])
def test_a_change_the_table_does_not_list_is_refused(phase: P, event: Event,
                                                      previous: P | None) -> None:
    with pytest.raises(LifecycleError) as info:
        step(phase, event, previous)
    err = info.value
    assert isinstance(err, FlightError)  # the CLI's one line and exit code
    assert (err.phase, err.event) == (str(phase), str(event))
    assert "\n" not in str(err) and str(phase) in str(err) and str(event) in str(err)


def test_every_phase_is_listed_and_the_ends_are_final() -> None:
    assert set(TRANSITIONS) == set(P)
    for phase in _ENDS:
        assert set(TRANSITIONS[phase]) == {Event.KILL}
    assert all(TRANSITIONS[p][Event.KILL] is P.KILLED for p in P)


def test_every_phase_can_be_reached_and_every_one_leads_to_the_ground() -> None:
    assert _reachable(P.PREFLIGHT) == set(P)
    for phase in P:
        assert _reachable(phase) & _ENDS, phase
    # Without the operator's kill, every phase still leads to landed.
    for phase in set(P) - {P.KILLED}:
        seen, todo = {phase}, deque([phase])
        while todo:
            here = todo.popleft()
            for event in TRANSITIONS[here]:
                if event is Event.KILL:
                    continue
                for nxt in _targets(here, event) - seen:
                    seen.add(nxt)
                    todo.append(nxt)
        assert P.LANDED in seen, phase


def test_the_docstring_table_is_the_table() -> None:
    """The module docstring's table (and its three closing sentences) say exactly what
    TRANSITIONS holds: the readable form cannot drift from the real one."""
    doc = lifecycle.__doc__ or ""
    said: set[tuple[P, Event, object]] = set()
    block = doc.split("::", 1)[1].split("\n\n")[1]
    phase: P | None = None
    for line in block.splitlines():
        words = line.split()
        if not words:
            continue
        if words[0].rstrip(",") in {p.value for p in P}:
            if words[0].endswith(","):
                continue  # "landed, killed: none"
            phase = P(words[0])
        assert phase is not None
        for event, target in re.findall(r"(\w+)\*? -> (\w+)", line):
            said.add((phase, Event(event), PREVIOUS if target == "PREVIOUS" else P(target)))
    in_air = (P.READY, P.JOINING, P.SHOW, P.LEAVING, P.RETURNING)
    for p in in_air:
        said |= {(p, Event.LAND, P.LANDING), (p, Event.TAKEN_OVER, P.LANDING),
                 (p, Event.FELL, P.FAILED), (p, Event.GIVE_UP, P.FAILED)}
    for p in (P.ARMING, P.TAKEOFF, P.LANDING, *in_air):
        said.add((p, Event.LOST, P.LOST))
    for p in P:
        said.add((p, Event.KILL, P.KILLED))
    table = {(p, e, t) for p, exits in TRANSITIONS.items() for e, t in exits.items()}
    assert said == table
