"""One path per vehicle: each kind sampled on its clock, and the views the sequence gives."""

from __future__ import annotations

import numpy as np
import pytest
from test_execute_support import make_plan

from groundctl.execute.leaving import Leave
from groundctl.execute.paths import (
    Path,
    PathClocks,
    PathKind,
    position_on_show_clock,
    sample_paths,
)
from groundctl.execute.sequence import StreamRequest
from groundctl.execute.showclock import ShowClock
from groundctl.plan.trajectory import Trajectories


def _running(show_time: float, now: float = 0.0) -> ShowClock:
    clock = ShowClock()
    clock.start(now - show_time)
    return clock


def _leave(plan, track: int, at: float) -> Leave:  # type: ignore[no-untyped-def]
    start, end = plan.state_at(at).pos[track], plan.landing_hover[track]
    pos = np.stack([start, end])[None]
    return Leave(at, Trajectories(np.array([0.0, 4.0]), pos, np.zeros_like(pos)))


def test_every_kind_is_sampled_on_its_own_clock() -> None:
    plan = make_plan()
    leave = _leave(plan, 1, 5.0)
    back = Trajectories(np.array([0.0, 4.0]), np.stack([plan.home + np.array([0, 0, 3.0]),
                                                         plan.landing_hover], axis=1),
                        np.zeros((plan.drones, 2, 3)))
    ret_clock = _running(1.0)
    paths = [Path(PathKind.PLAN, "plan", 0),
             Path(PathKind.HOLD, "hold", 1, point=(1.0, 2.0, 3.0)),
             Path(PathKind.WAY_OUT, "out", 1, leave=leave),
             Path(PathKind.RETURN, "return", 2, row=2),
             Path(PathKind.LANDING_POINT, "down", 0, point=(4.0, 5.0, 6.0))]
    clocks = PathClocks(plan, _running(6.0), returns=back, return_clock=ret_clock)
    pos, vel, acc = sample_paths(paths, np.zeros(5), clocks)
    state = plan.state_at(6.0)
    np.testing.assert_allclose(pos[0], state.pos[0])
    np.testing.assert_allclose(vel[0], state.vel[0])
    np.testing.assert_allclose(pos[1], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(pos[2], leave.state(6.0)[0])
    np.testing.assert_allclose(pos[3], back.evaluate(1.0, np.array([2]))[0][0])
    np.testing.assert_allclose(pos[4], [4.0, 5.0, 6.0])
    assert not vel[[1, 4]].any() and not acc[[1, 4]].any()
    # Each vehicle at its own instant (its lead): the way out before it begins is the plan.
    pos, _, _ = sample_paths(paths[2:3], np.array([-2.0]), clocks)
    np.testing.assert_allclose(pos[0], plan.state_at(4.0).pos[1])
    # A held way out: the point until the way out's show time, then the way out.
    held = Path(PathKind.WAY_OUT, "held", 1, point=(9.0, 9.0, 9.0), leave=leave)
    np.testing.assert_allclose(position_on_show_clock(held, plan, 4.9), [9.0, 9.0, 9.0])
    np.testing.assert_allclose(position_on_show_clock(held, plan, 5.5), leave.state(5.5)[0])


def test_the_requests_views_by_kind() -> None:
    plan = make_plan()
    leave = _leave(plan, 1, 5.0)
    req = StreamRequest(4.0, True, frozenset({1, 2, 3}), paths={
        1: Path(PathKind.PLAN, "plan", 0),
        2: Path(PathKind.WAY_OUT, "held", 1, point=(9.0, 9.0, 9.0), leave=leave),
        3: Path(PathKind.RETURN, "return", 2, row=0)})
    assert req.fixed == {2: (9.0, 9.0, 9.0)} and req.leaves == {} and req.follow == {3: 0}
    later = StreamRequest(5.5, True, req.sysids, paths=req.paths)
    assert later.fixed == {} and later.leaves == {2: leave}


def test_paths_refuse_what_they_cannot_sample() -> None:
    with pytest.raises(ValueError, match="a hold path needs a `point`"):
        Path(PathKind.HOLD, "x", 0)
    with pytest.raises(ValueError, match="a way_out path needs a `leave`"):
        Path(PathKind.WAY_OUT, "x", 0)
    with pytest.raises(ValueError, match="a return path needs a `row`"):
        Path(PathKind.RETURN, "x", 0)
    plan = make_plan()
    with pytest.raises(ValueError, match="`return` paths need"):
        sample_paths([Path(PathKind.RETURN, "x", 0, row=0)], np.zeros(1), PathClocks(plan, None))
    with pytest.raises(ValueError, match=r"`at` must have shape \(1,\)"):
        sample_paths([Path(PathKind.PLAN, "x", 0)], np.zeros(2), PathClocks(plan, None))
