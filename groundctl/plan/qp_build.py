"""Pieces both SCP models use to build their QPs once and update them in place."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import NDArray

from groundctl.errors import PlanningError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: OSQP settings of the quadrotor QPs (the unicycle starts from these).
#: ``check_dualgap`` off: OSQP >= 1.0 also waits for the duality gap to close,
#: which on these QPs lags the primal and dual residuals by hundreds of ADMM
#: iterations.  Without it, at the old 1e-3 tolerances, a symmetric head-on swap
#: settled on a wider, costlier dodge (2.29 m for 1.9 m asked); at 3e-4 it plans
#: the same as before, still faster (`benchmarks/bench_plan.py`: 1000 drones
#: 2.5 -> 1.9 s, 300 drones 0.39 -> 0.29 s; `groundctl plan shows/demo.toml`
#: 3.9 -> 2.6 s, same separation).
OSQP_SETTINGS: dict[str, float | int | bool] = {
    "verbose": False,
    "eps_abs": 3e-4,
    "eps_rel": 3e-4,
    "max_iter": 4000,
    "polishing": True,
    "adaptive_rho": True,
    "rho": 1.0,
    "check_dualgap": False,
}
#: Penalty per metre of separation slack: large enough that any feasible
#: separation is preferred to any saving in effort.
SLACK_WEIGHT = 1e2
#: OSQP outcomes the SCP accepts.
ACCEPTED_STATUS = ("solved", "solved inaccurate")
#: On "maximum iterations reached", ADMM resumes from its own iterate (warm start)
#: this many more times before the planner gives up: an unfinished iterate does not
#: meet the equality constraints (end states), so it is never used as a result.
RESUMES = 4


def solve_checked(solver: osqp.OSQP, transition: int, what: str,
                  time_left: Callable[[], float] | None = None) -> NDArray[np.float64]:
    """Solve, resuming an unfinished ADMM run; PlanningError unless OSQP solved it.

    ``time_left()`` (s), if given, bounds every resume too: none starts once it is spent."""
    res = solver.solve(raise_error=False)
    for _ in range(RESUMES):
        if res.info.status != "maximum iterations reached":
            break
        if time_left is not None:
            left = time_left()
            if left <= 0:
                break
            solver.update_settings(time_limit=left)
        res = solver.solve(raise_error=False)
    if res.info.status not in ACCEPTED_STATUS:
        raise PlanningError(transition, f"OSQP {res.info.status}", what)
    return np.asarray(res.x)


#: Max slack (m) still counted as "separation holds" at convergence.
SLACK_TOL = 5e-3
#: A pair-segment closer than separation + NEED_MARGIN must have rows in the QP of
#: every group it touches (coupled rows inside a group, obstacle rows across groups;
#: a pair of two drones in no group does not move).  The loop stops only after an
#: iteration in which no sample moved more than the tolerance, so a pair left out
#: (> NEED_MARGIN away) cannot have closed the gap as long as NEED_MARGIN > 2 x
#: tolerance; the verifier checks it again anyway.
NEED_MARGIN = 0.2
#: Largest SCP convergence tolerance that argument allows, m (the loader enforces it).
MAX_TOLERANCE = 0.09
#: A group's QP gets rows for its pair-segments within separation + BUILD_MARGIN (m),
#: widened by BUILD_WIDEN steps.  Every separation row couples two drones at one
#: step; many of them turn the KKT system into a 3D mesh (pairs x time) whose
#: factorisation fills in badly (measured: 25 drones, 2 m grid, margin 1.5 m:
#: 250 ms per refactorisation, 3.5 s per transition; margin 0.4 m: 0.17 s; the paper's
#: unicycle star: 0.31 s with margin 1.5 m and 3 steps, 0.19 s with these).  So
#: rows go only where a pair can become active; a pair that gets closer later is
#: caught by NEED_MARGIN and its group rebuilt.
BUILD_MARGIN = 0.4
BUILD_WIDEN = 1


class RowBuilder:
    """Accumulates the constraint matrix as COO triplets, block by block."""

    def __init__(self) -> None:
        self.r: list[IntArray] = []
        self.c: list[IntArray] = []
        self.v: list[FloatArray] = []
        self.count = 0
        self.nnz = 0

    def block(self, nrows: int, rows: IntArray, cols: IntArray,
              vals: FloatArray) -> tuple[slice, slice]:
        """Append a block; return its row range and its range in the triplet arrays."""
        self.r.append(rows + self.count)
        self.c.append(cols)
        self.v.append(vals)
        row_range = slice(self.count, self.count + nrows)
        coo_range = slice(self.nnz, self.nnz + len(vals))
        self.count += nrows
        self.nnz += len(vals)
        return row_range, coo_range


class FixedPattern:
    """A CSC matrix whose sparsity never changes; values are edited in COO order.

    ``values`` is in the order the :class:`RowBuilder` blocks were appended, so a
    block's coefficients are updated through the slice ``block()`` returned;
    :meth:`refresh` permutes them into the CSC data array OSQP takes.
    """

    def __init__(self, rows: RowBuilder, ncols: int) -> None:
        r = np.concatenate(rows.r)
        c = np.concatenate(rows.c)
        self.values = np.concatenate(rows.v)
        # Mark each COO entry with its 1-based position, convert once, read the
        # permutation back from the CSC data.
        marker = sp.csc_matrix((np.arange(1, len(r) + 1, dtype=float), (r, c)),
                               shape=(rows.count, ncols))
        marker.sort_indices()
        if marker.nnz != len(r):
            raise ValueError("`rows` holds duplicate (row, column) entries")
        self._perm = marker.data.astype(np.intp) - 1
        self.matrix = marker
        self.refresh()

    def refresh(self) -> NDArray[np.float64]:
        """Copy ``values`` into the matrix; return its CSC data (for ``osqp.update(Ax=...)``)."""
        self.matrix.data = self.values[self._perm]
        return self.matrix.data


def segment_normals(P: FloatArray, i: IntArray, j: IntArray, k: IntArray) -> FloatArray:
    """Unit normals (m, d) of the paper's linearised separation, one per pair-segment.

    The normal is drone i minus drone j at the middle of segment k of the previous
    iterate ``P`` (n, N+1, d); see :func:`chord_normals`.
    """
    return chord_normals(P[i, k] - P[j, k], P[i, k + 1] - P[j, k + 1])


def chord_normals(rel0: FloatArray, rel1: FloatArray) -> FloatArray:
    """Unit normals (m, d) of segments whose relative position runs from ``rel0`` to ``rel1``.

    The normal is the relative position at the middle of the segment.  A straight
    line through the other drone gives a zero midpoint vector: fall back to the
    segment start, then to a fixed direction, so a row is never all zeros.
    """
    start = rel0
    mid = 0.5 * (rel0 + rel1)
    norm = np.linalg.norm(mid, axis=1)
    mid = np.where(norm[:, None] > 1e-6, mid, start)
    norm = np.linalg.norm(mid, axis=1)
    fallback = np.zeros(rel0.shape[-1])
    fallback[1] = 1.0
    return np.where(norm[:, None] > 1e-6, mid / np.maximum(norm, 1e-12)[:, None], fallback)


def chord_clearance(P: FloatArray, segments: NDArray[np.int64],
                    A: FloatArray | None = None, dt: float = 0.0) -> FloatArray:
    """Value of each pair-segment's separation rows at ``P`` (and ``A``) itself, m.

    ``segments`` is (m, 3) rows (i, j, k); the value is the smaller of
    n.(p_i - p_j) at both segment ends with the normal of :func:`segment_normals`,
    i.e. how much separation the linearised constraint sees at the iterate; with the
    accelerations ``A`` (n, N, 3), less the bulge of the pair's relative parabola
    towards the other over the segment (dt^2 / 8 times n.(a_i - a_j), when positive).
    """
    i, j, k = segments[:, 0], segments[:, 1], segments[:, 2]
    rel0 = P[i, k] - P[j, k]
    rel1 = P[i, k + 1] - P[j, k + 1]
    nrm = chord_normals(rel0, rel1)
    value = np.minimum(np.einsum("md,md->m", nrm, rel0), np.einsum("md,md->m", nrm, rel1))
    if A is None:
        return np.asarray(value)
    towards = np.einsum("md,md->m", nrm, A[i, k] - A[j, k])
    return np.asarray(value - dt * dt / 8.0 * np.maximum(towards, 0.0))
