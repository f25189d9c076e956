"""A spare's way into a failed drone's track (issue 29): planned among the drones that
fly on, at the first formation it can reach, and checked exactly in continuous time."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from groundctl.errors import PlanningError
from groundctl.flight.joining import Moving, closest_approach, join_windows, plan_join
from groundctl.flight.returning import plan_leave
from groundctl.plan.plan import Plan
from groundctl.plan.planner import plan_show
from groundctl.plan.trajectory import Trajectories
from groundctl.show.loader import load_show
from groundctl.show.model import SpareSettings

TRACK = 4


@pytest.fixture(scope="module")
def plan() -> Plan:
    show = load_show("shows/quick.toml")
    return plan_show(replace(show, spares=SpareSettings(count=2, standby="air")),
                     workers=1).plan


def _dense_gap(plan: Plan, path: Moving, t0: float, t1: float, tracks: list[int],
               others: list[Moving] = ()) -> float:  # type: ignore[assignment]
    """The closest ``path`` comes to ``tracks`` and ``others`` on a 2 ms grid."""
    t = np.arange(t0, t1, 0.002)
    mine = path.position(t)
    gaps = [np.linalg.norm(plan.trajectories.evaluate(t, np.array(tracks))[0] - mine,
                           axis=2).min()] if tracks else []
    for m in others:
        inside = (t >= m.start) & (t <= m.end)
        if inside.any():
            gaps.append(np.linalg.norm(m.position(t[inside]) - mine[inside], axis=1).min())
    return float(min(gaps, default=np.inf))


def test_a_spare_joins_at_the_first_formation_it_can_reach(plan: Plan) -> None:
    assert plan.spares is not None
    start = plan.spares.points[0]
    join = plan_join(plan, TRACK, start, earliest=3.0, static=plan.spares.points[1:])
    first = plan.formations[0]
    assert join.at >= 3.0 and first.arrive <= join.until <= first.end
    assert join.until == pytest.approx(join_windows(plan, TRACK, start, 3.0)[0][1])
    # It starts where it waits, at rest, and ends on the track's plan, at rest.
    p0, v0, _ = join.state(join.at)
    p1, v1, _ = join.state(join.until)
    assert np.allclose(p0, start, atol=1e-6) and np.allclose(v0, 0.0, atol=1e-6)
    assert np.allclose(p1, plan.state_at(join.until).pos[TRACK], atol=1e-6)
    assert np.allclose(v1, 0.0, atol=1e-6)
    # Clear of every drone flying on, on a fine grid as well as by the exact check.
    others = [j for j in range(plan.drones) if j != TRACK]
    path = Moving(join.trajectory, join.at, join.at, join.until)
    assert _dense_gap(plan, path, join.at, join.until, others) >= plan.limits.min_separation
    assert join.plan_ms > 0


def test_closest_approach_is_exact_against_dense_sampling(plan: Plan) -> None:
    assert plan.spares is not None
    join = plan_join(plan, TRACK, plan.spares.points[0], earliest=3.0)
    path = Moving(join.trajectory, join.at, join.at, join.until)
    tracks = np.array([j for j in range(plan.drones) if j != TRACK], dtype=np.intp)
    exact, what = closest_approach(path, plan, tracks, [], np.zeros((0, 3)), join.at,
                                   join.until)
    dense = _dense_gap(plan, path, join.at, join.until, tracks.tolist())
    assert exact <= dense + 1e-6 and dense - exact < 5e-3
    assert what.startswith("drone ") and "at show time" in what
    # A static point: the distance to it, from the path's own cubic.
    point = join.state((join.at + join.until) / 2)[0] + np.array([0.3, 0.0, 0.0])
    exact, what = closest_approach(path, plan, tracks[:0], [], point[None, :], join.at,
                                   join.until)
    t = np.arange(join.at, join.until, 0.0005)
    dense = float(np.linalg.norm(path.position(t) - point, axis=1).min())
    assert exact <= min(dense, 0.3) + 1e-6 and dense - exact < 1e-3
    assert what.startswith("the drone at (")


def _still_path(point: list[float], start: float, end: float, spacing: float = 0.0) -> Moving:
    pos = np.array([[point, point]], dtype=float)
    return Moving(Trajectories(np.array([0.0, 1.0]), pos, np.zeros_like(pos)), start, start,
                  end, spacing)


def test_closest_approach_between_drones_at_rest(plan: Plan) -> None:
    """Relative cubics that are constant (both at rest) have hulls that only touch the
    bound: they are measured, not pruned (they were: nothing found, or a farther one)."""
    path = _still_path([0.0, 0.0, 10.0], 2.0, 6.0)
    near = _still_path([1.3, 0.0, 10.0], 0.0, 9.0)
    far = _still_path([5.0, 0.0, 10.0], 0.0, 9.0)
    none = np.zeros(0, dtype=np.intp)
    got, what = closest_approach(path, plan, none, [far, near], np.zeros((0, 3)), 2.0, 6.0)
    assert got == pytest.approx(1.3) and what.startswith("moving 1")


def test_a_column_counts_by_the_nearest_it_can_be(plan: Plan) -> None:
    """A descending drone is anywhere on its column: a column point 1 m from the next
    counts as the column stretch around it, never nearer than the column can be."""
    path = _still_path([1.42, 0.0, 5.5], 0.0, 4.0)  # between the points at 5 and 6 m
    columns = [_still_path([0.0, 0.0, z], 0.0, 4.0, spacing=1.0) for z in (5.0, 6.0)]
    got, _ = closest_approach(path, plan, np.zeros(0, dtype=np.intp), columns,
                              np.zeros((0, 3)), 0.0, 4.0)
    assert got <= 1.42 + 1e-9  # the column itself is 1.42 m away
    assert got == pytest.approx(1.42, abs=1e-6)  # not the 1.506 m to either point



def test_a_join_waits_until_the_failed_drone_has_left_its_slot(plan: Plan) -> None:
    """The failed drone hovers on its ring slot until show time 9 (heard again off its
    plan, held), then takes its way out: joining the ring at 8.4 s would meet it; the
    spare takes the track over after the ring, on its way to the square, and the check
    covers the failed drone's way out too."""
    assert plan.spares is not None
    slot = plan.formations[0].goals[TRACK]
    leave = plan_leave(plan, TRACK, 9.0, {}, start=slot)
    assert leave.held
    join = plan_join(plan, TRACK, plan.spares.points[0], earliest=3.0,
                     leaves={TRACK: leave})
    ring, square = plan.formations[0], plan.formations[1]
    assert ring.end < join.until <= square.end
    hovering = Moving(leave.trajectory, leave.at, 3.0, leave.until)
    path = Moving(join.trajectory, join.at, join.at, join.until)
    assert _dense_gap(plan, path, join.at, join.until, [], [hovering]) \
        >= plan.limits.min_separation


