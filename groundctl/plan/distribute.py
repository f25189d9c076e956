"""Where planning jobs run: local worker processes or a Ray cluster.

A :class:`TransitionExecutor` maps a picklable function over picklable jobs and
yields the results *in job order*; a job's own exception comes out as itself
(an ``InfeasibleTransition`` is the same class and message wherever it was
raised).  A job whose worker died is the ``lost`` callback's error (one line that
names the job), never a pool or Ray traceback.

* :class:`LocalExecutor` -- a ``ProcessPoolExecutor`` per :meth:`map` (in-process
  for one worker or one job); a dead worker's undelivered jobs are planned again
  one at a time in a fresh worker.
* :class:`RayExecutor` -- one ``ray.remote`` task per job, ``ray.get`` in order.
  ``ray`` is imported only here, lazily (the optional ``ray`` extra).

A transition's conflict groups are not jobs of this kind: each keeps a QP between
SCP iterations, so they go to :mod:`groundctl.plan.groupsolve`, whose workers (local
processes, or Ray actors on the cluster a :class:`RayExecutor` connected to) keep them.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Protocol, TypeVar

from groundctl.errors import ClusterError

J = TypeVar("J")
R = TypeVar("R")

log = logging.getLogger(__name__)

Lost = Callable[[Any, str], Exception]
"""``lost(job, why)``: the error for a job whose worker died (``why`` says how)."""

#: The message when ``--ray`` is asked for without the extra installed.
NEEDS_EXTRA = "--ray needs the ray extra: pip install 'groundctl[ray]'"


class TransitionExecutor(Protocol):
    """Runs jobs somewhere; results in job order."""

    def map(self, fn: Callable[[J], R], jobs: Sequence[J], lost: Lost) -> Iterator[R]:
        """``fn(job)`` for every job, yielded in order; a job's error raised as itself."""
        ...

    def close(self) -> None:
        """Release what the executor holds (worker processes, a cluster connection)."""
        ...


class LocalExecutor:
    """Worker processes on this machine (at most one per job)."""

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError("`workers` must be at least 1")
        self.workers = workers

    def map(self, fn: Callable[[J], R], jobs: Sequence[J], lost: Lost) -> Iterator[R]:
        workers = min(self.workers, len(jobs))
        done = 0
        if workers > 1:
            try:
                with ProcessPoolExecutor(max_workers=workers) as pool:
                    for res in pool.map(fn, jobs):
                        done += 1
                        yield res
            except BrokenProcessPool:
                # A worker died (killed, out of memory): what it had not delivered is
                # run again, one at a time in a fresh worker, so the job's own result or
                # error comes out -- or, if that one dies too, the ``lost`` line (never
                # this process killed in its place).
                log.warning("a planning worker process died: planning the %d remaining "
                            "job(s) again, one at a time", len(jobs) - done)
                for job in jobs[done:]:
                    with ProcessPoolExecutor(max_workers=1) as single:
                        try:
                            res = single.submit(fn, job).result()
                        except BrokenProcessPool:
                            raise lost(job, "was killed twice (out of memory?)") from None
                    done += 1
                    yield res
        for job in jobs[done:]:
            yield fn(job)

    def close(self) -> None:
        """Nothing held between maps: each map's pool is shut down when it ends."""


def _package_dir() -> str:
    import groundctl

    return str(Path(groundctl.__file__).resolve().parent)


class RayExecutor:
    """One Ray task per job on the cluster at ``address``.

    ``address`` as Ray takes it (``auto``, ``ray://host:10001``, ``host:6379``) or
    ``local`` to start a cluster on this machine.  If Ray is already initialised in
    this process (a test's ``ray.init()``), that connection is used and left open,
    with its own runtime env.  A connection made here carries
    ``runtime_env={"py_modules": [this groundctl package]}``: every worker runs the
    driver's groundctl (the same code, the same plan); the cluster's
    nodes need groundctl's dependencies (numpy, scipy, osqp) installed.
    """

    def __init__(self, address: str, *, num_cpus: int | None = None,
                 ship_code: bool = True, max_retries: int = 1) -> None:
        try:
            import ray
        except ImportError:
            raise ClusterError(address, NEEDS_EXTRA) from None
        self._ray = ray
        self.address = address
        self._owns = False
        # Directories in py_modules are uploaded only at the job level (ray.init), so
        # the driver's code ships only when this executor makes the connection.
        env: dict[str, Any] = (
            {"runtime_env": {"py_modules": [_package_dir()],
                             "excludes": ["__pycache__", "*.pyc"]}} if ship_code else {})
        if not ray.is_initialized():
            _probe(address)
            try:
                if address == "local":
                    ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False,
                             **env)
                else:
                    ray.init(address=address, log_to_driver=False, **env)
            except (ConnectionError, RuntimeError, ValueError, OSError) as exc:
                first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                raise ClusterError(address, f"cannot connect to the Ray cluster: {first}") \
                    from None
            self._owns = True
        self._options: dict[str, Any] = {"max_retries": max_retries}

    @property
    def cpus(self) -> int:
        """The cluster's CPUs (at least 1): transitions, and their conflict groups when
        there are fewer transitions than CPUs, are spread over them."""
        return max(1, int(self._ray.cluster_resources().get("CPU", 1)))

    def map(self, fn: Callable[[J], R], jobs: Sequence[J], lost: Lost) -> Iterator[R]:
        ray = self._ray
        task = ray.remote(fn).options(**self._options)
        refs = [task.remote(job) for job in jobs]
        for job, ref in zip(jobs, refs, strict=True):
            try:
                res = ray.get(ref)
            except ray.exceptions.RayTaskError as exc:
                cause = exc.cause
                if isinstance(cause, ray.exceptions.RayError):
                    raise lost(job, f"failed on the Ray cluster ({type(cause).__name__})") \
                        from None
                # Ray wraps the job's own error: raise it as itself, as locally.
                raise cause from None
            except ray.exceptions.RayError as exc:
                raise lost(job, f"lost its Ray worker ({type(exc).__name__})") from None
            yield res

    def close(self) -> None:
        """Disconnect (and stop a ``local`` cluster) if this executor connected."""
        if self._owns:
            self._ray.shutdown()
            self._owns = False


#: Seconds a cluster address has to accept a TCP connection before ``ray.init`` is tried
#: (Ray itself retries an unreachable address for minutes).
PROBE_TIMEOUT_S = 5.0


def _probe(address: str, timeout: float = PROBE_TIMEOUT_S) -> None:
    """ClusterError unless ``host:port`` / ``ray://host:port`` accepts a TCP connection
    within ``timeout`` (``local`` and ``auto`` are Ray's own to resolve)."""
    import socket
    from urllib.parse import urlsplit

    if address in ("local", "auto"):
        return
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if not host or port is None:
        raise ClusterError(address, "not a Ray address: give auto, local, HOST:PORT or "
                                    "ray://HOST:PORT")
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        raise ClusterError(address, f"cannot connect to the Ray cluster: nothing answers at "
                                    f"{host}:{port} ({exc.strerror or exc})") from None
