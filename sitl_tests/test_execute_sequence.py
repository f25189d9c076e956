"""The flight sequence state machine, driven with hand-made vehicle states and a float clock."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_execute_support import HOME, make_plan, make_vehicle, set_altitude

from groundctl.execute.leaving import LANDING_MARGIN_M, Leave, clear_spot_near
from groundctl.execute.sequence import (
    HOVER_BEFORE_SHOW_S,
    MAX_REPLANS,
    Arm,
    Disarm,
    Kill,
    Land,
    Notice,
    SequenceConfig,
    SetMode,
    ShowPhase,
    ShowSequence,
    Takeoff,
    VehiclePhase,
)
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.trajectory import Trajectories

ARDU, PX4 = Flavour.ARDUPILOT, Flavour.PX4


def _fleet(flavour: Flavour = ARDU, n: int = 2) -> dict[int, VehicleState]:
    return {i + 1: make_vehicle(i + 1, flavour=flavour, ned=(0.0, 3.0 * i, 0.0))
            for i in range(n)}


def _landing_swapped_plan() -> Plan:
    """make_plan() with tracks 0 and 1 landing on each other's takeoff spot."""
    plan = make_plan()
    swapped = plan.trajectories.pos.copy()
    swapped[0, -1], swapped[1, -1] = plan.trajectories.pos[1, -1], plan.trajectories.pos[0, -1]
    return replace(plan, trajectories=Trajectories(plan.trajectories.times, swapped,
                                                   plan.trajectories.vel))


def _armed_ardupilot(seq: ShowSequence, states: dict[int, VehicleState], now: float) -> float:
    """Drive an ArduPilot fleet from start to armed (takeoff sent); returns the time."""
    seq.start(now)
    for v in states.values():
        v.mode = "GUIDED"
    seq.update(now + 0.1, states)
    for v in states.values():
        v.armed = True
    seq.update(now + 0.2, states)
    return now + 0.2


def _airborne_ardupilot(seq: ShowSequence, states: dict[int, VehicleState], now: float) -> float:
    """Drive an ArduPilot fleet from start to the show clock running; returns the time."""
    _armed_ardupilot(seq, states, now)
    for v in states.values():
        set_altitude(v, 3.0)
    seq.update(now + 0.3, states)
    return now + 0.3


def test_ardupilot_sequence_guided_before_arming_then_show_then_landing() -> None:
    plan = make_plan()
    states = _fleet(ARDU)
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    assert seq.phase is ShowPhase.PREFLIGHT
    # ArduCopter's guided takeoff: GUIDED first, then arm, then NAV_TAKEOFF.
    assert seq.start(0.0) == [SetMode(1, "GUIDED"), SetMode(2, "GUIDED")]
    assert seq.phase is ShowPhase.ARMING
    assert seq.update(0.1, states) == []  # nothing happens until telemetry shows GUIDED
    for v in states.values():
        v.mode = "GUIDED"
    assert seq.update(0.2, states) == [Arm(1), Arm(2)]
    for v in states.values():
        v.armed = True
    assert seq.update(0.3, states) == [Takeoff(1, 3.0), Takeoff(2, 3.0)]
    assert seq.phase is ShowPhase.TAKEOFF
    assert seq.stream_request(0.3).sysids == frozenset()

    set_altitude(states[1], 2.8)
    set_altitude(states[2], 2.6)  # 0.4 m short: not there yet
    assert seq.update(1.0, states) == []
    assert seq.vehicles[1].phase is VehiclePhase.READY
    assert seq.stream_request(1.0).sysids == frozenset({1})
    assert not seq.stream_request(1.0).moving  # hovering at plan time 0 until everyone is up
    set_altitude(states[2], 2.95)
    assert seq.update(2.0, states) == []  # vehicle 1 still 0.2 m below its first plan point
    set_altitude(states[1], 2.9)
    assert seq.update(2.5, states) == [Notice(None, "show started with 2 vehicle(s)")]
    assert seq.phase is ShowPhase.SHOW

    req = seq.stream_request(5.5)
    assert req.sysids == frozenset({1, 2}) and req.moving and req.fixed == {}
    assert req.show_time == pytest.approx(3.0)

    assert seq.update(12.5, states) == [
        Notice(None, "show finished: returning to the landing slots")]
    assert seq.phase is ShowPhase.LANDING
    req = seq.stream_request(12.5)
    assert req.fixed == {1: (0.0, 0.0, 3.0), 2: (3.0, 0.0, 3.0)}
    assert not req.moving and req.show_time == plan.duration

    states[1].position_ned = (0.1, 0.0, -3.0)  # over its slot (show x=0, y=0.1 -> N 0.1)
    states[2].position_ned = (0.0, 1.0, -3.0)  # 2 m short of its slot
    assert seq.update(13.0, states) == [Land(1)]
    assert seq.vehicles[2].land_from is None  # not told to land yet
    states[2].position_ned = (0.0, 3.2, -3.0)
    assert seq.update(14.0, states) == [Land(2)]
    # Where each was told to land (its land mode descends over it): the report's
    # commanded separation of a closest approach during a descent (runner/stream.py).
    assert seq.vehicles[1].land_from == pytest.approx((0.0, 0.1))
    assert seq.vehicles[2].land_from == pytest.approx((3.2, 0.0))
    assert seq.stream_request(14.0).sysids == frozenset()
    states[1].armed = states[2].armed = False
    assert seq.update(20.0, states) == [Notice(1, "vehicle 1 landed"),
                                        Notice(2, "vehicle 2 landed")]
    assert seq.phase is ShowPhase.LANDED


def test_the_show_clock_starts_without_a_straggler_once_the_settle_time_is_over() -> None:
    states = _fleet(ARDU)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    _armed_ardupilot(seq, states, 0.0)
    set_altitude(states[1], 3.0)
    set_altitude(states[2], 2.75)  # takeoff done (within 0.3 m) but not settled (0.15 m)
    assert seq.update(1.0, states) == []
    assert seq.update(10.9, states) == []
    assert seq.update(11.0, states) == [Notice(None, "show started with 2 vehicle(s)")]


def test_the_show_clock_waits_until_every_vehicle_has_hovered_ready_long_enough() -> None:
    """A flight hovers each vehicle HOVER_BEFORE_SHOW_S before its show: its hover throttle
    (its thrust left) is measured before its path asks anything of it."""
    states = _fleet(ARDU)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU},
                       SequenceConfig(hover_before_show_s=HOVER_BEFORE_SHOW_S))
    _armed_ardupilot(seq, states, 0.0)
    set_altitude(states[1], 3.0)
    assert seq.update(1.0, states) == []  # vehicle 1 ready (and settled) at 1.0
    set_altitude(states[2], 3.0)
    assert seq.update(2.0, states) == []  # vehicle 2 ready at 2.0, both settled
    assert seq.update(1.0 + HOVER_BEFORE_SHOW_S, states) == []  # vehicle 2 not long enough
    assert seq.phase is not ShowPhase.SHOW
    assert seq.update(2.0 + HOVER_BEFORE_SHOW_S, states) == [
        Notice(None, "show started with 2 vehicle(s)")]


def test_px4_streams_setpoints_before_asking_for_offboard() -> None:
    states = _fleet(PX4, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: PX4}, SequenceConfig(offboard_lead_s=1.0))
    assert seq.start(0.0) == [Arm(1)]
    states[1].armed = True
    assert seq.update(0.5, states) == [Takeoff(1, 3.0)]
    set_altitude(states[1], 3.1)
    assert seq.update(4.0, states) == []
    # Setpoints flow from here, while still in the takeoff phase...
    assert seq.stream_request(4.0).sysids == frozenset({1})
    assert seq.vehicles[1].phase is VehiclePhase.TAKEOFF
    assert seq.update(4.5, states) == []
    # ...and only after offboard_lead_s is OFFBOARD requested.
    assert seq.update(5.0, states) == [SetMode(1, "OFFBOARD")]
    states[1].mode = "OFFBOARD"
    assert seq.update(5.2, states) == [Notice(None, "show started with 1 vehicle(s)")]


