"""The flight guard: our own stalls, overload and fleet-wide silence; safety responses."""

from __future__ import annotations

from dataclasses import replace

from groundctl.execute.guard import (
    FlightGuard,
    GuardConfig,
    Hold,
    LandAll,
    Release,
    TakeOut,
    TickFacts,
)

BASE = TickFacts(now=0.0, lag_s=0.0, period_s=0.1, last_sent_show_time=5.0,
                 fleet_silent=False, errors_m={1: 0.1, 2: 0.1}, limit_m=1.5, in_show=True)


def _run(guard: FlightGuard, start: float, end: float, **facts: object) -> list:
    out = []
    t = start
    while t < end - 1e-9:
        out += guard.tick(replace(BASE, now=t, **facts))  # type: ignore[arg-type]
        t += 0.1
    return out


def test_a_stall_stops_the_show_at_the_last_setpoints_then_resumes_once_settled() -> None:
    guard = FlightGuard()
    assert _run(guard, 0.0, 1.0) == []
    (hold,) = guard.tick(replace(BASE, now=2.5, lag_s=1.5, last_sent_show_time=3.9))
    assert isinstance(hold, Hold) and hold.reason == "stall" and hold.show_time == 3.9
    assert "stalled for 1.5 s" in hold.text
    # Keeping time again, but one drone still 0.8 m off its hold point: wait.
    assert _run(guard, 2.6, 5.0, errors_m={1: 0.8}) == []
    (release,) = _run(guard, 5.0, 5.5, errors_m={1: 0.2})
    assert isinstance(release, Release) and release.reason == "stall"


def test_overrunning_ticks_hold_the_show_and_persistent_overload_lands_the_fleet() -> None:
    guard = FlightGuard(GuardConfig(max_held_s=5.0))
    actions = _run(guard, 0.0, 0.6, lag_s=0.15)
    assert [a.reason for a in actions if isinstance(a, Hold)] == ["overload"]
    actions = _run(guard, 0.6, 6.0, lag_s=0.15)
    assert any(isinstance(a, LandAll) for a in actions)
    assert guard.landed_all and guard.held_s > 5.0


def test_fleet_wide_silence_holds_until_heard_and_settled() -> None:
    guard = FlightGuard()
    (hold,) = guard.tick(replace(BASE, fleet_silent=True))
    assert isinstance(hold, Hold) and hold.reason == "silence" and hold.show_time is None
    assert _run(guard, 0.1, 3.0, fleet_silent=True) == []
    assert _run(guard, 3.0, 3.5, errors_m={1: 1.2}) == []  # heard, not settled yet
    (release,) = guard.tick(replace(BASE, now=3.6))
    assert isinstance(release, Release) and release.reason == "silence"


def test_nothing_is_held_before_the_show_or_after_it() -> None:
    guard = FlightGuard()
    assert _run(guard, 0.0, 2.0, in_show=False, lag_s=2.0, fleet_silent=True) == []


def test_a_pair_closing_near_the_limit_holds_the_fleet() -> None:
    guard = FlightGuard()
    (hold,) = guard.tick(replace(BASE, closest_m=1.55, closest_pair=(3, 4), closing_mps=-0.5))
    assert isinstance(hold, Hold) and hold.reason == "safety"
    assert "vehicles (3, 4) are 1.55 m apart (limit 1.50 m)" in hold.text
    # Opening again, and nothing wrong once stopped: the show resumes.
    actions = _run(guard, 0.1, 8.0, closest_m=1.7, closing_mps=0.3, stopped=True)
    assert [type(a) for a in actions] == [Release]


def test_a_drone_off_its_path_holds_then_is_taken_out_if_it_stays_off() -> None:
    guard = FlightGuard()
    assert _run(guard, 0.0, 0.9, errors_m={1: 3.0, 2: 0.1}) == []  # not for long yet
    actions = _run(guard, 0.9, 1.3, errors_m={1: 3.0, 2: 0.1})
    (hold,) = [a for a in actions if isinstance(a, Hold)]
    assert "vehicle 1 is 3.0 m off its path" in hold.text
    actions = _run(guard, 1.3, 5.0, errors_m={1: 3.0, 2: 0.1}, stopped=True)
    (out,) = [a for a in actions if isinstance(a, TakeOut)]
    assert out.sysid == 1 and out.distance_m == 3.0
    # Taken out, it no longer counts; the others are fine: the show resumes.
    actions = _run(guard, 5.0, 9.0, errors_m={1: 3.0, 2: 0.1}, stopped=True)
    assert [type(a) for a in actions] == [Release]


def test_repeated_safety_holds_land_the_fleet() -> None:
    guard = FlightGuard(GuardConfig(max_safety_holds=1))
    t = 0.0
    kinds = []
    for _ in range(2):
        kinds += [type(a) for a in _run(guard, t, t + 0.2, closest_m=1.4)]
        kinds += [type(a) for a in _run(guard, t + 0.2, t + 7.0, closest_m=2.0, stopped=True)]
        t += 7.0
    assert kinds == [Hold, Release, LandAll]