def test_no_window_while_the_failed_drone_is_still_on_its_slot(plan: Plan) -> None:
    """Leaving from the end of the ring's hold (a replaced drone holds its formation
    whole), it is on the slot until then: the ring offers no window, and none in motion
    comes before it leaves."""
    assert plan.spares is not None
    ring = plan.formations[0]
    leave = plan_leave(plan, TRACK, ring.end, {})
    assert not leave.held
    windows = join_windows(plan, TRACK, plan.spares.points[0], 0.0, leave)
    assert windows and all(w.arrive > leave.at for w in windows)
    assert join_windows(plan, TRACK, plan.spares.points[0], 0.0)[0].arrive < leave.at


def test_a_way_in_beyond_the_limits_is_refused(plan: Plan) -> None:
    """A way in is checked against the limits as the verifier checks a plan."""
    from groundctl.plan.verify import kinematics, limit_violations

    t = np.array([0.0, 4.0])  # rest to rest: peak speed 1.5 d / T, acceleration 6 d / T²
    slow = Trajectories(t, np.array([[[0.0, 0.0, 5.0], [2.0, 0.0, 5.0]]]),
                        np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]]))
    assert limit_violations(kinematics(slow, plan.limits), plan.limits) == []
    fast = Trajectories(t, np.array([[[0.0, 0.0, 5.0], [12.0, 0.0, 5.0]]]),
                        np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]]))
    said = limit_violations(kinematics(fast, plan.limits), plan.limits)
    assert said[0].startswith("horizontal speed reaches 4.50 m/s (limit 4.0")


def test_a_drone_replaced_before_is_still_an_obstacle_on_its_way_out(plan: Plan) -> None:
    """The same hovering drone, handed over as one a spare already replaced (the track is
    flown by the spare now): still what the join waits for and keeps clear of."""
    assert plan.spares is not None
    slot = plan.formations[0].goals[TRACK]
    leave = plan_leave(plan, TRACK, 9.0, {}, start=slot)
    join = plan_join(plan, TRACK, plan.spares.points[0], earliest=3.0,
                     replaced=[(TRACK, leave)])
    assert join.until > plan.formations[0].end
    hovering = Moving(leave.trajectory, leave.at, 3.0, leave.until)
    path = Moving(join.trajectory, join.at, join.at, join.until)
    assert _dense_gap(plan, path, join.at, join.until, [], [hovering]) \
        >= plan.limits.min_separation


