"""The sequence's spares layer (issue 29), driven with hand-made vehicle states and a
float clock: which track is vacated and which spare goes, a join handed over and flown
through the lifecycle, a spare late or given up, land-all with spares in every phase,
and spare pads as obstacles.  Joins are planned for real (:func:`plan_join`)."""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from test_execute_support import geo_offset, make_vehicle, set_altitude
from test_flight_spares import air_spares_plan, spares_plan

from groundctl.execute.frames import show_to_enu
from groundctl.execute.leaving import Join
from groundctl.execute.sequence import (
    Action,
    Arm,
    Disarm,
    Land,
    Notice,
    SetMode,
    ShowPhase,
    ShowSequence,
    Takeoff,
    VehiclePhase,
)
from groundctl.flight import returning
from groundctl.flight.joining import plan_join
from groundctl.flight.returning import assign_landing, plan_leave
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState
from groundctl.plan.plan import Plan

ARDU = Flavour.ARDUPILOT
SPARES = {10: 0, 11: 1}


def _state(plan: Plan, sysid: int, where: np.ndarray) -> VehicleState:
    """A vehicle on the ground at show-frame ``where`` (its EKF origin there)."""
    e, n, u = show_to_enu(plan.origin, np.asarray(where, dtype=float)[None, :])[0]
    return make_vehicle(sysid, ekf_origin=geo_offset(plan.origin, float(e), float(n), float(u)))


def _fleet(plan: Plan) -> dict[int, VehicleState]:
    assert plan.spares is not None
    states = {t + 1: _state(plan, t + 1, plan.home[t]) for t in range(plan.drones)}
    for sysid, pad in SPARES.items():
        states[sysid] = _state(plan, sysid, plan.spares.pads[pad])
    return states


def _sequence(plan: Plan, **kwargs: object) -> ShowSequence:
    tracks = {t + 1: t for t in range(plan.drones)}
    flavours = {s: ARDU for s in [*tracks, *SPARES]}
    return ShowSequence(plan, tracks, flavours, spares=SPARES, **kwargs)  # type: ignore[arg-type]


def _up(seq: ShowSequence, states: dict[int, VehicleState], sysids: list[int],
        t: float, *, climb: bool = True) -> list[list[Action]]:
    """``sysids`` go GUIDED at ``t``, arm at ``t + 0.1`` and (``climb``) are at the takeoff
    altitude at ``t + 0.2``: each step seen by one update.  The updates' actions."""
    out = []
    for k, step in enumerate(("mode", "armed", "up")):
        for s in sysids:
            if step == "mode":
                states[s].mode = "GUIDED"
            elif step == "armed":
                states[s].armed = True
            elif climb:
                set_altitude(states[s], seq.plan.takeoff_altitude)
        out.append(seq.update(t + 0.1 * (k + 1), states))
    return out


def _showing(plan: Plan, **kwargs: object) -> tuple[ShowSequence, dict[int, VehicleState], float]:
    """The show clock running at our time 1.0, every show vehicle on its first point."""
    seq, states = _sequence(plan, **kwargs), _fleet(plan)
    seq.start(0.0)
    _up(seq, states, [s for s in states if s not in SPARES], 0.0, climb=False)
    for s in states:
        if s not in SPARES:
            set_altitude(states[s], plan.takeoff_altitude)
    actions = seq.update(1.0, states)
    assert Notice(None, f"show started with {plan.drones} vehicle(s)") in actions
    return seq, states, 1.0


def _fall(seq: ShowSequence, states: dict[int, VehicleState], sysid: int, now: float) -> None:
    states[sysid].armed = False
    set_altitude(states[sysid], 0.0)
    seq.update(now, states)
    assert seq.vehicles[sysid].phase is VehiclePhase.FAILED


def _sent() -> tuple[ShowSequence, dict[int, VehicleState], Join, float]:
    """The show running, vehicle 5 fallen, spare 10 sent into its track: the sequence,
    the states, the join and our time the spare is due to arm."""
    seq, states, now = _showing(spares_plan())
    _fall(seq, states, 5, now + 1.0)
    join = _join()
    seq.set_join(4, 10, join, now + 1.0)
    return seq, states, join, 1.0 + join.at - join.climb_s


