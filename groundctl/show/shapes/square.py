"""A square outline with points evenly spaced along its perimeter."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from groundctl.show.shapes.resample import along_polyline


def square(count: int, size: float) -> NDArray[np.float64]:
    """``count`` points evenly spaced along the perimeter of a square of side ``size``.

    The first point is the top-left corner, so every corner is a slot when
    ``count`` is a multiple of 4.
    """
    h = size / 2
    corners = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])
    return along_polyline(corners, count, closed=True)
