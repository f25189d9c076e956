"""One ``[[formation]]`` table -> a :class:`Formation`: shape, placement, colours, checks.

Each shape reads its own keys here and calls its pure generator in
:mod:`groundctl.show.shapes`; the generator's *scale key* (``size``,
``spacing``, ``dot_spacing``) is what a separation message tells the
operator to increase, since every generated shape scales linearly with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np
from numpy.typing import NDArray

from groundctl.files import FileProblem, read_regular_file
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
from groundctl.show.ranges import (
    ANGLE_DEG,
    MAX_GRADIENT_STOPS,
    MAX_NAME_CHARS,
    MAX_POINTS_FILE_BYTES,
    MAX_SLOTS,
    MAX_TEXT_CHARS,
    SIZE,
    above_zero,
)
from groundctl.show.reader import MISSING, Table, fmt
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
    points_dirs: tuple[Path, ...] = ()
    """Directories besides ``base_dir`` that point files may be read from."""
    max_flight_time: float = 900.0
    """[limits] max_flight_time: no transition or hold may be longer, s."""
    files_read: list[tuple[str, bytes]] = field(default_factory=list)
    """Every point file read so far (its name in the show file, its bytes), for the
    show's digest."""


def _count(t: Table, drones: int) -> int:
    count = t.integer("count", drones, minimum=1, maximum=MAX_SLOTS)
    if count < drones:
        raise t.error(f"'count' {count} is fewer than the {drones} drones; "
                      f"remove 'count' or set it to at least {drones}")
    return count


def _sized(t: Table, drones: int) -> tuple[int, float]:
    return _count(t, drones), t.ranged("size", MISSING, SIZE)