def test_arming_refusals_are_retried_then_the_vehicle_is_left_out_with_the_reason() -> None:
    states = _fleet(ARDU, n=3)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1, 3: 2}, dict.fromkeys((1, 2, 3), ARDU),
                       SequenceConfig(max_attempts=3, retry_after_s=1.0))
    seq.start(0.0)
    for v in states.values():
        v.mode = "GUIDED"
    seq.update(0.1, states)
    reason = "PreArm: Battery below minimum arming voltage"
    now = 0.2
    for attempt in (1, 2):
        assert seq.command_failed(Arm(2), reason, now) == []
        assert seq.update(now + 0.5, states) == []  # waits retry_after_s
        assert seq.update(now + 1.0, states) == [Arm(2)]
        assert seq.vehicles[2].attempts == attempt + 1
        now += 1.0
    assert seq.command_failed(Arm(2), reason, now) == [
        Notice(2, f"vehicle 2: arm failed 3 times: {reason}")]
    assert seq.vehicles[2].phase is VehiclePhase.FAILED
    assert seq.vehicles[2].reason == f"arm failed 3 times: {reason}"
    # Its slot is 3 m from the neighbours: the others fly on.
    assert seq.command_failed(Arm(2), reason, now) == []  # stale: nothing pending
    states[1].armed = states[3].armed = True
    assert seq.update(now + 0.1, states) == [Takeoff(1, 3.0), Takeoff(3, 3.0)]


def test_a_vehicle_left_on_a_neighbours_takeoff_path_aborts_the_show() -> None:
    home = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(make_plan(home=home), {1: 0, 2: 1}, {1: ARDU, 2: ARDU},
                       SequenceConfig(max_attempts=1))
    seq.start(0.0)
    states[1].mode = states[2].mode = "GUIDED"
    seq.update(0.1, states)
    states[1].armed = True
    assert seq.update(0.2, states) == [Takeoff(1, 3.0)]
    actions = seq.command_failed(Arm(2), "PreArm: Compass not calibrated", 0.3)
    assert actions == [
        Notice(2, "vehicle 2: arm failed 1 times: PreArm: Compass not calibrated"),
        Notice(None, "aborting the show: track 0 passes 1.00 m from excluded track 1's takeoff "
                     "slot during takeoff at t=0.0 s (minimum separation 1.50 m)"),
        Notice(None, "landing all vehicles"),
        Land(1),
    ]
    assert seq.vehicles[1].phase is VehiclePhase.LANDING


def test_wrong_mode_with_no_effect_is_resent_after_the_step_timeout() -> None:
    states = _fleet(ARDU, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: ARDU},
                       SequenceConfig(step_timeout_s=5.0, retry_after_s=1.0))
    seq.start(0.0)
    assert seq.update(4.9, states) == []
    assert seq.update(5.0, states) == []
    assert seq.vehicles[1].reason == "no effect after 5 s"
    assert seq.update(6.0, states) == [SetMode(1, "GUIDED")]


def test_a_lost_vehicle_is_still_streamed_its_plan_and_rejoins_when_heard_again() -> None:
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    t0 = _airborne_ardupilot(seq, states, 0.0)
    states[2].lost = True
    states[2].last_heard = 0.0
    actions = seq.update(t0 + 2.0, states)
    assert actions == [Notice(2, "vehicle 2 lost during show (silent for 2.3 s); still "
                                 "streamed its plan in case it hears us, otherwise its "
                                 "failsafe is in charge; the show goes on")]
    assert seq.vehicles[2].phase is VehiclePhase.LOST
    # Its plan is the one place sure to be clear of the others: keep sending it.
    req = seq.stream_request(t0 + 2.0)
    assert req.sysids == frozenset({1, 2}) and req.moving and not req.fixed
    assert seq.phase is ShowPhase.SHOW
    states[2].lost = False
    _at_plan_point(states[2], seq, 1, t0 + 3.0)
    assert seq.update(t0 + 3.0, states) == [
        Notice(2, "vehicle 2 heard again: back in the sequence (show)")]
    assert seq.vehicles[2].phase is VehiclePhase.SHOW


