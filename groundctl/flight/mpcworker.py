"""MPC solves in a worker process, one batch per tick, never waited for.

The control loop hands a batch of :class:`~groundctl.execute.mpc.MpcRequest` to
:meth:`MpcWorker.submit` and goes on; on a later tick :meth:`MpcWorker.collect`
returns the results if they are ready.  A batch that took longer than its
deadline is discarded (the caller keeps streaming the previous trajectory,
which carries on along its last velocity) and counted late; only one batch is
ever in flight, so a slow machine degrades to fewer solves, never to a queue.

Two times, two meanings:

* the *deadline* is the flight's: measured on the runner's clock, as real seconds at
  its pace (``clock.wall_interval``).  In flight that is real time.  In a paced dry-run
  (:class:`~groundctl.clock.PacedClock`) on a machine too busy to keep the pace, the
  clock waits for the late loops and the deadline with it, as every other timeout of
  the rehearsal does;
* the worker's *budgets* (the batch's, and how long a solve that OSQP stopped at its
  wall-time limit is resumed) are CPU seconds of the worker's thread: the work the
  solve may cost.  A worker preempted on a busy machine used to hit its wall limits
  with the work not done and fall back to stopping the vehicle (a weak one, stopped
  on its first climb, was 3.7 m off its path two seconds later); now it finishes, and
  if that is past the deadline the batch is dropped and the vehicle keeps what it flew.

The worker keeps one :class:`~groundctl.execute.mpc.MpcController` per vehicle
between batches (OSQP set up once per vehicle, warm-started tick to tick) and
solves each batch with :func:`~groundctl.execute.mpc.solve_in_priority`.  It
ignores stop signals (the ground station stops it) and runs single-threaded.
"""

from __future__ import annotations

import logging
import os
import pickle
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING

from groundctl.flight.workers import settle_worker
from groundctl.processes import helper_context

if TYPE_CHECKING:  # numpy must load in the worker only after its thread limits are set
    from groundctl.clock import Clock
    from groundctl.execute.mpc import MpcConfig, MpcController, MpcRequest, MpcResult

log = logging.getLogger(__name__)

# -- the worker's side ---------------------------------------------------------------------

_controllers: dict[int, MpcController] = {}
_config: MpcConfig | None = None


def _initialise(ground_station: int, config_pickle: bytes) -> None:
    settle_worker(ground_station)  # before numpy: the config comes as bytes, unpickled after
    global _config
    _config = pickle.loads(config_pickle)


def _solve_batch(requests: Sequence[MpcRequest], budget_s: float) -> dict[int, MpcResult]:
    """Solve in priority order until ``budget_s`` CPU seconds are spent: the vehicles
    not reached get no result this time (they keep their last trajectory, then their
    path), rather than the whole batch arriving late."""
    from groundctl.execute.mpc import MpcController, solve_in_priority

    wanted = {r.sysid for r in requests}
    for sysid in list(_controllers):
        if sysid not in wanted:  # handed back to its path: a fresh start next time
            del _controllers[sysid]
    for sysid in wanted:
        if sysid not in _controllers:
            _controllers[sysid] = MpcController(sysid, _config, clock=time.thread_time)
    return solve_in_priority(_controllers, requests, budget_s, time.thread_time)


def _ready() -> int:
    return os.getpid()


# -- the parent's side ---------------------------------------------------------------------


class MpcWorker:
    """One worker process solving MPC batches; see the module docstring."""

    def __init__(self, config: MpcConfig, deadline_s: float,
                 clock: Clock | None = None) -> None:
        """``deadline_s`` is real seconds at the pace of ``clock``, the flight's (module
        docstring; None: real time)."""
        if not deadline_s > 0:
            raise ValueError(f"`deadline_s` must be positive, got {deadline_s}")
        self.config = config
        self.deadline_s = deadline_s
        """Wall seconds a batch may take before its results are discarded."""
        self.late = 0
        """Batches discarded for missing their deadline."""
        self.failed = 0
        """Batches lost to a worker that died (a new one is started)."""
        self._executor: ProcessPoolExecutor | None = None
        self._future: Future[dict[int, MpcResult]] | None = None
        self._now: Callable[[], float] = time.monotonic if clock is None \
            else (lambda: clock.wall_interval(clock.now()))
        self._sent_at = 0.0
        self._done_at: float | None = None
        self._warm: Future[int] | None = None

    def start(self) -> None:
        """Start the worker (it loads numpy, scipy and OSQP in the background)."""
        if self._executor is None:
            self._executor = ProcessPoolExecutor(
                max_workers=1, mp_context=helper_context(),
                initializer=_initialise,
                initargs=(os.getpid(),
                          pickle.dumps(self.config, protocol=pickle.HIGHEST_PROTOCOL)))
            self._warm = self._executor.submit(_ready)

    @property
    def ready(self) -> bool:
        """The worker has started and can take a batch without paying for its imports."""
        return self._warm is not None and self._warm.done() and self._warm.exception() is None

    @property
    def busy(self) -> bool:
        """A batch is in flight."""
        return self._future is not None

    def submit(self, requests: Sequence[MpcRequest]) -> bool:
        """Send a batch unless one is in flight (or the worker is not up); True if sent."""
        if self._executor is None or self._future is not None or not self.ready \
                or not requests:
            return False
        try:
            future = self._executor.submit(_solve_batch, list(requests),
                                           0.6 * self.deadline_s)
        except (BrokenProcessPool, RuntimeError):
            self._restart()
            return False
        self._sent_at, self._done_at = self._now(), None

        def finished(_f: Future[dict[int, MpcResult]]) -> None:
            self._done_at = self._now()  # when it came back, not when it is looked at
        future.add_done_callback(finished)
        self._future = future
        return True

    def collect(self) -> dict[int, MpcResult] | None:
        """The batch's results if ready within its deadline; None otherwise (a batch past
        its deadline is counted late once it finishes, and its results dropped)."""
        fut = self._future
        if fut is None or not fut.done():
            return None
        self._future = None
        done = self._done_at if self._done_at is not None else self._now()
        late = done - self._sent_at > self.deadline_s
        try:
            results = fut.result()
        except BrokenProcessPool:
            self.failed += 1
            self._restart()
            return None
        except Exception:  # a bug in a solve must not stop the flight: paths are streamed
            log.exception("MPC batch failed")
            self.failed += 1
            return None
        if late:
            self.late += 1
            return None
        return results

    def overdue(self) -> bool:
        """A batch in flight is past its deadline (its result will be dropped)."""
        return self._future is not None and self._now() - self._sent_at > self.deadline_s

    def hung(self) -> bool:
        """A batch has been in flight for ten deadlines: the worker is stuck."""
        return self._future is not None \
            and self._now() - self._sent_at > 10 * self.deadline_s

    def _restart(self) -> None:
        self.close()
        self.start()

    def close(self) -> None:
        """Stop the worker (a batch in flight is abandoned)."""
        executor, self._executor = self._executor, None
        self._future = None
        if executor is not None:
            procs = list((getattr(executor, "_processes", None) or {}).values())
            executor.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                proc.kill()
            for proc in procs:
                proc.join(timeout=0.1)  # killed: reaped at once (this may be the loop)
