"""A SimFleet in its own process: the simulator on one core, the ground station on another.

In one process the simulator's thread and the ground station's event loop
share the GIL, and the dry-run of a 64-drone show cannot even keep real
time on a small machine.  :class:`SimProcess` runs the same
:class:`~groundctl.sim.fleet.SimFleet` in a child process (forked from the helpers'
fork server, :mod:`groundctl.processes`, so no thread or socket of the parent leaks into
it) and forwards calls over a
pipe: ``proc.call("cut_link", 3)`` is ``fleet.cut_link(3)`` over there,
``proc.get("overruns")`` reads an attribute.  Both sides share the
:class:`~groundctl.clock.ScaledClock` (it is defined on CLOCK_MONOTONIC, which
every process of the machine sees alike) or the dry-run's
:class:`~groundctl.clock.PacedClock` (in memory both processes map).

The child ignores Ctrl-C: the ground station decides what a Ctrl-C means
(land every vehicle) and the simulated vehicles must keep flying meanwhile.
It stops when told, or when the parent goes away (its pipe closes).
"""

from __future__ import annotations

import contextlib
import threading
import time
from multiprocessing.connection import Connection
from types import TracebackType
from typing import Any

from groundctl.clock import PacedClock, ScaledClock
from groundctl.errors import SimulatorError
from groundctl.processes import helper_context, settle_helper
from groundctl.sim.config import SimConfig

#: Seconds to wait for the child to build its fleet, or to answer a call.
START_TIMEOUT_S = 60.0
CALL_TIMEOUT_S = 10.0


def _serve(conn: Connection, config: SimConfig, clock: ScaledClock | PacedClock) -> None:
    # The parent lands the simulated fleet on a stop signal first and then stops this
    # child itself; a parent that dies outright closes the pipe, which ends the loop below.
    settle_helper()
    from groundctl.sim.fleet import SimFleet

    try:
        fleet = SimFleet(config, clock)
        fleet.start()
    except Exception as exc:  # reported to the parent, which raises it
        conn.send(("err", SimulatorError(f"the simulator process could not start: {exc}")))
        return
    conn.send(("ok", {"ports": fleet.ports, "sysids": list(fleet.sysids)}))
    try:
        while True:
            try:
                kind, name, args, kwargs = conn.recv()
            except (EOFError, OSError):
                break  # the parent is gone
            if kind == "stop":
                break
            try:
                if name.startswith("_"):
                    raise SimulatorError(f"{name} is not part of the simulator's interface")
                attr = getattr(fleet, name)
                conn.send(("ok", attr(*args, **kwargs) if kind == "call" else attr))
            except Exception as exc:
                conn.send(("err", exc))
    finally:
        error: Exception | None = None
        try:
            fleet.stop()
        except SimulatorError as exc:
            error = exc
        with contextlib.suppress(OSError, ValueError):
            conn.send(("stopped", error))


