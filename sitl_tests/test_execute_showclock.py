"""The show clock: braking holds along the plan, ramps, stops after a stall, history."""

from __future__ import annotations

import pytest

from groundctl.execute.showclock import MIN_RAMP_S, ShowClock, brake_ramp


def test_runs_at_full_rate_from_its_start() -> None:
    clock = ShowClock(ramp_s=2.0)
    assert clock.at(5.0).show_time == 0.0 and not clock.started
    clock.start(10.0)
    assert clock.started_at == 10.0
    c = clock.at(13.5)
    assert (c.show_time, c.rate, c.rate_change) == (3.5, 1.0, 0.0)
    with pytest.raises(ValueError, match="already started"):
        clock.start(11.0)


def test_a_hold_brakes_linearly_and_stops_half_a_ramp_on() -> None:
    clock = ShowClock(ramp_s=2.0)
    clock.start(0.0)
    assert clock.hold(4.0, "operator")
    assert clock.stop_time(4.0) == pytest.approx(5.0)
    c = clock.at(5.0)  # half-way down the ramp
    assert c.rate == pytest.approx(0.5) and c.rate_change == pytest.approx(-0.5)
    assert c.show_time == pytest.approx(4.0 + 0.75)
    assert clock.stopped(6.0) and clock.at(60.0).show_time == pytest.approx(5.0)
    assert not clock.hold(7.0, "operator")  # already held: nothing new


def test_the_clock_resumes_only_when_every_hold_is_released() -> None:
    clock = ShowClock(ramp_s=1.0)
    clock.start(0.0)
    clock.hold(2.0, "operator")
    clock.hold(2.5, "silence")
    assert not clock.release(5.0, "operator")  # still held for silence
    assert clock.at(6.0).rate == 0.0
    assert clock.release(6.0, "silence")
    assert clock.at(6.5).rate == pytest.approx(0.5)
    assert clock.at(9.0).rate == 1.0
    # 2.5 at rest, then half a ramp of catch-up, then full rate.
    assert clock.show_time(9.0) == pytest.approx(2.5 + 0.5 + 2.0)
    assert not clock.release(9.0, "never held")


def test_after_a_stall_it_stops_at_once_where_the_last_setpoints_were() -> None:
    clock = ShowClock(ramp_s=2.0)
    clock.start(0.0)
    clock.stop_at(7.5, 6.0, "stall")  # it stalled from 6.0 to 7.5
    c = clock.at(7.5)
    assert (c.show_time, c.rate) == (6.0, 0.0)
    assert clock.held and clock.stopped(7.5)
    # History: earlier instants keep their show times (LED timing, reports).
    assert clock.show_time(3.0) == pytest.approx(3.0)


def test_a_hold_during_the_ramp_up_brakes_from_the_rate_reached() -> None:
    clock = ShowClock(ramp_s=2.0)
    clock.start(0.0)
    clock.hold(1.0, "operator")
    clock.release(4.0, "operator")
    clock.hold(5.0, "overload")  # rate 0.5 there
    assert clock.at(5.0).rate == pytest.approx(0.5)
    assert clock.rest_at() == pytest.approx(6.0)
    assert clock.stopped(6.0)


def test_ramp_lengths_follow_the_braking_limit() -> None:
    assert brake_ramp(4.0, 2.0) == pytest.approx(2.0)
    assert brake_ramp(0.1, 2.0) == MIN_RAMP_S
    with pytest.raises(ValueError, match="`brake_accel` must be positive"):
        brake_ramp(1.0, 0.0)
    with pytest.raises(ValueError, match="`ramp_s` must be at least"):
        ShowClock(ramp_s=0.1)


def test_a_clock_started_for_later_takes_holds_from_its_start() -> None:
    clock = ShowClock(ramp_s=1.0)
    clock.start(10.0)  # a return that begins once the fleet has braked
    assert clock.hold(8.0, "operator")  # held before it began: it begins held
    assert clock.stopped(11.5) and clock.show_time(11.5) == pytest.approx(0.5)
    assert clock.release(9.0, "operator")
    assert clock.at(13.0).rate == 1.0


def test_the_revision_counts_every_change_of_course_and_nothing_else() -> None:
    c = ShowClock(ramp_s=1.0)
    assert c.revision == 0
    c.start(0.0)
    r = c.revision
    assert c.hold(5.0, "operator") and c.revision == r + 1
    assert not c.hold(5.5, "overload") and c.revision == r + 1  # already braking: same
    c.stop_at(6.0, 4.0, "stall")  # put back after a stall: a new course
    assert c.revision == r + 2
    assert not c.release(9.0, "operator") and c.revision == r + 2  # still held
    c.release(9.0, "overload")
    assert c.revision == r + 2
    assert c.release(9.5, "stall") and c.revision == r + 3
