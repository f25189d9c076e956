"""Where the SCP's conflict groups are solved: here, or in worker processes.

Every group of drones in conflict is one QP (:class:`~groundctl.plan.quad_qp.GroupQP`),
built once and solved again, relinearised and warm-started, at every SCP iteration
until it converges.  Groups whose obstacle rows name no drone of each other's (one
*colour*, :func:`colour_classes`) never see each other's trajectories, so the SCP
solves each colour as one batch (:meth:`GroupSolvers.solve`).

:class:`GroupSolvers` keeps the groups' QPs.  With one worker they live in this
process.  With more, this process and ``workers - 1`` worker processes (forked from
the helpers' fork server, :mod:`groundctl.processes`) each keep the QPs of the groups
given to them -- sticky, so a QP keeps its warm start and its factorisation -- and
solve their share of a batch at the same time.  A group goes to the one holding the
fewest when it is built, so which worker holds it depends only on the order of builds; a QP's
solution depends only on its own history of updates; so the plan is the same with
any number of workers (tested).

A worker that dies (killed, out of memory) costs time, not the plan: its groups are
built again here from their specs and its share of the batch is solved here, with a
warning (their warm starts are lost, so from then on the plan may differ from an
undisturbed one within OSQP's tolerance).  Workers leave with this process, also if it
is killed outright.  With ``ray`` the workers are actors on the Ray cluster the
process is connected to (``groundctl plan --ray``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import PlanningError
from groundctl.plan.qp_build import OSQP_SETTINGS
from groundctl.plan.quad_qp import GroupQP, ObstacleSegments, PairSegments
from groundctl.show.model import Limits

FloatArray = NDArray[np.float64]

log = logging.getLogger(__name__)

#: Wall seconds :meth:`GroupSolvers.close` waits for a worker to leave before killing it.
CLOSE_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class GroupSpec:
    """Everything a group's QP is built from (picklable: a worker builds it)."""

    start: FloatArray
    """(g, 3) start positions of the group's drones."""
    goal: FloatArray
    """(g, 3) goals."""
    ref: FloatArray
    """(g, N+1, 3) reference positions."""
    steps: int
    dt: float
    limits: Limits
    pairs: PairSegments
    """Coupled separation rows inside the group (group-local indices)."""
    obstacles: ObstacleSegments
    """Separation rows against drones outside the group."""
    alpha: float
    beta: float

    def build(self) -> GroupQP:
        return GroupQP(self.start, self.goal, self.ref, self.steps, self.dt, self.limits,
                       self.pairs, self.alpha, self.beta, OSQP_SETTINGS, self.obstacles)


@dataclass(frozen=True)
class SolveJob:
    """One solve of one group: the iterate to linearise around and the obstacles."""

    group: int
    """The group's id (given at :meth:`GroupSolvers.build`)."""
    P: FloatArray
    """(g, N+1, 3) positions of the group's drones at the current iterate."""
    V: FloatArray
    A: FloatArray
    trust: float
    """Trust region on positions, m."""
    others: FloatArray
    """(m_o, 2, 3) the other drone of every obstacle row at both ends of its segment."""
    others_acc: FloatArray
    """(m_o, 3) its acceleration on the segment."""
    time_limit: float
    """Seconds from the start of its batch by which the solve must end (0: no limit); a
    solve with none left fails with OSQP's "run time limit reached"."""


@dataclass(frozen=True)
class Solved:
    """A group's new iterate."""

    P: FloatArray
    V: FloatArray
    A: FloatArray
    S: FloatArray
    """Separation slacks, m."""


@dataclass(frozen=True)
class Failed:
    """OSQP did not solve the group's QP: its status."""

    status: str
    detail: str


Outcome = Solved | Failed


def _solve(qp: GroupQP, job: SolveJob, transition: int, since: float) -> Outcome:
    """Solve ``job`` on ``qp``; ``since`` (time.perf_counter) is when its batch began."""
    left = 0.0
    if job.time_limit > 0:
        left = job.time_limit - (time.perf_counter() - since)
        if left <= 0:
            return Failed("OSQP run time limit reached", "no time left in the batch")
    qp.linearise(job.P, job.V, job.A, job.trust, job.others, job.others_acc)
    try:
        P, V, A, S = qp.solve(transition, time_limit=left)
    except PlanningError as exc:
        return Failed(exc.status, exc.detail)
    return Solved(P, V, A, S)


def colour_classes(members: Sequence[NDArray[np.intp]],
                   obstacle_drones: Sequence[NDArray[np.intp]], n: int) -> list[list[int]]:
    """Groups (indices into ``members``) in batches that may be solved at once.

    Two groups are neighbours when an obstacle row of one names a drone of the other:
    each then reads where the other is.  Greedy colouring in the given order; the
    batches come colour by colour, each in that order.  Solving batch after batch is
    Gauss-Seidel as before -- every group sees where its neighbours of earlier colours
    have moved -- and the same whether a batch is solved here or spread over
    processes."""
    owner = np.full(n, -1, dtype=np.intp)
    for g, m in enumerate(members):
        owner[m] = g
    neighbours: list[set[int]] = [set() for _ in members]
    for g, drones in enumerate(obstacle_drones):
        for h in np.unique(owner[drones]).tolist():
            if h >= 0 and h != g:
                neighbours[g].add(h)
                neighbours[h].add(g)
    colour = [-1] * len(members)
    classes: list[list[int]] = []
    for g in range(len(members)):
        taken = {colour[h] for h in neighbours[g]}
        c = next(c for c in range(len(members) + 1) if c not in taken)
        colour[g] = c
        if c == len(classes):
            classes.append([])
        classes[c].append(g)
    return classes