@cache
def _join() -> Join:
    """Spare 10's way from its pad into track 4 (vehicle 5's), leaving after show time 3."""
    plan = spares_plan()
    assert plan.spares is not None
    return plan_join(plan, 4, plan.spares.pads[0], 3.0, static=plan.home[4][None, :],
                     climb=plan.takeoff_altitude)


def test_a_fallen_drone_vacates_its_track_and_the_nearest_spare_is_asked_for() -> None:
    plan = spares_plan()
    seq, states, now = _showing(plan)
    assert seq.join_needed == []  # nobody left
    _fall(seq, states, 5, now + 1.0)
    (track, spare, pad), = seq.join_needed
    assert track == 4 and spare in SPARES
    assert plan.spares is not None
    assert np.allclose(pad, plan.spares.pads[SPARES[spare]])
    # No spare for a track that is flown: handing one over changes nothing.
    assert seq.set_join(3, spare, replace(_join(), track=3), now + 1.0) == []
    assert spare not in seq.vehicles


def test_a_join_is_flown_through_the_lifecycle_dark_until_it_is_on_the_track() -> None:
    plan = spares_plan()
    seq, states, now = _showing(plan)
    _fall(seq, states, 5, now + 1.0)
    join = _join()
    actions = seq.set_join(4, 10, join, now + 1.0)
    assert [a.kind for a in actions if isinstance(a, Notice)] == ["spare_planned"]
    run = seq.vehicles[10]
    assert run.phase is VehiclePhase.PREFLIGHT and run.track == 4
    assert seq.vehicles[5].replaced_by == 10
    assert seq.join_needed == []  # the track has its spare
    assert seq.phase is ShowPhase.SHOW  # a spare arming mid-show is not the show arming
    # It arms at the way in's show time less its climb (the show clock started at 1.0).
    arm_at = 1.0 + join.at - join.climb_s
    assert SetMode(10, "GUIDED") not in seq.update(arm_at - 0.2, states)
    assert SetMode(10, "GUIDED") in seq.update(arm_at + 0.01, states)
    mode, armed, _ = _up(seq, states, [10], arm_at, climb=False)
    assert Arm(10) in mode and Takeoff(10, plan.takeoff_altitude) in armed
    set_altitude(states[10], plan.takeoff_altitude)
    seq.update(arm_at + 3.0, states)
    assert run.phase is VehiclePhase.JOINING
    req = seq.stream_request(arm_at + 3.0)
    assert 10 in req.sysids and req.paths[10].kind == "join"
    assert seq.dark(arm_at + 3.0) == {5, 10}  # the spare on its way, the drone that fell
    joined = seq.update(1.0 + join.until + 0.01, states)
    assert [a.kind for a in joined if isinstance(a, Notice)] == ["spare_joined"]
    assert run.phase is VehiclePhase.SHOW and seq.dark(1.0 + join.until) == {5}
    assert seq.stream_request(1.0 + join.until + 0.1).paths[10].kind == "plan"
    (r,) = seq.spares_report()["replacements"]  # type: ignore[misc]
    assert r["outcome"] == "joined" and r["spare"] == 10 and r["failed"] == 5


def test_a_spare_not_up_in_time_lands_back_on_its_pad_and_the_next_one_is_asked_for() -> None:
    seq, states, join, arm_at = _sent()
    seq.update(arm_at + 0.01, states)  # told to go GUIDED; it never does
    late = seq.update(1.0 + join.at + 1.5, states)
    assert Disarm(10) in late  # an Arm already sent may still be carried out
    run = seq.vehicles[10]
    assert run.phase is VehiclePhase.FAILED and run.never_flew
    assert 4 not in seq.grounded_tracks and seq.aborted is None  # no abort for a spare
    assert [a.kind for a in late if isinstance(a, Notice)] == ["spare_failed"]
    seq.update(1.0 + join.at + 1.6, states)
    (track, spare, _), = seq.join_needed
    assert (track, spare) == (4, 11)


