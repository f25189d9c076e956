"""Formation shapes: one small pure-numpy generator per family, and the placement step.

Every 2D generator returns (M, 2) points in a local plane frame (u, v)
centred on the origin and scaled by its size argument; :func:`place` rotates
them in their plane and maps them into the show frame.  ``sphere`` returns
(M, 3) points in show axes.
"""

from groundctl.show.shapes.circle import circle
from groundctl.show.shapes.grid import grid, grid_shape
from groundctl.show.shapes.line import line
from groundctl.show.shapes.place import PLANES, Plane, place, rotate2d
from groundctl.show.shapes.points import CsvProblem, parse_points_csv
from groundctl.show.shapes.sphere import sphere
from groundctl.show.shapes.spiral import spiral
from groundctl.show.shapes.square import square
from groundctl.show.shapes.star import star, star_outline
from groundctl.show.shapes.text import text, text_dot_count, unsupported_chars

__all__ = [
    "PLANES",
    "CsvProblem",
    "Plane",
    "circle",
    "grid",
    "grid_shape",
    "line",
    "parse_points_csv",
    "place",
    "rotate2d",
    "sphere",
    "spiral",
    "square",
    "star",
    "star_outline",
    "text",
    "text_dot_count",
    "unsupported_chars",
]