def _at_plan_point(state: VehicleState, seq: ShowSequence, track: int, now: float,
                   off: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
    """Put ``state`` (EKF origin at the show origin) on ``track``'s plan point, plus ``off``."""
    p = seq.plan.state_at(seq.show_time(now)).pos[track] + np.asarray(off)
    state.position_ned = (float(p[1]), float(p[0]), float(-p[2]))


def test_a_vehicle_heard_again_off_its_plan_holds_there_and_leaves_from_there() -> None:
    """Its autopilot held the last setpoint while the others flew on: snapping back
    would be a dash across the formation."""
    plan, states, seq, start = _in_formation_show()
    states[2].lost = True
    seq.update(start + 1.0, states)
    states[2].lost = False
    _at_plan_point(states[2], seq, 1, start + 2.0, off=(2.5, 0.0, 0.0))
    assert seq.update(start + 2.0, states) == [Notice(
        2, "vehicle 2 heard again 2.5 m off its plan: holding where it is, then leaving the "
           "show on a way out planned from there")]
    v = seq.vehicles[2]
    assert v.phase is VehiclePhase.LEAVING and v.hold_point is not None
    [(sysid, track, at, here)] = seq.leave_needed
    assert (sysid, track, here) == (2, 1, v.hold_point)
    assert at == pytest.approx(seq.show_time(start + 2.0) + 2.0)
    req = seq.stream_request(start + 2.0)
    assert req.fixed == {2: v.hold_point} and 1 in req.sysids  # hovering, the other flies on
    # Its way out, from where it hovers.
    leave = Leave(at, Trajectories(np.array([0.0, 3.0]), np.stack(
        [np.asarray(here), plan.landing_hover[1]])[None], np.zeros((1, 2, 3))), held=True)
    # A way out planned from its plan point (before it was stranded) is stale: refused.
    assert seq.set_leave(2, replace(leave, held=False), start + 2.5) == []
    assert seq.set_leave(2, leave, start + 2.5)[0].text.startswith("way out for vehicle 2")
    assert seq.stream_request(start + 2.5).fixed == {2: v.hold_point}  # not begun yet
    req = seq.stream_request(start + 4.5)
    assert req.fixed == {} and req.leaves == {2: leave}
    # No way out at all: it lands where it holds.
    _, states, seq, start = _in_formation_show()
    states[2].lost = True
    seq.update(start + 1.0, states)
    states[2].lost = False
    _at_plan_point(states[2], seq, 1, start + 2.0, off=(-3.0, 0.0, 0.0))
    seq.update(start + 2.0, states)
    assert seq.leave_failed(2, "no room", start + 2.1) == [
        Notice(2, "no safe way out of the show for vehicle 2 (no room); landing it where it "
                  "holds"), Land(2)]
    assert seq.vehicles[2].phase is VehiclePhase.LANDING


def _after_a_fleet_wide_silence() -> tuple[dict[int, VehicleState], ShowSequence, float]:
    """The formation show with both vehicles lost for a second and heard again."""
    _, states, seq, start = _in_formation_show()
    for v in states.values():
        v.lost = True
    seq.update(start + 1.0, states)
    for v in states.values():
        v.lost = False
    return states, seq, start


def test_two_vehicles_off_their_plans_at_once_land_the_fleet_on_one_joint_return() -> None:
    """A fleet-wide silence stranded both: one way out each, planned one at a time through
    a show that flies on, would each take the other for a drone on its plan.  One return,
    planned from where each hovers, lands everyone instead."""
    states, seq, start = _after_a_fleet_wide_silence()
    _at_plan_point(states[1], seq, 0, start + 2.0, off=(2.5, 0.0, 0.0))
    _at_plan_point(states[2], seq, 1, start + 2.0, off=(-2.5, 0.0, 0.0))
    actions = seq.update(start + 2.0, states)
    assert Notice(None, "vehicles 1, 2 are off their plans at once: landing the whole fleet "
                        "on one collision-free return planned from where each hovers") \
        in actions
    assert seq.ended and seq.leave_needed == []
    assert [s for s, _ in seq.return_needed or []] == [1, 2]
    for sysid in (1, 2):  # the return starts where each holds
        hold = seq.vehicles[sysid].hold_point
        assert hold is not None
        assert seq.return_start(sysid, start + 2.0) == pytest.approx(np.asarray(hold))


def test_no_return_for_drones_off_their_plans_lands_them_column_by_column_never_again() -> None:
    """The strong-wind livelock: stranded drones, land-all, no return, the show flown on,
    stranded again at once, 40 times over.  Now the last resort: everyone holds where it
    is and goes straight down, the lowest first, none with a drone below it."""
    states, seq, start = _after_a_fleet_wide_silence()
    # Vehicle 2 hovers 1 m right above where vehicle 1 is: 1 goes first, 2 waits.
    _at_plan_point(states[1], seq, 0, start + 2.0, off=(2.5, 0.0, 0.0))
    p1 = np.array(states[1].position_ned)
    states[2].position_ned = (float(p1[0]), float(p1[1]), float(p1[2]) - 1.0)
    seq.update(start + 2.0, states)
    assert seq.return_needed is not None
    starts = {s: seq.return_start(s, start + 3.0) for s in (1, 2)}
    actions = seq.return_failed("planner gave up", start + 3.0)
    assert isinstance(actions[0], Notice) and actions[0].kind == "land_in_columns"
    assert "one column at a time" in actions[0].text
    assert Land(1) in actions and Land(2) not in actions
    assert seq.in_columns and seq.ended and seq.return_needed is None
    assert seq.vehicles[1].phase is VehiclePhase.LANDING
    v2 = seq.vehicles[2]
    assert v2.phase is VehiclePhase.LEAVING and v2.hold_point is not None
    # It holds where its path stopped (where it was stranded), not over its landing spot.
    assert np.asarray(v2.hold_point) == pytest.approx(starts[2])
    assert np.linalg.norm(np.asarray(v2.hold_point) - seq.plan.landing_hover[1]) > 1.0
    assert seq.stream_request(start + 3.0).fixed == {2: v2.hold_point}  # holds meanwhile
    assert seq.land_one(2, start + 3.2)[0].text.startswith("every vehicle lands straight")
    # Nothing re-enters planning: no stranded land-all, no return asked, a stop signal
    # (or the guard) changes nothing.
    assert [a for a in seq.update(start + 3.5, states) if isinstance(a, Land)] == []
    assert seq.land_all(start + 3.6) == [
        Notice(None, "already landing every vehicle, one column at a time")]
    assert seq.return_needed is None and seq.leave_needed == []
    # Vehicle 1 lands and disarms below it: 2's column is clear of anyone in the air, and
    # the one on the ground is within GROUND_CLEARANCE_M, so 2 still waits ...
    states[1].position_ned = (float(p1[0]), float(p1[1]), 0.0)
    states[1].armed = False
    set_altitude(states[1], 0.0)
    seq.update(start + 20.0, states)
    assert seq.vehicles[1].phase is VehiclePhase.LANDED
    assert seq.vehicles[2].phase is VehiclePhase.LEAVING
    # ... until it drifts clear of where 1 stands: then down it goes.
    states[2].position_ned = (float(p1[0]) + 1.2, float(p1[1]), float(p1[2]) - 1.0)
    assert Land(2) in seq.update(start + 21.0, states)
    assert seq.vehicles[2].phase is VehiclePhase.LANDING


def test_one_vehicle_off_its_plan_leaves_alone_and_the_show_goes_on() -> None:
    _, states, seq, start = _in_formation_show()
    states[2].lost = True
    seq.update(start + 1.0, states)
    states[2].lost = False
    _at_plan_point(states[2], seq, 1, start + 2.0, off=(2.5, 0.0, 0.0))
    seq.update(start + 2.0, states)
    assert not seq.ended and [s for s, *_ in seq.leave_needed] == [2]


def test_a_vehicle_lost_during_the_show_is_sent_its_landing_point_after_the_end() -> None:
    states = _fleet(ARDU, n=2)
    plan = make_plan()
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    t0 = _airborne_ardupilot(seq, states, 0.0)
    states[2].lost = True
    seq.update(t0 + 1.0, states)
    seq.update(t0 + plan.duration + 0.1, states)
    req = seq.stream_request(t0 + plan.duration + 0.2)
    assert 2 in req.sysids
    np.testing.assert_allclose(req.fixed[2], plan.landing_hover[1])


def test_hold_freezes_the_show_clock_and_resume_continues_from_there() -> None:
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    t0 = _airborne_ardupilot(seq, states, 0.0)
    ramp = seq.clock.default_ramp_s
    # Braking along the plan: the clock's rate falls from 1 to 0 over the ramp, so the
    # show stops half a ramp further on (no overshoot past a frozen point).
    stop = 2.0 + ramp / 2
    assert seq.hold(t0 + 2.0) == [Notice(
        None, f"holding: braking along the plan, stopped at show time {stop:.1f} s")]
    assert seq.hold(t0 + 2.5) == [Notice(None, "already holding")]
    assert seq.stream_request(t0 + 2.0 + ramp / 2).moving  # still braking
    req = seq.stream_request(t0 + 30.0)
    assert req.show_time == pytest.approx(stop) and not req.moving
    assert seq.update(t0 + 30.0, states) == []  # the show does not end while held
    assert seq.resume(t0 + 30.0) == [Notice(None, f"resuming at show time {stop:.1f} s")]
    # Ramping up again: after the ramp, full rate (half a ramp behind a clock that jumped).
    after = seq.stream_request(t0 + 30.0 + ramp + 1.0).show_time
    assert after == pytest.approx(stop + ramp / 2 + 1.0)
    assert seq.resume(t0 + 31.0) == [Notice(None, "not holding: nothing to resume")]


def test_land_one_outside_the_show_returns_that_vehicle_at_once() -> None:
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    seq.start(0.0)
    # Taking off: not in the show yet, so straight down its own column (no way out needed).
    assert seq.land_one(2, 0.1)[0] == Notice(2, "landing vehicle 2")
    assert seq.vehicles[2].phase is VehiclePhase.LANDED and seq.leave_needed == []
    assert seq.land_one(9, 0.1) == [Notice(None, "no vehicle 9 in this show")]


def test_land_one_mid_show_without_a_formation_ahead_flies_on() -> None:
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})  # no formations
    t0 = _airborne_ardupilot(seq, states, 0.0)
    assert seq.land_one(2, t0 + 1.0) == [Notice(
        2, "vehicle 2: no formation left to leave the show from; it lands with the others at "
           "the end (land-here 2 brings it straight down now)")]
    req = seq.stream_request(t0 + 1.0)
    assert seq.vehicles[2].phase is VehiclePhase.SHOW and req.fixed == {} and req.leaves == {}


def _formation_plan(home: np.ndarray = HOME) -> Plan:
    """make_plan() with a formation reached at t=5 (every drone at rest there)."""
    plan = make_plan(home)
    up = FormationWindow(1, "up", 0.0, 5.0, 5.0, plan.trajectories.pos[:, 1])
    down = FormationWindow(2, "landing", 5.0, 10.0, 10.0, plan.trajectories.pos[:, 2])
    return replace(plan, formations=(up, down))


def _in_formation_show(flavour: Flavour = ARDU, home: np.ndarray = HOME
                       ) -> tuple[Plan, dict[int, VehicleState], ShowSequence, float]:
    """Two vehicles flying :func:`_formation_plan`; returns the show's start time."""
    plan = _formation_plan(home)
    states = _fleet(flavour, n=2)
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: flavour, 2: flavour},
                       SequenceConfig(offboard_lead_s=1.0))
    if flavour is ARDU:
        t0 = _airborne_ardupilot(seq, states, 0.0)
    else:  # arm, take off, setpoints for offboard_lead_s, OFFBOARD
        seq.start(0.0)
        for v in states.values():
            v.armed = True
        seq.update(0.1, states)
        for v in states.values():
            set_altitude(v, 3.0)
        seq.update(0.2, states)
        seq.update(1.3, states)
        for v in states.values():
            v.mode = "OFFBOARD"
        t0 = 1.4
        seq.update(t0, states)
    seq.update(t0 + 0.1, states)  # settled on the first plan point: the show clock runs
    assert seq.started_at is not None
    return plan, states, seq, t0 + 0.1


