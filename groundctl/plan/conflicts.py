"""Which drones can come close during a transition: spatial queries, not all pairs."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components
from scipy.spatial import cKDTree

IntArray = NDArray[np.intp]


#: Up to this many pair-samples, :func:`close_pair_segments` computes every distance
#: at once (one vectorised pass beats a KD-tree per step for small fleets).
DENSE_PAIR_SAMPLES = 200_000


def close_pair_segments(P: NDArray[np.float64], radius: float) -> NDArray[np.int64]:
    """(m, 3) rows (i, j, k), i < j: drones i and j are within ``radius`` at step k or k+1.

    ``P`` is (n, N+1, d) sampled positions.  Every pair at once for a small
    fleet, one KD-tree query per step for a large one.
    """
    n, k1, _ = P.shape
    if n * (n - 1) // 2 * k1 <= DENSE_PAIR_SAMPLES:
        i, j = np.triu_indices(n, 1)
        close = np.zeros((len(i), k1 + 1), dtype=bool)
        for c in range(P.shape[2]):  # per axis: no (pairs, steps, d) temporary
            diff = P[i, :, c] - P[j, :, c]
            if c == 0:
                dist2 = diff * diff
            else:
                dist2 += diff * diff
        close[:, 1:] = dist2 <= radius * radius
        # A close sample makes both segments that touch it candidates.
        seg = close[:, :-1] | close[:, 1:]  # (pairs, k1): segment k-1 and k around sample k
        q, k = np.nonzero(seg[:, 1:k1])
        return np.column_stack([i[q], j[q], k]).astype(np.int64)
    found: list[NDArray[np.int64]] = []
    for sample in range(k1):
        pairs = cKDTree(P[:, sample]).query_pairs(radius, output_type="ndarray")
        if len(pairs):
            pairs = np.sort(pairs, axis=1)
            # A close sample makes both segments that touch it candidates.
            for seg_k in (sample - 1, sample):
                if 0 <= seg_k < k1 - 1:
                    found.append(np.column_stack([pairs, np.full(len(pairs), seg_k)]))
    if not found:
        return np.empty((0, 3), dtype=np.int64)
    return unique_segments(np.concatenate(found).astype(np.int64), n, k1 - 1)


def within(P: NDArray[np.float64], segments: NDArray[np.int64], radius: float) -> NDArray[np.int64]:
    """The rows (i, j, k) of ``segments`` whose drones are within ``radius`` at step k or k+1.

    ``close_pair_segments(P, r)`` equals ``within(P, close_pair_segments(P, R), r)`` for
    any R >= r (same test, same order), so one spatial query per iterate serves every
    radius the SCP needs.
    """
    i, j, k = segments[:, 0], segments[:, 1], segments[:, 2]
    d0 = np.sum((P[i, k] - P[j, k]) ** 2, axis=1)
    d1 = np.sum((P[i, k + 1] - P[j, k + 1]) ** 2, axis=1)
    return segments[np.minimum(d0, d1) <= radius * radius]


def segments_with(P: NDArray[np.float64], g: int, radius: float) -> NDArray[np.int64]:
    """:func:`close_pair_segments` restricted to pairs with one of the first ``g`` drones.

    For a few drones moving among many whose trajectories are fixed: their
    distances to everyone, (g, n, N+1) at once, instead of every pair of the fleet.
    """
    n = P.shape[0]
    d2 = np.sum((P[:g, None] - P[None, :]) ** 2, axis=3)
    close = d2 <= radius * radius
    close[np.tril_indices(g, 0, n)] = False  # each moving pair once, never a drone itself
    i, j, k = np.nonzero(close[:, :, :-1] | close[:, :, 1:])
    return np.column_stack([i, j, k]).astype(np.int64)


def widen(segments: NDArray[np.int64], steps: int, by: int) -> NDArray[np.int64]:
    """Extend every pair's segments by ``by`` steps on both sides (clipped to the horizon)."""
    if not len(segments) or by <= 0:
        return segments
    offsets = np.arange(-by, by + 1)
    rows = np.repeat(segments, len(offsets), axis=0)
    rows[:, 2] += np.tile(offsets, len(segments))
    rows = rows[(rows[:, 2] >= 0) & (rows[:, 2] < steps)]
    return unique_segments(rows, int(rows[:, :2].max()) + 1, steps)


def groups(n: int, pairs: NDArray[np.int64], extra: IntArray,
           max_size: int | None = None, keep: Iterable[ArrayLike] = ()) -> list[IntArray]:
    """Connected components (size >= 2, or listed in ``extra``) of the pair graph; a
    component larger than ``max_size`` is cut into pieces of at most that many drones,
    each a breadth-first stretch of the graph (neighbours stay together).

    Pieces in ``keep`` (the last cut) that lie inside such a component stay as they
    are and only its other drones are cut anew: a new link elsewhere in the component
    would otherwise reshuffle every piece, and each reshuffled piece is a new QP to
    build and factorise, without its warm start."""
    graph = None
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
    # The kept pieces (disjoint: they were one cut) by the component they lie inside.
    kept: dict[int, list[IntArray]] = {}
    for piece in keep:
        piece = np.asarray(piece, dtype=np.intp)
        if len(piece) and members[piece].all() and (label[piece] == label[piece[0]]).all():
            kept.setdefault(int(label[piece[0]]), []).append(piece)
    taken = np.zeros(n, dtype=bool)
    out = []
    for lab in np.unique(label[members]):
        comp = np.flatnonzero((label == lab) & members)
        if max_size is None or len(comp) <= max_size or graph is None:
            out.append(comp)
            continue
        for piece in kept.get(int(lab), ()):
            out.append(piece)
            taken[piece] = True
        order = breadth_first_order(graph, int(comp[0]), directed=False,
                                    return_predecessors=False)
        order = order[~taken[order]]
        for lo in range(0, len(order), max_size):
            out.append(np.sort(order[lo:lo + max_size]).astype(np.intp))
    return out


def segment_keys(segments: NDArray[np.int64], n: int, steps: int) -> NDArray[np.int64]:
    """One int64 per (i, j, k) row, for fast set membership tests."""
    return (segments[:, 0] * n + segments[:, 1]) * steps + segments[:, 2]


def segments_from_keys(keys: NDArray[np.int64], n: int, steps: int) -> NDArray[np.int64]:
    """The (m, 3) rows (i, j, k) of :func:`segment_keys` ``keys``."""
    pair, k = np.divmod(keys, steps)
    i, j = np.divmod(pair, n)
    return np.column_stack([i, j, k]).astype(np.int64)


def unique_segments(segments: NDArray[np.int64], n: int, steps: int) -> NDArray[np.int64]:
    """Sorted distinct (i, j, k) rows (through 1-D keys: ``unique(axis=0)`` is slow)."""
    return segments_from_keys(np.unique(segment_keys(segments, n, steps)), n, steps)
