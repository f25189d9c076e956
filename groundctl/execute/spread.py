"""Hold points clear of each other: drones the wind (or a fault) pushed together are held
apart, not where they happen to be.  Pure numpy.

When the guard takes a drone out of the show "from where it is", or the last resort
holds every drone where its path stopped, those points can be closer than the show's
separation limit: the wind blew two drones together, and holding each where it is would
keep them there (measured: 12 m/s gusting 4, two hold points 0.66 m apart with a 1.5 m
limit).  :func:`spread_apart` moves the points that may move the least it can, sideways
only (a drone above or below another keeps its height: the columns of the last resort
are vertical), until every pair is at least the limit apart (in 3D).  Averaged pushes
can cancel in a symmetric crowd; what is still too close after :data:`MAX_PASSES` is
left as it is.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: Passes of pairwise pushes before giving up on a crowd that cannot be spread.
MAX_PASSES = 200
#: Pairs within this fraction of the limit count as apart (the pushes converge slowly).
TOLERANCE = 1e-3


def spread_apart(points: np.ndarray, movable: np.ndarray, limit: float,
                 max_move: float) -> np.ndarray:
    """``points`` (n, 3) with the ``movable`` ones (bool, n) pushed sideways until no two
    are within ``limit`` of each other in 3D; each moves at most ``max_move`` from where
    it was.  Pairs of two fixed points are left as they are.  Deterministic."""
    pts = np.array(points, dtype=float, copy=True)
    n = len(pts)
    if n < 2 or not np.any(movable) or limit <= 0:
        return pts
    movable = np.asarray(movable, dtype=bool)
    start = pts.copy()
    reach = limit * (1.0 - TOLERANCE)
    for _ in range(MAX_PASSES):
        pairs = cKDTree(pts).query_pairs(reach, output_type="ndarray")
        if len(pairs) == 0:
            break
        i, j = pairs[:, 0], pairs[:, 1]
        keep = movable[i] | movable[j]
        i, j = i[keep], j[keep]
        if len(i) == 0:
            break
        d = pts[i] - pts[j]
        dist = np.linalg.norm(d, axis=1)
        flat = d[:, :2].copy()
        flat_len = np.linalg.norm(flat, axis=1)
        # One straight above the other: push apart along a fixed direction per pair.
        same = flat_len < 1e-6
        angle = (i[same] * 0.618 + j[same] * 0.382) * 2.0 * np.pi
        flat[same] = np.column_stack([np.cos(angle), np.sin(angle)])
        flat_len[same] = 1.0
        unit = np.zeros_like(d)
        unit[:, :2] = flat / flat_len[:, None]
        # The horizontal distance that makes the pair ``limit`` apart at its height gap.
        dz = np.abs(d[:, 2])
        want_h = np.sqrt(np.maximum(limit * limit - dz * dz, 0.0))
        have_h = np.where(same, 0.0, np.linalg.norm(d[:, :2], axis=1))
        gap = np.maximum(want_h - have_h, 0.0) + limit * TOLERANCE
        gap = np.where(dist < reach, gap, 0.0)
        share_i = np.where(movable[i], np.where(movable[j], 0.5, 1.0), 0.0)
        share_j = np.where(movable[j], np.where(movable[i], 0.5, 1.0), 0.0)
        # Each point moves by the mean of its pushes (their sum overshoots where several
        # neighbours push the same way).
        push = np.zeros_like(pts)
        count = np.zeros(n)
        np.add.at(push, i, unit * (gap * share_i)[:, None])
        np.add.at(push, j, -unit * (gap * share_j)[:, None])
        np.add.at(count, i, share_i > 0)
        np.add.at(count, j, share_j > 0)
        pts += push / np.maximum(count, 1.0)[:, None]
        moved = pts - start
        far = np.linalg.norm(moved, axis=1)
        over = far > max_move
        pts[over] = start[over] + moved[over] * (max_move / far[over])[:, None]
    return pts
