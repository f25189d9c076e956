"""Text drawn with the 5x7 dot-matrix font, one drone per dot."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from groundctl.show.shapes.font import GLYPH_COLUMNS, GLYPH_ROWS, SUPPORTED, glyph

#: Blank columns between two characters.
_GAP = 1


def unsupported_chars(text: str) -> str:
    """The characters of ``text`` the font cannot draw, in order, without repeats."""
    bad = [ch for ch in text if (ch.upper() if ch.isascii() else ch) not in SUPPORTED]
    return "".join(dict.fromkeys(bad))


def text(value: str, dot_spacing: float) -> NDArray[np.float64]:
    """(M, 2) dots of ``value``, dots ``dot_spacing`` apart, centred on the origin.

    M is fixed by the string (see :func:`text_dot_count`); v points up.
    """
    cells = [(r, i * (GLYPH_COLUMNS + _GAP) + c)
             for i, ch in enumerate(value) for r, c in glyph(ch)]
    if not cells:
        return np.empty((0, 2))
    rc = np.array(cells, dtype=float)
    # Centre on the dots actually lit (not the character cells), so that a
    # narrow last glyph such as "I" does not shift the text off the centre.
    mid = (rc[:, 1].min() + rc[:, 1].max()) / 2
    u = (rc[:, 1] - mid) * dot_spacing
    v = ((GLYPH_ROWS - 1) / 2 - rc[:, 0]) * dot_spacing
    return np.column_stack([u, v])


def text_dot_count(value: str) -> int:
    """How many dots (slots) ``value`` draws."""
    return sum(len(glyph(ch)) for ch in value)
