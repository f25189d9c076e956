"""The show's wind limit: the fleet's wind, the hold, its release, the landing; and hold
points held apart (issue 35)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from groundctl.execute.guard import FlightGuard, Hold, LandAll, Release, TickFacts
from groundctl.execute.spread import spread_apart
from groundctl.execute.wind import WindConfig, WindVerdict, WindWatch, fleet_wind

BASE = TickFacts(now=0.0, lag_s=0.0, period_s=0.1, last_sent_show_time=5.0,
                 fleet_silent=False, limit_m=1.5, in_show=True, show_airborne=True)


def _ticks(watch: WindWatch, start: float, end: float, speeds: list[float],
           started: bool = True) -> list[tuple[float, WindVerdict]]:
    out = []
    for t in np.arange(start, end, 0.5):
        verdict = watch.tick(float(t), speeds, True, started)
        if verdict is not WindVerdict.NONE:
            out.append((float(t), verdict))
    return out


def test_the_fleets_wind_is_what_a_quarter_of_the_vehicles_reach() -> None:
    assert fleet_wind([]) is None
    assert fleet_wind([7.0]) == 7.0
    assert fleet_wind([3.0, 9.0]) == 9.0
    # One estimator gone astray among nine does not speak for the fleet; three do.
    assert fleet_wind([25.0] + [4.0] * 8) == 4.0
    assert fleet_wind([25.0, 12.0, 11.0] + [4.0] * 6) == 11.0


def test_a_wind_above_the_limit_holds_then_clears_after_ten_seconds_below() -> None:
    watch = WindWatch(10.0)
    assert _ticks(watch, 0.0, 5.0, [9.5, 9.0]) == []
    assert _ticks(watch, 5.0, 7.5, [11.0, 10.5]) == [(7.0, WindVerdict.HOLD)]
    assert watch.holds == 1 and watch.hold_peak == 11.0
    # 9.5 m/s is below the limit but not below 90 % of it: the hold stays.
    assert _ticks(watch, 7.5, 20.0, [9.5]) == []
    assert _ticks(watch, 20.0, 31.0, [8.0]) == [(30.0, WindVerdict.RELEASE)]
    assert watch.held_since is None and not watch.landed


def test_a_wind_that_stays_lands_the_fleet_once_and_is_then_no_longer_watched() -> None:
    watch = WindWatch(10.0, WindConfig(land_after_s=30.0))
    assert _ticks(watch, 0.0, 40.0, [12.0]) == [(2.0, WindVerdict.HOLD),
                                               (32.0, WindVerdict.LAND)]
    assert watch.landed and watch.strongest == 12.0
    assert _ticks(watch, 40.0, 80.0, [15.0]) == []


def test_no_estimate_is_no_sign_of_calm_and_a_wind_about_the_limit_ends_in_a_landing() -> None:
    watch = WindWatch(10.0)
    assert _ticks(watch, 0.0, 3.0, [12.0]) == [(2.0, WindVerdict.HOLD)]
    # The estimates stop (a stream lost): the hold stays until the landing.
    assert _ticks(watch, 3.0, 33.0, []) == [(32.0, WindVerdict.LAND)]
    # Gusting about the limit: each hold clears, but 90 s held in all lands the fleet.
    gusty = WindWatch(10.0, WindConfig(clear_for_s=2.0))
    verdicts = []
    for k in range(40):
        verdicts += _ticks(gusty, 10.0 * k, 10.0 * k + 5.0, [11.0])
        verdicts += _ticks(gusty, 10.0 * k + 5.0, 10.0 * k + 10.0, [5.0])
    kinds = [v for _, v in verdicts]
    assert kinds[-1] is WindVerdict.LAND and kinds.count(WindVerdict.LAND) == 1
    assert gusty.held_s >= 90.0 and gusty.holds > 10


def test_before_the_start_any_moment_above_holds_and_no_limit_watches_nothing() -> None:
    assert _ticks(WindWatch(10.0), 0.0, 1.0, [10.5], started=False) \
        == [(0.0, WindVerdict.HOLD)]
    unwatched = WindWatch(None)
    assert _ticks(unwatched, 0.0, 60.0, [30.0]) == []
    assert unwatched.strongest == 30.0  # still reported
    assert WindWatch(10.0).strongest is None  # nothing reported is not calm


def test_the_guard_holds_for_the_wind_says_why_and_lands_if_it_stays() -> None:
    guard = FlightGuard(max_wind=10.0)
    out = []
    for t in np.arange(0.0, 3.0, 0.1):
        out += guard.tick(replace(BASE, now=float(t), wind_mps=(12.5, 12.0, 3.0)))
    (hold,) = out
    assert isinstance(hold, Hold) and hold.reason == "wind"
    assert hold.text.startswith("the vehicles estimate 12.5 m/s of wind, above the show's "
                                "limit of 10 m/s: holding the show")
    out = []
    for t in np.arange(3.0, 40.0, 0.1):
        out += guard.tick(replace(BASE, now=float(t), wind_mps=(11.0, 14.0)))
    (land,) = out
    assert isinstance(land, LandAll) and "up to 14.0 m/s" in land.text
    assert land.text.startswith("the wind has not cleared (at most 9 m/s for 10 s) in 30 s")
    assert guard.landed_all and "wind" not in guard.active


def test_the_guard_releases_its_wind_hold_when_no_drone_is_in_the_air_for_the_show() -> None:
    guard = FlightGuard(max_wind=10.0)
    assert isinstance(guard.tick(replace(BASE, in_show=False, wind_mps=(11.0,)))[0], Hold)
    (release,) = guard.tick(replace(BASE, now=0.1, in_show=False, show_airborne=False))
    assert isinstance(release, Release) and release.reason == "wind"
    assert release.text == "wind hold dropped: no drone is in the air for the show"


def test_points_pushed_together_are_held_the_limit_apart_sideways() -> None:
    points = np.array([[0.0, 0.0, 10.0], [0.66, 0.0, 10.0], [0.5, 1.3, 10.0],
                       [5.0, 5.0, 10.0], [0.0, 0.0, 10.5]])
    spread = spread_apart(points, np.ones(5, dtype=bool), 1.5, 3.0)
    assert pdist(spread).min() >= 1.5 * (1 - 1e-3)
    assert np.array_equal(spread[:, 2], points[:, 2])  # sideways only
    assert np.array_equal(spread[3], points[3])  # clear already: not moved
    assert np.linalg.norm(spread - points, axis=1).max() < 1.5


def test_only_the_movable_points_move_and_never_further_than_allowed() -> None:
    points = np.array([[0.0, 0.0, 10.0], [0.2, 0.0, 10.0], [0.0, 0.0, 10.0]])
    movable = np.array([False, True, False])
    spread = spread_apart(points, movable, 1.5, 3.0)
    assert np.array_equal(spread[~movable], points[~movable])
    assert np.linalg.norm(spread[1, :2]) == pytest.approx(1.5, rel=2e-3)
    capped = spread_apart(points, movable, 1.5, 0.5)
    assert np.linalg.norm(capped[1] - points[1]) == pytest.approx(0.5)
    # Two fixed points too close stay as they are; nothing to move: unchanged.
    assert np.array_equal(spread_apart(points, np.zeros(3, dtype=bool), 1.5, 3.0), points)
