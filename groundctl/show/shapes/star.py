"""A star outline: ``arms`` tips, points evenly spaced along the outline."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def star_outline(arms: int, size: float, inner: float) -> NDArray[np.float64]:
    """The (2 * arms, 2) vertices: tips on radius size/2, notches on ``inner`` * size/2."""
    k = np.arange(2 * arms)
    radius = np.where(k % 2 == 0, size / 2, inner * size / 2)
    a = np.pi / 2 - np.pi * k / arms
    return radius[:, None] * np.column_stack([np.cos(a), np.sin(a)])


def star(count: int, size: float, arms: int = 5, inner: float = 0.4) -> NDArray[np.float64]:
    """``count`` points evenly spaced along a star outline, a point on every tip.

    ``size`` is the diameter through the tips; ``inner`` the notch radius as a
    fraction of the tip radius (0.382 draws the classic pentagram outline).
    Each arm (tip to notch to next tip) gets count / arms points starting on
    its tip (the first arms get one more when it does not divide): a tip's
    angle is acute, and two points straddling it would sit far closer
    together than the spacing along the outline.
    """
    verts = star_outline(arms, size, inner)
    closed = np.vstack([verts, verts[:1]])
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    period = cum[-1] / arms
    per_arm = np.full(arms, count // arms) + (np.arange(arms) < count % arms)
    arm = np.repeat(np.arange(arms), per_arm)
    k = np.arange(count) - np.repeat(np.cumsum(per_arm) - per_arm, per_arm)
    s = (arm + k / per_arm[arm]) * period
    return np.column_stack([np.interp(s, cum, closed[:, 0]), np.interp(s, cum, closed[:, 1])])
