"""Explicit points: an inline list in the show file or a CSV file of x, y, z."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class CsvProblem(Exception):
    """A CSV file of points that cannot be used; ``line`` is 1-based (0: the whole file)."""

    line: int
    """Line of the file the problem is on."""
    message: str
    """What is wrong, with the value."""


def parse_points_csv(content: str, max_points: int | None = None,
                     bound: float = 10_000.0) -> NDArray[np.float64]:
    """(M, 3) points from CSV text with a header naming the columns x, y and z.

    Other columns are ignored, so a file can carry extra data (ids, colours).
    At most ``max_points`` rows, every coordinate finite and within +-``bound``.
    Messages give line numbers and column names, never the file's text: the
    file may not be what the show file's author says it is.
    """
    try:
        rows = [(i + 1, row) for i, row in enumerate(csv.reader(io.StringIO(content)))
                if any(cell.strip() for cell in row)]
    except csv.Error as exc:  # a NUL byte, a field longer than the csv module allows
        line = int(getattr(exc, "line_num", 0) or 0)
        raise CsvProblem(line, "is not CSV text (a NUL byte or an over-long field)") from None
    if not rows:
        raise CsvProblem(0, "the file is empty; it needs a header 'x,y,z' and one row per point")
    header_line, header = rows[0]
    names = [h.strip().lower() for h in header]
    missing = [c for c in ("x", "y", "z") if c not in names]
    if missing:
        raise CsvProblem(header_line, f"the header (the first line) has no column "
                         f"{', '.join(repr(m) for m in missing)}; it needs 'x,y,z'")
    if max_points is not None and len(rows) - 1 > max_points:
        raise CsvProblem(0, f"{len(rows) - 1} points, more than the {max_points} a formation "
                            "may have")
    cols = [names.index(c) for c in ("x", "y", "z")]
    out = np.empty((len(rows) - 1, 3))
    for k, (line_no, row) in enumerate(rows[1:]):
        if len(row) < len(names):
            raise CsvProblem(line_no, f"{len(row)} values but the header has {len(names)} columns")
        for j, (col, axis) in enumerate(zip(cols, "xyz", strict=True)):
            try:
                val = float(row[col].strip())
            except ValueError:
                raise CsvProblem(line_no, f"'{axis}' is not a number") from None
            if not math.isfinite(val):
                raise CsvProblem(line_no, f"'{axis}' is not finite")
            if abs(val) > bound:
                raise CsvProblem(line_no, f"'{axis}' is beyond +-{bound:g} m")
            out[k, j] = val
    if out.shape[0] == 0:
        raise CsvProblem(header_line, "the file has a header but no points")
    return out
