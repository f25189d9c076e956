"""Points evenly spaced along a polyline, by arc length.

Even spacing matters more than anything else in a formation: the closest
pair of slots decides how small the formation may be for a given separation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def along_polyline(vertices: ArrayLike, count: int, *, closed: bool) -> FloatArray:
    """``count`` points evenly spaced by arc length along a polyline of (K, 2) vertices.

    A closed outline gets ``count`` equal gaps (the first point sits on the
    first vertex, the last one a gap before it); an open one puts its first
    and last points on its ends.
    """
    verts = np.asarray(vertices, dtype=float)
    if closed:
        verts = np.vstack([verts, verts[:1]])
    seg = np.linalg.norm(np.diff(verts, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    if count < 1:
        return np.empty((0, verts.shape[1]))
    if closed:
        s = np.arange(count) * (total / count)
    else:
        s = np.linspace(0.0, total, count) if count > 1 else np.array([total / 2])
    return np.column_stack([np.interp(s, cum, verts[:, k]) for k in range(verts.shape[1])])
