"""Home (takeoff and landing) positions on the ground, and the unicycle's start headings.

Layouts: ``grid`` (rows of ``columns``, ``spacing`` apart), ``points`` (given
in the file) and ``random`` (seeded, at least ``min_spacing`` apart, inside
an ``area`` and optionally inside an annulus ``around`` a point).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.show.reader import Table, fmt
from groundctl.show.shapes.grid import grid

FloatArray = NDArray[np.float64]

LAYOUTS = ("grid", "points", "random")
HEADING_MODES = ("random", "toward_center")
_KEYS = {
    "grid": ("layout", "spacing", "columns", "center", "headings"),
    "points": ("layout", "points", "headings"),
    "random": ("layout", "area", "center", "seed", "min_spacing", "annulus", "around",
               "headings"),
}
#: Candidates drawn per accepted drone before the random layout gives up.
_TRIES_PER_DRONE = 2000


def random_layout(n: int, area: tuple[float, float], center: tuple[float, float],
                  min_spacing: float, rng: np.random.Generator,
                  annulus: tuple[float, float] | None = None,
                  around: tuple[float, float] | None = None) -> FloatArray | None:
    """(n, 2) points uniform in the area (and annulus), >= ``min_spacing`` apart, or None.

    Dart throwing: candidates come in batches (vectorised), each accepted only
    if it keeps its distance from every point accepted before it.
    """
    half = np.array(area, dtype=float) / 2
    c = np.array(center, dtype=float)
    ring_c = np.array(around if around is not None else center, dtype=float)
    chosen = np.empty((0, 2))
    budget = _TRIES_PER_DRONE * n
    while len(chosen) < n and budget > 0:
        batch = min(budget, 256)
        budget -= batch
        if annulus is None:
            cand = c + rng.uniform(-1.0, 1.0, size=(batch, 2)) * half
        else:
            # Uniform over the annulus' area: radius ~ sqrt(uniform(r0^2, r1^2)).
            r = np.sqrt(rng.uniform(annulus[0] ** 2, annulus[1] ** 2, size=batch))
            a = rng.uniform(0.0, 2 * np.pi, size=batch)
            cand = ring_c + np.column_stack([r * np.cos(a), r * np.sin(a)])
            cand = cand[np.all(np.abs(cand - c) <= half, axis=1)]
        for p in cand:
            if len(chosen) == n:
                break
            if len(chosen) == 0 or np.min(np.hypot(*(chosen - p).T)) >= min_spacing:
                chosen = np.vstack([chosen, p])
    return chosen if len(chosen) == n else None


@dataclass(frozen=True)
class HomeLayout:
    """Home positions as laid out by ``[takeoff]``."""

    home: FloatArray
    """(n, 3) positions on the ground (z = 0 unless the file gives z)."""
    seed: int
    """Seed of the random layout (0 otherwise), reused for random headings."""
    scale_key: str | None
    """Key that spreads the layout out ('spacing' for a grid), for separation advice."""
    scale: float
    """That key's value."""


def read_home(table: Table, n: int, min_separation: float, unicycle: bool) -> HomeLayout:
    """Read ``[takeoff]``'s layout into home positions (headings are read separately)."""
    layout = table.string("layout", "grid", choices=LAYOUTS)
    table.check_keys(_KEYS[layout], {k: f"a key of layout '{lay}'" for lay, keys in
                                     _KEYS.items() for k in keys if k not in _KEYS[layout]})
    seed = 0
    if layout == "grid":
        spacing = table.number("spacing", 3.0, positive=True)
        columns = table.integer("columns", max(1, math.ceil(math.sqrt(n))), minimum=1)
        cx, cy = table.vector("center", (2,), (0.0, 0.0))
        xy = grid(n, spacing, columns) + np.array([cx, cy])
        return HomeLayout(np.column_stack([xy, np.zeros(n)]), 0, "spacing", spacing)
    elif layout == "points":
        pts = table.point_list("points", (2, 3))
        if len(pts) != n:
            raise table.error(f"'points' has {len(pts)} points but the show has {n} drones")
        home = np.column_stack([pts[:, :2], pts[:, 2] if pts.shape[1] == 3 else np.zeros(n)])
        if unicycle and np.any(home[:, 2] != 0):
            raise table.error("the unicycle model flies flat: give 'points' as [x, y] "
                              "(every home at z = 0)")
    else:
        area = table.vector("area", (2,))
        if min(area) <= 0:
            raise table.error(f"'area' must be two positive sizes [w, h], got {list(area)}")
        center = table.vector("center", (2,), (0.0, 0.0))
        seed = table.integer("seed", 0)
        spacing = table.number("min_spacing", min_separation, positive=True)
        annulus = table.vector("annulus", (2,)) if table.has("annulus") else None
        if annulus is not None and not 0 <= annulus[0] < annulus[1]:
            raise table.error(f"'annulus' must be [r_min, r_max] with 0 <= r_min < r_max, "
                              f"got {list(annulus)}")
        if table.has("around") and annulus is None:
            raise table.error("'around' needs 'annulus' = [r_min, r_max]")
        around = table.vector("around", (2,), center)
        xy = random_layout(n, (area[0], area[1]), (center[0], center[1]), spacing,
                           np.random.default_rng(seed),
                           (annulus[0], annulus[1]) if annulus else None, (around[0], around[1]))
        if xy is None:
            where = " and the 'annulus'" if annulus else ""
            raise table.error(f"could not place {n} drones {fmt(spacing)} m apart in the "
                              f"'area'{where}; enlarge them or lower 'min_spacing'")
        home = np.column_stack([xy, np.zeros(n)])
    return HomeLayout(home, seed, None, 0.0)


def read_headings(table: Table, n: int, seed: int, home: FloatArray,
                  target_centre: FloatArray) -> FloatArray | None:
    """(n,) start headings in radians (from +x toward +y), or None if not given.

    ``toward_center`` points each drone at ``target_centre`` (the first
    formation's centre); ``random`` uses the layout's seed, offset so the
    headings are not correlated with the positions drawn from the same seed.
    """
    if not table.has("headings"):
        return None
    value = table.get("headings")
    if isinstance(value, str):
        mode = table.string("headings", choices=HEADING_MODES)
        if mode == "random":
            return np.random.default_rng([seed, 1]).uniform(-np.pi, np.pi, size=n)
        d = np.asarray(target_centre, dtype=float)[:2] - home[:, :2]
        return np.arctan2(d[:, 1], d[:, 0])
    if isinstance(value, int | float) and not isinstance(value, bool):
        return np.full(n, math.radians(table.number("headings")))
    degrees = table.vector("headings", (n,))
    return np.radians(np.array(degrees))
