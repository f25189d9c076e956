"""The executor's replanner against its real MPC worker process and OSQP: who it replans,
what it streams them, and what it does with a stale or late trajectory."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest
from flight_fixtures import quick_plan

from groundctl.execute.mpc import MpcConfig, MpcRequest
from groundctl.execute.paths import Path, PathClocks, PathKind, sample_paths
from groundctl.execute.showclock import ShowClock
from groundctl.flight.mpcworker import MpcWorker
from groundctl.flight.replanning import STALE_S, Replanner
from groundctl.plan.plan import Plan

RATE_HZ = 10.0
MID_SHOW = 12.0  # mid-transition in the quick show: every drone at speed


@pytest.fixture(scope="module")
def plan() -> Plan:
    return quick_plan()


@pytest.fixture
def replanner(plan: Plan) -> Iterator[Replanner]:
    r = Replanner(plan, plan.mpc, RATE_HZ, deadline_s=5.0)  # a busy machine is no failure
    r.start()
    yield r
    r.close()


def _fleet(plan: Plan) -> tuple[dict[int, Path], PathClocks]:
    clock = ShowClock()
    clock.start(0.0)
    paths = {t + 1: Path(PathKind.PLAN, "the show plan", t) for t in range(plan.drones)}
    return paths, PathClocks(plan, clock, 0.0)


def _on_paths(paths: dict[int, Path], clocks: PathClocks, now: float
              ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    ids = sorted(paths)
    pos, vel, _ = sample_paths([paths[s] for s in ids], np.full(len(ids), now), clocks)
    return dict(zip(ids, pos, strict=True)), dict(zip(ids, vel, strict=True))


def _fly_until_solved(r: Replanner, paths: dict[int, Path], clocks: PathClocks,
                      positions: dict[int, np.ndarray], velocities: dict[int, np.ndarray],
                      now: float, sysid: int) -> list[tuple[str, str, dict]]:
    """Tick (every vehicle where it is) until ``sysid`` has a trajectory; the events."""
    events: list[tuple[str, str, dict]] = []
    give_up = time.monotonic() + 60.0  # the worker's imports on a busy machine
    while sysid not in r.results:
        assert time.monotonic() < give_up, (events, r.worker.late, r.worker.failed)
        events += r.tick(now, paths, clocks, positions, velocities, {})
        time.sleep(0.02)
    return events


def test_a_drone_pushed_off_its_path_is_replanned_back_from_where_it_is(
        replanner: Replanner, plan: Plan) -> None:
    paths, clocks = _fleet(plan)
    positions, velocities = _on_paths(paths, clocks, MID_SHOW)
    pushed = positions[5] + np.array([1.5, 0.0, 0.0])
    positions[5] = pushed
    events = _fly_until_solved(replanner, paths, clocks, positions, velocities, MID_SHOW, 5)
    assert [(e, f["system_id"]) for e, _, f in events if e == "mpc_started"] == [
        ("mpc_started", 5)]
    assert replanner.active == {5}  # nobody else was off, nor predicted in conflict
    res = replanner.results[5]
    assert res.status == "solved"
    # Streamed from where it is (1.5 m is beyond REINIT_M: a rejoin, not a nudge)...
    start = replanner.overrides(res.t0, lambda s: 0.0)[5][0]
    assert np.linalg.norm(start - pushed) < 0.2
    # ... back on its path by the end of the horizon, within its limits all the way.
    end_on_path = sample_paths([paths[5]], np.array([res.end]), clocks)[0][0]
    assert np.linalg.norm(res.pos[-1] - end_on_path) < 0.15
    assert np.max(np.linalg.norm(res.vel[:, :2], axis=1)) <= plan.limits.max_speed_h + 1e-6
    # Every neighbour kept at the separation limit at every step of what it flies.
    for sysid, path in paths.items():
        if sysid == 5:
            continue
        theirs = sample_paths([path] * len(res.pos), res.t0 + replanner.config.dt
                              * np.arange(len(res.pos)), clocks)[0]
        assert np.min(np.linalg.norm(res.pos - theirs, axis=1)) >= plan.limits.min_separation
    report = replanner.report()
    assert report["activations"] == 1 and report["vehicles"] == [5]
    assert report["solve_ms"]["solves"] >= 1 and report["late"] == 0
    assert set(report) == set(Replanner.off_report())


def test_a_trajectory_is_not_flown_past_stale_and_a_calm_fleet_is_left_alone(
        replanner: Replanner, plan: Plan) -> None:
    paths, clocks = _fleet(plan)
    for k in range(20):
        now = MID_SHOW + k / RATE_HZ
        positions, velocities = _on_paths(paths, clocks, now)
        calm = {s: p + np.array([0.1, -0.1, 0.05]) for s, p in positions.items()}  # calm air
        assert replanner.tick(now, paths, clocks, calm, velocities, {}) == []
    assert replanner.active == set() and replanner.overrides(now, lambda s: 0.0) == {}
    now += 1.0 / RATE_HZ
    positions, velocities = _on_paths(paths, clocks, now)
    positions[3] = positions[3] + np.array([0.0, 0.0, -1.2])
    _fly_until_solved(replanner, paths, clocks, positions, velocities, now, 3)
    t0 = replanner.results[3].t0
    assert set(replanner.overrides(t0, lambda s: 0.0)) == {3}
    # The worker fell behind (no new batch): after STALE_S the vehicle gets its path again.
    assert replanner.overrides(t0 + STALE_S + 0.05, lambda s: 0.0) == {}


def test_a_batch_past_its_deadline_is_dropped_and_counted_late(plan: Plan) -> None:
    worker = MpcWorker(MpcConfig(dt=1.0 / RATE_HZ, steps=30), deadline_s=1e-3)
    worker.start()
    try:
        give_up = time.monotonic() + 60.0
        while not worker.ready:
            assert time.monotonic() < give_up
            time.sleep(0.05)
        t = np.arange(31) / RATE_HZ
        ref = np.stack([2.0 * t, np.zeros_like(t), np.full_like(t, 10.0)], axis=1)
        vel = np.tile([2.0, 0.0, 0.0], (31, 1))
        request = MpcRequest(sysid=4, t0=0.0, p0=np.array([0.0, 1.5, 10.0]), v0=vel[0],
                             ref_pos=ref, ref_vel=vel, ref_acc=np.zeros((31, 3)),
                             limits=plan.limits)
        # A fresh worker builds the QP on its first batch: never back within 1 ms.
        assert worker.submit([request])
        while worker.busy:
            assert worker.collect() is None  # nothing to fly from a late batch
            time.sleep(0.002)
        assert (worker.late, worker.failed) == (1, 0)
        worker.deadline_s = 30.0  # the next one, given time, comes back and is used
        assert worker.submit([request])
        results = None
        while results is None:
            assert time.monotonic() < give_up
            results = worker.collect()
            time.sleep(0.002)
        assert results[4].status == "solved" and worker.late == 1
    finally:
        worker.close()
