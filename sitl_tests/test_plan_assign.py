"""The assignment: exact up to EXACT_UP_TO drones, pairwise optimal (multiscale) above."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from groundctl.plan import assign as assign_module
from groundctl.plan.assign import assign, pairwise_optimal


def _cost(start: NDArray[np.float64], slots: NDArray[np.float64], goal: NDArray[np.intp]) -> float:
    return float(((start - slots[goal]) ** 2).sum())


def _worst_swap(start: NDArray[np.float64], slots: NDArray[np.float64],
                goal: NDArray[np.intp]) -> float:
    """The most negative (a_i - a_j) . (g_i - g_j) over all pairs, by brute force."""
    da = start[:, None, :] - start[None, :, :]
    dg = slots[goal][:, None, :] - slots[goal][None, :, :]
    return float(np.einsum("ijk,ijk->ij", da, dg).min())


def _grid_to_sphere(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    side = int(np.ceil(np.sqrt(n)))
    xy = np.stack(np.meshgrid(np.arange(side), np.arange(side)), axis=-1).reshape(-1, 2)[:n]
    start = np.column_stack([2.0 * xy - side, np.zeros(n)])
    k = np.arange(n) + 0.5
    phi, theta = np.arccos(1 - 2 * k / n), np.pi * (1 + 5 ** 0.5) * k
    r = 2.2 * np.sqrt(n / (4 * np.pi))
    slots = r * np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                                 np.cos(phi)]) + np.array([0.0, 0.0, r + 8.0])
    return start, slots


@pytest.mark.parametrize("case", ["grid-sphere", "clouds", "odd-size"])
def test_the_multiscale_assignment_leaves_no_pair_that_gains_by_swapping(case: str) -> None:
    rng = np.random.default_rng(3)
    if case == "grid-sphere":
        start, slots = _grid_to_sphere(900)
    elif case == "clouds":
        start = rng.uniform(-40, 40, (800, 3))
        slots = rng.normal(0, 15, (800, 3)) + np.array([0.0, 0.0, 30.0])
    else:  # cells of 10 and 11 drones: only cells of equal size may be matched
        start, slots = rng.uniform(-40, 40, (617, 3)), rng.uniform(-40, 40, (617, 3)) + 60.0
    goal = pairwise_optimal(start, slots)
    assert sorted(goal.tolist()) == list(range(start.shape[0]))
    # CAPT's property: no two drones would do better by swapping their slots.
    assert _worst_swap(start, slots, goal) > -1e-6
    rows, cols = linear_sum_assignment(cdist(start, slots, "sqeuclidean"))
    best = float(cdist(start, slots, "sqeuclidean")[rows, cols].sum())
    assert best <= _cost(start, slots, goal) <= best * 1.001
    assert np.array_equal(goal, pairwise_optimal(start.copy(), slots.copy()))  # deterministic


def test_fewer_drones_than_a_cell_get_the_exact_assignment() -> None:
    rng = np.random.default_rng(5)
    start, slots = rng.uniform(-5, 5, (7, 3)), rng.uniform(-5, 5, (7, 3))
    rows, cols = linear_sum_assignment(cdist(start, slots, "sqeuclidean"))
    assert pairwise_optimal(start, slots).tolist() == cols[np.argsort(rows)].tolist()


def test_only_large_square_assignments_are_multiscale(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(assign_module, "EXACT_UP_TO", 100)
    start, slots = _grid_to_sphere(400)
    assert np.array_equal(assign(start, slots), pairwise_optimal(start, slots))
    # More slots than drones: the exact solver, whatever the size.
    extra = np.vstack([slots, slots[:5] + 50.0])
    rows, cols = linear_sum_assignment(cdist(start, extra, "sqeuclidean"))
    goal = assign(start, extra)
    assert _cost(start, extra, goal) == pytest.approx(
        float(cdist(start, extra, "sqeuclidean")[rows, cols].sum()))
