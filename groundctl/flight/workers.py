"""Planning in a worker process, with deadlines, so the control loop keeps its GIL.

The flight executor's 10 Hz loop must not wait for the SCP planner: in a
thread of the same process the planner holds the GIL the loop needs, and
under load the loop falls behind.  :class:`PlannerPool` runs
:func:`~groundctl.flight.returning.plan_return` and
:func:`~groundctl.flight.returning.plan_leave` in a child process instead
(forked from the helpers' fork server, :mod:`groundctl.processes`, so no thread or
socket of the parent leaks into it).  The plan is
sent once, when a worker starts; a request carries only its own small
arguments.

Each request has a deadline in wall seconds.  Past it the caller gets
:class:`~groundctl.errors.PlanningTimeout`; the request is withdrawn if it had
not started, and its result is dropped if it had (the worker finishes it
first: with one worker the next request waits for that, within its own
deadline).  The planner's own errors (InfeasibleTransition, PlanningError)
reach the caller unchanged.  A worker that dies fails the request in flight
with :class:`~groundctl.errors.FlightError`, and a new worker is started at
once for the next one.  What to do about any of these (try again, give up,
land) is the caller's decision, not this module's.

Workers ignore SIGINT, SIGTERM and SIGHUP, which reach the whole process
group: the ground station decides what a stop signal means (land every
vehicle, which may need one more plan), and stops the workers itself.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import logging
import math
import os
import pickle
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from types import TracebackType
from typing import TYPE_CHECKING, Any

from groundctl.errors import FlightError, PlanningTimeout
from groundctl.processes import helper_context, leave_with, settle_helper

# Nothing here may import numpy at module level: a worker imports this module before
# its initializer runs, and the thread limits below only work before numpy loads.
if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from groundctl.execute.leaving import Join, Leave
    from groundctl.plan.plan import Plan
    from groundctl.plan.trajectory import Trajectories

log = logging.getLogger(__name__)

#: Wall seconds a worker may take to start (a fresh interpreter importing numpy,
#: scipy and osqp, and loading the plan).
START_DEADLINE_S = 60.0
#: Wall seconds :meth:`PlannerPool.close` waits for each killed worker to be reaped.
REAP_TIMEOUT_S = 2.0
#: The keyword under which :func:`~groundctl.flight.returning.plan_return` takes
#: fixed obstacles (k, 3), as :func:`~groundctl.flight.returning.plan_leave` does.
OBSTACLES_KEYWORD = "static"
#: How much nicer than the control loop a worker runs (os.nice): on a busy machine the
#: loop that streams setpoints must win the CPU from its own planning and MPC, which have
#: deadlines and safe fallbacks (measured: MPC started on five vehicles of a ground
#: station already late, and its solves made the loop later still, until the overload
#: guard held the show).
WORKER_NICE = 5


# -- the worker's side ---------------------------------------------------------------------

#: The plan every request of this worker is about (set by :func:`_initialise`).
_plan: Plan | None = None


def settle_worker(ground_station: int) -> None:
    """What every worker process does first (planning, MPC): ignore stop signals, go
    single-threaded (numpy loaded after this; a worker forked from the fork server has it
    single-threaded already) and leave with ``ground_station`` (its process id).  A
    worker's initializer takes its arguments as pickled bytes and unpickles them after
    this."""
    settle_helper()
    with contextlib.suppress(OSError):
        os.nice(WORKER_NICE)
    # Ignoring the stop signals, a worker whose ground station was killed outright
    # (SIGKILL, a crash) would live on for ever: it leaves once the ground station is
    # gone.  Not "once its parent is gone": its parent is the fork server, which in turn
    # lives as long as any process it forked (each holds the server's keep-alive pipe).
    leave_with(ground_station)


def _initialise(ground_station: int, plan_pickle: bytes) -> None:
    """Worker start-up: :func:`settle_worker`, load the plan, import the planner (so that
    the first request does not pay for it)."""
    settle_worker(ground_station)
    global _plan
    _plan = pickle.loads(plan_pickle)
    import groundctl.flight.returning  # noqa: F401  (the import is the point)


def _worker_pid() -> int:
    """The worker's process id (also the warm-up's no-op)."""
    return os.getpid()


def _run_pickled(request: bytes) -> Any:
    """Unpickle ``(function, with_plan, args, kwargs)`` and call ``function(plan, *args,
    **kwargs)`` (``function(*args, **kwargs)`` if not ``with_plan``)."""
    function, with_plan, args, kwargs = pickle.loads(request)
    if with_plan:
        if _plan is None:
            raise FlightError("the planning worker has no plan (it was started without "
                              "its initializer)")
        return function(_plan, *args, **kwargs)
    return function(*args, **kwargs)


# -- the parent's side ---------------------------------------------------------------------


class PlannerPool:
    """Worker processes that plan land-all returns and ways out of ``plan``, with deadlines.

    Use it as ``async with PlannerPool(plan) as pool:`` (started and warmed up on
    entry, closed on exit), or call :meth:`start`, :meth:`warm_up` and :meth:`close`.
    Its methods are meant for one event loop's thread.
    """

    def __init__(self, plan: Plan, max_workers: int = 1) -> None:
        if max_workers < 1:
            raise ValueError(f"`max_workers` must be at least 1, not {max_workers}")
        self.max_workers = max_workers
        """How many worker processes plan at the same time."""
        self._plan_pickle = pickle.dumps(plan, protocol=pickle.HIGHEST_PROTOCOL)
        self._executor: ProcessPoolExecutor | None = None
        self._warming: Future[Any] | None = None
        self._closed = False

    # -- life cycle --------------------------------------------------------------------

    def start(self) -> None:
        """Create the workers and start one of them loading (without waiting: see
        :meth:`warm_up`).  Does nothing if they are there already."""
        if self._closed:
            raise FlightError("the planning pool is closed; create a new one")
        if self._executor is None:
            self._executor = ProcessPoolExecutor(
                max_workers=self.max_workers, mp_context=helper_context(),
                initializer=_initialise, initargs=(os.getpid(), self._plan_pickle))
            # Processes start on demand: this no-op starts one, and loads the plan there.
            self._warming = self._executor.submit(_worker_pid)

    async def warm_up(self, deadline_s: float = START_DEADLINE_S) -> int:
        """Wait until a worker has started, loaded the plan and imported the planner;
        the process id of the worker that answered."""
        self.start()
        warming, self._warming = self._warming, None
        if warming is not None and not warming.done():
            return int(await self._wait(warming, self._executor, "loading the show's plan",
                                        deadline_s, time.monotonic() + deadline_s))
        return int(await self._call("loading the show's plan", deadline_s,
                                    _worker_pid, with_plan=False))

    def close(self) -> None:
        """Stop the workers without waiting for a plan in progress (killed: they ignore
        SIGTERM).  Requests still waiting fail with FlightError."""
        self._closed = True
        executor, self._executor, self._warming = self._executor, None, None
        if executor is not None:
            self._stop(executor)

    async def __aenter__(self) -> PlannerPool:
        self.start()
        try:
            await self.warm_up()
        except BaseException:
            self.close()
            raise
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # -- requests ----------------------------------------------------------------------

    async def plan_return(self, tracks: list[int], start: NDArray[np.float64],
                          deadline_s: float, obstacles: NDArray[np.float64] | None = None,
                          **kwargs: Any) -> Trajectories:
        """:func:`~groundctl.flight.returning.plan_return` of ``tracks`` from ``start``,
        in a worker, within ``deadline_s`` wall seconds.

        ``obstacles`` (k, 3), fixed points to keep clear of, go to the planner as
        :data:`OBSTACLES_KEYWORD` if it takes them (and are left out, with a warning, if
        it does not yet); further ``kwargs`` go to it as they are.  Raises
        PlanningTimeout past the deadline, FlightError if the worker dies, and the
        planner's InfeasibleTransition / PlanningError.
        """
        from groundctl.flight import returning

        if obstacles is not None:
            if OBSTACLES_KEYWORD in inspect.signature(returning.plan_return).parameters:
                kwargs = {**kwargs, OBSTACLES_KEYWORD: obstacles}
            elif len(obstacles):
                log.warning("plan_return takes no %r obstacles yet: the return is planned "
                            "without the %d given", OBSTACLES_KEYWORD, len(obstacles))
        return await self._call(
            f"planning the return of {len(tracks)} drone(s)", deadline_s,
            returning.plan_return, list(tracks), start, **kwargs)

    async def plan_leave(self, track: int, at: float, leaves: Mapping[int, Leave],
                         absent: Collection[int], static: NDArray[np.float64] | None,
                         start: NDArray[np.float64] | None, deadline_s: float, *,
                         what: str | None = None,
                         joins: Mapping[int, Join] | None = None,
                         replaced: Sequence[tuple[int, Leave]] = ()) -> Leave:
        """:func:`~groundctl.flight.returning.plan_leave` of ``track`` (same arguments),
        in a worker, within ``deadline_s`` wall seconds.

        ``what`` names the request in errors ("planning vehicle 5's way out"; by default
        it names the track).  Raises PlanningTimeout past the deadline, FlightError if
        the worker dies, and the planner's InfeasibleTransition / PlanningError.
        """
        from groundctl.flight import returning

        return await self._call(
            what or f"planning track {track}'s way out", deadline_s, returning.plan_leave,
            track, at, dict(leaves), list(absent), static, start, joins=dict(joins or {}),
            replaced=list(replaced))

    async def plan_join(self, track: int, pad: NDArray[np.float64], earliest: float,
                        deadline_s: float, *, absent: Collection[int],
                        leaves: Mapping[int, Leave], joins: Mapping[int, Join],
                        static: NDArray[np.float64] | None, climb: float,
                        climb_s: float | None = None, what: str | None = None,
                        replaced: Sequence[tuple[int, Leave]] = ()) -> Join:
        """:func:`~groundctl.flight.joining.plan_join` of a spare on ``pad`` into
        ``track`` (same arguments), in a worker, within ``deadline_s`` wall seconds.
        Raises PlanningTimeout past the deadline, FlightError if the worker dies, and
        PlanningError when no window works."""
        from groundctl.flight import joining

        return await self._call(
            what or f"planning a spare's way into track {track + 1}", deadline_s,
            joining.plan_join, track, pad, earliest, absent=list(absent),
            leaves=dict(leaves), joins=dict(joins), static=static, climb=climb,
            climb_s=climb_s, replaced=list(replaced))

    # -- machinery ---------------------------------------------------------------------

    async def _call(self, what: str, deadline_s: float, function: Callable[..., Any],
                    *args: Any, with_plan: bool = True, **kwargs: Any) -> Any:
        """``function(plan, *args, **kwargs)`` in a worker (without ``plan`` if not
        ``with_plan``), within ``deadline_s`` wall seconds."""
        if not deadline_s > 0.0:
            raise ValueError(f"`deadline_s` must be positive, not {deadline_s}")
        # Pickled here and now: a queued request is pickled later, in a thread of the
        # executor, and the caller's dicts and arrays may change meanwhile.
        request = pickle.dumps((function, with_plan, args, kwargs),
                               protocol=pickle.HIGHEST_PROTOCOL)
        self.start()
        executor = self._executor
        assert executor is not None
        due = time.monotonic() + deadline_s  # before submit(): it may be answered at once
        try:
            future = executor.submit(_run_pickled, request)
        except BrokenProcessPool:
            # The worker died while idle (or while finishing a request dropped at its
            # deadline): nobody was waiting for it, so this request gets a new one.
            executor = self._replace(executor)
            try:
                future = executor.submit(_run_pickled, request)
            except BrokenProcessPool as exc:
                raise self._died(executor, what, exc) from exc
        return await self._wait(future, executor, what, deadline_s, due)

    async def _wait(self, future: Future[Any], executor: ProcessPoolExecutor | None,
                    what: str, deadline_s: float, due: float) -> Any:
        """The result of ``future`` (from ``executor``) by ``due`` (time.monotonic()),
        ``deadline_s`` after the request."""
        # When the answer came, seen from the executor's thread: a busy event loop may
        # notice it only after the deadline, or notice the deadline only after it came.
        # Added before wrap_future's own callback, so it has run by the time the loop
        # sees the future done.
        arrived: list[float] = []
        future.add_done_callback(lambda _: arrived.append(time.monotonic()))
        waiting = asyncio.wrap_future(future)
        try:
            await asyncio.wait({waiting}, timeout=None if math.isinf(deadline_s)
                               else max(due - time.monotonic(), 0.0))
            # Decided on the executor's future and the time it was answered, not on what
            # the loop has seen of it yet.
            if not arrived or arrived[0] > due:
                raise PlanningTimeout(what, deadline_s)
            try:
                return future.result()
            except BrokenProcessPool as exc:
                raise self._died(executor, what, exc) from exc
            except CancelledError:
                # Not the caller (that would have been raised by the wait above): the
                # request itself was withdrawn, which only close() does.
                raise FlightError(f"the planning pool was closed while {what}") from None
        finally:
            # Past the deadline, or the caller was cancelled: withdraw the request if it
            # has not started (cancelling ``waiting`` cancels ``future``); a running one
            # cannot be stopped, and its result is dropped.
            if not waiting.done():
                waiting.cancel()
            elif not waiting.cancelled():
                waiting.exception()  # seen through ``future``: not "never retrieved"

    def _died(self, executor: ProcessPoolExecutor | None, what: str,
              exc: BrokenProcessPool) -> FlightError:
        """The error for a request whose worker died; a new worker starts for the next."""
        if executor is not None and executor is self._executor and not self._closed:
            self._replace(executor)
        if self._closed:
            return FlightError(f"the planning pool was closed while {what}")
        return FlightError(f"the planning worker died while {what} ({exc}); a new worker "
                           "is starting for the next request")

    def _replace(self, broken: ProcessPoolExecutor) -> ProcessPoolExecutor:
        """Stop ``broken`` and start (and warm up) a new executor in its place."""
        if self._executor is broken:
            self._executor = None
        self._stop(broken)
        self.start()
        assert self._executor is not None
        return self._executor

    @staticmethod
    def _stop(executor: ProcessPoolExecutor) -> None:
        """Shut ``executor`` down at once and kill its workers."""
        # A private attribute, but the only handle on the processes; shutdown() drops it.
        processes = list((getattr(executor, "_processes", None) or {}).values())
        executor.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            if process.is_alive():
                process.kill()  # SIGKILL: they ignore SIGTERM
        for process in processes:
            process.join(REAP_TIMEOUT_S)