def test_a_spare_up_but_past_its_instant_does_not_set_off() -> None:
    plan = spares_plan()
    seq, states, join, arm_at = _sent()
    seq.update(arm_at + 0.01, states)
    _up(seq, states, [10], arm_at, climb=False)
    # Up only after its way in should have begun (and the late check was not reached).
    set_altitude(states[10], plan.takeoff_altitude)
    seq.update(1.0 + join.at + 0.9, states)
    assert seq.vehicles[10].phase is VehiclePhase.JOINING  # up within a second: it goes
    # ... but one up later than that lands back on its pad instead.
    seq2, states2, _, _ = _sent()
    seq2.update(arm_at + 0.01, states2)
    _up(seq2, states2, [10], arm_at, climb=False)
    seq2.vehicles[10].phase = VehiclePhase.READY  # up, its takeoff done, too late
    seq2.vehicles[10].pending = None
    actions = seq2.update(1.0 + join.at + 2.0, states2)  # ... one up later does not
    assert Land(10) in actions and seq2.vehicles[10].phase is VehiclePhase.LANDING


@pytest.mark.parametrize("phase", ["preflight", "ready", "joining"])
def test_land_all_with_a_spare_on_its_way(phase: str) -> None:
    plan = spares_plan()
    seq, states, join, arm_at = _sent()
    t = 2.5
    if phase != "preflight":
        seq.update(arm_at + 0.01, states)
        _up(seq, states, [10], arm_at, climb=False)
        set_altitude(states[10], plan.takeoff_altitude)
        t = arm_at + 0.3 if phase == "ready" else 1.0 + join.at + 0.5
        seq.vehicles[10].pending = None if phase == "ready" else seq.vehicles[10].pending
        if phase == "ready":
            # Up and hovering over its pad before its way in begins.
            seq.vehicles[10].phase = VehiclePhase.READY
        else:
            seq.update(t, states)
            assert seq.vehicles[10].phase is VehiclePhase.JOINING
    actions = seq.land_all(t)
    run = seq.vehicles[10]
    if phase == "preflight":
        assert run.phase is VehiclePhase.LANDED  # stood down on its pad
        seq.update(t + 0.1, states)
        (r,) = seq.spares_report()["replacements"]  # type: ignore[misc]
        assert r["outcome"].startswith("failed")
    elif phase == "ready":
        assert run.phase is VehiclePhase.LANDING and Land(10) in actions  # straight down
    else:
        # In the air on its way in: it is flown home with everyone, on the planned return.
        assert run.phase is VehiclePhase.RETURNING
        needed = seq.return_needed
        assert needed is not None and (10, 4) in needed


def test_spare_pads_are_obstacles_for_every_landing() -> None:
    plan = spares_plan()
    assert plan.spares is not None
    # Spare 11 failed pre-flight: only 10 is ready, but both pads hold a vehicle.
    seq = ShowSequence(plan, {t + 1: t for t in range(plan.drones)},
                       {s: ARDU for s in range(1, plan.drones + 2)}, spares={10: 0})
    down = np.array(seq.down_positions())
    for pad in plan.spares.pads:
        assert np.min(np.linalg.norm(down - pad, axis=1)) < 1e-9


def test_two_drones_of_one_track_never_get_the_same_landing_spot() -> None:
    plan = spares_plan()
    start = plan.landing_hover[[4, 4]] + np.array([[0.0, 0.0, 2.0], [3.0, 0.0, 2.0]])
    goals = assign_landing(plan, [4, 4], start, np.zeros((0, 3)))
    assert not np.allclose(goals[0], goals[1])


def test_a_drone_that_leaves_the_show_goes_dark_and_the_fleet_lands_lit() -> None:
    """Out of the show while it runs (it fell, the operator brought it down), a drone's
    LEDs are off for the rest of the flight; at land-all the others land in their
    colours as they always have."""
    plan = spares_plan()
    seq, states, now = _showing(plan, use_spares=False)
    assert seq.dark(now + 0.5) == set()
    _fall(seq, states, 5, now + 1.0)
    assert seq.dark(now + 1.0) == {5}
    seq.land_here(2, now + 1.5)
    assert seq.vehicles[2].phase is VehiclePhase.LANDING
    assert seq.dark(now + 1.5) == {2, 5}
    seq.land_all(now + 2.0)
    seq.update(now + 2.1, states)
    assert seq.dark(now + 2.1) == {2, 5}
    # Brought down after the show was called off: it lands in its colours like the rest.
    seq.land_here(4, now + 2.2)
    assert seq.vehicles[4].phase is VehiclePhase.LANDING
    assert seq.dark(now + 2.3) == {2, 5}


