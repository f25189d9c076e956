"""Formation colours: one colour, a gradient across the shape, or one colour per point.

Colours are written as "#rrggbb", "#rgb", a name from :data:`NAMED`, or
[r, g, b] with 0-255 integers; the output is (M, 3) floats in [0, 1].
"""

from __future__ import annotations

import re
from typing import Literal

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
GradientAxis = Literal["u", "v", "radial"]
GRADIENT_AXES: tuple[GradientAxis, ...] = ("u", "v", "radial")

#: A few names for the colours shows use most.
NAMED: dict[str, tuple[int, int, int]] = {
    "black": (0, 0, 0),
    "white": (255, 255, 255),
    "red": (255, 0, 0),
    "orange": (255, 136, 0),
    "yellow": (255, 255, 0),
    "gold": (255, 200, 0),
    "green": (0, 255, 0),
    "cyan": (0, 255, 255),
    "blue": (0, 0, 255),
    "purple": (160, 0, 255),
    "magenta": (255, 0, 255),
    "pink": (255, 105, 180),
}

_HEX = re.compile(r"#(?:[0-9a-fA-F]{3}|[0-9a-fA-F]{6})")


class ColorError(ValueError):
    """A colour value that cannot be read; the message says why and what is accepted."""


def parse_color(value: object) -> FloatArray:
    """One colour as a (3,) float array in [0, 1]; :class:`ColorError` if it is not a colour."""
    if isinstance(value, str):
        text = value.strip()
        if text.lower() in NAMED:
            return np.array(NAMED[text.lower()], dtype=float) / 255.0
        if _HEX.fullmatch(text):
            digits = text[1:]
            if len(digits) == 3:
                digits = "".join(ch * 2 for ch in digits)
            return np.array([int(digits[i:i + 2], 16) for i in (0, 2, 4)], dtype=float) / 255.0
        raise ColorError(f"{value!r} is not a colour; write '#rrggbb', '#rgb', [r, g, b] with "
                         f"0-255 values, or one of {', '.join(NAMED)}")
    if isinstance(value, list):
        ok = len(value) == 3 and all(
            isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255 for c in value)
        if ok:
            return np.array(value, dtype=float) / 255.0
        raise ColorError(f"{value!r} is not a colour; [r, g, b] needs three integers 0-255")
    raise ColorError(f"{value!r} is not a colour; write '#rrggbb' or [r, g, b]")


def gradient_parameter(local: FloatArray, axis: GradientAxis) -> FloatArray:
    """Position t in [0, 1] of each local point along ``axis``.

    ``local`` is the shape before placement: (M, 2) in (u, v), or (M, 3) in
    show axes where u is x and v is z (what the audience sees).
    """
    pts = np.asarray(local, dtype=float)
    if axis == "radial":
        centre = (pts.max(axis=0) + pts.min(axis=0)) / 2
        t = np.linalg.norm(pts - centre, axis=1)
    else:
        col = 0 if axis == "u" else (1 if pts.shape[1] == 2 else 2)
        t = pts[:, col]
    span = float(t.max() - t.min()) if len(t) else 0.0
    return (t - t.min()) / span if span > 1e-12 else np.zeros(len(t))


def gradient(stops: FloatArray, t: FloatArray) -> FloatArray:
    """(M, 3) colours at positions ``t`` in [0, 1] of evenly spaced ``stops`` (K, 3)."""
    stops = np.asarray(stops, dtype=float)
    pos = np.linspace(0.0, 1.0, len(stops))
    return np.column_stack([np.interp(t, pos, stops[:, k]) for k in range(3)])
