"""A ring of evenly spaced points."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def circle(count: int, size: float) -> NDArray[np.float64]:
    """``count`` points evenly spaced on a circle of diameter ``size``, the first at the top."""
    a = np.pi / 2 - 2 * np.pi * np.arange(count) / count
    return (size / 2) * np.column_stack([np.cos(a), np.sin(a)])