def test_spares_in_the_air_take_off_with_the_fleet_wait_dark_and_land_at_the_end() -> None:
    plan = air_spares_plan()
    assert plan.spares is not None
    seq, states = _sequence(plan), _fleet(plan)
    # Armed with everyone (ArduPilot: GUIDED first).
    assert {SetMode(s, "GUIDED") for s in SPARES} <= set(seq.start(0.0))
    actions = _up(seq, states, list(states), 0.0)[-1]
    # The show starts with its nine; the spares hover at their points, dark, not in it.
    assert Notice(None, f"show started with {plan.drones} vehicle(s)") in actions
    for s, k in SPARES.items():
        run = seq.vehicles[s]
        assert run.phase is VehiclePhase.READY and run.standing_by
        path = seq.path(s, 2.0)
        assert path is not None and path.kind == "hold"
        assert np.allclose(path.point, plan.spares.points[k])  # type: ignore[arg-type]
    assert seq.dark(2.0) == set(SPARES)
    assert seq.phase is ShowPhase.SHOW
    # Sent in from where it hovers: the same run takes the track, no arming.
    _fall(seq, states, 5, 2.0)
    (track, spare, start), = seq.join_needed
    assert np.allclose(start, plan.spares.points[SPARES[spare]])
    join = plan_join(plan, track, np.asarray(start), 3.0, static=plan.home[4][None, :])
    assert join.climb_s == 0.0
    seq.set_join(track, spare, join, 2.0)
    seq.update(2.1, states)
    assert seq.vehicles[spare].phase is VehiclePhase.JOINING
    assert seq.vehicles[spare].track == track
    other = next(s for s in SPARES if s != spare)
    # At the end the one never sent comes straight down onto its pad.
    seq.update(1.0 + plan.duration + 0.1, states)  # the show ends ...
    actions = seq.update(1.0 + plan.duration + 0.2, states)  # ... and it is told to land
    assert Land(other) in actions
    assert seq.vehicles[other].phase is VehiclePhase.LANDING


def _air_showing() -> tuple[ShowSequence, dict[int, VehicleState]]:
    """Air spares hovering at their points, the show running from our time 0.3."""
    plan = air_spares_plan()
    seq, states = _sequence(plan), _fleet(plan)
    seq.start(0.0)
    _up(seq, states, list(states), 0.0)
    assert seq.started_at is not None
    return seq, states


def test_no_spares_keeps_air_spares_on_their_pads() -> None:
    plan = air_spares_plan()
    seq = _sequence(plan, use_spares=False)
    assert not set(SPARES) & set(seq.vehicles)
    assert not {a.sysid for a in seq.start(0.0) if not isinstance(a, Notice)} & set(SPARES)


def test_air_spares_lost_or_low_come_down_on_their_pads_never_on_a_return() -> None:
    seq, states = _air_showing()
    states[10].lost = True
    seq.update(1.0, states)
    assert seq.vehicles[10].phase is VehiclePhase.LOST
    actions = seq.land_all(1.1)
    assert Land(10) in actions and seq.vehicles[10].lost_from is VehiclePhase.LANDING
    needed = seq.return_needed
    assert needed is not None and all(s not in SPARES for s, _ in needed)
    assert Land(11) in actions and seq.vehicles[11].phase is VehiclePhase.LANDING
    # Below the show's battery minimum a spare standing by goes down, and is not chosen.
    seq, states = _air_showing()
    states[11].battery_remaining_pct = 15.0  # the show's minimum is 20 %
    actions = seq.update(1.0, states)
    assert Land(11) in actions and seq.vehicles[11].phase is VehiclePhase.LANDING
    _fall(seq, states, 5, 1.1)
    assert [spare for _, spare, _ in seq.join_needed] == [10]