def _grid(t: Table, drones: int) -> LocalShape:
    rows = t.integer("rows", 0, minimum=1, maximum=MAX_SLOTS) if t.has("rows") else None
    cols = t.integer("columns", 0, minimum=1, maximum=MAX_SLOTS) if t.has("columns") else None
    if rows is not None and cols is not None:
        if t.has("count"):
            raise t.error("give 'count' or 'rows' and 'columns', not all three")
        count = rows * cols
        if count > MAX_SLOTS:
            raise t.error(f"'rows' x 'columns' is {count} points, more than {MAX_SLOTS}")
    else:
        count = _count(t, drones)
        if rows is not None:
            cols = -(-count // rows)
    r, c = shapes.grid_shape(count, cols)
    if t.has("spacing") == t.has("size"):
        raise t.error("give exactly one of 'spacing' (between neighbours) and 'size' "
                      "(width of the longer side)")
    if t.has("spacing"):
        spacing = t.ranged("spacing", MISSING, SIZE)
        return LocalShape(shapes.grid(count, spacing, c), "spacing", spacing)
    size = t.ranged("size", MISSING, SIZE)
    return LocalShape(shapes.grid(count, size / max(r - 1, c - 1, 1), c), "size", size)


def _text(t: Table) -> LocalShape:
    value = t.string("text")
    if not value.strip():
        raise t.error("'text' is empty; write at least one character")
    if len(value) > MAX_TEXT_CHARS:
        raise t.error(f"'text' must be at most {MAX_TEXT_CHARS} characters, got {len(value)}")
    bad = shapes.unsupported_chars(value)
    if bad:
        raise t.error(f"'text' has characters the font cannot draw: {bad!r}; "
                      f"it draws {SUPPORTED.replace(' ', '')} and space")
    spacing = t.ranged("dot_spacing", DEFAULT_DOT_SPACING, above_zero(1000.0))
    dots = shapes.text_dot_count(value)
    if dots > MAX_SLOTS:
        raise t.error(f"'text' draws {dots} dots, more than {MAX_SLOTS}; write fewer characters")
    return LocalShape(shapes.text(value, spacing), "dot_spacing", spacing)


def _points(t: Table, ctx: Context) -> LocalShape:
    if t.has("points") == t.has("file"):
        raise t.error("give exactly one of 'points' (inline [x, y, z] or [u, v]) and "
                      "'file' (a CSV with columns x,y,z)")
    if t.has("points"):
        return LocalShape(t.point_list("points", (2, 3)), None, 0.0)
    name = t.string("file")
    content = _read_points_file(t, name, ctx)
    try:
        pts = shapes.parse_points_csv(content, max_points=MAX_SLOTS)
    except shapes.CsvProblem as exc:
        at = f" line {exc.line}" if exc.line else ""
        raise t.error(f"'file' {name}{at}: {exc.message}") from None
    return LocalShape(pts, None, 0.0)


def _read_points_file(t: Table, name: str, ctx: Context) -> str:
    """The text of point file ``name``: a regular file of bounded size under the show
    file's directory or a ``points_dirs`` directory (symbolic links resolved first).

    No message quotes what the file holds: a show file from elsewhere must not be
    able to make groundctl print a line of a file it points at.
    """
    csv_path = ctx.base_dir / name
    roots = [ctx.base_dir, *ctx.points_dirs]
    try:
        real = csv_path.resolve()
        inside = any(real.is_relative_to(root.resolve()) for root in roots)
    except (OSError, RuntimeError, ValueError):  # a loop of links, a NUL in the name
        raise t.error(f"'file' {name!r} is not a usable file name") from None
    if not inside:
        where = " or ".join(str(r) for r in roots)
        raise t.error(f"'file' {name!r} is outside the show file's directory: point files "
                      f"must be under {where} (allow another directory with --points-dir)")
    try:
        raw = read_regular_file(real, MAX_POINTS_FILE_BYTES)
    except FileProblem as exc:
        if exc.missing:
            raise t.error(f"'file' {name!r} not found (looked for {csv_path})") from None
        raise t.error(f"'file' {name!r}: {exc}") from None
    try:
        content = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise t.error(f"'file' {name!r} is not UTF-8 text (byte {exc.start})") from None
    ctx.files_read.append((name, raw))
    return content


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
        arms = t.integer("arms", 5, minimum=3, maximum=100)
        inner = t.number("inner", 0.4, positive=True, maximum=1.0)
        pts = shapes.star(count, size, arms, inner)
    elif shape == "spiral":
        pts = shapes.spiral(count, size, t.ranged("turns", 2.0, above_zero(100.0)))
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
            if len(value) > MAX_GRADIENT_STOPS:
                raise t.error(f"'gradient' may have at most {MAX_GRADIENT_STOPS} colours, got "
                              f"{len(value)}")
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
    raw_name = data.get("name")
    if isinstance(raw_name, str) and raw_name.isprintable() and len(raw_name) <= MAX_NAME_CHARS:
        t.where = formation_where(index, raw_name)
    shape = t.string("shape", choices=SHAPES)
    name = t.string("name", shape, max_length=MAX_NAME_CHARS)
    t.where = formation_where(index, name)
    others = {k: f"a key of shape {', '.join(s for s in SHAPES if k in SHAPE_KEYS[s])}"
              for keys in SHAPE_KEYS.values() for k in keys}
    allowed = COMMON_KEYS + SHAPE_KEYS[shape]
    t.check_keys(allowed, {k: v for k, v in others.items() if k not in allowed})

    unicycle = isinstance(ctx.model, UnicycleModel)
    transition = t.number("transition", positive=True, maximum=ctx.max_flight_time)
    hold = t.number("hold", 0.0, minimum=0.0, maximum=ctx.max_flight_time)
    if unicycle and hold > 0:
        raise t.error(f"'hold' must be 0 for the unicycle model, got {fmt(hold)}: "
                      "it flies at constant speed and cannot hover")
    plane = t.string("plane", "horizontal" if unicycle else "vertical", choices=shapes.PLANES)
    rotation = t.ranged("rotation", 0.0, ANGLE_DEG)
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