class SimProcess:
    """A :class:`~groundctl.sim.fleet.SimFleet` running in a child process."""

    def __init__(self, config: SimConfig, clock: ScaledClock | PacedClock) -> None:
        if not isinstance(clock, (ScaledClock, PacedClock)):
            raise SimulatorError("a simulator process needs a ScaledClock or a PacedClock "
                                 "(shared by both processes)")
        ctx = helper_context()
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, config, clock),
                                 name="groundctl-sim", daemon=True)
        self._lock = threading.Lock()
        self._asked: tuple[str, float] | None = None  # (name, when) of a call not read yet
        self._answered: tuple[str, Any] | None = None  # its (kind, value), read meanwhile
        self._proc.start()
        child.close()
        info = self._receive(START_TIMEOUT_S, "start")
        self.ports: list[int] = info["ports"]
        """UDP port of each vehicle, in vehicle order."""
        self.sysids: list[int] = info["sysids"]
        """System ids, in vehicle order."""
        self._stopped = False

    @property
    def alive(self) -> bool:
        """True while the child process runs (False once it stopped, was killed or died)."""
        return self._proc.is_alive()

    @property
    def pid(self) -> int:
        """The child process's id."""
        assert self._proc.pid is not None  # started in __init__
        return self._proc.pid

    @property
    def exitcode(self) -> int | None:
        """The child's exit code (negative: the signal that ended it), None while it runs."""
        return self._proc.exitcode

    def _died(self, what: str, exc: BaseException) -> SimulatorError:
        # The pipe breaks as the child exits, a moment before it can be reaped.
        self._proc.join(1.0)
        self._kill()
        error = SimulatorError(f"the simulator process died (exit code {self._proc.exitcode}) "
                               f"during {what}")
        error.__cause__ = exc  # a broken pipe: how callers tell a death from a refusal
        return error

    def _receive(self, timeout: float, what: str) -> Any:
        return self._unwrap(self._receive_raw(timeout, what))

    def _receive_raw(self, timeout: float, what: str) -> tuple[str, Any]:
        try:
            if not self._conn.poll(timeout):
                raise self._no_answer(what, timeout)
            kind, value = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise self._died(what, exc) from exc
        return kind, value

    def _no_answer(self, what: str, timeout: float) -> SimulatorError:
        self._kill()
        return SimulatorError(f"the simulator process did not answer {what} within "
                              f"{timeout:.0f} s")

    @staticmethod
    def _unwrap(answer: tuple[str, Any]) -> Any:
        kind, value = answer
        if kind == "err":
            raise value
        return value

    def _request(self, kind: str, name: str, args: tuple[Any, ...],
                 kwargs: dict[str, Any]) -> Any:
        with self._lock:
            if self._stopped:
                raise SimulatorError(f"the simulator process has stopped: cannot {kind} "
                                     f"{name}")
            if self._asked is not None:  # its answer comes first on the pipe: keep it
                self._answered = self._receive_raw(CALL_TIMEOUT_S, self._asked[0])
                self._asked = None
            try:
                self._conn.send((kind, name, args, kwargs))
            except OSError as exc:  # BrokenPipeError, ConnectionResetError: the child is gone
                raise self._died(name, exc) from exc
            return self._receive(CALL_TIMEOUT_S, name)

    def ask(self, name: str, *args: Any, **kwargs: Any) -> None:
        """Send ``fleet.name(*args, **kwargs)`` without waiting for it: :meth:`answer`
        reads what it returned once it has come.  One at a time (while one is
        outstanding this does nothing), for a caller that must not wait on the child:
        the dry-run's truth probe runs on the ground station's control loop, which
        waited a scheduling delay of the simulator's process every tick on a busy
        machine."""
        with self._lock:
            if self._asked is not None or self._answered is not None or self._stopped:
                return
            try:
                self._conn.send(("call", name, args, kwargs))
            except OSError as exc:
                raise self._died(name, exc) from exc
            self._asked = (name, time.monotonic())

    def answer(self) -> tuple[bool, Any]:
        """``(True, value)`` of what the call sent by :meth:`ask` returned, once it has
        come (never waits; its exception is raised here); ``(False, None)`` before."""
        with self._lock:
            if self._answered is not None:
                got, self._answered = self._answered, None
                return True, self._unwrap(got)
            if self._asked is None:
                return False, None
            name, at = self._asked
            try:
                ready = self._conn.poll(0)
            except (EOFError, OSError) as exc:
                raise self._died(name, exc) from exc
            if not ready:
                if time.monotonic() - at > CALL_TIMEOUT_S:
                    raise self._no_answer(name, CALL_TIMEOUT_S)
                return False, None
            self._asked = None
            return True, self._unwrap(self._receive_raw(0.0, name))

    def call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        """``fleet.name(*args, **kwargs)`` in the child; its exception is raised here.

        A child that died raises :class:`SimulatorError` (caused by the broken pipe).
        """
        return self._request("call", name, args, kwargs)

    def get(self, name: str) -> Any:
        """``fleet.name`` (an attribute or property) in the child."""
        return self._request("get", name, (), {})

    def stop(self) -> None:
        """Stop the fleet and the process; raises the loop's failure if it had one, or
        :class:`SimulatorError` if the child had died (it is cleaned up all the same)."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
            error: Exception | None = None
            try:
                self._conn.send(("stop", "", (), {}))
                while self._conn.poll(CALL_TIMEOUT_S):
                    kind, value = self._conn.recv()
                    if kind == "stopped":
                        error = value
                        break
            except (EOFError, OSError) as exc:
                self._proc.join(CALL_TIMEOUT_S)
                if self._proc.exitcode != 0:  # 0: it stopped without a word (pipe closing)
                    error = self._died("stop", exc)
            self._proc.join(CALL_TIMEOUT_S)
            self._kill()
            self._conn.close()
        if error is not None:
            raise error

    def _kill(self) -> None:
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(5.0)

    def __enter__(self) -> SimProcess:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()