class GroupSolvers:
    """The groups' QPs of one transition, and where they are solved.

    ``workers`` 1: here.  More: this process and ``workers - 1`` worker processes
    (``ray``: actors on the Ray cluster this process is connected to), started at the
    first build.  Close it (or use it as a context manager) to stop them."""

    def __init__(self, transition: int, workers: int = 1, ray: bool = False) -> None:
        if workers < 1:
            raise ValueError("`workers` must be at least 1")
        self.transition = transition
        self.workers = workers
        self.ray = ray
        self._specs: dict[int, GroupSpec] = {}
        self._here = _Keeper(transition)  # this process's own groups
        self._where: dict[int, int] = {}  # group -> slot (-1: here)
        self._slots: list[_Slot | None] = []
        self._load: dict[int, int] = {-1: 0}  # groups per slot
        self._started = False

    # -- the parent's side -------------------------------------------------------------
    def build(self, group: int, spec: GroupSpec) -> None:
        """Build group ``group``'s QP (in a worker: sent, built while the SCP goes on)."""
        self._specs[group] = spec
        if self.workers > 1 and not self._started:
            self._start()
        # This process is a solver too (slot -1): it would only wait for the others.
        live = [-1] + [w for w, c in enumerate(self._slots) if c is not None]
        w = min(live, key=lambda w: (self._load[w], w))
        self._where[group] = w
        self._load[w] += 1
        if w < 0:
            self._here.build(group, spec)
        else:
            self._send(w, ("build", group, spec))

    def forget(self, groups: Sequence[int]) -> None:
        """Drop QPs that are no longer needed (their groups merged or were rebuilt)."""
        by_slot: dict[int, list[int]] = {}
        for g in groups:
            self._specs.pop(g, None)
            w = self._where.pop(g)
            self._load[w] -= 1
            by_slot.setdefault(w, []).append(g)
        for w, gs in by_slot.items():
            if w < 0:
                self._here.forget(gs)
            else:
                self._send(w, ("forget", gs))

    def solve(self, jobs: Sequence[SolveJob]) -> list[Outcome]:
        """Solve a batch of groups that do not see each other; outcomes in job order."""
        since = time.perf_counter()
        out: list[Outcome | None] = [None] * len(jobs)
        sent: dict[int, list[int]] = {}
        for q, job in enumerate(jobs):
            w = self._where[job.group]
            if w >= 0:
                sent.setdefault(w, []).append(q)
        for w, qs in sent.items():
            self._send(w, ("solve", [jobs[q] for q in qs]))
        # Our own share while the workers solve theirs (and what a dead one left).
        self._solve_here(jobs, [q for q, job in enumerate(jobs)
                                if self._where[job.group] == -1], out, since)
        for w, qs in sent.items():
            todo = [q for q in qs if out[q] is None]  # its worker died on the send: done
            if not todo:
                continue
            slot = self._slots[w]
            try:
                if slot is None:
                    raise EOFError
                reply = slot.receive()
            except EOFError:  # its worker is gone: here
                self._take_back(w)
                self._solve_here(jobs, todo, out, since)
                continue
            if isinstance(reply, Exception):
                raise reply
            for q, outcome in zip(todo, reply, strict=True):
                out[q] = outcome
        done = [o for o in out if o is not None]
        if len(done) != len(jobs):
            raise RuntimeError("a group of the batch was not solved")
        return done

    def _solve_here(self, jobs: Sequence[SolveJob], which: Sequence[int],
                    out: list[Outcome | None], since: float) -> None:
        reply = self._here.solve([jobs[q] for q in which], since)
        if isinstance(reply, Exception):
            raise reply
        for q, outcome in zip(which, reply, strict=True):
            out[q] = outcome

    def close(self) -> None:
        """Stop the workers (each leaves when told; one that does not is killed)."""
        for slot in self._slots:
            if slot is not None:
                slot.close()
        self._slots = []

    def __enter__(self) -> GroupSolvers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _start(self) -> None:
        self._started = True
        for _ in range(self.workers - 1):
            slot: _Slot = (_RaySlot(self.transition) if self.ray
                           else _ProcessSlot(self.transition))
            self._load[len(self._slots)] = 0
            self._slots.append(slot)

    def _send(self, w: int, message: tuple[object, ...]) -> None:
        slot = self._slots[w]
        if slot is not None and not slot.send(message):
            self._take_back(w)

    def _take_back(self, w: int) -> None:
        """Worker ``w`` died: build its groups here from their specs."""
        slot = self._slots[w]
        if slot is None:
            return
        self._slots[w] = None
        mine = [g for g, at in self._where.items() if at == w]
        log.warning("a group solver %s died (%s): solving its %d group(s) in the planning "
                    "process", slot.kind, slot.why(), len(mine))
        slot.close()
        for g in mine:
            self._here.build(g, self._specs[g])
            self._where[g] = -1
        self._load[-1] += self._load[w]
        self._load[w] = 0