def test_a_show_that_cannot_start_lands_the_air_spares() -> None:
    plan = air_spares_plan()
    seq, states = _sequence(plan), _fleet(plan)
    seq.start(0.0)
    _up(seq, states, list(SPARES), 0.0)  # only the spares get up; the show's drones ...
    for s in states:
        if s not in SPARES:
            seq.vehicles[s].phase = VehiclePhase.FAILED  # ... are all given up
    actions = seq.update(1.0, states)
    assert {Land(s) for s in SPARES} <= set(actions)


def test_a_replaced_drone_on_its_way_out_is_an_obstacle_of_its_own_beside_the_spare(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The track a spare takes over is flown by the spare: for the planners it stays on
    its plan, and the drone replaced, still on its way out, is a way out of its own
    (it was the track's way out, so the spare on the track's plan was nobody's)."""
    plan = spares_plan()
    seq, states, now = _showing(plan)
    said = seq.replace(3, now + 1.0)
    ((sysid, track, at, _hold),) = seq.leave_needed
    assert sysid == 3
    # Healthy, it holds the formation whole: it leaves at the end of the ring's hold.
    assert at == pytest.approx(plan.formations[0].end)
    assert any("at the end of its formation's hold" in a.text for a in said
               if isinstance(a, Notice))
    leave = plan_leave(plan, track, at, seq.leaves)
    seq.set_leave(3, leave, now + 1.0)
    assert seq.leaves == {track: leave} and seq.replaced_leaves == []
    seq.update(now + 1.1, states)
    ((vacated, spare, _pad),) = seq.join_needed
    assert vacated == track
    assert plan.spares is not None
    join = plan_join(plan, track, plan.spares.pads[SPARES[spare]], seq.show_time(now + 1.1),
                     leaves=seq.leaves, climb=plan.takeoff_altitude)
    seq.set_join(track, spare, join, now + 1.2)
    assert seq.vehicles[3].replaced_by == spare
    assert seq.leaves == {} and seq.replaced_leaves == [(track, leave)]
    # A way out planned now sees each drone once: the others on their plans, the spare on
    # its way in (then on the track's plan), the drone replaced on its way out -- not the
    # track's plan as well, with nobody on it between the two.
    rows: list[int] = []
    real = returning.plan_among

    def counting(*args: object, **kwargs: object) -> object:
        others_at = args[7]
        rows.append(others_at(np.array([0.0, 1.0])).shape[0])  # type: ignore[operator]
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(returning, "plan_among", counting)
    plan_leave(plan, 0, leave.at, seq.leaves, joins=seq.joins, replaced=seq.replaced_leaves)
    assert rows == [(plan.drones - 2) + 1 + 1]
    monkeypatch.undo()
    # The spare flies its way in and is on the track's plan (out of seq.joins) while the
    # drone it replaced is still on its way out.
    arm_at = now + join.at - join.climb_s
    _up(seq, states, [spare], arm_at, climb=False)
    set_altitude(states[spare], plan.takeoff_altitude)
    seq.update(arm_at + 3.0, states)
    seq.update(now + join.until + 0.01, states)
    assert seq.vehicles[spare].phase is VehiclePhase.SHOW and seq.joins == {}
    t_on = join.until + 0.01
    assert leave.at < t_on < leave.until
    assert seq.replaced_leaves == [(track, leave)] and track not in seq.leaves
    # (Before, the drone replaced stood for the track in seq.leaves: the spare on the
    # track's plan was nobody's obstacle.)  Ways out planned from here keep clear of
    # both: the spare on the track's plan and the drone replaced on its way out.
    for other_track in (0, 7, 8):
        at_o = seq.show_time(now + join.until + 0.01) + 2.0
        other = plan_leave(plan, other_track, at_o, seq.leaves, joins=seq.joins,
                           replaced=seq.replaced_leaves)
        t = np.linspace(at_o, min(other.until, plan.duration), 2001)
        mine = other.position(t)
        spare_at = plan.trajectories.evaluate(t, np.array([track]))[0][0]
        replaced_at = leave.position(t)
        for theirs in (spare_at, replaced_at):
            assert float(np.linalg.norm(mine - theirs, axis=1).min()) \
                >= plan.limits.min_separation - 1e-3, other_track
    # Down, it is where it is (a drone down), not a way out any more.
    _fall(seq, states, 3, now + join.until + 1.0)
    assert seq.replaced_leaves == []
