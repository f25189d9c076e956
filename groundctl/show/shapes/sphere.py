"""A sphere: the Fibonacci lattice, the most even cheap spread of N points on a sphere."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_GOLDEN_ANGLE = np.pi * (3 - np.sqrt(5))


def sphere(count: int, size: float) -> NDArray[np.float64]:
    """(count, 3) points on a sphere of diameter ``size`` centred on the origin (show axes).

    Heights are offset by half a step so that no two points sit on the poles,
    where the plain lattice puts its closest pair.
    """
    i = np.arange(count)
    z = 1 - (2 * i + 1) / count
    rho = np.sqrt(np.clip(1 - z**2, 0.0, None))
    a = _GOLDEN_ANGLE * i
    return (size / 2) * np.column_stack([rho * np.cos(a), rho * np.sin(a), z])
