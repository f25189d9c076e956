"""Many vehicles at once (package docstring, "Many vehicles at once"): each solved in
ascending system id against the fresh results of the ones before it."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace

import numpy as np

from groundctl.execute.mpc.controller import MpcController
from groundctl.execute.mpc.types import FloatArray, MpcRequest, MpcResult


def with_predictions(request: MpcRequest, fresh: Mapping[int, MpcResult],
                     dt: float, owns: Mapping[int, FloatArray | None] | None = None
                     ) -> MpcRequest:
    """``request`` with the neighbours in ``fresh`` predicted by those results (replaced
    where the request has them, added where it does not), sampled at its instants.

    ``owns`` (system id -> :attr:`MpcRequest.own`) says how far each vehicle is expected
    to fly from its result: a neighbour is where its result plus its own deviation puts
    it, given relative to this request's own deviation, like the request's other
    neighbours."""
    # A "path" or "unsafe" result is not flown (the executor streams that vehicle's
    # path): it must not stand for where that vehicle will be.
    others = {int(r.sysid): r for r in fresh.values()
              if r.sysid != request.sysid and r.status in ("solved", "fallback")}
    if not others:
        return request
    times = request.t0 + dt * np.arange(len(request.ref_pos))
    nb = request.others.copy()
    ids = list(request.other_ids)
    extra = []
    extra_ids = []
    mine = 0.0 if request.own is None else request.own
    for sid, res in others.items():
        traj, _, _ = res.sample(times)
        theirs = (owns or {}).get(sid)
        traj = traj + (0.0 if theirs is None else theirs) - mine
        if sid in ids:
            nb[ids.index(sid)] = traj
        else:
            extra.append(traj)
            extra_ids.append(sid)
    if extra:
        nb = np.concatenate([nb, np.stack(extra)])
        ids = ids + extra_ids
    return replace(request, neighbours=nb, neighbour_ids=np.asarray(ids, dtype=np.intp))


def solve_in_priority(controllers: Mapping[int, MpcController],
                      requests: Iterable[MpcRequest], budget_s: float = math.inf,
                      clock: Callable[[], float] = time.perf_counter
                      ) -> dict[int, MpcResult]:
    """Solve every request in ascending system id, each against the fresh results of the
    ones before it (module docstring: why every pair then keeps its separation).

    ``controllers`` maps system id to that vehicle's controller; ``requests`` hold the
    executor's predictions for everyone, of which the earlier vehicles' are replaced.
    Once ``budget_s`` (of ``clock``) is spent the rest are left unsolved: they get no
    result, rather than every result coming too late.
    """
    ordered = sorted(requests, key=lambda r: r.sysid)
    sysids = [r.sysid for r in ordered]
    if len(set(sysids)) != len(sysids):
        raise ValueError("`requests` holds two requests for the same vehicle")
    missing = [s for s in sysids if s not in controllers]
    if missing:
        raise ValueError(f"`controllers` has no controller for vehicle {missing[0]}")
    fresh: dict[int, MpcResult] = {}
    owns = {r.sysid: r.own for r in ordered}
    start = clock()
    for req in ordered:
        if clock() - start > budget_s:
            break
        ctrl = controllers[req.sysid]
        fresh[req.sysid] = ctrl.solve(with_predictions(req, fresh, ctrl.config.dt, owns))
    return fresh
