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
from scipy.spatial import cKDTree

from groundctl.show.ranges import ANGLE_DEG, MAX_COORD, MAX_DRONES, MAX_SEED, SPACING
from groundctl.show.reader import MISSING, Table, fmt
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

    Dart throwing: candidates come in batches, each accepted only if it keeps
    its distance from every point accepted before it.  A batch is first
    checked against the points accepted in earlier batches in one KD-tree
    query (most candidates of a crowded area fail here), and only the rest one
    by one against the batch's own earlier picks: the same points as checking
    every candidate against everything, at a fraction of the cost.
    """
    half = np.array(area, dtype=float) / 2
    c = np.array(center, dtype=float)
    ring_c = np.array(around if around is not None else center, dtype=float)
    chosen = np.empty((0, 2))
    tree: cKDTree | None = None
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
        if tree is not None and len(cand):
            # Distance to the nearest earlier pick; < min_spacing rejects the candidate.
            gap, _ = tree.query(cand, k=1, distance_upper_bound=min_spacing)
            cand = cand[~(gap < min_spacing)]
        picked: list[FloatArray] = []
        for p in cand:
            if len(chosen) + len(picked) == n:
                break
            if not picked or np.min(np.hypot(*(np.array(picked) - p).T)) >= min_spacing:
                picked.append(p)
        if picked:
            chosen = np.vstack([chosen, np.array(picked)])
            tree = cKDTree(chosen)
    return chosen if len(chosen) == n else None


def packing_limit(area: tuple[float, float], spacing: float) -> int:
    """The most points ``spacing`` apart that a w x h rectangle can hold at all.

    Oler's inequality for points at mutual distance >= 1 in a convex domain K:
    n <= (2 / sqrt 3) A(K) + P(K) / 2 + 1 (area and perimeter in units of the
    spacing).  Above it no layout exists, so there is no point throwing darts.
    """
    w, h = area[0] / spacing, area[1] / spacing
    return math.floor(2 / math.sqrt(3) * w * h + (w + h) + 1)


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
        spacing = table.ranged("spacing", 3.0, SPACING)
        columns = table.integer("columns", max(1, math.ceil(math.sqrt(n))), minimum=1,
                                maximum=MAX_DRONES)
        cx, cy = table.vector("center", (2,), (0.0, 0.0))
        xy = grid(n, spacing, columns) + np.array([cx, cy])
        return HomeLayout(np.column_stack([xy, np.zeros(n)]), 0, "spacing", spacing)
    elif layout == "points":
        pts = table.point_list("points", (2, 3), max_count=MAX_DRONES)
        if len(pts) != n:
            raise table.error(f"'points' has {len(pts)} points but the show has {n} drones")
        home = np.column_stack([pts[:, :2], pts[:, 2] if pts.shape[1] == 3 else np.zeros(n)])
        if unicycle and np.any(home[:, 2] != 0):
            raise table.error("the unicycle model flies flat: give 'points' as [x, y] "
                              "(every home at z = 0)")
    else:
        area = table.vector("area", (2,), bound=2 * MAX_COORD)
        if min(area) <= 0:
            raise table.error(f"'area' must be two positive sizes [w, h], got {list(area)}")
        center = table.vector("center", (2,), (0.0, 0.0))
        seed = table.integer("seed", 0, minimum=0, maximum=MAX_SEED)
        spacing = table.ranged("min_spacing", min(min_separation, SPACING.high), SPACING)
        annulus = table.vector("annulus", (2,)) if table.has("annulus") else None
        if annulus is not None and not 0 <= annulus[0] < annulus[1]:
            raise table.error(f"'annulus' must be [r_min, r_max] with 0 <= r_min < r_max, "
                              f"got {list(annulus)}")
        if table.has("around") and annulus is None:
            raise table.error("'around' needs 'annulus' = [r_min, r_max]")
        around = table.vector("around", (2,), center)
        most = packing_limit((area[0], area[1]), spacing)
        if n > most:
            raise table.error(f"could not place {n} drones {fmt(spacing)} m apart in the "
                              f"'area': it holds at most {most} points that far apart; "
                              "enlarge it or lower 'min_spacing'")
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
        return np.full(n, math.radians(table.ranged("headings", MISSING, ANGLE_DEG)))
    degrees = table.vector("headings", (n,), bound=ANGLE_DEG.high)
    return np.radians(np.array(degrees))
