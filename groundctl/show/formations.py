"""One ``[[formation]]`` table -> a :class:`Formation`: shape, placement, colours, checks.

Each shape reads its own keys here and calls its pure generator in
:mod:`groundctl.show.shapes`; the generator's *scale key* (``size``,
``spacing``, ``dot_spacing``) is what a separation message tells the
operator to increase, since every generated shape scales linearly with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np
from numpy.typing import NDArray

from groundctl.show import shapes
from groundctl.show.colors import (
    GRADIENT_AXES,
    ColorError,
    GradientAxis,
    gradient,
    gradient_parameter,
    parse_color,
)
from groundctl.show.model import Formation, Model, UnicycleModel
from groundctl.show.reader import Table, fmt
from groundctl.show.shapes.font import SUPPORTED

FloatArray = NDArray[np.float64]

#: Keys every formation may have.
COMMON_KEYS = ("name", "shape", "center", "plane", "rotation", "transition", "hold",
               "color", "gradient", "gradient_axis", "colors")
#: Shape-specific keys, by shape.  Also the list of shapes.
SHAPE_KEYS: dict[str, tuple[str, ...]] = {
    "grid": ("count", "rows", "columns", "spacing", "size"),
    "line": ("count", "size"),
    "circle": ("count", "size"),
    "square": ("count", "size"),
    "star": ("count", "size", "arms", "inner"),
    "spiral": ("count", "size", "turns"),
    "sphere": ("count", "size"),
    "text": ("text", "dot_spacing"),
    "points": ("points", "file"),
}
SHAPES = tuple(SHAPE_KEYS)
DEFAULT_DOT_SPACING = 2.0
DEFAULT_COLOR = "#ffffff"


@dataclass(frozen=True)
class LocalShape:
    """A shape before placement, and the key that scales it."""

    points: FloatArray
    """(M, 2) in the plane's (u, v), or (M, 3) in show axes relative to ``center``."""
    scale_key: str | None
    """Key whose value scales the shape linearly (None: explicit points)."""
    scale: float
    """That key's value."""


@dataclass(frozen=True)
class Context:
    """What a formation needs to know about the rest of the show."""

    path: str
    """Show file path, for messages."""
    base_dir: Path
    """Directory that relative file names (CSV) are resolved against."""
    drones: int
    """Number of drones."""
    model: Model
    """Dynamics model (the unicycle flies flat at ``takeoff_altitude``)."""
    takeoff_altitude: float
    """Height of the start positions above home, m."""


def _count(t: Table, drones: int) -> int:
    count = t.integer("count", drones, minimum=1)
    if count < drones:
        raise t.error(f"'count' {count} is fewer than the {drones} drones; "
                      f"remove 'count' or set it to at least {drones}")
    return count


def _sized(t: Table, drones: int) -> tuple[int, float]:
    return _count(t, drones), t.number("size", positive=True)


