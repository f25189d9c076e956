"""Every separation conflict of a plan, not only the worst: pair, when, how close.

The continuous-time check is dense sampling with a bound.  Per knot segment
(cubic Hermite curves), candidate pairs come from a KD-tree at the segment's
start with the radius the limit plus the most two drones can close during the
segment (twice the fleet's top speed there times its length).  Each candidate
pair is sampled at :data:`SAMPLES` instants of the segment; between two
samples ``delta`` apart the distance can fall below the sampled one by at most
``v_rel * delta / 2`` (``v_rel`` the pair's largest relative speed on the
segment), so pairs within that bound of the limit are re-sampled finely
enough that the bound is under :data:`BOUND_M`.  A pair's violating segments
that follow each other are one conflict, reported at its closest instant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.plan.trajectory import Trajectories
from groundctl.plan.verify import DIST_TOL

FloatArray = NDArray[np.float64]

#: Samples per knot segment for every candidate pair.
SAMPLES = 16
#: Largest error of a reported distance, m.
BOUND_M = 1e-3


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
    n = tr.drones
    if n < 2:
        return []
    below = limit - DIST_TOL
    ts = tr.dense_times(SAMPLES)
    pos, vel, _ = tr.evaluate(ts)
    speed = np.linalg.norm(vel, axis=2)
    found: dict[tuple[int, int], list[tuple[int, float, float]]] = {}
    for k in range(len(tr.times) - 1):
        window = slice(k * SAMPLES, (k + 1) * SAMPLES + 1)
        h = float(tr.times[k + 1] - tr.times[k])
        top = float(speed[:, window].max())
        pairs = cKDTree(tr.pos[:, k]).query_pairs(limit + 2 * top * h + 0.1,
                                                  output_type="ndarray")
        if not len(pairs):
            continue
        i, j = pairs[:, 0], pairs[:, 1]
        d = np.linalg.norm(pos[i, window] - pos[j, window], axis=2)
        vrel = np.linalg.norm(vel[i, window] - vel[j, window], axis=2).max(axis=1)
        # Kinematic bound between samples; the relative speed can exceed the sampled top
        # a little inside the segment, hence the factor 2.
        slack = 2 * vrel * (h / SAMPLES) / 2
        dmin = d.min(axis=1)
        at = ts[window][np.argmin(d, axis=1)]
        near = np.flatnonzero(dmin - slack < below)
        if len(near):
            fine_n = int(min(4000, max(SAMPLES, np.ceil(2 * vrel[near].max() * h
                                                        / (2 * BOUND_M)))))
            fine = tr.times[k] + np.linspace(0.0, 1.0, fine_n + 1) * h
            pi, _, _ = tr.evaluate(fine, i[near])
            pj, _, _ = tr.evaluate(fine, j[near])
            dn = np.linalg.norm(pi - pj, axis=2)
            dmin[near] = dn.min(axis=1)
            at[near] = fine[np.argmin(dn, axis=1)]
        for q in np.flatnonzero(dmin < below):
            found.setdefault((int(i[q]), int(j[q])), []).append((k, float(dmin[q]),
                                                                 float(at[q])))
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