def _way_out(plan: Plan, track: int, at: float, seconds: float = 4.0) -> Leave:
    start = plan.state_at(at).pos[track]
    end = plan.landing_hover[track]
    pos = np.stack([start, end])[None]
    return Leave(at, Trajectories(np.array([0.0, seconds]), pos, np.zeros_like(pos)))


def test_land_one_mid_show_leaves_at_the_next_formation_on_a_planned_way_out() -> None:
    plan, states, seq, start = _in_formation_show()
    assert seq.land_one(2, start + 1.0) == [Notice(
        2, "vehicle 2 leaves the show at show time 5.0 s, on a way out planned around the "
           "others")]
    assert seq.land_one(2, start + 1.5) == [Notice(
        2, "vehicle 2 already leaves the show at show time 5.0 s")]
    assert seq.leave_needed == [(2, 1, 5.0, None)]
    # Until its way out is planned and begins, it flies its plan.
    assert seq.stream_request(start + 1.0).leaves == {}
    leave = _way_out(plan, 1, 5.0)
    assert seq.set_leave(2, leave, start + 2.0) == [Notice(
        2, "way out for vehicle 2 planned: from show time 5.0 s, 4.0 s to its landing spot")]
    assert seq.leave_needed == [] and seq.leaves == {1: leave}
    assert seq.stream_request(start + 2.0).leaves == {2: leave}
    assert seq.vehicles[2].phase is VehiclePhase.SHOW
    assert seq.update(start + 5.2, states) == [Notice(2, "vehicle 2 leaves the show")]
    assert seq.vehicles[2].phase is VehiclePhase.LEAVING
    assert seq.phase is ShowPhase.SHOW  # the other one is still in the show
    # Arrived over its landing spot once the way out is flown: land.
    assert seq.update(start + 8.0, states) == []
    hover = plan.landing_hover[1]
    states[2].position_ned = (float(hover[1]), float(hover[0]), float(-hover[2]))
    assert seq.update(start + 9.2, states) == [Land(2)]
    assert seq.vehicles[2].phase is VehiclePhase.LANDING


def test_a_way_out_ready_too_late_moves_on_and_one_that_fails_flies_on() -> None:
    plan, _, seq, start = _in_formation_show()
    seq.land_one(2, start + 1.0)
    # Planning outlived its instant (show time 5.0 s): the next one is past the plan's end.
    assert seq.set_leave(2, _way_out(plan, 1, 5.0), start + 5.5) == [Notice(
        2, "no safe way out of the show for vehicle 2 (its way out was ready too late; no "
           "formation left to leave from); it flies on and lands with the others (land-here 2 "
           "brings it straight down now)")]
    assert seq.leave_needed == [] and seq.vehicles[2].phase is VehiclePhase.SHOW
    _, _, seq2, start = _in_formation_show()
    seq2.land_one(2, start + 1.0)
    assert seq2.leave_failed(2, "landing column not clear", start + 1.5) == [Notice(
        2, "no safe way out of the show for vehicle 2 (landing column not clear); it flies on "
           "and lands with the others (land-here 2 brings it straight down now)")]
    assert seq2.leave_needed == [] and seq2.vehicles[2].phase is VehiclePhase.SHOW


def test_land_all_while_one_is_leaving_returns_it_from_its_way_out() -> None:
    plan, states, seq, start = _in_formation_show()
    seq.land_one(2, start + 1.0)
    leave = _way_out(plan, 1, 5.0)
    seq.set_leave(2, leave, start + 2.0)
    seq.update(start + 6.0, states)
    assert seq.vehicles[2].phase is VehiclePhase.LEAVING
    seq.land_all(start + 6.0)
    stop = seq.clock.stop_time(start + 6.0)  # the show brakes to a stop
    assert seq.vehicles[2].phase is VehiclePhase.RETURNING
    assert sorted(seq.return_needed or []) == [(1, 0), (2, 1)]
    # While the return is planned it hovers where its way out had brought it.
    req = seq.stream_request(seq.clock.rest_at() + 0.1)
    assert not req.moving and req.leaves == {2: leave}
    assert req.show_time == pytest.approx(stop)
    np.testing.assert_allclose(seq.return_start(2, start + 9.0), leave.state(stop)[0])


def test_kill_needs_confirmation() -> None:
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    t0 = _airborne_ardupilot(seq, states, 0.0)
    assert seq.kill(1, t0 + 1.0) == [
        Notice(1, "kill vehicle 1 not sent: it stops the motors and the drone falls; "
                  "confirm to kill")]
    assert seq.vehicles[1].phase is VehiclePhase.SHOW
    assert seq.kill(1, t0 + 1.0, confirm=True) == [
        Kill(1), Notice(1, "vehicle 1 killed by the operator")]
    assert seq.stream_request(t0 + 1.0).sysids == frozenset({2})


def test_land_all_during_takeoff_lands_climbers_and_stands_down_the_rest() -> None:
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    seq.start(0.0)
    states[1].mode = states[2].mode = "GUIDED"
    seq.update(0.1, states)
    states[1].armed = True
    seq.update(0.2, states)  # vehicle 1 taking off, vehicle 2 still arming
    assert seq.land_all(0.3) == [Notice(None, "landing all vehicles"), Land(1), Disarm(2),
                                 Notice(2, "vehicle 2 stood down on the ground")]
    assert seq.stream_request(0.3).sysids == frozenset()
    states[1].armed = False
    assert seq.update(5.0, states) == [Notice(1, "vehicle 1 landed")]
    assert seq.phase is ShowPhase.LANDED


def test_constructor_rejects_inconsistent_tables() -> None:
    with pytest.raises(ValueError, match=r"`flavours` has no autopilot for vehicle\(s\) \[2\]"):
        ShowSequence(make_plan(), {1: 0, 2: 1}, {1: ARDU})
    with pytest.raises(ValueError, match="`tracks` gives one track to two vehicles"):
        ShowSequence(make_plan(), {1: 0, 2: 0}, {1: ARDU, 2: ARDU})


def test_land_is_resent_when_the_vehicle_never_enters_its_land_mode() -> None:
    states = _fleet(PX4, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: PX4}, SequenceConfig(step_timeout_s=5.0))
    seq.start(0.0)
    states[1].armed = True
    seq.update(0.1, states)  # taking off
    assert seq.land_one(1, 1.0) == [Notice(1, "landing vehicle 1"), Land(1)]
    states[1].mode = "AUTO.TAKEOFF"
    assert seq.update(6.0, states) == []
    assert seq.vehicles[1].reason == "no effect after 5 s"
    assert seq.update(7.0, states) == [Land(1)]
    states[1].mode = "AUTO.LAND"
    assert seq.update(20.0, states) == []  # descending takes as long as it takes
    states[1].armed = False
    assert seq.update(30.0, states) == [Notice(1, "vehicle 1 landed")]


def test_a_land_whose_acks_are_lost_counts_as_landing_once_its_land_mode_is_seen() -> None:
    """Half the packets lost: LAND carried out, every ACK of it (and of its repeats) lost.
    The mode change is the effect: the timeouts do not give the vehicle up."""
    states = _fleet(ARDU, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: ARDU}, SequenceConfig(max_attempts=3))
    t0 = _airborne_ardupilot(seq, states, 0.0)
    land = seq.land_here(1, t0 + 1.0)[-1]
    assert land == Land(1)
    states[1].mode = "LAND"
    seq.update(t0 + 1.5, states)
    for k in range(5):  # more timeouts than max_attempts
        assert seq.command_failed(land, "no COMMAND_ACK after 3 tries", t0 + 2.0 + k) == []
    v = seq.vehicles[1]
    assert v.phase is VehiclePhase.LANDING and v.reason != "no COMMAND_ACK after 3 tries"
    states[1].armed = False
    assert Notice(1, "vehicle 1 landed") in seq.update(t0 + 12.0, states)
    # Not in its land mode: the timeouts count, and the vehicle is given up in the end.
    states = _fleet(ARDU, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: ARDU}, SequenceConfig(max_attempts=2))
    t0 = _airborne_ardupilot(seq, states, 0.0)
    land = seq.land_here(1, t0 + 1.0)[-1]
    seq.command_failed(land, "timeout", t0 + 2.0)
    seq.vehicles[1].attempts = 2
    assert any("failed 2 times" in getattr(a, "text", "")
               for a in seq.command_failed(land, "timeout", t0 + 3.0))