def _grid(t: Table, drones: int) -> LocalShape:
    rows = t.integer("rows", 0, minimum=1) if t.has("rows") else None
    cols = t.integer("columns", 0, minimum=1) if t.has("columns") else None
    if rows is not None and cols is not None:
        if t.has("count"):
            raise t.error("give 'count' or 'rows' and 'columns', not all three")
        count = rows * cols
    else:
        count = _count(t, drones)
        if rows is not None:
            cols = -(-count // rows)
    r, c = shapes.grid_shape(count, cols)
    if t.has("spacing") == t.has("size"):
        raise t.error("give exactly one of 'spacing' (between neighbours) and 'size' "
                      "(width of the longer side)")
    if t.has("spacing"):
        spacing = t.number("spacing", positive=True)
        return LocalShape(shapes.grid(count, spacing, c), "spacing", spacing)
    size = t.number("size", positive=True)
    return LocalShape(shapes.grid(count, size / max(r - 1, c - 1, 1), c), "size", size)


def _text(t: Table) -> LocalShape:
    value = t.string("text")
    if not value.strip():
        raise t.error("'text' is empty; write at least one character")
    bad = shapes.unsupported_chars(value)
    if bad:
        raise t.error(f"'text' has characters the font cannot draw: {bad!r}; "
                      f"it draws {SUPPORTED.replace(' ', '')} and space")
    spacing = t.number("dot_spacing", DEFAULT_DOT_SPACING, positive=True)
    return LocalShape(shapes.text(value, spacing), "dot_spacing", spacing)


def _points(t: Table, ctx: Context) -> LocalShape:
    if t.has("points") == t.has("file"):
        raise t.error("give exactly one of 'points' (inline [x, y, z] or [u, v]) and "
                      "'file' (a CSV with columns x,y,z)")
    if t.has("points"):
        return LocalShape(t.point_list("points", (2, 3)), None, 0.0)
    name = t.string("file")
    csv_path = ctx.base_dir / name
    try:
        content = csv_path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise t.error(f"'file' {name!r} not found (looked for {csv_path})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise t.error(f"'file' {name!r} cannot be read: {exc}") from exc
    try:
        pts = shapes.parse_points_csv(content)
    except shapes.CsvProblem as exc:
        at = f" line {exc.line}" if exc.line else ""
        raise t.error(f"'file' {name}{at}: {exc.message}") from None
    return LocalShape(pts, None, 0.0)


def local_shape(shape: str, t: Table, ctx: Context) -> LocalShape:
    """Read ``shape``'s own keys and generate its points before placement."""
    n = ctx.drones
    if shape == "grid":
        return _grid(t, n)
    if shape == "text":
        return _text(t)
    if shape == "points":
        return _points(t, ctx)
    count, size = _sized(t, n)
    if shape == "line":
        pts = shapes.line(count, size)
    elif shape == "circle":
        pts = shapes.circle(count, size)
    elif shape == "square":
        pts = shapes.square(count, size)
    elif shape == "star":
        arms = t.integer("arms", 5, minimum=3)
        inner = t.number("inner", 0.4, positive=True, maximum=1.0)
        pts = shapes.star(count, size, arms, inner)
    elif shape == "spiral":
        pts = shapes.spiral(count, size, t.number("turns", 2.0, positive=True))
    else:
        pts = shapes.sphere(count, size)
    return LocalShape(pts, "size", size)


def read_colors(t: Table, local: FloatArray) -> FloatArray:
    """(M, 3) colours in [0, 1] from ``color``, ``gradient`` or ``colors`` (white if none)."""
    given = [k for k in ("color", "gradient", "colors") if t.has(k)]
    if len(given) > 1:
        raise t.error(f"give only one of 'color', 'gradient' and 'colors', got "
                      f"{' and '.join(repr(k) for k in given)}")
    if t.has("gradient_axis") and not t.has("gradient"):
        raise t.error("'gradient_axis' needs 'gradient' = [colour, colour, ...]")
    m = len(local)
    key = given[0] if given else "color"
    try:
        if key == "color":
            return np.tile(parse_color(t.get("color", DEFAULT_COLOR)), (m, 1))
        value = t.get(key)
        if not isinstance(value, list) or not all(isinstance(v, str | list) for v in value):
            raise t.error(f"'{key}' must be an array of colours, got {_short(value)}")
        if key == "gradient":
            if len(value) < 2:
                raise t.error(f"'gradient' needs at least 2 colours, got {len(value)}")
            axis = t.string("gradient_axis", "u", choices=GRADIENT_AXES)
            stops = np.array([parse_color(v) for v in value])
            return gradient(stops, gradient_parameter(local, cast(GradientAxis, axis)))
        if len(value) != m:
            raise t.error(f"'colors' has {len(value)} colours but the shape has {m} points")
        return np.array([parse_color(v) for v in value])
    except ColorError as exc:
        raise t.error(f"'{key}': {exc}") from None


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def formation_where(index: int, name: str) -> str:
    """The ``where`` of messages about a formation: ``formation 3 'star'``."""
    return f"formation {index} '{name}'"


def read_formation(data: dict[str, object], index: int, ctx: Context) -> tuple[Formation, Table,
                                                                               LocalShape]:
    """Build formation ``index`` (1-based) from its table; shape-level problems raise here."""
    t = Table(data, ctx.path, f"formation {index}")
    if isinstance(data.get("name"), str):
        t.where = formation_where(index, str(data["name"]))
    shape = t.string("shape", choices=SHAPES)
    name = t.string("name", shape)
    t.where = formation_where(index, name)
    others = {k: f"a key of shape {', '.join(s for s in SHAPES if k in SHAPE_KEYS[s])}"
              for keys in SHAPE_KEYS.values() for k in keys}
    allowed = COMMON_KEYS + SHAPE_KEYS[shape]
    t.check_keys(allowed, {k: v for k, v in others.items() if k not in allowed})

    unicycle = isinstance(ctx.model, UnicycleModel)
    transition = t.number("transition", positive=True)
    hold = t.number("hold", 0.0, minimum=0.0)
    if unicycle and hold > 0:
        raise t.error(f"'hold' must be 0 for the unicycle model, got {fmt(hold)}: "
                      "it flies at constant speed and cannot hover")
    plane = t.string("plane", "horizontal" if unicycle else "vertical", choices=shapes.PLANES)
    rotation = t.number("rotation", 0.0)
    flat = f"the unicycle model flies flat at 'takeoff_altitude' {fmt(ctx.takeoff_altitude)} m"
    if unicycle and shape == "sphere":
        raise t.error(f"shape 'sphere' is 3D but {flat}; use a 2D shape")
    if unicycle and plane == "vertical":
        raise t.error(f"'plane' \"vertical\" is not possible: {flat}; "
                      "use plane = \"horizontal\" (the default for this model)")

    # Explicit points are positions in their own right: no centre needed.
    given = t.has("center") or shape != "points"
    if unicycle:
        raw = t.vector("center", (2, 3)) if given else (0.0, 0.0)
        if len(raw) == 3 and abs(raw[2] - ctx.takeoff_altitude) > 1e-9:
            raise t.error(f"'center' z {fmt(raw[2])} m is not possible: {flat}; "
                          "give 'center' as [x, y]")
        center = (raw[0], raw[1], ctx.takeoff_altitude)
    else:
        raw = t.vector("center", (3,)) if given else (0.0, 0.0, 0.0)
        center = (raw[0], raw[1], raw[2])

    local = local_shape(shape, t, ctx)
    if unicycle and local.points.shape[1] == 3:
        # 3D points (a CSV, inline [x, y, z]) give absolute heights, which must
        # then be the flight level itself.
        center = (center[0], center[1], 0.0)
    points = shapes.place(local.points, center, cast(shapes.Plane, plane), rotation)
    if unicycle and local.points.shape[1] == 3:
        off = np.flatnonzero(np.abs(points[:, 2] - ctx.takeoff_altitude) > 1e-9)
        if len(off):
            raise t.error(f"point {off[0] + 1} is at z = {fmt(float(points[off[0], 2]))} m but "
                          f"{flat}; give points as [x, y]")
    if len(points) < ctx.drones:
        raise t.error(f"{ctx.drones} drones but the shape has {len(points)} points")
    colors = read_colors(t, local.points)
    formation = Formation(name=name, shape=shape, points=points, colors=colors,
                          transition_s=transition, hold_s=hold, index=index)
    return formation, t, local

