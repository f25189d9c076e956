"""Pre-flight checks, the per-vehicle report, and flying without excluded drones."""

from __future__ import annotations

import numpy as np
import pytest
from test_execute_support import HOME, make_plan, make_vehicle

from groundctl.errors import PreflightFailed
from groundctl.execute.mapping import Assignment, auto_assign, explicit_assign
from groundctl.execute.preflight import (
    Thresholds,
    check_vehicle,
    remaining_plan_conflicts,
    run_preflight,
)

NOW = 100.0


def _assignment(n: int = 3) -> Assignment:
    return auto_assign(HOME, {i + 1: HOME[i] for i in range(n)})


def test_a_healthy_vehicle_passes_every_check() -> None:
    v = make_vehicle(1, NOW)
    results = check_vehicle(v, auto_assign(HOME, {1: [0.2, 0.0, 0.0]}), NOW + 0.5)
    assert [r.name for r in results] == ["heartbeat", "gps", "position", "battery", "slot",
                                         "link", "autopilot"]
    assert all(r.ok for r in results), results
    assert str(results[4]) == "slot: track 0, 0.2 m from its slot"
    assert str(results[5]) == "link: loss 0%, RTT 20 ms"


def test_each_failure_says_the_value_and_the_rule() -> None:
    v = make_vehicle(2, NOW, battery=45.0, fix=2, rtt_s=0.4, lost_packets=30)
    v.ekf_origin = None
    failed = {r.name: r.detail for r in check_vehicle(v, _assignment(), NOW + 2.5) if not r.ok}
    assert failed == {
        "heartbeat": "last HEARTBEAT 2.5 s ago (limit 2.0 s)",
        "gps": "fix type 2 (need 3: 3D fix)",
        "position": "EKF origin unknown (no GPS_GLOBAL_ORIGIN)",
        "battery": "45 % (minimum 60 %)",
        "link": "loss 23% (limit 20%), RTT 400 ms (limit 250 ms)",
    }


def test_a_vehicle_that_estimates_more_wind_than_the_show_allows_is_not_ready() -> None:
    th = Thresholds(max_wind=10.0)
    v = make_vehicle(1, NOW)
    by_name = {r.name: r for r in check_vehicle(v, _assignment(1), NOW, th)}
    # On the ground an estimator has learnt no wind yet: passes, and says so.
    assert by_name["wind"].ok and by_name["wind"].detail == "no estimate yet (limit 10 m/s)"
    v.wind_ned, v.wind_at = (-8.0, -9.0, 0.0), NOW - 1.0
    (wind,) = [r for r in check_vehicle(v, _assignment(1), NOW, th) if r.name == "wind"]
    assert not wind.ok and wind.detail == "12.0 m/s estimated, above the show's limit of " \
                                          "10 m/s"
    v.wind_ned = (3.0, 4.0, 1.0)
    (wind,) = [r for r in check_vehicle(v, _assignment(1), NOW, th) if r.name == "wind"]
    assert wind.ok and wind.detail == "5.0 m/s (limit 10 m/s)"
    assert "wind" not in {r.name for r in check_vehicle(v, _assignment(1), NOW)}


def test_unknown_values_fail_rather_than_pass() -> None:
    v = make_vehicle(3, NOW, rtt_s=None)
    v.flavour, v.battery_remaining_pct, v.gps_fix_type = None, None, None
    v.last_heartbeat, v.position_ned = None, None
    failed = {r.name: r.detail for r in check_vehicle(v, auto_assign(HOME, {}), NOW)
              if not r.ok}
    assert failed == {
        "heartbeat": "no autopilot HEARTBEAT yet",
        "gps": "no GPS_RAW_INT yet",
        "position": "no local position (no LOCAL_POSITION_NED)",
        "battery": "battery level unknown",
        "slot": "no track assigned (extra vehicle)",
        "link": "no TIMESYNC answer yet (clock offset unknown)",
        "autopilot": "autopilot unknown: cannot command its modes",
    }


def test_report_renders_one_line_per_vehicle_and_honours_exclusions() -> None:
    vehicles = {1: make_vehicle(1, NOW), 2: make_vehicle(2, NOW, battery=45.0),
                3: make_vehicle(3, NOW)}
    positions = {1: HOME[0], 2: HOME[1], 3: HOME[2] + [0.0, 4.2, 0.0]}
    report = run_preflight(vehicles, auto_assign(HOME, positions), NOW,
                           Thresholds(min_battery_pct=50.0))
    assert report.lines() == [
        "vehicle 1: ready",
        "vehicle 2: NOT READY: battery: 45 % (minimum 50 %)",
        "vehicle 3: NOT READY: slot: vehicle 3 is 4.2 m from the nearest takeoff slot "
        "(tolerance 3.0 m)",
    ]
    with pytest.raises(PreflightFailed) as exc:
        report.require_all()
    assert exc.value.failures == {
        2: ["battery: 45 % (minimum 50 %)"],
        3: ["slot: vehicle 3 is 4.2 m from the nearest takeoff slot (tolerance 3.0 m)"]}
    assert str(exc.value).startswith("pre-flight checks failed: vehicle 2: battery: 45 %")
    report.require_all(excluded={2, 3})
    assert report.render(excluded={2, 3}).splitlines()[1] == "vehicle 2: excluded by the operator"


