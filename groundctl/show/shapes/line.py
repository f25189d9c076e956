"""A straight line of evenly spaced points along u."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def line(count: int, size: float) -> NDArray[np.float64]:
    """``count`` points along u from -size/2 to +size/2 (one point sits at the centre)."""
    u = np.linspace(-size / 2, size / 2, count) if count > 1 else np.zeros(count)
    return np.column_stack([u, np.zeros(count)])
