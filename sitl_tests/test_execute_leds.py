"""LED colour changes found exactly from the plan's keyframes, sent one link delay early."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from flight_fixtures import quick_plan

from groundctl.execute.leds import CHANGE_GUARD_S, LedSchedule
from groundctl.execute.setpoints import StreamTarget, quantise_rgb
from groundctl.flight.monitor import FlightMonitor
from groundctl.link.state import GeoPoint
from groundctl.plan.plan import FormationWindow, Plan
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import GeoOrigin, Limits

SYSIDS = (11, 12, 13)
EPS = 10 * CHANGE_GUARD_S


def led_plan() -> Plan:
    """Three hovering drones.  Colours, keyed at 0, 2, 2, 4, 6, 8 s:

    * tracks 0 and 1 (identical): black, a step to orange at 2.0, held, then a
      fade to cyan over 4-6 s (red falls 255 -> 0 every ~7.8 ms: the rate cap
      has work to do), held;
    * track 2: a slow fade of blue 0 -> 0.2 over 0-2 s, then constant.
    """
    n = 3
    home = np.column_stack([np.arange(n) * 3.0, np.zeros(n), np.zeros(n)])
    up = home + np.array([0.0, 0.0, 5.0])
    times = np.array([0.0, 8.0])
    pos = np.repeat(up[:, None, :], 2, axis=1)
    color_times = np.array([0.0, 2.0, 2.0, 4.0, 6.0, 8.0])
    colors = np.zeros((n, 6, 3))
    orange, cyan = [1.0, 0.5, 0.0], [0.0, 1.0, 1.0]
    colors[:2, 2:4] = orange
    colors[:2, 4:] = cyan
    colors[2, 1:, 2] = 0.2
    return Plan(show_name="leds", origin=GeoOrigin(47.3977, 8.5456, 488.0, 0.0),
                limits=Limits(min_separation=1.5), model="quadrotor", home=home,
                takeoff_altitude=5.0, trajectories=Trajectories(times, pos, np.zeros_like(pos)),
                color_times=color_times, colors=colors,
                formations=(FormationWindow(1, "hover", 0.0, 0.0, 8.0, up),))


def schedule(min_interval_s: float = 0.05) -> LedSchedule:
    return LedSchedule(led_plan(), [0, 1, 2], SYSIDS, min_interval_s=min_interval_s)


def sampled_colours(plan: Plan, track: int, t0: float, t1: float) -> list[tuple[int, ...]]:
    """The distinct quantised colours the plan shows in (t0, t1), in order, sampled at 10 us.

    The grid is offset so no sample lands exactly on a tie (x * 255 = k + 0.5,
    where ``rint`` rounds half to even and shows a colour for no time at all).
    """
    t = np.arange(t0 + 3.7e-6, t1, 1e-5)
    q = quantise_rgb(np.stack([np.interp(t, plan.color_times, plan.colors[track, :, c])
                               for c in range(3)], axis=1))
    keep = np.ones(len(q), dtype=bool)
    keep[1:] = (q[1:] != q[:-1]).any(axis=1)
    return [tuple(map(int, row)) for row in q[keep]]


def test_a_step_appears_at_its_keyframe_and_is_sent_one_delay_early() -> None:
    sched = schedule()
    due = [c for c in sched.changes(1.9, 2.0, [0.03, 0.0, 0.0]) if c.sysid == 11]
    assert len(due) == 1
    (step,) = due
    assert step.show_time == pytest.approx(2.0, abs=1e-6)
    assert step.send_at == pytest.approx(1.97, abs=1e-6)
    assert step.rgb == (255, 128, 0)
    # Not before: the window ending just before 1.97 holds nothing for 11.
    assert not [c for c in sched.changes(1.0, 1.9699, [0.03, 0.0, 0.0]) if c.sysid == 11]


def test_every_fade_colour_is_sent_without_a_cap() -> None:
    plan = led_plan()
    sched = LedSchedule(plan, [0, 1, 2], SYSIDS, min_interval_s=0.0)
    for row, track in enumerate((0, 2)):
        sysid = SYSIDS[track]
        got = [c for c in sched.changes(-1.0, 9.0, np.zeros(3)) if c.sysid == sysid]
        assert [c.rgb for c in got] == sampled_colours(plan, track, 0.0, 8.0)[1:], row
    fade = [c for c in sched.changes(3.9, 6.1, np.zeros(3)) if c.sysid == 11]
    # Red falls and blue rises through 255 half levels together; green's 127
    # (127.5 -> 255) fall between them.
    assert len(fade) == 255 + 127


def test_the_rate_cap_merges_fade_steps_but_keeps_their_last_and_their_timing() -> None:
    plan = led_plan()
    every = LedSchedule(plan, [0, 1, 2], SYSIDS, min_interval_s=0.0)
    capped = schedule(0.05)
    zero = np.zeros(3)
    all_11 = [c for c in every.changes(-1.0, 9.0, zero) if c.sysid == 11]
    kept_11 = [c for c in capped.changes(-1.0, 9.0, zero) if c.sysid == 11]
    assert 0 < len(kept_11) < len(all_11)
    # Kept changes are exact changes (same instant, same colour), >= 50 ms apart.
    exact = {(round(c.show_time, 9), c.rgb) for c in all_11}
    assert all((round(c.show_time, 9), c.rgb) in exact for c in kept_11)
    gaps = np.diff([c.show_time for c in kept_11])
    assert gaps.min() >= 0.05 - 1e-9
    assert gaps[gaps < 1.0].max() < 0.05 + 0.0079  # the cap plus one fade step, no more
    # The step and the end of the fade are always sent; each dropped colour is
    # merged into a kept change less than min_interval_s later.
    assert kept_11[0].rgb == (255, 128, 0) and kept_11[-1].rgb == (0, 255, 255)
    kept_times = np.array([c.show_time for c in kept_11])
    for c in all_11:
        if (round(c.show_time, 9), c.rgb) in {(round(k.show_time, 9), k.rgb) for k in kept_11}:
            continue
        later = kept_times[kept_times > c.show_time]
        assert len(later) and later[0] - c.show_time < 0.05, c
    # Track 2's slow fade (one level every ~39 ms) is merged too, last level kept.
    slow = [c for c in capped.changes(-1.0, 9.0, zero) if c.sysid == 13]
    assert slow[-1].rgb == (0, 0, 51) and slow[-1].show_time < 2.0


def test_each_colour_is_the_plans_from_its_show_time_and_not_before() -> None:
    plan = led_plan()
    for c in schedule().changes(-1.0, 9.0, np.zeros(3)):
        track = SYSIDS.index(c.sysid)
        at = tuple(map(int, quantise_rgb(plan.colors_at(c.show_time + EPS)[track])))
        before = tuple(map(int, quantise_rgb(plan.colors_at(c.show_time - EPS)[track])))
        assert at == c.rgb, c
        assert before != c.rgb, c


def test_consecutive_windows_neither_repeat_nor_miss_a_change() -> None:
    sched = schedule()
    delays = np.array([0.031, 0.0, 0.2])
    whole = sched.changes(-5.0, 10.0, delays)
    rng = np.random.default_rng(7)
    edges = np.concatenate([[-5.0], np.sort(rng.uniform(-1.0, 9.0, 400)), [10.0]])
    # Include window edges exactly on send instants: the boundary case.
    edges = np.sort(np.concatenate([edges, [c.send_at for c in whole[::7]]]))
    pieces = [c for t0, t1 in pairwise(edges)
              for c in sched.changes(float(t0), float(t1), delays)]
    assert sorted(pieces, key=lambda c: (c.sysid, c.show_time)) == \
        sorted(whole, key=lambda c: (c.sysid, c.show_time))
    assert len(set(pieces)) == len(pieces)
    assert [c.send_at for c in whole] == sorted(c.send_at for c in whole)
    assert sched.changes(3.0, 3.0, delays) == []


def test_each_vehicle_gets_its_own_delay() -> None:
    sched = schedule()
    delays = np.array([0.0, 0.12, 0.05])
    got = sched.changes(-1.0, 9.0, delays)
    a = [c for c in got if c.sysid == 11]
    b = [c for c in got if c.sysid == 12]  # same colours as 11
    assert [c.show_time for c in a] == [c.show_time for c in b]
    assert all(c.send_at == pytest.approx(c.show_time - d, abs=1e-12)
               for c in got for d in [delays[SYSIDS.index(c.sysid)]])
    # So a window takes 12's step 120 ms before 11's.
    assert [c.sysid for c in sched.changes(1.85, 1.9, delays) if c.sysid != 13] == [12]
    batch = sched.window(1.85, 1.9, delays)
    steps = batch.rows < 2
    assert batch.rows[steps].tolist() == [1] and batch.rgb[steps].tolist() == [[255, 128, 0]]


def test_colour_at_gives_the_scheduled_colour_on_arrival() -> None:
    sched = schedule()
    np.testing.assert_array_equal(sched.colour_at(1.9, [0.0, 0.0, 0.0])[:2], [[0, 0, 0]] * 2)
    # A refresh sent at 1.98 over a 30 ms link arrives after the step.
    np.testing.assert_array_equal(sched.colour_at(1.98, [0.03, 0.0, 0.0])[:2],
                                  [[255, 128, 0], [0, 0, 0]])
    # Mid-fade it repeats the last colour the changes sent, never a merged step.
    sent = sched.changes(-1.0, 5.0, np.zeros(3))
    last_11 = [c for c in sent if c.sysid == 11][-1]
    assert tuple(sched.colour_at(5.0, np.zeros(3))[0].tolist()) == last_11.rgb
    np.testing.assert_array_equal(sched.colour_at(100.0, np.zeros(3)),
                                  [[0, 255, 255], [0, 255, 255], [0, 0, 51]])
    np.testing.assert_array_equal(sched.colour_at(-3.0, np.zeros(3)), np.zeros((3, 3)))


def test_from_targets_follows_the_stream_order() -> None:
    origin = GeoPoint(47.3977, 8.5456, 488.0)
    sched = LedSchedule.from_targets(led_plan(), [StreamTarget(7, 2, origin),
                                                  StreamTarget(9, 0, origin)])
    assert sched.sysids.tolist() == [7, 9] and sched.tracks.tolist() == [2, 0]
    assert [c.sysid for c in sched.changes(1.99, 2.01, [0.0, 0.0])] == [9]


def test_bad_arguments_name_the_parameter() -> None:
    sched = schedule()
    with pytest.raises(ValueError, match=r"^`delays` must have shape \(3,\), got \(2,\)$"):
        sched.changes(0.0, 1.0, [0.0, 0.0])
    with pytest.raises(ValueError, match=r"`t1` must not be before `t0`, got t0=1.0, t1=0.5"):
        sched.changes(1.0, 0.5, np.zeros(3))
    with pytest.raises(ValueError, match=r"`delays` must be finite and non-negative"):
        sched.window(0.0, 1.0, [0.0, -0.1, 0.0])
    with pytest.raises(ValueError, match=r"`delays` must have shape \(3,\), got \(3, 1\)"):
        sched.colour_at(0.0, np.zeros((3, 1)))
    with pytest.raises(ValueError, match=r"`min_interval_s` must be non-negative, got -1"):
        LedSchedule(led_plan(), [0], [1], min_interval_s=-1)
    with pytest.raises(ValueError, match=r"`tracks` names tracks \[5\] outside the plan's 0..2"):
        LedSchedule(led_plan(), [0, 5], [1, 2])
    with pytest.raises(ValueError, match=r"`sysids` must have shape \(2,\) like `tracks`"):
        LedSchedule(led_plan(), [0, 1], [1])
    with pytest.raises(ValueError, match=r"must not repeat a system id"):
        LedSchedule(led_plan(), [0, 1], [1, 1])
    # Two vehicles may share a track (one leaving it, a spare joining it).
    assert len(LedSchedule(led_plan(), [0, 0], [1, 2]).sysids) == 2


def test_quick_show_colours_appear_on_time_as_the_monitor_measures_them() -> None:
    plan = quick_plan()
    n = plan.drones
    sysids = list(range(1, n + 1))
    tracks = np.random.default_rng(3).permutation(n)
    sched = LedSchedule(plan, tracks, sysids)
    delays = np.random.default_rng(4).uniform(0.005, 0.08, n)
    monitor = FlightMonitor(plan, dict(zip(sysids, tracks.tolist(), strict=True)))
    ticks = np.arange(-0.1, plan.duration + 0.2, 0.1)
    sent = 0
    for t0, t1 in pairwise(ticks):
        for c in sched.changes(float(t0), float(t1), delays):
            # Sent at send_at, applied on arrival one delay later.
            shown = c.send_at + delays[sysids.index(c.sysid)]
            monitor.observe_led(c.sysid, c.rgb, shown, shown)
            sent += 1
    errors = np.array(monitor.led_errors())
    assert sent > 100 and len(errors) == sent
    assert sum(v.led_unmatched for v in monitor.vehicles.values()) == 0
    assert np.abs(errors).mean() < 0.01
    assert np.abs(errors).max() < 1e-6