def test_a_failing_spare_is_a_spare_fewer_not_a_show_failure() -> None:
    pads = np.array([[9.0, 0.0, 0.0], [3.0, 6.0, 0.0]])
    vehicles = {1: make_vehicle(1, NOW), 2: make_vehicle(2, NOW), 3: make_vehicle(3, NOW),
                7: make_vehicle(7, NOW, battery=45.0), 8: make_vehicle(8, NOW)}
    positions = {1: HOME[0], 2: HOME[1], 3: HOME[2], 7: pads[0], 8: pads[1] + [0.2, 0, 0]}
    assignment = auto_assign(HOME, positions, pads=pads)
    report = run_preflight(vehicles, assignment, NOW)
    # Checked, every track having a vehicle (not ignored as extra) ...
    assert report.spares == {7: 0, 8: 1} and report.extra == {}
    assert [r.name for r in report.results[7]] == ["heartbeat", "gps", "position", "battery",
                                                   "slot", "link", "autopilot"]
    assert str(report.results[8][4]) == "slot: spare 2, 0.2 m from its pad"
    # ... but never blocking: the show passes, the spare is listed not ready.
    assert report.failures() == {}
    report.require_all()
    assert report.spare_failures() == {7: ["battery: 45 % (minimum 60 %)"]}
    assert report.ready_spares() == {8: 1}
    assert report.ready_spares(excluded={8}) == {}
    assert report.lines()[3:] == [
        "vehicle 7 (spare 1): NOT READY: battery: 45 % (minimum 60 %)",
        "vehicle 8 (spare 2): ready"]
    assert report.summary() == "3/3 ready; spares 1/2 ready"
    assert report.failing_by_check() == []
    # A fleet file's spare off its pad fails its slot check, as a show drone off its slot
    # does: still a spare fewer.
    marked = explicit_assign({1: 0, 2: 1, 3: 2}, HOME, positions, 0.1, pads, spares={7, 8})
    far = run_preflight(vehicles, marked, NOW, Thresholds(slot_tolerance_m=0.1))
    assert far.spare_failures()[8] == ["slot: spare 2, 0.2 m from its pad (tolerance 0.1 m)"]
    assert far.failures() == {} and far.ready_spares() == {}


def test_excluding_a_far_drone_leaves_no_conflict() -> None:
    assert remaining_plan_conflicts(make_plan(), {2}) == []
    assert remaining_plan_conflicts(make_plan(), set()) == []


def test_an_excluded_drone_next_to_a_takeoff_column_is_a_conflict() -> None:
    home = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [6.0, 0.0, 0.0]])
    conflicts = remaining_plan_conflicts(make_plan(home=home, min_separation=1.5), {1})
    assert {(c.track, c.phase) for c in conflicts} == {(0, "takeoff"), (0, "landing")}
    takeoff = next(c for c in conflicts if c.phase == "takeoff")
    assert takeoff.distance == pytest.approx(1.0)
    assert str(takeoff) == ("track 0 passes 1.00 m from excluded track 1's takeoff slot during "
                            "takeoff at t=0.0 s (minimum separation 1.50 m)")


def test_a_low_show_start_passing_over_an_excluded_drone_is_a_conflict() -> None:
    # Track 0 starts 0.5 m up and flies 4 m along +y while climbing 2 m; track 1's
    # slot is 2 m ahead on the ground, clear of track 0's vertical climb.
    home = np.array([[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    conflicts = remaining_plan_conflicts(make_plan(home=home, takeoff_altitude=0.5,
                                                   min_separation=1.5), {1})
    phases = {c.phase for c in conflicts}
    assert phases == {"show start", "show end"}
    start = next(c for c in conflicts if c.phase == "show start")
    assert start.track == 0 and start.excluded_track == 1
    assert start.distance < 1.5 and 0.0 < start.time < 5.0


def test_conflict_check_rejects_unknown_tracks() -> None:
    with pytest.raises(ValueError, match=r"`excluded_tracks` \[7\] are not tracks"):
        remaining_plan_conflicts(make_plan(), {7})
