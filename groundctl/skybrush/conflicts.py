"""Every separation conflict of a plan, not only the worst: pair, when, how close.

The pair-segments closer than the limit come from the verifier's own exact
continuous-time search (:func:`groundctl.plan.verify.close_segments`).  A pair's
violating segments that follow each other are one conflict, reported at its closest
instant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import DIST_TOL, close_segments

FloatArray = NDArray[np.float64]

@dataclass(frozen=True)
class Conflict:
    """Two drones closer than the limit over one stretch of time."""

    a: int
    """First drone, 0-based."""
    b: int
    """Second drone, 0-based."""
    start: float
    """Show time the stretch begins (a knot at or before the first violation), s."""
    end: float
    """Show time it ends (a knot at or after the last), s."""
    time: float
    """Show time of the closest approach, s."""
    distance: float
    """The closest approach, m."""

    def line(self, limit: float, names: tuple[str, ...] = (), offset: float = 0.0) -> str:
        """One line for the operator; ``offset`` added to the times (the source's clock)."""
        def who(i: int) -> str:
            return f"{i + 1} ({names[i]})" if names else str(i + 1)
        return (f"conflict: drones {who(self.a)} and {who(self.b)} come {self.distance:.3f} m "
                f"apart at t = {self.time + offset:.2f} s (min_separation {limit:g} m; below "
                f"it within the knots {self.start + offset:.2f} to {self.end + offset:.2f} s)")


def find_conflicts(tr: Trajectories, limit: float) -> list[Conflict]:
    """Every stretch in which two drones of ``tr`` come closer than ``limit`` (less the
    verifier's DIST_TOL), in time order."""
    rows, dist, at = close_segments(tr, limit - DIST_TOL)
    found: dict[tuple[int, int], list[tuple[int, float, float]]] = {}
    for (i, j, k), d, t in zip(rows, dist, at, strict=True):
        found.setdefault((int(i), int(j)), []).append((int(k), float(d), float(t)))
    out = []
    for (a, b), segs in found.items():
        run: list[tuple[int, float, float]] = []
        for s in [*segs, (-10, 0.0, 0.0)]:
            if run and s[0] != run[-1][0] + 1:
                best = min(run, key=lambda r: r[1])
                out.append(Conflict(a, b, float(tr.times[run[0][0]]),
                                    float(tr.times[run[-1][0] + 1]), best[2], best[1]))
                run = []
            run.append(s)
    return sorted(out, key=lambda c: (c.time, c.a, c.b))
