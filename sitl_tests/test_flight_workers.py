"""Planning in a worker process: the same plans as in-process, deadlines, dead workers.

One pool (one spawned worker, about half a second to start) serves most tests;
the ones that kill or close a worker get their own.  pytest-asyncio is not a
dependency: each test drives its coroutine with ``asyncio.run``.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import os
import pickle
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from flight_fixtures import quick_plan

from groundctl import errors
from groundctl.errors import (
    FlightError,
    GroundctlError,
    PlanningError,
    PlanningTimeout,
    SeparationConflict,
)
from groundctl.execute.leaving import Leave, leave_time
from groundctl.flight import returning
from groundctl.flight.returning import column, plan_leave, plan_return
from groundctl.flight.workers import OBSTACLES_KEYWORD, WORKER_NICE, PlannerPool

#: Wall seconds: generous, so a loaded machine does not fail a test that is not about them.
DEADLINE_S = 30.0


@pytest.fixture(scope="module")
def pool() -> Iterator[PlannerPool]:
    pool = PlannerPool(quick_plan())
    pool.start()
    asyncio.run(pool.warm_up())
    yield pool
    pool.close()


def _takeoff_start() -> tuple[list[int], np.ndarray]:
    """Every track, from the start of the show: the fleet rising into the ring (the
    straight lines cross, so the planner has work to do, about 0.3 s of it)."""
    plan = quick_plan()
    return list(range(plan.drones)), plan.state_at(0.0).pos


def _crowded_start() -> tuple[list[int], np.ndarray]:
    """Every track from the square, with track 1 10 cm from track 0: nothing can
    separate them in time."""
    plan = quick_plan()
    start = plan.state_at(20.0).pos.copy()
    start[1] = start[0] + np.array([0.1, 0.0, 0.0])
    return list(range(plan.drones)), start


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_the_worker_runs_nicer_than_the_control_loop(pool: PlannerPool) -> None:
    pid = asyncio.run(pool.warm_up())
    mine = os.getpriority(os.PRIO_PROCESS, 0)
    assert os.getpriority(os.PRIO_PROCESS, pid) == min(mine + WORKER_NICE, 19)


# -- same plans as in-process --------------------------------------------------------------


def test_a_return_planned_by_the_worker_is_the_one_planned_in_process(
        pool: PlannerPool) -> None:
    tracks, start = _takeoff_start()
    got = asyncio.run(pool.plan_return(tracks, start, DEADLINE_S))
    want = plan_return(quick_plan(), tracks, start)
    assert got.pos.shape == want.pos.shape
    assert np.allclose(got.pos, want.pos)
    assert got.end == pytest.approx(want.end)


def test_a_way_out_planned_by_the_worker_is_the_one_planned_in_process(
        pool: PlannerPool) -> None:
    plan = quick_plan()
    at = leave_time(plan, 4, 1.0)
    assert at is not None
    got = asyncio.run(pool.plan_leave(4, at, {}, (), None, None, DEADLINE_S))
    want = plan_leave(plan, 4, at, {})
    assert isinstance(got, Leave)
    assert got.at == want.at and not got.held
    assert got.trajectory.end == pytest.approx(want.trajectory.end)
    t = np.linspace(at, want.until, 200)
    assert np.allclose(got.position(t), want.position(t))


def test_a_way_out_around_another_way_out_goes_to_the_worker_whole(pool: PlannerPool) -> None:
    plan = quick_plan()
    at = leave_time(plan, 0, 1.0)
    assert at is not None
    first = plan_leave(plan, 0, at, {})
    got = asyncio.run(pool.plan_leave(1, at, {0: first}, [8], np.empty((0, 3)), None,
                                      DEADLINE_S, what="planning vehicle 2's way out"))
    want = plan_leave(plan, 1, at, {0: first}, [8], np.empty((0, 3)))
    t = np.linspace(at, want.until, 200)
    assert np.allclose(got.position(t), want.position(t))


def test_obstacles_the_return_planner_does_not_take_yet_are_left_out_with_a_warning(
        pool: PlannerPool, caplog: pytest.LogCaptureFixture) -> None:
    if OBSTACLES_KEYWORD in inspect.signature(returning.plan_return).parameters:
        pytest.skip("plan_return takes obstacles now: they are passed through")
    tracks, start = _takeoff_start()
    with caplog.at_level(logging.WARNING, logger="groundctl.flight.workers"):
        got = asyncio.run(pool.plan_return(tracks, start, DEADLINE_S,
                                           obstacles=column(np.array([50.0, 50.0, 5.0]))))
    assert np.allclose(got.pos, plan_return(quick_plan(), tracks, start).pos)
    assert "plan_return takes no 'static' obstacles yet" in caplog.text
    assert "without the 6 given" in caplog.text


# -- deadlines -----------------------------------------------------------------------------


def test_a_plan_past_its_deadline_raises_and_the_pool_serves_the_next_request(
        pool: PlannerPool) -> None:
    tracks, start = _takeoff_start()
    with pytest.raises(PlanningTimeout) as caught:
        asyncio.run(pool.plan_return(tracks, start, 1e-4))
    assert caught.value.deadline_s == 1e-4
    assert caught.value.what == "planning the return of 9 drone(s)"
    assert str(caught.value) == ("planning the return of 9 drone(s) took longer than its "
                                 "0.0001 s deadline")
    assert isinstance(caught.value, FlightError)
    # The late one is still being planned; this one waits for it, then gets its own.
    got = asyncio.run(pool.plan_return(tracks, start, DEADLINE_S))
    assert np.allclose(got.pos, plan_return(quick_plan(), tracks, start).pos)


def test_a_way_out_past_its_deadline_is_named_as_the_caller_said(pool: PlannerPool) -> None:
    plan = quick_plan()
    at = leave_time(plan, 4, 1.0)
    assert at is not None
    with pytest.raises(PlanningTimeout, match=r"^planning vehicle 5's way out took longer "
                                              r"than its 0\.0001 s deadline$"):
        asyncio.run(pool.plan_leave(4, at, {}, (), None, None, 1e-4,
                                    what="planning vehicle 5's way out"))


def test_the_deadline_must_be_positive(pool: PlannerPool) -> None:
    tracks, start = _takeoff_start()
    with pytest.raises(ValueError, match=r"`deadline_s` must be positive, not 0\.0"):
        asyncio.run(pool.plan_return(tracks, start, 0.0))


def test_the_event_loop_runs_on_while_the_worker_plans(pool: PlannerPool) -> None:
    tracks, start = _takeoff_start()

    async def scenario() -> int:
        turns = 0
        planning = True

        async def spin() -> None:
            nonlocal turns
            while planning:
                turns += 1
                await asyncio.sleep(0)

        spinner = asyncio.create_task(spin())
        try:
            await pool.plan_return(tracks, start, DEADLINE_S)
        finally:
            planning = False
            await spinner
        return turns

    assert asyncio.run(scenario()) > 20


# -- the planner's errors ------------------------------------------------------------------


def test_an_infeasible_return_raises_the_planners_error_unchanged(pool: PlannerPool) -> None:
    tracks, start = _crowded_start()
    with pytest.raises(PlanningError) as in_process:
        plan_return(quick_plan(), tracks, start)
    with pytest.raises(PlanningError) as caught:
        asyncio.run(pool.plan_return(tracks, start, DEADLINE_S))
    assert type(caught.value) is type(in_process.value) is SeparationConflict
    assert vars(caught.value) == vars(in_process.value)
    assert str(caught.value) == str(in_process.value)


def test_a_blocked_landing_column_raises_the_planners_error_unchanged(
        pool: PlannerPool) -> None:
    plan = quick_plan()
    at = leave_time(plan, 2, 1.0)
    assert at is not None
    blocked = column(plan.landing[2] + np.array([0.3, 0.0, 1.0]))
    with pytest.raises(PlanningError) as caught:
        asyncio.run(pool.plan_leave(2, at, {}, (), blocked, None, DEADLINE_S))
    assert caught.value.status == "landing column not clear"
    assert "above track 2's landing spot" in caught.value.detail


def _every_error() -> list[GroundctlError]:
    return [
        errors.ShowFileError("shows/star.toml", "formation 3 'star'", "40 drones"),
        errors.InfeasibleTransition(2, "star", 12.5, 8.0, "too far"),
        errors.PlanningError(1, "max iterations", "slack 0.2 m"),
        errors.PlanFileError("x.plan", "not a plan"),
        errors.UnsafePlan(["a too close", "b too high"]),
        errors.LinkError("socket closed"),
        errors.CommandRefused(3, "ARM", "DENIED", "not ready"),
        errors.CommandTimeout(3, "TAKEOFF", 3, 1.5),
        errors.VehicleLost(4, 2.5),
        errors.PreflightFailed({1: ["gps"], 2: ["battery", "ekf"]}),
        errors.FlightError("the flight could not go on"),
        errors.PlanningTimeout("planning vehicle 5's way out", 2.0),
        errors.SimulatorError("no such vehicle"),
    ]


@pytest.mark.parametrize("error", _every_error(), ids=lambda e: type(e).__name__)
def test_every_error_crosses_a_process_boundary_with_its_data(error: GroundctlError) -> None:
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is type(error)
    assert str(back) == str(error) and back.args == error.args
    assert vars(back) == vars(error)


def test_a_planning_timeout_names_the_request_and_the_deadline() -> None:
    error = PlanningTimeout("planning vehicle 5's way out", 2.0)
    assert str(error) == "planning vehicle 5's way out took longer than its 2.0 s deadline"
    assert error.reason == str(error) and error.exit_code == errors.EXIT_UNSAFE


# -- dead workers, stop signals, closing ---------------------------------------------------


def test_a_killed_worker_fails_the_request_in_flight_and_the_next_one_gets_a_new_one(
) -> None:
    tracks, start = _takeoff_start()

    async def scenario() -> tuple[BaseException | None, Any, int, int]:
        async with PlannerPool(quick_plan()) as pool:
            first = await pool.warm_up()
            request = asyncio.create_task(pool.plan_return(tracks, start, DEADLINE_S))
            await asyncio.sleep(0)  # submitted; the plan takes far longer than this
            os.kill(first, signal.SIGKILL)
            failed: BaseException | None = None
            try:
                await request
            except BaseException as exc:
                failed = exc
            traj = await pool.plan_return(tracks, start, DEADLINE_S)
            second = await pool.warm_up()
        return failed, traj, first, second

    failed, traj, first, second = asyncio.run(scenario())
    assert type(failed) is FlightError
    assert str(failed).startswith("the planning worker died while planning the return of "
                                  "9 drone(s) (")
    assert second != first
    assert np.allclose(traj.pos, plan_return(quick_plan(), tracks, start).pos)


def test_workers_ignore_stop_signals_and_close_kills_them() -> None:
    tracks, start = _takeoff_start()

    async def scenario() -> tuple[int, int, BaseException | None]:
        pool = PlannerPool(quick_plan())
        pool.start()
        pid = await pool.warm_up()
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):
            os.kill(pid, getattr(signal, name))
        await pool.plan_return(tracks, start, DEADLINE_S)
        same = await pool.warm_up()
        # Closing while a plan is in progress fails it at once, and the worker is gone.
        request = asyncio.create_task(pool.plan_return(tracks, start, DEADLINE_S))
        await asyncio.sleep(0)
        pool.close()
        failed: BaseException | None = None
        try:
            await request
        except BaseException as exc:
            failed = exc
        return pid, same, failed

    pid, same, failed = asyncio.run(scenario())
    assert same == pid
    assert not _alive(pid)
    assert type(failed) is FlightError
    assert str(failed) == "the planning pool was closed while planning the return of 9 drone(s)"


def test_a_closed_pool_takes_no_more_requests() -> None:
    pool = PlannerPool(quick_plan())
    pool.close()
    tracks, start = _takeoff_start()
    with pytest.raises(FlightError, match="the planning pool is closed; create a new one"):
        asyncio.run(pool.plan_return(tracks, start, DEADLINE_S))


_ORPHAN_PARENT = """
import asyncio, sys
sys.path.insert(0, sys.argv[1])
from flight_fixtures import quick_plan
from groundctl.flight.workers import PlannerPool

async def main() -> None:
    pool = PlannerPool(quick_plan())
    print(await pool.warm_up(), flush=True)
    await asyncio.sleep(600)

if __name__ == "__main__":
    asyncio.run(main())
"""


def test_a_worker_whose_ground_station_is_killed_outright_does_not_live_on(
        tmp_path: Path) -> None:
    """Workers ignore the stop signals (the ground station decides what they mean), so a
    ground station killed with SIGKILL left them running for ever; they leave with it."""
    script = tmp_path / "parent.py"
    script.write_text(_ORPHAN_PARENT)
    parent = subprocess.Popen([sys.executable, str(script), str(Path(__file__).parent)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        worker = int(parent.stdout.readline())
        os.kill(worker, 0)  # alive
        parent.kill()
        parent.wait(10)
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            try:
                os.kill(worker, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            os.kill(worker, signal.SIGKILL)
            raise AssertionError(f"worker {worker} outlived its killed ground station")
    finally:
        if parent.poll() is None:
            parent.kill()