def test_a_vehicle_lost_on_its_slot_next_to_a_climber_aborts_the_show() -> None:
    home = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(make_plan(home=home), {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    seq.start(0.0)
    states[1].mode = "GUIDED"
    states[2].lost = True
    states[2].last_heard = 0.0
    actions = seq.update(1.0, states)
    lost, abort = actions[:2]
    assert isinstance(lost, Notice) and isinstance(abort, Notice)
    assert lost.text.startswith("vehicle 2 lost during arming (silent for 1.0 s)")
    assert abort.text.startswith("aborting the show: track 0 passes 1.00 m")
    # Vehicle 1 is in GUIDED and would be armed next: it is stood down instead.
    assert actions[2:] == [Notice(None, "landing all vehicles"), Disarm(1),
                           Notice(1, "vehicle 1 stood down on the ground")]
    assert seq.phase is ShowPhase.LANDED
    assert seq.start(2.0) == [Notice(None, "the sequence has already started or been stopped")]


def test_land_all_mid_show_hovers_until_a_return_plan_is_given_then_follows_it() -> None:
    states = _fleet(ARDU, n=2)
    plan = make_plan()
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    t0 = _airborne_ardupilot(seq, states, 0.0)
    seq.land_all(t0 + 2.0)
    assert seq.return_needed == [(1, 0), (2, 1)]
    rest = seq.clock.rest_at()  # braking along the plan meanwhile, then hovering
    stop = 2.0 + seq.clock.default_ramp_s / 2
    req = seq.stream_request(rest + 0.5)
    assert req.sysids == frozenset({1, 2}) and not req.moving and not req.fixed
    assert req.show_time == pytest.approx(stop) and not req.follow
    start = plan.state_at(stop).pos[:2]
    np.testing.assert_allclose(seq.return_start(1, t0 + 3.0), start[0])
    goal = plan.landing_hover[:2]
    back = Trajectories(np.array([0.0, 4.0]), np.stack([start, goal], axis=1),
                        np.zeros((2, 2, 3)))
    assert seq.set_return(back, [2, 1], t0 + 3.0) == [
        Notice(None, "flying the 4.0 s return to the landing points")]
    assert seq.return_needed is None
    begin = max(t0 + 3.0, rest)  # the return starts once planned and the fleet has stopped
    req = seq.stream_request(begin + 1.0)
    assert req.follow == {1: 1, 2: 0} and req.follow_trajectories is back
    assert req.return_clock is not None
    assert req.return_clock.show_time(begin + 1.0) == pytest.approx(1.0)
    req = seq.stream_request(begin + 4.5)  # the return is over: hold over the landing points
    assert not req.follow and set(req.fixed) == {1, 2}


def test_a_failed_return_plan_mid_show_flies_the_rest_of_the_show_home() -> None:
    """The plan is the one way home known to be collision-free: rather than straight
    lines across the formation, the show flies on to its end and lands from there."""
    states = _fleet(ARDU, n=2)
    plan = make_plan()
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    t0 = _airborne_ardupilot(seq, states, 0.0)
    seq.land_all(t0 + 2.0)
    (notice,) = seq.return_failed("planner gave up", t0 + 3.0)
    assert "no collision-free return could be planned (planner gave up): the show flies on" \
        in notice.text
    assert seq.return_needed is None and not seq.ended and not seq.paused
    assert [v.phase for v in seq.vehicles.values()] == [VehiclePhase.SHOW] * 2
    req = seq.stream_request(t0 + 3.0 + 2 * seq.clock.default_ramp_s)
    assert req.moving and not req.fixed
    seq.update(t0 + plan.duration + 10.0, states)  # its end: to the landing spots, as usual
    assert [v.phase for v in seq.vehicles.values()] == [VehiclePhase.RETURNING] * 2


def test_a_failed_return_after_the_show_flies_straight_with_a_warning() -> None:
    states = _fleet(ARDU, n=2)
    plan = make_plan()
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    t0 = _airborne_ardupilot(seq, states, 0.0)
    seq.update(t0 + plan.duration + 1.0, states)
    seq.land_all(t0 + plan.duration + 1.0)
    (notice,) = seq.return_failed("planner gave up", t0 + plan.duration + 2.0)
    assert "flying straight to the landing points" in notice.text
    assert set(seq.stream_request(t0 + plan.duration + 2.5).fixed) == {1, 2}


def test_an_abort_before_the_show_brings_drones_down_their_own_takeoff_column() -> None:
    # Track 0 is planned to land on track 1's takeoff spot; vehicle 2 (track 1)
    # never arms and stands there, so the show is aborted during takeoff.
    plan = _landing_swapped_plan()
    np.testing.assert_allclose(plan.landing[0], plan.home[1])
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU}, SequenceConfig(max_attempts=1))
    seq.start(0.0)
    states[1].mode = states[2].mode = "GUIDED"
    seq.update(0.1, states)
    states[1].armed = True
    seq.update(0.2, states)
    set_altitude(states[1], 3.0)
    seq.update(0.3, states)
    assert seq.vehicles[1].phase is VehiclePhase.READY
    actions = seq.command_failed(Arm(2), "PreArm: Compass not calibrated", 0.4)
    assert any("aborting the show" in a.text for a in actions if isinstance(a, Notice))
    req = seq.stream_request(0.5)
    assert req.fixed == {1: (0.0, 0.0, 3.0)}  # its own column, not vehicle 2's spot


def test_two_vehicles_off_their_first_points_abort_the_show_once() -> None:
    # Both up but blown 4 m east of their first plan points (a strong wind before the
    # show): excluding vehicle 1 (track 0, left on its slot, where track 1 lands) aborts
    # the show and returns everyone; vehicle 2 is then returning with the fleet, not
    # excluded after it (that was a LifecycleError: returning cannot take not_at_start).
    plan = _landing_swapped_plan()
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU})
    _armed_ardupilot(seq, states, 0.0)
    for v in states.values():
        n, e, _ = v.position_ned or (0.0, 0.0, 0.0)
        v.position_ned = (n, e + 4.0, 0.0)
        set_altitude(v, 3.0)
    seq.update(0.3, states)
    assert seq.started_at is None  # waiting for them to settle on their first points
    actions = seq.update(0.3 + seq.config.settle_timeout_s + 0.1, states)
    texts = [a.text for a in actions if isinstance(a, Notice)]
    assert any("aborting the show" in t for t in texts), texts
    assert seq.aborted is not None and seq.started_at is None
    assert seq.vehicles[1].phase is VehiclePhase.RETURNING  # over its own slot, then down
    assert seq.vehicles[2].phase is VehiclePhase.RETURNING


def test_a_refused_repeat_of_an_accepted_takeoff_is_not_a_failure() -> None:
    # The first NAV_TAKEOFF's ACK was lost; the link's resend is refused because
    # the vehicle is already climbing.  The climb is what counts.
    states = _fleet(ARDU, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: ARDU}, SequenceConfig(max_attempts=1))
    seq.start(0.0)
    states[1].mode = "GUIDED"
    seq.update(0.1, states)
    states[1].armed = True
    assert seq.update(0.2, states) == [Takeoff(1, 3.0)]
    set_altitude(states[1], 1.2)
    assert seq.update(1.0, states) == []
    assert seq.command_failed(Takeoff(1, 3.0), "MAV_RESULT_FAILED", 1.1) == []
    assert seq.vehicles[1].phase is VehiclePhase.TAKEOFF
    set_altitude(states[1], 3.0)
    seq.update(2.0, states)
    assert seq.vehicles[1].phase in (VehiclePhase.READY, VehiclePhase.SHOW)


