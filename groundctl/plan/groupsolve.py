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

A worker that dies (killed, out of memory) loses nothing but time: its groups are
built again here from their specs and its share of the batch is solved here, with a
warning.  Workers leave with this process, also if it is killed outright.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

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

    ``workers`` 1: here.  More: this process and ``workers - 1`` worker processes,
    started at the first build.  Close it (or use it as a context manager) to stop
    them."""

    def __init__(self, transition: int, workers: int = 1) -> None:
        if workers < 1:
            raise ValueError("`workers` must be at least 1")
        self.transition = transition
        self.workers = workers
        self._specs: dict[int, GroupSpec] = {}
        self._here: dict[int, GroupQP] = {}
        self._where: dict[int, int] = {}  # group -> worker (-1: here)
        self._procs: list[BaseProcess] = []
        self._conns: list[Connection | None] = []
        self._load: list[int] = []
        self._here_load = 0

    # -- the parent's side -------------------------------------------------------------
    def build(self, group: int, spec: GroupSpec) -> None:
        """Build group ``group``'s QP (in a worker: sent, built while the SCP goes on)."""
        self._specs[group] = spec
        if self.workers > 1 and not self._procs:
            self._start()
        # This process is a solver too (slot -1): it would only wait for the others.
        live = [-1] + [w for w, c in enumerate(self._conns) if c is not None]
        w = min(live, key=lambda w: (self._here_load if w < 0 else self._load[w], w))
        self._where[group] = w
        if w < 0:
            self._here[group] = spec.build()
            self._here_load += 1
            return
        self._load[w] += 1
        if not self._send(w, ("build", group, spec)):
            self._take_back(w)

    def forget(self, groups: Sequence[int]) -> None:
        """Drop QPs that are no longer needed (their groups merged or were rebuilt)."""
        by_worker: dict[int, list[int]] = {}
        for g in groups:
            self._specs.pop(g, None)
            if self._here.pop(g, None) is not None:
                self._here_load -= 1
            w = self._where.pop(g, -1)
            if w >= 0:
                self._load[w] -= 1
                by_worker.setdefault(w, []).append(g)
        for w, gs in by_worker.items():
            if self._conns[w] is not None and not self._send(w, ("forget", gs)):
                self._take_back(w)

    def solve(self, jobs: Sequence[SolveJob]) -> list[Outcome]:
        """Solve a batch of groups that do not see each other; outcomes in job order."""
        since = time.perf_counter()
        out: list[Outcome | None] = [None] * len(jobs)
        sent: dict[int, list[int]] = {}
        for q, job in enumerate(jobs):
            w = self._where[job.group]
            if w >= 0:
                sent.setdefault(w, []).append(q)
        for w, qs in list(sent.items()):
            if not self._send(w, ("solve", [jobs[q] for q in qs])):
                self._take_back(w)
                del sent[w]
        # Our own share while the workers solve theirs.
        for q, job in enumerate(jobs):
            if self._where[job.group] == -1:
                out[q] = _solve(self._here[job.group], job, self.transition, since)
        for w, qs in sent.items():
            conn = self._conns[w]
            try:
                if conn is None:
                    raise EOFError
                reply = conn.recv()
            except (EOFError, OSError):
                self._take_back(w)
                reply = [_solve(self._here[jobs[q].group], jobs[q], self.transition, since)
                         for q in qs]
            if isinstance(reply, BaseException):
                raise reply
            for q, outcome in zip(qs, reply, strict=True):
                out[q] = outcome
        done = [o for o in out if o is not None]
        if len(done) != len(jobs):
            raise RuntimeError("a group of the batch was not solved")
        return done

    def close(self) -> None:
        """Stop the workers (each leaves when told; one that does not is killed)."""
        for w, conn in enumerate(self._conns):
            if conn is not None:
                self._send(w, None)
                conn.close()
        for p in self._procs:
            p.join(CLOSE_TIMEOUT_S)
            if p.is_alive():
                p.kill()
                p.join()
        self._procs, self._conns, self._load = [], [], []

    def __enter__(self) -> GroupSolvers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _start(self) -> None:
        from groundctl.processes import helper_context

        ctx = helper_context()
        for _ in range(self.workers - 1):
            mine, theirs = ctx.Pipe()
            p = ctx.Process(target=_serve, args=(theirs, os.getpid(), self.transition),
                            name="groundctl-group-solver", daemon=True)
            p.start()
            theirs.close()
            self._procs.append(p)
            self._conns.append(mine)
            self._load.append(0)

    def _send(self, w: int, message: object) -> bool:
        conn = self._conns[w]
        if conn is None:
            return False
        try:
            conn.send(message)
        except (OSError, ValueError):
            return False
        return True

    def _take_back(self, w: int) -> None:
        """Worker ``w`` died: build its groups here from their specs."""
        conn = self._conns[w]
        if conn is None:
            return
        self._conns[w] = None
        conn.close()
        mine = [g for g, at in self._where.items() if at == w]
        log.warning("a group solver process died (exit code %s): solving its %d group(s) "
                    "in the planning process", self._procs[w].exitcode, len(mine))
        for g in mine:
            self._here[g] = self._specs[g].build()
            self._where[g] = -1
            self._here_load += 1
        self._load[w] = 0


# -- the worker's side ---------------------------------------------------------------------
def _serve(conn: Connection, planner: int, transition: int) -> None:
    """A worker: build, forget and solve what ``conn`` brings until told to stop (None)
    or until the planning process ``planner`` is gone."""
    from groundctl.processes import leave_with, settle_helper

    settle_helper()
    leave_with(planner)
    qps: dict[int, GroupQP | Exception] = {}
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        kind = message[0]
        if kind == "build":
            try:
                qps[message[1]] = message[2].build()
            except Exception as exc:  # raised by the parent at the next solve
                qps[message[1]] = exc
        elif kind == "forget":
            for g in message[1]:
                qps.pop(g, None)
        elif kind == "solve":
            since = time.perf_counter()
            try:
                reply: list[Outcome] | Exception = [
                    _solve(_built(qps[job.group]), job, transition, since)
                    for job in message[1]]
            except Exception as exc:  # a bug, not an OSQP status: the parent raises it
                reply = exc
            try:
                conn.send(reply)
            except Exception:  # an exception that does not pickle
                conn.send(RuntimeError(repr(reply)))


def _built(qp: GroupQP | Exception) -> GroupQP:
    if isinstance(qp, Exception):
        raise qp
    return qp
