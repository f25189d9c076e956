"""One drone leaving a show in progress: planned around the drones that fly on."""

from __future__ import annotations

import numpy as np
import pytest
from flight_fixtures import quick_plan

from groundctl.errors import PlanningError
from groundctl.execute.authority import beyond, scaled_limits
from groundctl.execute.leaving import LANDING_MARGIN_M, LEAVE_LEAD_S, leave_duration, leave_time
from groundctl.flight.returning import assign_landing, column, plan_leave, plan_return
from groundctl.plan.scp_quad import plan_among
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import Limits, PlannerSettings

LIM = Limits(min_separation=1.5, min_alt=0.0, max_alt=100.0)


def _line_flying_east(times: np.ndarray) -> np.ndarray:
    """Five drones along y = 0 at 10 m, 3 m apart, flying east at 1.6 m/s."""
    x = (np.arange(5) * 3.0 - 12.0)[:, None] + 1.6 * np.asarray(times)[None, :]
    return np.stack([x, np.zeros_like(x), np.full_like(x, 10.0)], axis=2)


def test_a_drone_crosses_a_line_of_moving_drones_without_touching_them() -> None:
    start, goal = np.array([[0.0, -5.0, 10.0]]), np.array([[0.0, 5.0, 10.0]])
    res = plan_among(1, "cross", start, goal, 8.0, LIM, PlannerSettings(), _line_flying_east)
    t = np.linspace(0.0, 8.0, 4001)
    me = res.trajectories.evaluate(t)[0][0]
    closest = float(np.linalg.norm(_line_flying_east(t) - me[None], axis=2).min())
    straight = start + (goal - start) * (t / 8.0)[:, None]
    assert float(np.linalg.norm(_line_flying_east(t) - straight[None], axis=2).min()) < 0.5
    assert closest >= 1.5 - 1e-3
    np.testing.assert_allclose(res.trajectories.pos[0, [0, -1]], [start[0], goal[0]])
    assert res.max_slack < 5e-3


