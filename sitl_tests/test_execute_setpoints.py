"""Per-vehicle setpoints from the plan, and when LED colours are (re)sent."""

from __future__ import annotations

import numpy as np
import pytest
from test_execute_support import ORIGIN, geo_offset, make_plan

from groundctl.execute.frames import show_to_ned, show_vel_to_ned
from groundctl.execute.leaving import Leave
from groundctl.execute.paths import Path, PathKind
from groundctl.execute.setpoints import LedTracker, SetpointStream, StreamTarget, quantise_rgb
from groundctl.execute.showclock import ShowClock
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import GeoOrigin

A = geo_offset(ORIGIN, 0.0, 0.0)
B = geo_offset(ORIGIN, 18.0, 24.0)


def _stream(origin: GeoOrigin = ORIGIN) -> SetpointStream:
    # Vehicle 11 flies track 2, vehicle 12 track 0, from different EKF origins.
    return SetpointStream(make_plan(origin=origin),
                          [StreamTarget(11, 2, A), StreamTarget(12, 0, B)], lead_s=0.15)


def _running(show_time: float, now: float = 0.0) -> ShowClock:
    """A show clock running at full rate, at ``show_time`` at our time ``now``."""
    clock = ShowClock()
    clock.start(now - show_time)
    return clock


def test_setpoints_lead_the_show_clock_and_use_each_vehicles_frame() -> None:
    stream = _stream(GeoOrigin(ORIGIN.lat, ORIGIN.lon, ORIGIN.alt, 90.0))
    sp = stream.at(100.0, {11: 50.0, 12: -20.0}, clock=_running(2.0, 100.0))
    state = stream.plan.state_at(2.15)
    assert sp.sysids == (11, 12)
    np.testing.assert_allclose(sp.pos_ned[0], show_to_ned(stream.plan.origin, A, state.pos[2]),
                               atol=1e-6)
    np.testing.assert_allclose(sp.pos_ned[1], show_to_ned(stream.plan.origin, B, state.pos[0]),
                               atol=1e-6)
    np.testing.assert_allclose(sp.vel_ned, show_vel_to_ned(stream.plan.origin, state.vel[[2, 0]]))
    np.testing.assert_allclose(sp.acc_ned, show_vel_to_ned(stream.plan.origin, state.acc[[2, 0]]))
    assert np.abs(sp.vel_ned).max() > 0.1  # mid-transition: real feed-forward
    # The stamp is the instant the setpoint is for (now + lead) on each vehicle's clock.
    assert sp.time_boot_ms.tolist() == [150_150, 80_150]


def _point(track: int, point: np.ndarray) -> Path:
    return Path(PathKind.LANDING_POINT, "test", track,
                point=tuple(float(x) for x in point))  # type: ignore[arg-type]


def _out(leave: Leave, track: int = 2) -> Path:
    return Path(PathKind.WAY_OUT, "test", track, leave=leave)


def test_same_show_point_differs_by_the_origin_offset_between_vehicles() -> None:
    plan = make_plan()
    stream = SetpointStream(plan, [StreamTarget(1, 0, A), StreamTarget(2, 1, B)], lead_s=0.0)
    sp = stream.at(0.0, {}, paths={2: _point(1, plan.home[0] + [0.0, 0.0, 3.0])})
    np.testing.assert_allclose(sp.pos_ned[0] - sp.pos_ned[1], [24.0, 18.0, 0.0], atol=1e-3)
    assert sp.time_boot_ms.tolist() == [0, 0]  # offsets unknown


def test_paused_clock_hovers_at_the_plan_point_without_feed_forward_or_lead() -> None:
    stream = _stream()
    clock = _running(2.0, 100.0)
    clock.stop_at(100.0, 2.0, "operator")
    sp = stream.at(100.0, {11: 50.0}, clock=clock)
    np.testing.assert_allclose(sp.pos_ned[0], show_to_ned(ORIGIN, A, stream.plan.state_at(2.0)
                                                          .pos[2]), atol=1e-6)
    assert not sp.vel_ned.any() and not sp.acc_ned.any()
    assert sp.time_boot_ms.tolist() == [150_150, 0]


def test_a_braking_clock_brakes_every_drone_along_its_own_path() -> None:
    stream = SetpointStream(make_plan(), [StreamTarget(11, 2, A), StreamTarget(12, 0, A)],
                            lead_s=0.0)
    clock = _running(2.0, 10.0)
    clock.hold(10.0, "operator", ramp_s=2.0)
    plan = stream.plan
    for now in (10.5, 11.0, 11.5):
        c = clock.at(now)
        sp = stream.at(now, {}, clock=clock)
        state = plan.state_at(c.show_time)
        # On the plan at the warped time, velocity scaled by the rate, and the rate's
        # change adding the along-path deceleration.
        np.testing.assert_allclose(sp.pos_ned[0], show_to_ned(ORIGIN, A, state.pos[2]),
                                   atol=1e-6)
        np.testing.assert_allclose(sp.vel_ned[0], show_vel_to_ned(
            ORIGIN, c.rate * state.vel[2][None])[0], atol=1e-9)
        np.testing.assert_allclose(sp.acc_ned[0], show_vel_to_ned(
            ORIGIN, (c.rate ** 2 * state.acc[2] + c.rate_change * state.vel[2])[None])[0],
            atol=1e-9)
    stopped = stream.at(12.5, {}, clock=clock)
    assert clock.stopped(12.5) and not stopped.vel_ned.any() and not stopped.acc_ned.any()
    assert clock.show_time(12.5) == pytest.approx(3.0)  # half the ramp at the full rate