def test_a_join_that_meets_a_drone_is_refused_and_retried_later(plan: Plan) -> None:
    """A drone down on the ground is no obstacle to a join in the air; one hovering at
    the ring slot (another spare, say) is, for the ring: the track is taken over on its
    way from the ring to the square, once it is clear of the ring slot."""
    assert plan.spares is not None
    ring, square = plan.formations[0], plan.formations[1]
    ring_slot = ring.goals[TRACK]
    join = plan_join(plan, TRACK, plan.spares.points[0], earliest=3.0,
                     static=ring_slot[None, :] + np.array([[0.0, 0.0, 0.5]]))
    assert ring.end < join.until <= square.arrive


def test_a_spare_takes_a_track_over_in_motion_between_two_formations(plan: Plan) -> None:
    """Between the ring and the square the track is in motion: the spare arrives on it
    with its velocity and acceleration (no jump in its setpoints), sooner than the
    square's rest, clear of everyone and within the limits the whole way."""
    assert plan.spares is not None
    ring, square = plan.formations[0], plan.formations[1]
    start = plan.spares.points[0]
    windows = join_windows(plan, TRACK, start, ring.end - 2.0)
    moving = [w for w in windows if w.arrive < square.arrive]
    assert moving and all(np.linalg.norm(w.vel) > 0.0 for w in moving)
    join = plan_join(plan, TRACK, start, earliest=ring.end - 2.0,
                     static=plan.spares.points[1:])
    assert ring.end < join.until < square.arrive
    assert join.until == pytest.approx(moving[0].arrive)
    p1, v1, _ = join.state(join.until)
    mine = plan.state_at(join.until)
    assert np.allclose(p1, mine.pos[TRACK], atol=1e-6)
    assert np.allclose(v1, mine.vel[TRACK], atol=1e-6)
    assert np.linalg.norm(v1) > 0.5
    # Its last step accelerates as the track does there (within the QP's tolerance).
    tau = np.linspace(join.trajectory.end - 0.05, join.trajectory.end - 1e-6, 5)
    a_end = join.trajectory.evaluate(tau)[2][0]
    assert np.abs(a_end - mine.acc[TRACK]).max() < 0.3
    # Within the limits, on a fine grid.
    t = np.linspace(0.0, join.trajectory.end, 4001)
    _, v, a = join.trajectory.evaluate(t)
    lim = plan.limits
    assert np.linalg.norm(v[0, :, :2], axis=1).max() <= lim.max_speed_h + 1e-3
    assert v[0, :, 2].max() <= lim.max_speed_up + 1e-3
    assert -v[0, :, 2].max() <= lim.max_speed_down + 1e-3
    assert np.linalg.norm(a[0], axis=1).max() <= lim.max_accel + 1e-2
    others = [j for j in range(plan.drones) if j != TRACK]
    path = Moving(join.trajectory, join.at, join.at, join.until)
    assert _dense_gap(plan, path, join.at, join.until, others) >= plan.limits.min_separation


def test_no_window_left_is_one_line(plan: Plan) -> None:
    assert plan.spares is not None
    with pytest.raises(PlanningError) as exc:
        plan_join(plan, TRACK, plan.spares.points[0], earliest=plan.duration)
    assert str(exc.value) == (f"transition 0: planner failed: no join (track {TRACK + 1}: "
                              "no formation left to join before the show ends)")


def test_a_spare_on_the_ground_climbs_first(plan: Plan) -> None:
    from groundctl.flight.joining import climb_time
    from groundctl.plan.spares import place_spares

    ground = place_spares(SpareSettings(count=1), plan)
    pad = ground.pads[0]
    join = plan_join(plan, TRACK, pad, earliest=3.0, climb=plan.takeoff_altitude)
    assert join.climb_s == pytest.approx(climb_time(plan, plan.takeoff_altitude))
    assert join.at - join.climb_s >= 3.0 - 1e-9
    top = pad + np.array([0.0, 0.0, plan.takeoff_altitude])
    assert np.allclose(join.state(join.at)[0], top, atol=1e-6)
    # Something 0.8 m beside its column: no window is clear while it climbs (the column
    # counts by the least its points, 1 m apart, stand for: 0.62 m).
    beside = pad + np.array([0.8, 0.0, 2.0])
    with pytest.raises(PlanningError, match=r"its climb from the pad would come 0\.6\d m "
                                            r"from the drone at"):
        plan_join(plan, TRACK, pad, earliest=3.0, climb=plan.takeoff_altitude,
                  static=beside[None, :])
