"""The sequence's policies as pure functions: a vehicle's view in, a decision out, without
a fleet, a plan or a clock (groundctl/execute/sequence/policies).  How the sequence
carries the decisions out is in test_execute_sequence.py."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from groundctl.execute.sequence.policies.battery import (
    BatteryMove,
    BatteryView,
    battery_due,
    battery_move,
)
from groundctl.execute.sequence.policies.homing import NoReturn, no_return
from groundctl.execute.sequence.policies.lastresort import column_clear, say_blocked
from groundctl.execute.sequence.policies.modes import (
    ModeLeft,
    fence_acted,
    link_failsafe,
    mode_left,
    retake_goes_on,
)
from groundctl.execute.sequence.policies.operator import (
    KillVerdict,
    LandHere,
    LandOne,
    kill_asked,
    land_here_asked,
    land_one_asked,
)
from groundctl.execute.sequence.policies.refusals import (
    Refused,
    climbing,
    refused,
    takeoff_verdict,
)
from groundctl.execute.sequence.policies.rejoin import Landing, Rejoin, heard_landing, rejoin
from groundctl.execute.sequence.policies.spares import SpareView, choose_spares
from groundctl.execute.sequence.policies.stranded import (
    ArmedAgain,
    GivenUp,
    armed_again,
    given_up,
    too_many_stranded,
)
from groundctl.execute.sequence.policies.waysout import (
    Late,
    Offered,
    WithoutWayOut,
    late,
    offered,
    without_way_out,
)
from groundctl.execute.sequence.types import (
    COLUMN_WAIT_S,
    FENCE_NOTICE_S,
    MAX_LATE_LEAVES,
    MAX_RETAKES,
    RETAKE_WINDOW_S,
    STRANDED_LAND_ALL,
    Arm,
    Land,
    SetMode,
    Takeoff,
    VehiclePhase,
    VehicleRun,
)
from groundctl.link.flavours import Flavour
from groundctl.link.state import StatusText, VehicleState

SHOW, LEAVING = VehiclePhase.SHOW, VehiclePhase.LEAVING


# -- battery -----------------------------------------------------------------------------


@pytest.mark.parametrize(("pct", "phase", "low", "critical", "due"), [
    (25.0, SHOW, False, False, False),     # above the 20 % threshold
    (20.0, SHOW, False, False, False),     # at it: not below
    (19.9, SHOW, False, False, True),      # below it mid-show
    (19.9, SHOW, True, False, False),      # already told to leave for it
    (19.9, LEAVING, False, False, False),  # leaving already: only a critical one counts
    (9.9, LEAVING, True, False, True),     # below half: due whatever it is doing
    (9.9, SHOW, True, True, False),        # already landed where it is
])
def test_a_battery_is_due_once_below_the_threshold_mid_show_or_below_half_anywhere(
        pct: float, phase: VehiclePhase, low: bool, critical: bool, due: bool) -> None:
    assert battery_due(BatteryView(pct, 20.0, phase, low, critical)) is due


def test_one_low_battery_leaves_the_show_and_a_critical_one_lands_where_it_is() -> None:
    low = BatteryView(15.0, 20.0, SHOW, False, False)
    assert battery_move(low, low_in_flight=1, fleet=30, show_over=False,
                        column_clear=False) is BatteryMove.LEAVE
    critical = BatteryView(8.0, 20.0, SHOW, False, False)
    assert battery_move(critical, low_in_flight=1, fleet=30, show_over=False,
                        column_clear=True) is BatteryMove.LAND_HERE
    # Somebody below it: not straight down through them, it leaves on a way out.
    assert battery_move(critical, low_in_flight=1, fleet=30, show_over=False,
                        column_clear=False) is BatteryMove.LEAVE
    # Already returning (or leaving) and nobody clear below: that is its way down.
    returning = BatteryView(8.0, 20.0, VehiclePhase.RETURNING, True, False)
    assert battery_move(returning, low_in_flight=1, fleet=30, show_over=False,
                        column_clear=False) is BatteryMove.NOTHING


@pytest.mark.parametrize(("fleet", "low", "move"), [
    (9, 1, BatteryMove.LEAVE),      # one is not "across the fleet"
    (9, 2, BatteryMove.LAND_ALL),   # at least two ...
    (30, 2, BatteryMove.LEAVE),     # ... and a tenth of the fleet
    (30, 3, BatteryMove.LAND_ALL),
    (1000, 99, BatteryMove.LEAVE),
    (1000, 100, BatteryMove.LAND_ALL),
])
def test_low_batteries_across_a_tenth_of_the_fleet_land_everyone(
        fleet: int, low: int, move: BatteryMove) -> None:
    view = BatteryView(15.0, 20.0, SHOW, False, False)
    assert battery_move(view, low_in_flight=low, fleet=fleet, show_over=False,
                        column_clear=False) is move


def test_after_the_show_a_low_fleet_is_already_on_its_way_down() -> None:
    view = BatteryView(8.0, 20.0, VehiclePhase.RETURNING, True, False)
    assert battery_move(view, low_in_flight=5, fleet=9, show_over=True,
                        column_clear=False) is BatteryMove.NOTHING
    assert battery_move(view, low_in_flight=5, fleet=9, show_over=True,
                        column_clear=True) is BatteryMove.LAND_HERE


# -- a flight mode left by the vehicle ------------------------------------------------------


def _vehicle(flavour: Flavour = Flavour.ARDUPILOT, **fields: object) -> VehicleRun:
    return VehicleRun(sysid=2, track=1, flavour=flavour, phase=SHOW, **fields)


def _state(mode: str, **fields: object) -> VehicleState:
    state = VehicleState(system_id=2, mode=mode)
    for name, value in fields.items():
        setattr(state, name, value)
    return state


def test_a_failsafe_mode_right_after_its_own_silence_is_taken_back() -> None:
    v = _vehicle()
    state = _state("LOITER", stream_gaps=1, last_stream_gap_s=2.0)
    assert link_failsafe(v, state, 100.0, 20.0, ())
    assert mode_left(v, state, 100.0, 20.0, ()) is ModeLeft.RETAKE
    # A gap too short to trip a failsafe, and none looked at since: a pilot's doing.
    assert mode_left(v, _state("LOITER", stream_gaps=1, last_stream_gap_s=0.5), 100.0, 20.0,
                     ()) is ModeLeft.RESPECT
    # The gap already looked at, but it ended within the window: still the failsafe's.
    seen = _vehicle(gap_seen=1, gap_at=100.0 - RETAKE_WINDOW_S)
    assert link_failsafe(seen, state, 100.0, 20.0, ())
    assert not link_failsafe(seen, state, 100.1, 20.0, ())


@pytest.mark.parametrize("why", ["pilot", "fence", "battery", "retakes", "not a failsafe"])
def test_what_is_not_a_link_loss_failsafe_is_respected(why: str) -> None:
    v = _vehicle(retakes=MAX_RETAKES if why == "retakes" else 0)
    fields: dict[str, object] = {"stream_gaps": 1, "last_stream_gap_s": 2.0}
    mode = "RTL"
    if why == "pilot":
        fields = {}  # no silence of its own, no hold of ours
    elif why == "fence":
        st = StatusText("Fence Breached", 2, 100.0 - FENCE_NOTICE_S)
        fields["statustexts"] = deque([st])
        assert fence_acted(_state(mode, **fields), 100.0)
    elif why == "battery":
        fields["battery_remaining_pct"] = 12.0
    elif why == "not a failsafe":
        mode = "STABILIZE"
    assert mode_left(v, _state(mode, **fields), 100.0, 20.0, ()) is ModeLeft.RESPECT


def test_our_own_stall_or_a_fleet_silence_explains_a_failsafe() -> None:
    v = _vehicle()
    state = _state("BRAKE")  # no gap in its own telemetry
    assert mode_left(v, state, 50.0, 20.0, {"operator"}) is ModeLeft.RESPECT
    assert mode_left(v, state, 50.0, 20.0, {"stall"}) is ModeLeft.RETAKE
    assert mode_left(v, state, 50.0, 20.0, {"silence", "operator"}) is ModeLeft.RETAKE


def test_a_px4_vehicle_we_starved_of_setpoints_is_taken_back_an_ardupilot_one_is_not() -> None:
    # Only PX4 leaves OFFBOARD for want of setpoints (ArduPilot's GUIDED holds).
    px4 = _vehicle(Flavour.PX4, streamed_at=10.0)
    assert link_failsafe(px4, _state("AUTO.LOITER"), 11.5, 20.0, ())
    assert not link_failsafe(px4, _state("AUTO.LOITER"), 10.5, 20.0, ())
    # Setpoints resumed at 10.5 after a starved second, and flowing since: a failsafe
    # mode seen within STARVED_WINDOW_S of the resumption is still ours, not later.
    resumed = _vehicle(Flavour.PX4, streamed_at=11.9, starved_at=10.5)
    assert link_failsafe(resumed, _state("AUTO.LOITER"), 12.0, 20.0, ())
    flowing = _vehicle(Flavour.PX4, streamed_at=13.9, starved_at=10.5)
    assert not link_failsafe(flowing, _state("AUTO.LOITER"), 14.0, 20.0, ())
    ardupilot = _vehicle(streamed_at=10.0, starved_at=11.0)
    assert not link_failsafe(ardupilot, _state("LOITER"), 11.5, 20.0, ())


def test_a_retake_under_way_goes_on_until_its_battery_or_fence_says_otherwise() -> None:
    v = _vehicle(Flavour.PX4, retaking="AUTO.LOITER", sent_at=20.0)
    assert retake_goes_on(v, _state("AUTO.LOITER"), 20.0)
    assert retake_goes_on(v, _state("AUTO.LAND"), 20.0)  # PX4's hold moved on to its land
    assert not retake_goes_on(v, _state("AUTO.RTL"), 20.0)
    assert mode_left(v, _state("AUTO.LOITER"), 21.0, 20.0, ()) is ModeLeft.RETAKE
    assert mode_left(v, _state("AUTO.LOITER", battery_remaining_pct=5.0), 21.0, 20.0,
                     ()) is ModeLeft.RESPECT
    fence = deque([StatusText("Geofence violated", 2, 15.0)])
    assert not retake_goes_on(v, _state("AUTO.LOITER", statustexts=fence), 20.0)
    # Without a battery threshold the battery never decides.
    assert retake_goes_on(v, _state("AUTO.LOITER", battery_remaining_pct=5.0), None)


# -- a command refused or without effect ------------------------------------------------------


def test_a_stale_answer_or_one_whose_effect_is_seen_changes_nothing() -> None:
    v = _vehicle(pending=Arm(2), attempts=1)
    assert refused(None, Arm(2), 3) is Refused.STALE
    assert refused(v, SetMode(2, "GUIDED"), 3) is Refused.STALE  # moved on from it
    landing = _vehicle(pending=Land(2), attempts=1, mode="LAND")
    assert refused(landing, Land(2), 3) is Refused.DONE  # only the ACK was lost
    assert refused(_vehicle(pending=Land(2), attempts=1, mode="GUIDED"), Land(2),
                   3) is Refused.RETRY


def test_a_refused_command_is_retried_until_its_attempts_run_out() -> None:
    assert refused(_vehicle(pending=Arm(2), attempts=2), Arm(2), 3) is Refused.RETRY
    assert refused(_vehicle(pending=Arm(2), attempts=3), Arm(2), 3) is Refused.GIVE_UP


def test_a_refused_takeoff_is_judged_by_the_climb() -> None:
    takeoff = Takeoff(2, 3.0)
    on_ground = _vehicle(pending=takeoff, attempts=1, altitude=0.05, takeoff_from=0.0)
    assert not climbing(on_ground)
    assert refused(on_ground, takeoff, 3) is Refused.JUDGE_LATER  # whatever the attempts
    assert refused(_vehicle(pending=takeoff, attempts=9, altitude=0.0), takeoff,
                   3) is Refused.JUDGE_LATER
    lifting = _vehicle(pending=takeoff, attempts=1, altitude=0.6, takeoff_from=0.1)
    assert climbing(lifting) and refused(lifting, takeoff, 3) is Refused.DONE
    # The verdict, once it has had the time to lift off.
    assert takeoff_verdict(lifting, 3) is Refused.DONE
    assert takeoff_verdict(on_ground, 3) is Refused.RETRY
    assert takeoff_verdict(_vehicle(pending=takeoff, attempts=3, altitude=0.0), 3) \
        is Refused.GIVE_UP
    # Unknown height: not climbing.
    assert not climbing(_vehicle(altitude=None, takeoff_from=0.0))


# -- a lost vehicle heard again ---------------------------------------------------------------


@pytest.mark.parametrize(("lost_from", "off_plan", "how"), [
    (VehiclePhase.ARMING, False, Rejoin.STAND_DOWN),
    (VehiclePhase.TAKEOFF, True, Rejoin.STAND_DOWN),  # never joins a show planned without it
    (VehiclePhase.SHOW, True, Rejoin.STRANDED),
    (VehiclePhase.SHOW, False, Rejoin.BACK),
    (VehiclePhase.READY, True, Rejoin.BACK),  # off a plan it had not begun: no dash
    (VehiclePhase.LANDING, False, Rejoin.BACK),
])
def test_a_vehicle_heard_again_rejoins_by_where_it_was_lost(
        lost_from: VehiclePhase, off_plan: bool, how: Rejoin) -> None:
    assert rejoin(lost_from, off_plan) is how


@pytest.mark.parametrize(("flavour", "mode", "armed", "doing"), [
    (Flavour.ARDUPILOT, "LAND", False, Landing.DOWN),
    (Flavour.ARDUPILOT, "LAND", True, Landing.DESCENDING),
    (Flavour.PX4, "AUTO.LAND", True, Landing.DESCENDING),
    (Flavour.ARDUPILOT, "GUIDED", True, Landing.LAND_LOST),
    (Flavour.PX4, "OFFBOARD", True, Landing.LAND_LOST),
    (Flavour.PX4, "AUTO.LOITER", True, Landing.LAND_LOST),  # PX4's Hold after our silence
    (Flavour.ARDUPILOT, "RTL", True, Landing.NOT_OURS),
    (Flavour.PX4, "POSCTL", True, Landing.NOT_OURS),  # a pilot
])
def test_a_vehicle_heard_again_while_landing_is_judged_by_what_it_does(
        flavour: Flavour, mode: str, armed: bool, doing: Landing) -> None:
    assert heard_landing(flavour, _state(mode, armed=armed)) is doing


# -- ways out ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("awaits", "planned_held", "holds", "now", "verdict"), [
    (True, False, False, 10.0, Offered.TAKE),
    (True, False, False, 12.0, Offered.TAKE),  # handed over at its very instant
    (True, False, False, 12.5, Offered.TOO_LATE),
    (True, True, True, 11.0, Offered.TAKE),  # from where it holds off its plan
    (False, False, False, 10.0, Offered.OVERTAKEN),  # landed, lost, the show over ...
    (True, False, True, 10.0, Offered.OVERTAKEN),  # stranded since it was asked for
    (True, True, False, 10.0, Offered.OVERTAKEN),  # back on its plan since
    (False, False, False, 20.0, Offered.OVERTAKEN),  # overtaken is judged before late
])
def test_a_way_out_handed_over_is_taken_only_if_still_awaited_for_the_same_start_in_time(
        awaits: bool, planned_held: bool, holds: bool, now: float, verdict: Offered) -> None:
    assert offered(awaits=awaits, planned_held=planned_held, holds_off_plan=holds,
                   show_time=now, starts_at=12.0) is verdict


def _asked(value: Any) -> tuple[list[int], Callable[[], Any]]:
    """A lazy answer and the count of times it was asked for."""
    count: list[int] = []

    def answer() -> Any:
        count.append(1)
        return value
    return count, answer


@pytest.mark.parametrize(("times", "following", "verdict", "asked"), [
    (1, 18.0, Late.NEXT_INSTANT, 1),
    (MAX_LATE_LEAVES - 1, 18.0, Late.NEXT_INSTANT, 1),
    (MAX_LATE_LEAVES, 18.0, Late.TOO_MANY, 0),  # bounded: never a way out chased forever
    (1, None, Late.NO_INSTANT, 1),  # no formation left to leave from
])
def test_a_late_way_out_is_tried_at_the_next_instant_a_bounded_number_of_times(
        times: int, following: float | None, verdict: Late, asked: int) -> None:
    count, answer = _asked(following)
    assert late(times, MAX_LATE_LEAVES, answer) is verdict
    assert len(count) == asked


@pytest.mark.parametrize(("phase", "holds", "where"), [
    (VehiclePhase.LEAVING, True, WithoutWayOut.LAND_WHERE_IT_HOLDS),  # stranded off its plan
    (VehiclePhase.SHOW, False, WithoutWayOut.FLY_ON),  # the plan keeps it apart
    (VehiclePhase.SHOW, True, WithoutWayOut.FLY_ON),  # a hold point not yet flown to
    (VehiclePhase.LOST, True, WithoutWayOut.FLY_ON),  # nothing to send it meanwhile
])
def test_without_a_way_out_only_a_vehicle_holding_off_its_plan_comes_straight_down(
        phase: VehiclePhase, holds: bool, where: WithoutWayOut) -> None:
    assert without_way_out(phase, holds) is where


# -- the land-all return when none can be planned ------------------------------------------


@pytest.mark.parametrize(("interrupted", "off_plan", "how"), [
    (True, False, NoReturn.SHOW_ON),  # the show is the one way home known to be clear
    (True, True, NoReturn.COLUMNS),  # not clear of drones hovering off it: no livelock
    (False, False, NoReturn.STRAIGHT),
    (False, True, NoReturn.STRAIGHT),  # after the show there is no show to fly on
])
def test_without_a_return_plan_the_fleet_flies_the_show_on_lands_in_columns_or_goes_straight(
        interrupted: bool, off_plan: bool, how: NoReturn) -> None:
    assert no_return(interrupted, off_plan) is how


# -- vehicles off their plans and given up ----------------------------------------------------

_FLYING = {"armed": True, "lost": False, "altitude_m": 8.0, "in_flight_mode": True}


@pytest.mark.parametrize(("change", "verdict"), [
    ({}, ArmedAgain.BACK),
    ({"off_plan": True}, ArmedAgain.STRANDED),
    ({"in_show": False}, ArmedAgain.LAND_HERE),  # before or after the show: down here
    ({"in_show": False, "off_plan": True}, ArmedAgain.LAND_HERE),
    ({"armed": False}, ArmedAgain.NOT_FLYING),
    ({"lost": True}, ArmedAgain.NOT_FLYING),  # silent: its failsafe is in charge
    ({"altitude_m": None}, ArmedAgain.NOT_FLYING),
    ({"altitude_m": 0.2}, ArmedAgain.NOT_FLYING),  # armed on the ground is not flying
    ({"in_flight_mode": False}, ArmedAgain.NOT_FLYING),  # a pilot or a failsafe has it
])
def test_a_vehicle_given_up_as_disarmed_is_judged_by_its_own_telemetry(
        change: dict[str, object], verdict: ArmedAgain) -> None:
    view: dict[str, object] = {**_FLYING, "in_show": True, **change}
    count, answer = _asked(view.pop("off_plan", False))
    assert armed_again(**view, off_plan=answer) is verdict
    # The plan is evaluated only for a vehicle flying in the show (every update).
    assert len(count) == (verdict in (ArmedAgain.BACK, ArmedAgain.STRANDED))


def test_the_fleet_lands_once_enough_are_stranded_at_once() -> None:
    assert not too_many_stranded(STRANDED_LAND_ALL - 1)
    assert too_many_stranded(STRANDED_LAND_ALL) and too_many_stranded(STRANDED_LAND_ALL + 3)


@pytest.mark.parametrize(("was", "where"), [
    (VehiclePhase.LANDING, GivenUp.BY_HAND),
    (VehiclePhase.ARMING, GivenUp.ON_THE_GROUND),
    (VehiclePhase.TAKEOFF, GivenUp.LAND_ON_SLOT),  # its spot may be another's landing spot
    (VehiclePhase.SHOW, GivenUp.LAND_HERE),
    (VehiclePhase.READY, GivenUp.LAND_HERE),
    (VehiclePhase.LEAVING, GivenUp.LAND_HERE),
])
def test_a_vehicle_given_up_goes_down_by_where_it_was(was: VehiclePhase, where: GivenUp) -> None:
    assert given_up(was) is where


# -- the last resort ---------------------------------------------------------------------------


def _at(x: float, y: float, z: float) -> np.ndarray:
    return np.array([x, y, z], dtype=float)


def test_a_column_is_clear_of_drones_above_it_and_of_landed_drones_beside_its_spot() -> None:
    here = _at(0.0, 0.0, 10.0)
    limit = 1.5
    assert column_clear(here, [], limit_m=limit, above_m=0.0)
    # Below it within the limit sideways: blocked; beyond the limit (and margin): clear.
    assert not column_clear(here, [(_at(1.0, 0.0, 4.0), False)], limit_m=limit, above_m=0.0)
    assert column_clear(here, [(_at(1.6, 0.0, 4.0), False)], limit_m=limit, above_m=0.0)
    assert not column_clear(here, [(_at(1.6, 0.0, 4.0), False)], limit_m=limit, above_m=0.0,
                            margin_m=0.2)
    # Above it: left behind by the descent (above_m 0), or counted up to above_m.
    assert column_clear(here, [(_at(0.5, 0.0, 11.0), False)], limit_m=limit, above_m=0.0)
    assert not column_clear(here, [(_at(0.5, 0.0, 11.0), False)], limit_m=limit,
                            above_m=limit)
    # A drone down on the ground counts only near where this one lands.
    landed = [(_at(1.0, 0.0, 0.0), True)]
    assert not column_clear(here, landed, limit_m=limit, above_m=0.0)
    assert column_clear(here, landed, limit_m=limit, above_m=0.0, ground_m=0.8)
    assert not column_clear(here, landed, limit_m=limit, above_m=0.0, ground_m=1.2)


def test_a_blocked_column_is_said_once_after_the_wait() -> None:
    assert not say_blocked(None, 100.0, False)
    assert not say_blocked(10.0, 10.0 + COLUMN_WAIT_S - 0.1, False)
    assert say_blocked(10.0, 10.0 + COLUMN_WAIT_S, False)
    assert not say_blocked(10.0, 10.0 + 5 * COLUMN_WAIT_S, True)


# -- the operator's per-vehicle commands ---------------------------------------------------------


@pytest.mark.parametrize(("known", "columns", "mid_show", "leaving", "at", "verdict"), [
    (False, False, True, False, 12.0, LandOne.UNKNOWN),
    (True, True, True, False, 12.0, LandOne.IN_COLUMNS),  # it lands with the columns
    (True, False, False, False, None, LandOne.LAND_NOW),  # before, after, returning
    (True, False, True, True, None, LandOne.ALREADY_LEAVING),
    (True, False, True, False, None, LandOne.NO_FORMATION_LEFT),
    (True, False, True, False, 12.0, LandOne.LEAVE_AT_NEXT),  # never a line home mid-show
])
def test_land_one_lands_now_off_the_show_and_leaves_on_a_way_out_in_it(
        known: bool, columns: bool, mid_show: bool, leaving: bool, at: float | None,
        verdict: LandOne) -> None:
    count, answer = _asked(at)
    assert land_one_asked(known=known, in_columns=columns, mid_show=mid_show,
                          leaving=leaving, next_instant=answer) is verdict
    assert len(count) == (verdict in (LandOne.NO_FORMATION_LEFT, LandOne.LEAVE_AT_NEXT))


@pytest.mark.parametrize(("phase", "verdict"), [
    (None, LandHere.UNKNOWN),
    (VehiclePhase.LANDED, LandHere.ALREADY),
    (VehiclePhase.LANDING, LandHere.ALREADY),
    (VehiclePhase.FAILED, LandHere.ALREADY),
    (VehiclePhase.PREFLIGHT, LandHere.STAND_DOWN),
    (VehiclePhase.ARMING, LandHere.STAND_DOWN),
    (VehiclePhase.TAKEOFF, LandHere.DOWN_HERE),
    (VehiclePhase.SHOW, LandHere.DOWN_HERE),
    (VehiclePhase.RETURNING, LandHere.DOWN_HERE),
])
def test_land_here_brings_down_whatever_flies_and_stands_down_what_does_not(
        phase: VehiclePhase | None, verdict: LandHere) -> None:
    assert land_here_asked(phase) is verdict


def test_kill_needs_a_known_vehicle_and_a_confirmation() -> None:
    assert kill_asked(False, True) is KillVerdict.UNKNOWN
    assert kill_asked(True, False) is KillVerdict.NEEDS_CONFIRM
    assert kill_asked(True, True) is KillVerdict.KILL


# -- spares: which one takes over a track ------------------------------------------------

def _spare(sysid: int, x: float, *, ready: bool = True, busy: bool = False,
           on_ground: bool = False) -> SpareView:
    return SpareView(sysid, (x, 0.0, 5.0), ready, busy, on_ground)


def test_the_spare_that_can_be_there_first_goes_first() -> None:
    spares = [_spare(70, 30.0), _spare(71, 10.0), _spare(72, 20.0)]
    got = choose_spares([0.0, 0.0, 5.0], spares, enabled=True, max_speed_h=5.0, climb_s=7.0)
    assert got.order == (71, 72, 70) and got.spare == 71
    assert got.why == "spare 71 goes, 2 s away from where it hovers at the show's speed " \
                      "(2 more to try)"


def test_a_spare_on_its_pad_counts_its_climb() -> None:
    # 10 m away on the ground (2 s + 7 s climbing) against 30 m away in the air (6 s).
    spares = [_spare(70, 10.0, on_ground=True), _spare(71, 30.0)]
    got = choose_spares((0.0, 0.0, 5.0), spares, enabled=True, max_speed_h=5.0, climb_s=7.0)
    assert got.order == (71, 70)
    # Ties go to the lower system id: the choice is repeatable.
    tie = choose_spares((0.0, 0.0, 5.0), [_spare(9, 10.0), _spare(4, -10.0)], enabled=True,
                        max_speed_h=5.0, climb_s=7.0)
    assert tie.order == (4, 9)


def test_spares_that_cannot_go_are_left_out_and_said() -> None:
    spares = [_spare(70, 1.0, ready=False), _spare(71, 2.0, busy=True), _spare(72, 3.0),
              _spare(73, 4.0)]
    got = choose_spares((0.0, 0.0, 5.0), spares, enabled=True, max_speed_h=5.0, climb_s=7.0,
                        tried={72})
    assert got.order == (73,)
    none = choose_spares((0.0, 0.0, 5.0), spares, enabled=True, max_speed_h=5.0, climb_s=7.0,
                         tried={72, 73})
    assert none.spare is None
    assert none.why == ("no spare can go (4 in all: 1 already flying a track or into one, "
                        "1 not ready, 2 failed to join it already)")


def test_no_spares_asked_or_none_in_the_show() -> None:
    off = choose_spares((0.0, 0.0, 5.0), [_spare(70, 1.0)], enabled=False, max_speed_h=5.0,
                        climb_s=7.0)
    assert off.spare is None and "--no-spares" in off.why
    empty = choose_spares((0.0, 0.0, 5.0), [], enabled=True, max_speed_h=5.0, climb_s=7.0)
    assert empty.spare is None and empty.why == "the show has no spares"
    with pytest.raises(ValueError, match="max_speed_h"):
        choose_spares((0.0, 0.0, 5.0), [_spare(70, 1.0)], enabled=True, max_speed_h=0.0,
                      climb_s=7.0)
