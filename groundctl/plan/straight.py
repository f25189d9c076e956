"""Synchronised straight lines, checked exactly in continuous time.  Pure.

Every drone of a transition flies its own straight line from ``start`` to
``goal`` with one shared rest-to-rest profile ``s(t)``, rising from 0 to 1.  A
pair's relative position is then ``r0 + s(t) (r1 - r0)``: as ``s`` sweeps
``[0, 1]`` it moves along the segment from ``r0`` (their offset at the start) to
``r1`` (at the goal), so its closest approach over the whole transition is the
distance from the origin to that segment, in closed form, whatever the
profile and however finely it is sampled.  (The plan's knots carry the
profile's own velocities, so the Hermite curve between them stays on each
drone's line too; the continuous-time verifier judges the plan in the end.)

This is the planner's floor: a transition whose straight lines keep every
pair apart needs no optimisation at all, and one the optimiser cannot solve
is never refused while its straight lines keep the limit.

Up to PRUNE_ABOVE drones the check runs over all n (n - 1) / 2 pairs, in blocks of
rows so that memory stays bounded.  Above, a spatial index prunes first: the profile
is shared, so at each of CHUNKS stretches of ``s`` every drone lies in a small sphere
around its line's midpoint on that stretch, and a KD-tree per stretch gives the pairs
whose spheres come within reach; the closed form then runs on those alone (10,000
drones grid -> sphere: 15 s over every pair, well under that pruned).  Exact either
way: a pair that comes closer than the reach is within it on some stretch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Rows of the pair matrix handled at once (memory: BLOCK x n x 3 doubles per temporary).
BLOCK = 256
#: Distances are compared with this tolerance, m.
TOL = 1e-9
#: Fleets above this size are pruned with a spatial index first.
PRUNE_ABOVE = 1500
#: Stretches of the shared profile the pruning looks at separately.
CHUNKS = 48


@dataclass(frozen=True)
class StraightCheck:
    """Every pair of the transition's straight lines, closest approach against its target."""

    min_separation_m: float
    """The closest any pair comes, m (inf with fewer than two drones)."""
    pair: tuple[int, int] | None
    """The pair that comes closest (0-based drone indices)."""
    below_limit: int
    """Pairs that come closer than the separation limit."""
    below_target: int
    """Pairs that come closer than their target: the limit plus the tracking margin, or,
    where the pair's own start or goal offsets are closer than that, no closer than those
    (and never below the limit)."""

    @property
    def keeps_limit(self) -> bool:
        return self.below_limit == 0

    @property
    def keeps_target(self) -> bool:
        return self.below_target == 0


def segment_closest(r0: FloatArray, r1: FloatArray) -> FloatArray:
    """Distance from the origin to each segment ``r0[k] -> r1[k]`` (..., 3)."""
    d = r1 - r0
    dd = np.einsum("...i,...i->...", d, d)
    along = -np.einsum("...i,...i->...", r0, d)
    u = np.clip(np.divide(along, dd, out=np.zeros_like(dd), where=dd > 0), 0.0, 1.0)
    return np.asarray(np.linalg.norm(r0 + u[..., None] * d, axis=-1), dtype=np.float64)


def check_straight_lines(start: FloatArray, goal: FloatArray, limit: float,
                         margin: float = 0.0, block: int = BLOCK) -> StraightCheck:
    """Closest approach of every pair flying synchronised straight lines ``start`` ->
    ``goal`` (n, 3), against ``limit`` and the per-pair target (see :class:`StraightCheck`)."""
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    if start.shape != goal.shape or start.ndim != 2 or start.shape[1] != 3:
        raise ValueError(f"`start` and `goal` must both be (n, 3), not {start.shape} and "
                         f"{goal.shape}")
    if block < 1:
        raise ValueError(f"`block` must be at least 1, not {block}")
    n = len(start)
    if n > PRUNE_ABOVE:
        return _check_pruned(start, goal, limit, margin)
    best, pair = np.inf, None
    below_limit = below_target = 0
    for lo in range(0, max(n - 1, 0), block):
        hi = min(lo + block, n - 1)
        # Row i of the block against every j > i (the rest of the row is masked).
        r0 = start[lo:hi, None, :] - start[None, :, :]
        r1 = goal[lo:hi, None, :] - goal[None, :, :]
        closest = segment_closest(r0, r1)
        ends = np.minimum(np.linalg.norm(r0, axis=-1), np.linalg.norm(r1, axis=-1))
        upper = np.arange(n)[None, :] > np.arange(lo, hi)[:, None]
        closest = np.where(upper, closest, np.inf)
        target = np.minimum(limit + margin, np.maximum(limit, ends))
        below_limit += int(np.count_nonzero(closest < limit - TOL))
        below_target += int(np.count_nonzero(closest < target - TOL))
        k = int(np.argmin(closest))
        if closest.flat[k] < best:
            best = float(closest.flat[k])
            i, j = divmod(k, n)
            pair = (lo + i, j)
    return StraightCheck(best, pair, below_limit, below_target)


def _check_pruned(start: FloatArray, goal: FloatArray, limit: float, margin: float
                  ) -> StraightCheck:
    """:func:`check_straight_lines` on the pairs a spatial index leaves (see the module)."""
    from scipy.spatial import cKDTree

    delta = goal - start
    # The closest pair at the start or at the goal bounds the minimum from above; every
    # pair below the target or that minimum must be measured, no other.
    ends = [cKDTree(x).query(x, k=2)[0][:, 1].min() for x in (start, goal)]
    reach = max(float(min(ends)), limit + margin) * (1 + 1e-9) + TOL
    radius = np.linalg.norm(delta, axis=1) / (2 * CHUNKS)
    r_max = float(radius.max())
    found = []
    for c in range(CHUNKS):
        mid = start + (c + 0.5) / CHUNKS * delta
        pairs = cKDTree(mid).query_pairs(reach + 2 * r_max, output_type="ndarray")
        gap = (np.linalg.norm(mid[pairs[:, 0]] - mid[pairs[:, 1]], axis=1)
               - radius[pairs[:, 0]] - radius[pairs[:, 1]])
        found.append(pairs[gap < reach])
    pairs = np.unique(np.concatenate(found), axis=0) if found else np.empty((0, 2), np.intp)
    if not len(pairs):  # unreachable with two drones or more: the closest pair is in
        return StraightCheck(np.inf, None, 0, 0)
    i, j = pairs[:, 0], pairs[:, 1]
    r0, r1 = start[i] - start[j], goal[i] - goal[j]
    closest = segment_closest(r0, r1)
    ends_ij = np.minimum(np.linalg.norm(r0, axis=1), np.linalg.norm(r1, axis=1))
    target = np.minimum(limit + margin, np.maximum(limit, ends_ij))
    k = int(np.argmin(closest))
    return StraightCheck(float(closest[k]), (int(i[k]), int(j[k])),
                         int(np.count_nonzero(closest < limit - TOL)),
                         int(np.count_nonzero(closest < target - TOL)))