def test_a_drone_handed_over_in_motion_arrives_with_the_velocity_asked() -> None:
    """A spare joining a track mid-transition: it crosses the moving line and arrives at
    its goal with the track's velocity and the last step's acceleration, within the
    limits; an end state it cannot reach in the time is a PlanningError."""
    start, goal = np.array([[0.0, -5.0, 10.0]]), np.array([[2.0, 5.0, 11.0]])
    vel, acc = np.array([[1.5, 1.0, 0.2]]), np.array([[0.4, -0.3, 0.0]])
    res = plan_among(1, "join", start, goal, 8.0, LIM, PlannerSettings(), _line_flying_east,
                     goal_vel=vel, goal_acc=acc)
    tr = res.trajectories
    np.testing.assert_allclose(tr.pos[0, [0, -1]], [start[0], goal[0]])
    np.testing.assert_allclose(tr.vel[0, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(tr.vel[0, -1], vel[0], atol=1e-9)
    t = np.linspace(0.0, 8.0, 4001)
    p, v, a = tr.evaluate(t)
    np.testing.assert_allclose(a[0, -1], acc[0], atol=0.05)
    assert np.linalg.norm(v[0, :, :2], axis=1).max() <= LIM.max_speed_h + 1e-3
    assert np.linalg.norm(a[0], axis=1).max() <= LIM.max_accel + 1e-2
    closest = float(np.linalg.norm(_line_flying_east(t) - p[0][None], axis=2).min())
    assert closest >= 1.5 - 1e-3
    # Climbing at the end of a descent: the cubic guess dips far below the floor; the
    # plan keeps within the altitude limits (the guess is clipped, the box never empty).
    low = Limits(min_separation=1.5, min_alt=2.0, max_alt=100.0)
    dip = plan_among(1, "join", np.array([[0.0, 0.0, 10.0]]), np.array([[0.0, 4.0, 5.0]]),
                     22.0, low, PlannerSettings(), lambda times: np.zeros((0, len(times), 3)),
                     goal_vel=np.array([[0.0, 0.5, 2.0]]))
    z = dip.trajectories.evaluate(np.linspace(0.0, 22.0, 2001))[0][0, :, 2]
    assert z.min() >= low.min_alt - 0.01  # knots on the floor, the cubic between them
    np.testing.assert_allclose(dip.trajectories.vel[0, -1], [0.0, 0.5, 2.0], atol=1e-9)
    # Arriving 4 m/s the wrong way after 2 s from rest 0.5 m behind: beyond the limits.
    with pytest.raises(PlanningError):
        plan_among(1, "join", np.array([[0.0, 0.0, 10.0]]), np.array([[0.5, 0.0, 10.0]]),
                   2.0, LIM, PlannerSettings(), lambda times: np.zeros((0, len(times), 3)),
                   goal_vel=np.array([[-4.0, 0.0, 0.0]]))


def test_leave_time_is_the_next_rest_on_a_formation_that_leaves_time_to_get_home() -> None:
    plan = quick_plan()
    ring, square, _landing = plan.formations
    # In the ring's hold, with the lead to spare: right away (lead later).
    assert leave_time(plan, 0, ring.arrive) == pytest.approx(ring.arrive + LEAVE_LEAD_S)
    # Too late in the ring's hold: the square's arrival.
    assert leave_time(plan, 0, ring.end - 1.0) == pytest.approx(square.arrive)
    # Past the last formation before landing: nothing left, it lands with the others.
    assert leave_time(plan, 0, square.end) is None
    # A drone a spare replaces holds its formation whole: the end of the hold.
    assert leave_time(plan, 0, ring.arrive, after_hold=True) == pytest.approx(ring.end)
    assert leave_time(plan, 0, ring.end - 1.0, after_hold=True) == pytest.approx(square.end)
    assert leave_time(plan, 0, square.end, after_hold=True) is None
    at = leave_time(plan, 4, 0.0)
    assert at is not None and at + leave_duration(plan, 4, at) <= plan.duration


@pytest.mark.parametrize("track", [0, 4, 8])
def test_the_way_out_keeps_the_limit_against_the_show_flying_on(track: int) -> None:
    plan = quick_plan()
    at = leave_time(plan, track, 1.0)
    assert at is not None
    leave = plan_leave(plan, track, at, {})
    np.testing.assert_allclose(leave.state(at)[0], plan.state_at(at).pos[track], atol=1e-9)
    np.testing.assert_allclose(leave.state(leave.until)[0], plan.landing_hover[track],
                               atol=1e-9)
    t = np.linspace(at, plan.duration, 4000)
    others = np.array([j for j in range(plan.drones) if j != track])
    gap = np.linalg.norm(plan.trajectories.evaluate(t, others)[0] - leave.position(t)[None],
                         axis=2)
    assert float(gap.min()) >= plan.limits.min_separation - 1e-3


def test_a_second_way_out_avoids_the_first_and_a_blocked_column_is_refused() -> None:
    plan = quick_plan()
    at = leave_time(plan, 0, 1.0)
    assert at is not None
    first = plan_leave(plan, 0, at, {})
    second = plan_leave(plan, 1, at, {0: first})
    t = np.linspace(at, max(first.until, second.until), 2000)
    assert float(np.linalg.norm(first.position(t) - second.position(t), axis=1).min()) \
        >= plan.limits.min_separation - 1e-3
    # Somebody standing right under its landing point: no way to land there.
    blocked = column(plan.landing[2] + np.array([0.3, 0.0, 1.0]))
    with pytest.raises(PlanningError):
        plan_leave(plan, 2, at, {}, static=blocked)


def test_a_drone_holding_off_its_plan_is_an_obstacle_where_it_holds() -> None:
    plan = quick_plan()
    at = leave_time(plan, 1, 1.0)
    assert at is not None
    # Track 0 was heard again right on the way track 1 would take out, and holds there
    # until long after track 1 has gone by.
    alone = plan_leave(plan, 1, at, {})
    hold = alone.state(at + alone.trajectory.end / 2)[0]
    held = plan_leave(plan, 0, alone.until + 2.0, {}, start=hold)
    assert held.held and np.allclose(held.state(at)[0], hold)
    second = plan_leave(plan, 1, at, {0: held})
    t = np.linspace(at, second.until, 3000)
    assert float(np.linalg.norm(second.position(t) - hold, axis=1).min()) \
        >= plan.limits.min_separation - 1e-3
    # Not so if it were taken to fly its plan until its way out begins.
    assert float(np.linalg.norm(alone.position(t) - hold, axis=1).min()) < 0.1


def test_a_return_with_a_weak_vehicle_is_planned_within_what_it_can_fly() -> None:
    # Land-all from mid-transition (show time 11 s): at full limits the way home asks
    # more than a vehicle at 60 % can fly; at its authority it asks nothing beyond it,
    # and takes longer.
    plan = quick_plan()
    tracks = list(range(plan.drones))
    start = plan.state_at(11.0).pos
    weak = scaled_limits(plan.limits, 0.6)

    def asks(traj: Trajectories) -> str | None:
        _, vel, acc = traj.evaluate(traj.dense_times(16))
        return beyond(weak, vel.reshape(-1, 3), acc.reshape(-1, 3))
    full = plan_return(plan, tracks, start)
    slow = plan_return(plan, tracks, start, authority=0.6)
    assert asks(full) is not None
    assert asks(slow) is None
    assert slow.times[-1] > full.times[-1]
    with pytest.raises(ValueError, match="authority must be in"):
        plan_return(plan, tracks, start, authority=0.0)


def test_no_drone_lands_within_the_limit_and_its_landing_margin_of_a_drone_down() -> None:
    # Track 8's drone came down 1.6 m beside track 0's spot, outside the grid (beyond the
    # 1.5 m limit, but a drone lands within LANDING_MARGIN_M of its spot): track 0 is sent
    # to the spot left free instead.
    plan = quick_plan()
    tracks = list(range(plan.drones - 1))
    spot = plan.landing_hover[0]
    start = plan.state_at(11.0).pos[tracks]
    down = np.array([[spot[0] - 1.6, spot[1], 0.0]])
    goals = assign_landing(plan, tracks, start, down)
    gap = np.linalg.norm(goals[:, :2] - down[:, :2], axis=1)
    assert gap.min() >= plan.limits.min_separation + LANDING_MARGIN_M
    assert len({tuple(g) for g in goals.round(3)}) == len(tracks)  # one spot each
    far = np.array([[spot[0] - 1.5 - LANDING_MARGIN_M - 0.1, spot[1], 0.0]])
    assert np.allclose(assign_landing(plan, tracks, start, far), plan.landing_hover[tracks])


def test_a_points_distance_to_the_fence_is_to_its_nearest_edge_inside_or_out() -> None:
    """What a clear landing spot keeps from the geofence (and what makes a point on the
    fence line count as inside it): the nearest edge, its ends included."""
    from groundctl.show.checks import inside_polygon, polygon_edge_distance

    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    points = np.array([[5.0, 5.0, 3.0],    # the middle: 5 m from every side
                       [1.0, 4.0, 0.0],    # inside, 1 m from the west side
                       [13.0, 14.0, 0.0],  # outside, beyond a corner: 5 m from it
                       [10.0, 2.5, 0.0]])  # on the east side
    np.testing.assert_allclose(polygon_edge_distance(points, square), [5.0, 1.0, 5.0, 0.0])
    assert inside_polygon(points, square).tolist() == [True, True, False, True]
