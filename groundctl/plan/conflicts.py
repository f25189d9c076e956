"""Which drones can come close during a transition: spatial queries, not all pairs."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

IntArray = NDArray[np.intp]


def close_pair_segments(P: NDArray[np.float64], radius: float) -> NDArray[np.int64]:
    """(m, 3) rows (i, j, k), i < j: drones i and j are within ``radius`` at step k or k+1.

    ``P`` is (n, N+1, d) sampled positions.  One KD-tree query per step.
    """
    _n, k1, _ = P.shape
    found: list[NDArray[np.int64]] = []
    for k in range(k1):
        pairs = cKDTree(P[:, k]).query_pairs(radius, output_type="ndarray")
        if len(pairs):
            pairs = np.sort(pairs, axis=1)
            # A close sample makes both segments that touch it candidates.
            for seg in (k - 1, k):
                if 0 <= seg < k1 - 1:
                    found.append(np.column_stack([pairs, np.full(len(pairs), seg)]))
    if not found:
        return np.empty((0, 3), dtype=np.int64)
    return np.unique(np.concatenate(found).astype(np.int64), axis=0)


def widen(segments: NDArray[np.int64], steps: int, by: int) -> NDArray[np.int64]:
    """Extend every pair's segments by ``by`` steps on both sides (clipped to the horizon)."""
    if not len(segments) or by <= 0:
        return segments
    offsets = np.arange(-by, by + 1)
    rows = np.repeat(segments, len(offsets), axis=0)
    rows[:, 2] += np.tile(offsets, len(segments))
    rows = rows[(rows[:, 2] >= 0) & (rows[:, 2] < steps)]
    return np.unique(rows, axis=0)


def groups(n: int, pairs: NDArray[np.int64], extra: IntArray) -> list[IntArray]:
    """Connected components (size >= 2, or listed in ``extra``) of the pair graph."""
    if len(pairs):
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        _, label = connected_components(graph, directed=False)
    else:
        label = np.arange(n)
    members = np.zeros(n, dtype=bool)
    if len(pairs):
        members[pairs[:, 0]] = True
        members[pairs[:, 1]] = True
    members[extra] = True
    out = []
    for lab in np.unique(label[members]):
        out.append(np.flatnonzero((label == lab) & members))
    return out


def segment_keys(segments: NDArray[np.int64], n: int, steps: int) -> NDArray[np.int64]:
    """One int64 per (i, j, k) row, for fast set membership tests."""
    return (segments[:, 0] * n + segments[:, 1]) * steps + segments[:, 2]
