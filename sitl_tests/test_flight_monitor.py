"""The flight monitor: telemetry carried to the tick, separation, tracking, LED timing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_execute_support import ORIGIN, geo_offset, make_plan, make_vehicle

from groundctl.flight.monitor import FlightMonitor, nearest_pair, telemetry_positions
from groundctl.link.state import VehicleState
from groundctl.link.timesync import NS, TimesyncSample
from groundctl.show.checks import BRUTE_FORCE_PAIRS


def _with_sample(v: VehicleState, ned: tuple[float, float, float],
                 vel: tuple[float, float, float], sample_at: float, offset_s: float) -> None:
    """``v`` reported ``ned``/``vel`` at our time ``sample_at``; vehicle clock = ours + offset."""
    v.position_ned, v.velocity_ned = ned, vel
    v.local_time_boot_ms = round((sample_at + offset_s) * 1000)
    v.timesync.samples.clear()
    v.timesync.samples.append(TimesyncSample(int(offset_s * NS), 1_000_000, sample_at))


def test_each_sample_is_carried_to_the_tick_with_its_own_velocity() -> None:
    a = make_vehicle(1, now=10.0)
    b = make_vehicle(2, now=10.0, ekf_origin=geo_offset(ORIGIN, 3.0, 0.0))
    _with_sample(a, (0.0, 0.0, -5.0), (0.0, 4.0, 0.0), sample_at=9.95, offset_s=50.0)
    _with_sample(b, (0.0, 0.0, -5.0), (0.0, -4.0, 0.0), sample_at=9.90, offset_s=80.0)
    ids, pos = telemetry_positions(make_plan(), {1: a, 2: b}, now=10.0)
    assert ids == [1, 2]
    # a: 0.05 s at 4 m/s east; b: from 3 m east, 0.1 s at 4 m/s west.
    np.testing.assert_allclose(pos, [[0.2, 0.0, 5.0], [2.6, 0.0, 5.0]], atol=2e-3)
    sep = nearest_pair(ids, pos)
    assert sep.pair == (1, 2) and sep.distance_m == pytest.approx(2.4, abs=2e-3)


def test_a_sample_dated_after_it_arrived_is_carried_from_its_arrival() -> None:
    # A TIMESYNC offset estimated on a busy machine (every round trip held up on one leg)
    # put the sample 0.3 s in the future: taken at its word it would not be carried at
    # all; it cannot be younger than its arrival (0.1 s before the tick).
    a = make_vehicle(1, now=10.0)
    _with_sample(a, (0.0, 0.0, -5.0), (0.0, 2.0, 0.0), sample_at=10.3, offset_s=50.0)
    a.local_received_at = 9.9
    ids, pos = telemetry_positions(make_plan(), {1: a}, now=10.0)
    assert ids == [1]
    np.testing.assert_allclose(pos, [[0.2, 0.0, 5.0]], atol=2e-3)
    a.local_received_at = 10.5  # arrived after its dating: the dating stands
    np.testing.assert_allclose(telemetry_positions(make_plan(), {1: a}, now=10.5)[1],
                               [[0.4, 0.0, 5.0]], atol=2e-3)


def test_stale_and_lost_vehicles_are_left_out() -> None:
    a = make_vehicle(1, now=10.0)
    b = make_vehicle(2, now=10.0)
    _with_sample(a, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), sample_at=8.5, offset_s=0.0)  # 1.5 s old
    b.lost = True
    assert telemetry_positions(make_plan(), {1: a, 2: b}, now=10.0)[0] == []
    assert nearest_pair([], np.zeros((0, 3))).distance_m == math.inf


@pytest.mark.parametrize("n", [2, 3, 9, BRUTE_FORCE_PAIRS, BRUTE_FORCE_PAIRS + 1, 200])
def test_the_nearest_pair_is_every_pairs_closest_on_either_side_of_the_kd_tree(n: int) -> None:
    """Every pair compared on a small fleet, a KD-tree on a large one: the same answer as
    the distance matrix, the pair named by system id (low first)."""
    rng = np.random.default_rng(n)
    for _ in range(20):
        pos = rng.uniform(-20.0, 20.0, (n, 3))
        ids = [int(s) for s in rng.permutation(254)[:n] + 1]
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
        d[np.diag_indices(n)] = np.inf
        i, j = np.unravel_index(np.argmin(d), d.shape)
        sep = nearest_pair(ids, pos)
        assert sep.distance_m == pytest.approx(d[i, j], rel=1e-12)
        assert sep.pair == (min(ids[i], ids[j]), max(ids[i], ids[j]))
    assert nearest_pair([7], pos[:1]).distance_m == math.inf


def test_tracking_error_and_pattern_error_against_the_plan() -> None:
    plan = make_plan()
    mon = FlightMonitor(plan, {1: 0, 2: 1})
    states = {}
    for sysid, track in ((1, 0), (2, 1)):
        v = make_vehicle(sysid, now=10.0)
        want = plan.state_at(2.0).pos[track]
        off = 0.3 if sysid == 2 else 0.0
        _with_sample(v, (want[1] + off, want[0], -want[2]), (0.0, 0.0, 0.0), 10.0, 0.0)
        states[sysid] = v
    mon.observe(10.0, 2.0, in_show={1, 2}, states=states)
    assert mon.vehicles[1].max_error_m == pytest.approx(0.0, abs=1e-3)
    assert mon.vehicles[2].max_error_m == pytest.approx(0.3, abs=1e-3)
    assert mon.vehicles[2].max_error_at_s == 2.0
    assert mon.max_tracking_error() == pytest.approx(0.3, abs=1e-3)
    assert mon.rms_tracking_error() == pytest.approx(math.sqrt(0.09 / 2), abs=1e-3)


def test_each_excursion_beyond_half_a_metre_is_timed_until_it_is_back() -> None:
    plan = make_plan()
    mon = FlightMonitor(plan, {1: 0})
    v = make_vehicle(1, now=10.0)
    # Off its plan by these many metres at these times (our clock), in the show.
    for now, off in ((10.0, 0.2), (10.1, 0.7), (10.2, 1.5), (10.9, 0.6), (11.3, 0.4),
                     (11.4, 0.1), (12.0, 0.9), (12.1, 0.8)):
        want = plan.state_at(2.0).pos[0]
        _with_sample(v, (want[1] + off, want[0], -want[2]), (0.0, 0.0, 0.0), now, 0.0)
        mon.observe(now, 2.0, in_show={1}, states={1: v})
    # Out at 10.1, back at 11.3; out again at 12.0 and not back when the flight ends.
    assert mon.vehicles[1].recovery_s == [pytest.approx(1.2), None]
    assert mon.recovery() == {"excursions": 2, "max_s": pytest.approx(1.2), "never": 1}
    calm = FlightMonitor(plan, {1: 0})
    assert calm.recovery() == {"excursions": 0, "max_s": None, "never": 0}


def test_led_changes_are_timed_against_the_plans_colour_keys() -> None:
    plan = make_plan()  # black at 0 s fading to orange (255, 128, 0) at 10 s
    mon = FlightMonitor(plan, {1: 0})
    # (128, 64, 0) is the plan's colour from t = 5.0 s on: shown at 5.1 s is 0.1 s late.
    mon.observe_led(1, (128, 64, 0), changed_at=100.0, show_time_of=5.1)
    assert mon.vehicles[1].led_errors_s == [pytest.approx(0.1, abs=0.03)]
    mon.observe_led(1, (128, 64, 0), changed_at=100.0, show_time_of=5.1)  # same change again
    assert len(mon.vehicles[1].led_errors_s) == 1
    mon.observe_led(1, (0, 255, 0), changed_at=101.0, show_time_of=6.0)  # never in the plan
    assert mon.vehicles[1].led_unmatched == 1


def test_the_flight_budget_does_not_run_while_the_show_is_held_skipped_ticks_included() -> None:
    from groundctl.flight.runner import FlightBudget

    budget = FlightBudget(100.0, started=10.0)
    now = 10.0
    for _ in range(50):  # flying: 5 s of the budget gone
        now += 0.1
        budget.tick(now, held=False)
    # Held, on a loop so late that it ticks once every 2 s (19 ticks skipped each time):
    # all 60 s are held time, not 30 periods of 0.1 s.
    for _ in range(30):
        now += 2.0
        budget.tick(now, held=True)
    assert budget.held_s == pytest.approx(60.0)
    assert not budget.expired(now + 94.0)  # 5 s flown + 94 s < 100 s
    assert budget.expired(now + 95.5)