def test_a_point_path_overrides_the_plan_and_past_the_end_there_is_no_feed_forward() -> None:
    stream = _stream()
    slots = stream.landing_slots()
    np.testing.assert_allclose(slots, [[6.0, 0.0, 3.0], [0.0, 0.0, 3.0]])
    sp = stream.at(0.0, {}, clock=_running(9.95), paths={12: _point(0, slots[1])})
    np.testing.assert_allclose(sp.pos_ned[1], show_to_ned(ORIGIN, B, slots[1]), atol=1e-6)
    assert not sp.vel_ned.any() and not sp.acc_ned.any()
    with pytest.raises(ValueError, match="`paths` names vehicle 5, which is not streamed"):
        stream.at(0.0, {}, clock=_running(1.0), paths={5: _point(0, slots[0])})


def test_colours_are_quantised_to_bytes_and_iterated_per_vehicle() -> None:
    sp = _stream().at(0.0, {}, show_time=10.0, ended=True)
    assert [s.rgb for s in sp] == [(255, 128, 0), (255, 128, 0)]
    assert quantise_rgb([[1.2, -0.1, 0.2]]).tolist() == [[255, 0, 51]]
    first = next(iter(sp))
    assert first.sysid == 11 and len(first.pos_ned) == 3 and len(sp) == 2


def test_stream_rejects_bad_targets() -> None:
    plan = make_plan()
    with pytest.raises(ValueError, match=r"`targets` name tracks \[3\]"):
        SetpointStream(plan, [StreamTarget(1, 3, A)])
    with pytest.raises(ValueError, match="must not repeat a system id"):
        SetpointStream(plan, [StreamTarget(1, 0, A), StreamTarget(1, 1, A)])
    # Two vehicles may share a track (one leaving it, a spare joining it), and a spare's
    # row is given its track when it takes one over.
    stream = SetpointStream(plan, [StreamTarget(1, 0, A), StreamTarget(2, 0, A)])
    stream.retrack(2, 1)
    assert [t.track for t in stream.targets] == [0, 1]
    with pytest.raises(ValueError, match="outside the plan"):
        stream.retrack(2, 7)
    with pytest.raises(ValueError, match="`lead_s` must be non-negative"):
        SetpointStream(plan, [], lead_s=-1.0)


def test_led_sent_on_change_and_refreshed_every_second() -> None:
    leds = LedTracker(refresh_s=1.0)
    red, blue = [255, 0, 0], [0, 0, 255]
    assert leds.due([1, 2], [red, red], now=0.0) == [(1, (255, 0, 0)), (2, (255, 0, 0))]
    assert leds.due([1, 2], [red, red], now=0.5) == []
    assert leds.due([1, 2], [red, blue], now=0.6) == [(2, (0, 0, 255))]
    assert leds.due([1, 2], [red, blue], now=1.0) == [(1, (255, 0, 0))]
    assert leds.due([1, 2], [red, blue], now=1.6) == [(2, (0, 0, 255))]
    leds.forget(1)
    assert leds.due([1], [red], now=1.7) == [(1, (255, 0, 0))]
    with pytest.raises(ValueError, match=r"`rgb` must have shape \(1, 3\)"):
        leds.due([1], [red, red], now=2.0)


def test_a_vehicle_on_its_way_out_flies_it_from_its_show_time_on() -> None:
    stream = _stream()
    plan = stream.plan
    # Vehicle 11 (track 2) leaves at show time 5.0 s: 4 s from its formation point home.
    start, end = plan.state_at(5.0).pos[2], plan.landing_hover[2]
    pos = np.stack([start, end])[None]
    vel = np.zeros_like(pos)  # rest to rest: a cubic with zero end velocities
    leave = Leave(5.0, Trajectories(np.array([0.0, 4.0]), pos, vel))
    before = stream.at(0.0, {}, clock=_running(4.0), paths={11: _out(leave)})
    # its plan until then
    assert np.allclose(before.pos_ned, stream.at(0.0, {}, clock=_running(4.0)).pos_ned)
    during = stream.at(0.0, {}, clock=_running(6.85), paths={11: _out(leave)})  # 2.0 s, lead
    p, v, _ = leave.state(7.0)
    np.testing.assert_allclose(during.pos_ned[0], show_to_ned(ORIGIN, A, p), atol=1e-6)
    np.testing.assert_allclose(during.vel_ned[0], show_vel_to_ned(ORIGIN, v[None])[0], atol=1e-9)
    assert np.abs(during.vel_ned[0]).max() > 0.1
    clock = _running(6.85)
    clock.stop_at(0.0, 6.85, "operator")
    held = stream.at(0.0, {}, clock=clock, paths={11: _out(leave)})  # show clock held
    np.testing.assert_allclose(held.pos_ned[0], show_to_ned(ORIGIN, A, leave.state(6.85)[0]),
                               atol=1e-6)
    assert not held.vel_ned[0].any()
    after = stream.at(0.0, {}, clock=_running(9.95), paths={11: _out(leave)})  # over its spot
    np.testing.assert_allclose(after.pos_ned[0], show_to_ned(ORIGIN, A, end), atol=1e-6)
    assert not after.vel_ned[0].any()
    with pytest.raises(ValueError, match="`paths` names vehicle 5, which is not streamed"):
        stream.at(0.0, {}, clock=_running(1.0), paths={5: _out(leave)})
