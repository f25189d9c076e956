"""An Archimedean spiral with points evenly spaced along its arc length."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from groundctl.show.shapes.resample import along_polyline

#: Polyline vertices per turn used to measure arc length (error well under 1 mm
#: for show-sized spirals).
_VERTICES_PER_TURN = 720


def spiral(count: int, size: float, turns: float = 2.0) -> NDArray[np.float64]:
    """``count`` points evenly spaced by arc length on a spiral of outer diameter ``size``.

    The radius grows linearly from g to size/2 over ``turns`` turns, where g is
    also the gap between neighbouring arms: starting at the centre instead
    would crowd the innermost points far closer together than the rest.
    """
    outer = size / 2
    gap = outer / (turns + 1)
    theta = np.linspace(0.0, 2 * np.pi * turns, max(int(_VERTICES_PER_TURN * turns), 2))
    r = gap * (1 + theta / (2 * np.pi))
    verts = np.column_stack([r * np.cos(theta), r * np.sin(theta)])
    return along_polyline(verts, count, closed=False)