def test_a_refused_takeoff_is_judged_by_the_climb_once_it_could_have_lifted_off() -> None:
    # Unsigned, anyone can send a refusal (a forged COMMAND_ACK from the vehicle's own
    # address), and an autopilot refuses a repeat of a takeoff it is spooling up for
    # (2.6 s on ArduCopter): neither may ground a vehicle that is taking off.
    states = _fleet(ARDU, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: ARDU}, SequenceConfig(max_attempts=3))
    t = _armed_ardupilot(seq, states, 0.0)
    set_altitude(states[1], 0.0)
    seq.update(t + 0.1, states)
    for k in range(3):  # a refusal every tick, never the vehicle's word: no resend
        assert seq.command_failed(Takeoff(1, 3.0), "MAV_RESULT_FAILED", t + 0.2 + k) == []
    assert seq.update(t + 3.0, states) == []
    set_altitude(states[1], 0.4)  # lifting off: 0.4 m above where it was sent its takeoff
    assert seq.update(t + 7.0, states) == [Notice(
        1, "vehicle 1 climbs although its takeoff was refused (MAV_RESULT_FAILED): its "
           "takeoff goes on")]
    assert seq.vehicles[1].attempts == 1 and seq.vehicles[1].reason is None
    set_altitude(states[1], 3.0)
    seq.update(t + 8.0, states)
    assert seq.vehicles[1].phase in (VehiclePhase.READY, VehiclePhase.SHOW)


def test_a_takeoff_up_before_its_refusal_is_judged_drops_the_refusal() -> None:
    states = _fleet(ARDU, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: ARDU}, SequenceConfig(takeoff_retry_after_s=4.0))
    t = _armed_ardupilot(seq, states, 0.0)
    assert seq.command_failed(Takeoff(1, 3.0), "MAV_RESULT_FAILED", t + 0.1) == []
    set_altitude(states[1], 3.0)  # a quick climb: up before the verdict at t + 4.1
    assert seq.update(t + 3.5, states)[0] == Notice(
        1, "vehicle 1 climbs although its takeoff was refused (MAV_RESULT_FAILED): its "
           "takeoff goes on")
    v = seq.vehicles[1]
    assert v.phase in (VehiclePhase.READY, VehiclePhase.SHOW)
    assert v.reason is None and v.retry_at is None


def test_a_takeoff_refused_and_never_climbing_is_resent_then_given_up() -> None:
    states = _fleet(ARDU, n=1)
    seq = ShowSequence(make_plan(), {1: 0}, {1: ARDU},
                       SequenceConfig(max_attempts=3, takeoff_retry_after_s=4.0))
    now = _armed_ardupilot(seq, states, 0.0)
    set_altitude(states[1], 0.05)
    for attempt in (1, 2):
        assert seq.command_failed(Takeoff(1, 3.0), "MAV_RESULT_DENIED", now + 0.1) == []
        assert seq.update(now + 4.0, states) == []
        assert seq.update(now + 4.1, states) == [Takeoff(1, 3.0)]
        assert seq.vehicles[1].attempts == attempt + 1
        now += 4.1
    assert seq.command_failed(Takeoff(1, 3.0), "MAV_RESULT_DENIED", now + 0.1) == []
    assert seq.vehicles[1].phase is VehiclePhase.TAKEOFF
    actions = seq.update(now + 4.1, states)
    assert actions[:2] == [Notice(1, "vehicle 1: takeoff failed 3 times: MAV_RESULT_DENIED"),
                           Land(1)]
    assert seq.vehicles[1].reason == "takeoff failed 3 times: MAV_RESULT_DENIED"


def test_a_takeoff_given_up_near_a_landing_spot_aborts_the_show() -> None:
    # Vehicle 2 lands back on its own takeoff spot, where track 0 is planned to land.
    plan = _landing_swapped_plan()
    states = _fleet(ARDU, n=2)
    seq = ShowSequence(plan, {1: 0, 2: 1}, {1: ARDU, 2: ARDU}, SequenceConfig(max_attempts=1))
    _armed_ardupilot(seq, states, 0.0)
    assert seq.command_failed(Takeoff(2, 3.0), "MAV_RESULT_FAILED", 0.3) == []
    set_altitude(states[1], 0.3)  # vehicle 1 is lifting off; vehicle 2 stays down
    assert seq.update(4.0, states) == []  # judged only once it could have lifted off
    actions = seq.update(4.3, states)
    assert actions[:2] == [Notice(2, "vehicle 2: takeoff failed 1 times: MAV_RESULT_FAILED"),
                           Land(2)]
    assert any(isinstance(a, Notice) and "aborting the show" in a.text for a in actions)
    assert Land(1) in actions  # vehicle 1 was still climbing: straight back down


@pytest.mark.parametrize("flavour, taken_over", [(ARDU, "RTL"), (PX4, "AUTO.LOITER")])
def test_a_vehicle_whose_autopilot_leaves_the_flight_mode_is_out_of_the_show(
        flavour: Flavour, taken_over: str) -> None:
    """A failsafe (offboard or GCS loss, battery) or a pilot took it: no more setpoints,
    no fight with its autopilot, and it counts as down once it has disarmed."""
    _, states, seq, start = _in_formation_show()
    flight_mode = "GUIDED" if flavour is ARDU else "OFFBOARD"
    states[2].mode = flight_mode  # vehicle 1 stays an ArduPilot in GUIDED
    seq.vehicles[2].flavour = flavour
    seq.land_one(2, start + 1.0)  # a pending way out is dropped with it
    states[2].mode = taken_over
    assert seq.update(start + 1.5, states) == [Notice(
        2, f"vehicle 2 switched to {taken_over} by itself (failsafe or pilot) during show: out "
           "of the show, its autopilot is in charge until it is down")]
    assert seq.vehicles[2].phase is VehiclePhase.LANDING and seq.leave_needed == []
    assert seq.vehicles[2].reason == f"left {flight_mode} for {taken_over} during show"
    assert seq.stream_request(start + 1.5).sysids == frozenset({1})
    assert seq.update(start + 4.0, states) == []  # no command, no timeout: its autopilot's
    states[2].armed = False
    assert seq.update(start + 4.5, states) == [Notice(2, "vehicle 2 landed")]
    assert seq.vehicles[1].phase is VehiclePhase.SHOW


def test_a_silence_too_short_to_be_lost_is_still_checked_for_falling_behind() -> None:
    _, states, seq, start = _in_formation_show()
    for v in states.values():
        v.last_heard = start + 1.0
    seq.update(start + 1.0, states)
    states[1].last_heard = states[2].last_heard = start + 1.1  # heard as usual: no check
    _at_plan_point(states[1], seq, 0, start + 1.1)
    assert seq.update(start + 1.1, states) == []
    # Vehicle 2 silent for 1.9 s (not lost: a gap in its own stream, on its own clock),
    # then heard 2.5 m beside its plan.
    states[1].last_heard, states[2].last_heard = start + 3.0, start + 3.0
    states[2].stream_gaps, states[2].last_stream_gap_s = 1, 1.9
    _at_plan_point(states[1], seq, 0, start + 3.0)
    _at_plan_point(states[2], seq, 1, start + 3.0, off=(2.5, 0.0, 0.0))
    assert seq.update(start + 3.0, states) == [Notice(
        2, "vehicle 2 heard again after 1.9 s, 2.5 m off its plan: holding where it is, then "
           "leaving the show on a way out planned from there")]
    assert seq.vehicles[2].phase is VehiclePhase.LEAVING
    assert seq.vehicles[1].phase is VehiclePhase.SHOW


def test_off_its_plan_too_late_for_a_way_out_it_holds_until_the_end_then_returns() -> None:
    """A way out runs on the show clock, which stops at the plan's end: one that would
    not finish by then is not started (it would hover half-way for ever)."""
    plan, states, seq, start = _in_formation_show()
    states[2].lost = True
    seq.update(start + 8.0, states)
    states[2].lost = False
    _at_plan_point(states[2], seq, 1, start + 8.5, off=(2.5, 0.0, 0.0))
    assert seq.update(start + 8.5, states) == [Notice(
        2, "vehicle 2 heard again 2.5 m off its plan: holding where it is until the show "
           "ends, then to its landing spot")]
    assert seq.leave_needed == []
    assert seq.stream_request(start + 9.0).fixed == {2: seq.vehicles[2].hold_point}
    seq.update(start + 10.5, states)  # the show ends
    assert seq.vehicles[2].phase is VehiclePhase.RETURNING
    np.testing.assert_allclose(seq.stream_request(start + 10.6).fixed[2],
                               plan.landing_hover[1])


# -- degrading safely ------------------------------------------------------------------