class _Keeper:
    """A worker's groups: builds, forgets and solves what it is sent."""

    def __init__(self, transition: int) -> None:
        self.transition = transition
        self.qps: dict[int, GroupQP | Exception] = {}

    def build(self, group: int, spec: GroupSpec) -> None:
        try:
            self.qps[group] = spec.build()
        except Exception as exc:  # raised by the parent at the group's next solve
            self.qps[group] = exc

    def forget(self, groups: Sequence[int]) -> None:
        for g in groups:
            self.qps.pop(g, None)

    def solve(self, jobs: Sequence[SolveJob], since: float | None = None
              ) -> list[Outcome] | Exception:
        """The outcomes, or the exception a bug raised (the parent raises it).  Time
        limits count from ``since`` (time.perf_counter; default: now)."""
        since = time.perf_counter() if since is None else since
        try:
            return [_solve(_built(self.qps[job.group]), job, self.transition, since)
                    for job in jobs]
        except Exception as exc:
            return exc


def _built(qp: GroupQP | Exception) -> GroupQP:
    if isinstance(qp, Exception):
        raise qp
    return qp


class _Slot(Protocol):
    kind: str

    def send(self, message: tuple[object, ...]) -> bool:
        """Pass a ("build", group, spec), ("forget", groups) or ("solve", jobs) on;
        False if the worker is gone."""
        ...

    def receive(self) -> list[Outcome] | Exception:
        """The reply to the last "solve"; EOFError if the worker is gone."""
        ...

    def why(self) -> str:
        ...

    def close(self) -> None:
        ...


class _ProcessSlot:
    """A worker process forked from the helpers' fork server, over a pipe."""

    kind = "process"

    def __init__(self, transition: int) -> None:
        from groundctl.processes import helper_context

        ctx = helper_context()
        self.conn, theirs = ctx.Pipe()
        self.process: BaseProcess = ctx.Process(
            target=_serve, args=(theirs, os.getpid(), transition),
            name="groundctl-group-solver", daemon=True)
        self.process.start()
        theirs.close()

    def send(self, message: tuple[object, ...]) -> bool:
        try:
            self.conn.send(message)
        except (OSError, ValueError):
            return False
        return True

    def receive(self) -> list[Outcome] | Exception:
        try:
            reply: list[Outcome] | Exception = self.conn.recv()
        except (EOFError, OSError):
            raise EOFError from None
        return reply

    def why(self) -> str:
        return f"exit code {self.process.exitcode}"

    def close(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self.conn.send(None)
        self.conn.close()
        self.process.join(CLOSE_TIMEOUT_S)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()


class _RaySlot:
    """An actor on the Ray cluster this process is connected to (inside a Ray task: the
    task's own cluster).  It asks for no CPU of its own -- the transition's task holds
    one and mostly waits for its actors -- and actors are spread over the nodes."""

    kind = "Ray actor"

    def __init__(self, transition: int) -> None:
        import ray

        self._ray: Any = ray
        keeper: Any = ray.remote(num_cpus=0, max_restarts=0)(_Keeper)
        self.actor: Any = keeper.options(scheduling_strategy="SPREAD").remote(transition)
        self._pending: object | None = None
        self._why = ""

    def send(self, message: tuple[object, ...]) -> bool:
        kind = message[0]
        if kind == "build":
            self.actor.build.remote(message[1], message[2])
        elif kind == "forget":
            self.actor.forget.remote(message[1])
        elif kind == "solve":
            self._pending = self.actor.solve.remote(message[1])
        return True

    def receive(self) -> list[Outcome] | Exception:
        try:
            reply: list[Outcome] | Exception = self._ray.get(self._pending)
        except self._ray.exceptions.RayError as exc:
            self._why = type(exc).__name__
            raise EOFError from None
        return reply

    def why(self) -> str:
        return self._why or "lost"

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._ray.kill(self.actor)


# -- the worker's side ---------------------------------------------------------------------
def _serve(conn: Connection, planner: int, transition: int) -> None:
    """A worker process: build, forget and solve what ``conn`` brings until told to stop
    (None) or until the planning process ``planner`` is gone."""
    from groundctl.processes import leave_with, settle_helper

    settle_helper()
    leave_with(planner)
    keeper = _Keeper(transition)
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        kind = message[0]
        if kind == "build":
            keeper.build(message[1], message[2])
        elif kind == "forget":
            keeper.forget(message[1])
        elif kind == "solve":
            reply = keeper.solve(message[1])
            try:
                conn.send(reply)
            except Exception:  # an exception that does not pickle
                conn.send(RuntimeError(repr(reply)))
