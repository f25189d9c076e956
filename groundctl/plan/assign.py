"""Which drone flies to which slot of the next formation.

Minimising the sum of *squared* distances (not distances) is the classic
choice for swarms: the optimal assignment's straight lines never cross in a
way that makes two drones swap through each other, which leaves far less for
the collision-avoidance step to fix (Turpin, Michael, Kumar: CAPT).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist


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
    cost = cdist(start, slots, "sqeuclidean")
    rows, cols = linear_sum_assignment(cost)
    goal = np.empty(start.shape[0], dtype=np.intp)
    goal[rows] = cols
    return goal


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
