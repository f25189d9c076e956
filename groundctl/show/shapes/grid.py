"""A rectangular grid of points, rows along v, columns along u."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


def grid_shape(count: int, columns: int | None = None) -> tuple[int, int]:
    """(rows, columns) for ``count`` points; as square as possible unless ``columns`` is given."""
    cols = columns if columns is not None else max(1, math.ceil(math.sqrt(count)))
    return max(1, math.ceil(count / cols)), cols


def grid(count: int, spacing: float, columns: int | None = None) -> NDArray[np.float64]:
    """``count`` points on a grid ``spacing`` apart, filled row by row from the top.

    A partial last row is centred under the others, so the grid stays symmetric.
    """
    rows, cols = grid_shape(count, columns)
    idx = np.arange(count)
    r, c = idx // cols, idx % cols
    in_row = np.where(r == rows - 1, count - (rows - 1) * cols, cols)
    u = (c - (in_row - 1) / 2) * spacing
    v = ((rows - 1) / 2 - r) * spacing
    return np.column_stack([u, v]).astype(float)
