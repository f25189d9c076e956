"""Put a shape's local points into the show frame.

Generators work in a local 2D plane frame (u, v) centred on the origin; this
step rotates them in their plane and maps the plane into the show frame.  The
audience looks along +y, so a *vertical* formation is drawn in the x-z plane
with u to the audience's right (+x) and v up (+z).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
Plane = Literal["horizontal", "vertical"]
PLANES: tuple[Plane, ...] = ("vertical", "horizontal")


def rotate2d(points: ArrayLike, rotation_deg: float) -> FloatArray:
    """Rotate (M, 2) points counter-clockwise by ``rotation_deg`` about the origin."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    a = np.radians(rotation_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return pts @ rot.T


def place(points2d: ArrayLike, center: ArrayLike, plane: Plane = "vertical",
          rotation_deg: float = 0.0) -> FloatArray:
    """Map local (M, 2) plane points, or (M, 3) points, to (M, 3) show-frame points.

    (M, 2): rotated in-plane by ``rotation_deg`` (counter-clockwise as seen by
    the audience for vertical, from above for horizontal), then
    ``horizontal``: (u, v) -> (x, y) at z = center z; ``vertical``: (u, v) ->
    (x, z) at y = center y.  (M, 3) points (sphere, explicit 3D points) are
    already in show-frame axes: ``plane`` is ignored and ``rotation_deg``
    turns them about the vertical axis through ``center``.
    """
    pts = np.asarray(points2d, dtype=float)
    c = np.asarray(center, dtype=float).reshape(3)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise ValueError("`points2d` must be an (M, 2) or (M, 3) array")
    out = np.empty((pts.shape[0], 3))
    if pts.shape[1] == 3:
        out[:, :2] = rotate2d(pts[:, :2], rotation_deg)
        out[:, 2] = pts[:, 2]
        return out + c
    uv = rotate2d(pts, rotation_deg)
    if plane == "horizontal":
        out[:, 0], out[:, 1], out[:, 2] = uv[:, 0], uv[:, 1], 0.0
    elif plane == "vertical":
        out[:, 0], out[:, 1], out[:, 2] = uv[:, 0], 0.0, uv[:, 1]
    else:
        raise ValueError(f"`plane` must be one of {PLANES}, got {plane!r}")
    return out + c
