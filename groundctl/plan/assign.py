"""Which drone flies to which slot of the next formation.

Minimising the sum of *squared* distances (not distances) is the classic
choice for swarms: the optimal assignment's straight lines never cross in a
way that makes two drones swap through each other, which leaves far less for
the collision-avoidance step to fix (Turpin, Michael, Kumar: CAPT).

CAPT's separation argument uses only that no *two* drones would do better by
swapping their slots: (a_i - a_j) . (g_i - g_j) >= 0 for every pair.  Up to
`EXACT_UP_TO` drones the assignment is the exact optimum (scipy's
shortest-augmenting-path solver); above it that solver grows about as N^3
(10,000 drones grid -> sphere: 85-110 s), so a larger square assignment is
built multiscale instead (`pairwise_optimal`): cells of about `CELL` drones
matched to cells of slots, each cell pair solved exactly, neighbourhoods of a
few hundred drones re-solved exactly, then repaired until no pair would swap.
It keeps CAPT's property and lands within 0.02 % of the optimum's cost
(10,000 drones grid -> sphere: 0.003 % in about 5 s).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

#: Fleets above this size get their cost matrix reduced before the solver (see `assign`).
REDUCE_ABOVE = 1000
#: Square assignments above this size are pairwise optimal, not exact (see `pairwise_optimal`).
EXACT_UP_TO = 3000
#: Drones per cell in `pairwise_optimal`'s coarse level (10 measured best of 5, 10 and 30).
CELL = 10
#: Drones per neighbourhood re-solved exactly in `pairwise_optimal`, and how many sweeps.
_HOOD = 300
_SWEEPS = 4
#: Rows of the pair matrix computed at once in `_swaps` (10 MB of float64 at 1024 x 1024).
_BLOCK = 1024
#: Drones whose swaps are re-solved together as one exact assignment in `_repair`.
_JOINT = 400
#: Repair passes before `_repair` gives up improving (a valid assignment either way).
_MAX_PASSES = 1000
#: Assignments of at least this many drones are remembered (see `assign`), and how many.
REMEMBER_FROM = 500
REMEMBERED = 8

_remembered: OrderedDict[bytes, NDArray[np.intp]] = OrderedDict()


def assign(start: NDArray[np.float64], slots: NDArray[np.float64]) -> NDArray[np.intp]:
    """Slot index for each drone: ``slots[assign(start, slots)[i]]`` is drone i's goal.

    ``start`` is (n, d), ``slots`` (m, d) with m >= n; every drone gets a
    distinct slot and the sum of squared distances is minimal.
    """
    start = np.asarray(start, dtype=float)
    slots = np.asarray(slots, dtype=float)
    if start.ndim != 2 or slots.ndim != 2 or start.shape[1] != slots.shape[1]:
        raise ValueError("`start` and `slots` must be (n, d) and (m, d) arrays")
    if slots.shape[0] < start.shape[0]:
        raise ValueError(
            f"`slots` has {slots.shape[0]} points for {start.shape[0]} drones"
        )
    key = None
    if start.shape[0] >= REMEMBER_FROM:
        # The loader checks every transition's minimum time on the planner's own
        # assignment, and the planner then assigns again: at 10,000 drones that is
        # a minute and a half twice.  The same points give the same answer.
        digest = hashlib.sha256()
        for a in (start, slots):
            digest.update(np.asarray(a.shape, dtype=np.int64).tobytes())
            digest.update(np.ascontiguousarray(a).tobytes())
        key = digest.digest()
        known = _remembered.get(key)
        if known is not None:
            _remembered.move_to_end(key)
            return known.copy()
    if start.shape[0] == slots.shape[0] > EXACT_UP_TO:
        goal = pairwise_optimal(start, slots)
    else:
        goal = _exact(start, slots)
    if key is not None:
        _remembered[key] = goal.copy()
        while len(_remembered) > REMEMBERED:
            _remembered.popitem(last=False)
    return goal


def _exact(start: NDArray[np.float64], slots: NDArray[np.float64]) -> NDArray[np.intp]:
    cost = cdist(start, slots, "sqeuclidean")
    if start.shape[0] > REDUCE_ABOVE:
        # Subtracting each row's minimum (and, when every slot is taken, each column's)
        # leaves the optimal assignments as they are but starts the shortest-augmenting-path
        # solver from far better duals: 3000 drones grid -> sphere 17 s -> 2.4 s.  Smaller
        # fleets keep the plain call, whose tie-breaking existing plans were made with.
        cost -= cost.min(axis=1, keepdims=True)
        if slots.shape[0] == start.shape[0]:
            cost -= cost.min(axis=0, keepdims=True)
    rows, cols = linear_sum_assignment(cost)
    goal = np.empty(start.shape[0], dtype=np.intp)
    goal[rows] = cols
    return goal


def pairwise_optimal(start: NDArray[np.float64], slots: NDArray[np.float64],
                     cell: int = CELL) -> NDArray[np.intp]:
    """A one-to-one assignment of n drones to n slots where no two drones gain by swapping.

    Both point sets are cut by the same balanced k-d bisection into about
    n / ``cell`` cells (the cell sizes depend on n alone, so both sides get the
    same sizes); cells of drones are matched to cells of slots of the same size by
    their centroids, exactly; each matched pair is assigned exactly; neighbourhoods of
    `_HOOD` drones are re-solved exactly; then `_repair` swaps until no pair improves.
    Deterministic.
    """
    n = start.shape[0]
    leaves = max(1, n // cell)
    drone_cells = _kd_cells(start, leaves)
    slot_cells = _kd_cells(slots, leaves)
    sizes_d = np.array([len(c) for c in drone_cells])
    sizes_s = np.array([len(c) for c in slot_cells])
    centre_d = np.array([start[c].mean(axis=0) for c in drone_cells])
    centre_s = np.array([slots[c].mean(axis=0) for c in slot_cells])
    coarse = cdist(centre_d, centre_s, "sqeuclidean") * sizes_d[:, None]
    # Cells differ in size by at most one; only equal sizes may be matched.
    coarse[sizes_d[:, None] != sizes_s[None, :]] = np.inf
    _, match = linear_sum_assignment(coarse)
    goal = np.empty(n, dtype=np.intp)
    for mine, theirs in zip(drone_cells, (slot_cells[j] for j in match), strict=True):
        rows, cols = linear_sum_assignment(cdist(start[mine], slots[theirs], "sqeuclidean"))
        goal[mine[rows]] = theirs[cols]
    # Cell boundaries cost more than pairs can mend (random clouds: 0.8 % over the
    # optimum when repaired at once); re-solving neighbourhoods of a few hundred drones
    # exactly, cut alternately by where the drones are and where they go, brings that
    # to about 0.02 % before the repair.
    for sweep in range(_SWEEPS):
        by = start if sweep % 2 == 0 else slots[goal]
        for hood in _kd_cells(by, max(1, n // _HOOD)):
            rows, cols = linear_sum_assignment(cdist(start[hood], slots[goal[hood]], "sqeuclidean"))
            goal[hood[rows]] = goal[hood][cols]
    return _repair(start, slots, goal)


def _kd_cells(points: NDArray[np.float64], leaves: int) -> list[NDArray[np.intp]]:
    """Index sets of a balanced k-d bisection into ``leaves`` cells, split along the widest axis."""
    cells: list[NDArray[np.intp]] = []
    stack = [(np.arange(points.shape[0]), leaves)]
    while stack:
        idx, count = stack.pop()
        if count == 1:
            cells.append(idx)
            continue
        left = count // 2
        cut = idx.shape[0] * left // count
        here = points[idx]
        axis = int(np.argmax(np.ptp(here, axis=0)))
        order = idx[np.argsort(here[:, axis], kind="stable")]
        stack.append((order[cut:], count - left))
        stack.append((order[:cut], left))
    return cells


def _repair(start: NDArray[np.float64], slots: NDArray[np.float64],
            goal: NDArray[np.intp]) -> NDArray[np.intp]:
    """Swap slots until no pair of drones lowers the summed squared distance by swapping.

    Swapping i and j changes the cost by -2 (a_i - a_j) . (g_i - g_j).  Each pass
    takes a disjoint set of improving swaps, best first (or, once few drones are
    involved, solves them together exactly); a pair's gain depends only on its two
    drones, so after the first pass only the pairs of drones that moved are looked at.
    """
    scale = float(np.abs(start).max() + np.abs(slots).max()) ** 2 + 1.0
    tol = 1e-10 * scale
    moved = np.arange(start.shape[0])
    pending = np.zeros((0, 2), dtype=np.intp)
    for _ in range(_MAX_PASSES):
        fresh = _swaps(start, slots[goal], moved, tol)
        still = ~np.isin(pending, moved).any(axis=1)
        pairs = np.concatenate([pending[still], fresh])
        if pairs.shape[0] == 0:
            break
        i, j = pairs[:, 0], pairs[:, 1]
        gain = np.einsum("ij,ij->i", start[i] - start[j], slots[goal[i]] - slots[goal[j]])
        involved = np.unique(pairs)
        if involved.shape[0] <= _JOINT:
            rows, cols = linear_sum_assignment(
                cdist(start[involved], slots[goal[involved]], "sqeuclidean"))
            goal[involved[rows]] = goal[involved][cols]
            moved = involved
            pending = np.zeros((0, 2), dtype=np.intp)
            continue
        used = np.zeros(start.shape[0], dtype=bool)
        take = np.zeros(pairs.shape[0], dtype=bool)
        for k in np.argsort(gain, kind="stable"):
            a, b = i[k], j[k]
            if not (used[a] or used[b]):
                used[a] = used[b] = take[k] = True
        ti, tj = i[take], j[take]
        goal[ti], goal[tj] = goal[tj], goal[ti].copy()
        moved = np.flatnonzero(used)
        pending = pairs[~take]
    return goal


def _swaps(start: NDArray[np.float64], goals: NDArray[np.float64], rows: NDArray[np.intp],
           tol: float) -> NDArray[np.intp]:
    """Pairs (i, j), i in ``rows``, whose swap lowers the cost by more than ``tol``; each once."""
    own = np.einsum("ij,ij->i", start, goals)
    in_rows = np.zeros(start.shape[0], dtype=bool)
    in_rows[rows] = True
    found = []
    for s in range(0, rows.shape[0], _BLOCK):
        r = rows[s:s + _BLOCK]
        gain = own[r, None] + own[None, :] - start[r] @ goals.T - goals[r] @ start.T
        ri, j = np.nonzero(gain < -tol)
        i = r[ri]
        # A pair with both drones in ``rows`` is found from both sides: keep i < j.
        keep = ~in_rows[j] | (i < j)
        found.append(np.column_stack([i[keep], j[keep]]))
    return np.concatenate(found) if found else np.zeros((0, 2), dtype=np.intp)


def assign_chain(start: NDArray[np.float64],
                 formations: Sequence[NDArray[np.float64]]) -> list[NDArray[np.intp]]:
    """Slot index per drone for each formation in turn (show order).

    The first formation is assigned from ``start``, each later one from the
    slots the drones were given in the previous one.
    """
    chain = []
    prev = np.asarray(start, dtype=float)
    for slots in formations:
        idx = assign(prev, slots)
        chain.append(idx)
        prev = np.asarray(slots, dtype=float)[idx]
    return chain