def test_a_lost_vehicle_keeps_the_flight_open_until_it_is_seen_down() -> None:
    _plan, states, seq, start = _in_formation_show()
    states[2].lost = True
    seq.update(start + 1.0, states)
    assert seq.vehicles[2].phase is VehiclePhase.LOST
    states[1].armed = False  # the other one is down (say, after landing)
    seq.vehicles[1].phase = VehiclePhase.LANDED
    assert seq.phase is not ShowPhase.LANDED  # silence is never "down"
    assert seq.settled and seq.lost == [2]
    assert 2 in seq.stream_request(start + 1.0).sysids  # still streamed its plan


def test_a_vehicle_given_up_as_disarmed_that_flies_on_is_taken_back_off_its_plan() -> None:
    """Its disarm was a wrong report: armed, in the air, in GUIDED, and hovering where it
    was given up while the show flew on.  Nobody in charge of it would be the danger: it
    holds there and leaves on a way out."""
    _plan, states, seq, start = _in_formation_show()
    states[2].armed = False
    seq.update(start + 1.0, states)
    assert seq.vehicles[2].phase is VehiclePhase.FAILED
    states[2].armed = True
    _at_plan_point(states[2], seq, 1, start + 3.0, off=(2.5, 0.0, 0.0))
    assert seq.update(start + 3.0, states) == [Notice(
        2, "vehicle 2 armed in the air after all, 2.5 m off its plan: holding where it is, "
           "then leaving the show on a way out planned from there")]
    v = seq.vehicles[2]
    assert v.phase is VehiclePhase.LEAVING and v.hold_point is not None and not v.fell
    assert seq.stream_request(start + 3.0).fixed == {2: v.hold_point}
    assert [s for s, *_ in seq.leave_needed] == [2]
    # A vehicle that really crashed stays down: armed or not, it is not in the air.
    _plan, states, seq, start = _in_formation_show()
    states[2].armed = False
    seq.update(start + 1.0, states)
    set_altitude(states[2], 0.0)
    states[2].armed = True
    seq.update(start + 2.0, states)
    assert seq.vehicles[2].phase is VehiclePhase.FAILED


def test_a_vehicle_disarmed_in_the_air_is_out_of_the_show_and_an_obstacle() -> None:
    _plan, states, seq, start = _in_formation_show()
    states[2].armed = False
    (notice,) = seq.update(start + 1.0, states)
    assert isinstance(notice, Notice) and "disarmed in the air during show" in notice.text
    v = seq.vehicles[2]
    assert v.phase is VehiclePhase.FAILED and "crash or motor failure" in (v.reason or "")
    assert 2 not in seq.stream_request(start + 1.0).sysids
    assert len(seq.down_positions()) == 1  # where it fell is kept clear


def test_a_low_battery_sends_a_vehicle_home_and_a_critical_one_down_where_it_is() -> None:
    _plan, states, seq, start = _in_formation_show()
    states[1].battery_remaining_pct = 15.0  # below the default 20 %
    actions = seq.update(start + 1.0, states)
    assert any(isinstance(a, Notice) and "battery 15 % is below the show's 20 %" in a.text
               for a in actions)
    assert seq.vehicles[1].leave_at is not None  # it leaves on a way out
    _plan, states, seq, start = _in_formation_show()
    states[2].battery_remaining_pct = 8.0  # critical, and nobody below it
    actions = seq.update(start + 1.1, states)
    assert Land(2) in actions and seq.vehicles[2].phase is VehiclePhase.LANDING


def test_low_batteries_across_the_fleet_land_everyone_on_one_return() -> None:
    _plan, states, seq, start = _in_formation_show()
    states[1].battery_remaining_pct = states[2].battery_remaining_pct = 15.0
    actions = seq.update(start + 1.0, states)
    assert Notice(None, "batteries low across the fleet (2 vehicles below 20 %): landing "
                        "every vehicle") in actions
    assert seq.ended and seq.return_needed == [(1, 0), (2, 1)]


def test_a_link_loss_failsafe_after_a_silence_is_taken_back_but_a_pilot_is_not() -> None:
    _plan, states, seq, start = _in_formation_show()
    # Vehicle 2's own telemetry stopped for 2 s and it came back in AUTO-like LOITER.
    states[2].stream_gaps, states[2].last_stream_gap_s = 1, 2.0
    states[2].mode = "LOITER"
    actions = seq.update(start + 1.0, states)
    assert SetMode(2, "GUIDED") in actions
    assert seq.vehicles[2].phase is VehiclePhase.SHOW
    states[2].mode = "GUIDED"
    (back,) = seq.update(start + 1.2, states)
    assert isinstance(back, Notice) and "back in GUIDED" in back.text
    # Vehicle 1 switched to LOITER with no silence of its own: a pilot, not fought.
    states[1].mode = "LOITER"
    seq.update(start + 1.3, states)
    assert seq.vehicles[1].phase is VehiclePhase.LANDING


def test_a_px4_failsafe_after_we_sent_it_no_setpoints_for_a_second_is_taken_back() -> None:
    """Our loop starved for 1.5 s (no hold in force, no gap in the vehicle's own
    telemetry): the hold mode a PX4 vehicle is found in is its offboard-loss failsafe,
    our doing.  Left to it, it would land straight down through the formation."""
    _plan, states, seq, start = _in_formation_show(PX4)
    seq.streamed([1, 2], start + 0.5)
    seq.streamed([1], start + 1.0)
    seq.streamed([1], start + 1.5)
    # The first tick after the stall, before anything is sent again: already ours.
    states[2].mode = "AUTO.LOITER"
    for sysid in (1, 2):
        _at_plan_point(states[sysid], seq, sysid - 1, start + 2.0)
    actions = seq.update(start + 2.0, states)
    assert SetMode(2, "OFFBOARD") in actions and seq.vehicles[2].phase is VehiclePhase.SHOW
    seq.streamed([1, 2], start + 2.0)
    assert seq.vehicles[2].starved_at == start + 2.0 and seq.vehicles[1].starved_at is None
    # Vehicle 1 was never starved: the same mode is a pilot's (or its own), not fought.
    states[1].mode = "AUTO.LOITER"
    seq.update(start + 2.1, states)
    assert seq.vehicles[1].phase is VehiclePhase.LANDING


def test_a_retake_under_way_gives_way_to_a_battery_failsafe() -> None:
    _plan, states, seq, start = _in_formation_show(PX4)
    seq.streamed([1, 2], start + 0.5)
    states[2].mode = "AUTO.LOITER"
    _at_plan_point(states[2], seq, 1, start + 2.0)
    assert SetMode(2, "OFFBOARD") in seq.update(start + 2.0, states)
    assert seq.vehicles[2].retaking == "AUTO.LOITER"
    # Before it is back, its battery failsafe takes it home: not fought over.
    states[2].mode, states[2].battery_remaining_pct = "AUTO.RTL", 5.0
    actions = seq.update(start + 2.5, states)
    assert SetMode(2, "OFFBOARD") not in actions
    assert seq.vehicles[2].phase is VehiclePhase.LANDING and seq.vehicles[2].retaking is None


def test_holds_for_the_ground_stations_own_trouble_do_not_strand_a_vehicle() -> None:
    _plan, states, seq, start = _in_formation_show()
    assert seq.hold_for("silence", start + 1.0)
    states[2].stream_gaps, states[2].last_stream_gap_s = 1, 3.0
    _at_plan_point(states[2], seq, 1, start + 1.5, off=(2.5, 0.0, 0.0))
    seq.update(start + 1.5, states)
    assert seq.vehicles[2].phase is VehiclePhase.SHOW  # the whole fleet was silent
    assert seq.release("silence", start + 5.0)
    assert not seq.paused


def test_a_stall_stops_the_show_clock_where_the_last_setpoints_were() -> None:
    _plan, _states, seq, start = _in_formation_show()
    seq.stop_for("stall", start + 3.0, 1.6)
    assert seq.show_time(start + 3.0) == pytest.approx(1.6)
    assert seq.holds == {"stall"} and not seq.stream_request(start + 3.0).moving
    seq.release("stall", start + 4.0)
    assert seq.stream_request(start + 4.0 + seq.clock.default_ramp_s).moving


def test_a_landing_spot_taken_by_a_drone_down_elsewhere_calls_for_a_new_return() -> None:
    plan, states, seq, start = _in_formation_show()
    seq.land_here(1, start + 1.0)
    states[1].armed = False
    slot2 = plan.landing_hover[1]
    # Vehicle 1 came down right under vehicle 2's landing spot.
    _at_plan_point(states[1], seq, 0, start + 1.0)
    states[1].position_ned = (float(slot2[1]), float(slot2[0]), 0.0)  # NED of show x, y
    seq.update(start + 2.0, states)
    assert seq.vehicles[1].phase is VehiclePhase.LANDED
    seq.update(start + plan.duration + 1.0, states)  # the show ends
    states[2].position_ned = (float(slot2[1]), float(slot2[0]), -float(slot2[2]))
    actions = seq.update(start + plan.duration + 2.0, states)
    assert Land(2) not in actions
    assert seq.return_needed == [(2, 1)]


def test_with_no_landing_spot_free_a_drone_lands_on_the_nearest_clear_ground() -> None:
    """The last resort once new returns are used up and no spot of the plan is free:
    not "landing where it is" (over the drone that is down), but the nearest ground
    clear of every drone down and every spot someone lands on."""
    plan, states, seq, start = _in_formation_show(home=HOME[:2])
    seq.land_here(1, start + 1.0)
    states[1].armed = False
    # Vehicle 1 came down between the two landing spots, too close to either.
    mid = (plan.landing_hover[0] + plan.landing_hover[1]) / 2.0
    _at_plan_point(states[1], seq, 0, start + 1.0)
    states[1].position_ned = (float(mid[1]), float(mid[0]), 0.0)
    seq.update(start + 2.0, states)
    assert seq.vehicles[1].phase is VehiclePhase.LANDED
    seq.update(start + plan.duration + 1.0, states)  # the show ends
    seq._replans = MAX_REPLANS  # the new returns for a blocked spot are used up
    slot2 = plan.landing_hover[1]
    states[2].position_ned = (float(slot2[1]), float(slot2[0]), -float(slot2[2]))
    actions = seq.update(start + plan.duration + 2.0, states)
    assert Land(2) not in actions
    assert [a.kind for a in actions if isinstance(a, Notice)] == ["clear_spot"]
    spot = np.asarray(seq.vehicles[2].landing_point)
    keep = plan.limits.min_separation + LANDING_MARGIN_M
    assert np.hypot(*(spot[:2] - mid[:2])) >= keep
    assert np.hypot(*(spot[:2] - slot2[:2])) <= keep + plan.limits.min_separation
    assert spot[2] == pytest.approx(slot2[2])
    # Over it, it lands.
    states[2].position_ned = (float(spot[1]), float(spot[0]), -float(spot[2]))
    assert Land(2) in seq.update(start + plan.duration + 3.0, states)


def test_the_nearest_clear_ground_keeps_off_drones_down_and_inside_the_geofence() -> None:
    plan = make_plan(HOME[:2])
    sep = plan.limits.min_separation
    down = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    spot = clear_spot_near(plan, np.array([0.5, 0.0, 3.0]), down=down)
    assert spot is not None and spot[2] == 3.0
    d = np.hypot(*(down[:, :2] - spot[:2]).T)
    assert d.min() >= sep + LANDING_MARGIN_M
    assert np.hypot(*(spot[:2] - [0.5, 0.0])) <= sep + LANDING_MARGIN_M + 1.0
    # A spot someone else lands on keeps the limit too.
    blocked = spot[None, :]
    other = clear_spot_near(plan, np.array([0.5, 0.0, 3.0]), blocked, down)
    assert other is not None and np.hypot(*(other[:2] - spot[:2])) >= sep
    # Only inside the geofence: a fence around the drones down leaves no clear ground.
    fenced = replace(plan, limits=replace(plan.limits, geofence=(
        (-1.0, -1.0), (2.0, -1.0), (2.0, 1.0), (-1.0, 1.0))))
    assert clear_spot_near(fenced, np.array([0.5, 0.0, 3.0]), down=down) is None
    wider = replace(plan, limits=replace(plan.limits, geofence=(
        (-1.0, -1.0), (6.0, -1.0), (6.0, 1.0), (-1.0, 1.0))))
    inside = clear_spot_near(wider, np.array([0.5, 0.0, 3.0]), down=down)
    assert inside is not None and -1.0 <= inside[0] <= 6.0 and -1.0 <= inside[1] <= 1.0
    # ... by the arrive tolerance at least: a drone descends within it of its spot.
    assert -0.5 <= inside[0] <= 5.5 and -0.5 <= inside[1] <= 0.5


def _landing_after_show(flavour: Flavour = ARDU) -> tuple[ShowSequence, dict[int, VehicleState]]:
    """Two vehicles flown through the show to the end; vehicle 1 sent LAND at t=13."""
    states = _fleet(flavour)
    seq = ShowSequence(make_plan(), {1: 0, 2: 1}, {1: flavour, 2: flavour})
    _airborne_ardupilot(seq, states, 0.0)
    for v in states.values():
        set_altitude(v, 3.0)
    seq.update(1.0, states)
    assert seq.phase is ShowPhase.SHOW
    seq.update(12.5, states)
    states[1].position_ned = (0.1, 0.0, -3.0)  # over its slot
    states[2].position_ned = (0.0, 1.0, -3.0)  # still 2 m short of its slot
    assert seq.update(13.0, states) == [Land(1)]
    assert seq.vehicles[1].phase is VehiclePhase.LANDING
    return seq, states


def test_a_land_lost_in_a_silence_is_sent_again_when_heard_still_in_guided() -> None:
    seq, states = _landing_after_show()
    states[1].lost = True  # frozen: the LAND (and its retries) went nowhere
    actions = seq.update(14.0, states)
    assert seq.vehicles[1].phase is VehiclePhase.LOST
    assert [a.kind for a in actions if isinstance(a, Notice)] == ["lost"]
    states[1].lost = False  # heard again, still hovering in GUIDED over its spot
    actions = seq.update(22.0, states)
    assert Land(1) in actions
    notice = next(a for a in actions if isinstance(a, Notice))
    assert notice.text == "vehicle 1 heard again still in GUIDED: its LAND was lost, " \
                          "sending it again"
    assert seq.vehicles[1].phase is VehiclePhase.LANDING
    states[1].mode = "LAND"
    assert seq.update(23.0, states) == []  # descending
    states[1].armed = False
    assert seq.update(35.0, states) == [Notice(1, "vehicle 1 landed")]
    assert seq.vehicles[1].phase is VehiclePhase.LANDED
    assert seq.lost == []


def test_a_vehicle_lost_while_landing_and_heard_again_disarmed_is_counted_landed() -> None:
    seq, states = _landing_after_show()
    states[1].lost = True
    seq.update(14.0, states)
    states[2].position_ned = (0.0, 3.2, -3.0)
    assert seq.update(15.0, states) == [Land(2)]
    states[2].armed = False
    seq.update(20.0, states)
    assert seq.settled and seq.lost == [1]  # everyone else down: the driver waits for it
    # It got the LAND before the silence, touched down and disarmed meanwhile.
    states[1].lost, states[1].armed, states[1].mode = False, False, "LAND"
    actions = seq.update(30.0, states)
    assert Land(1) not in actions
    assert [a.text for a in actions if isinstance(a, Notice)] == [
        "vehicle 1 heard again: down and disarmed", "vehicle 1 landed"]
    assert seq.vehicles[1].phase is VehiclePhase.LANDED
    assert seq.lost == [] and seq.phase is ShowPhase.LANDED


def test_heard_again_while_landing_in_another_mode_is_not_fought() -> None:
    seq, states = _landing_after_show()
    states[1].lost = True
    seq.update(14.0, states)
    states[1].lost, states[1].mode = False, "RTL"  # its GCS failsafe took it home
    actions = seq.update(20.0, states)
    assert not any(isinstance(a, Land) for a in actions)
    assert [a.text for a in actions if isinstance(a, Notice)] == [
        "vehicle 1 heard again: in RTL (its failsafe or a pilot)"]
    states[1].armed = False
    assert seq.update(40.0, states) == [Notice(1, "vehicle 1 landed")]
