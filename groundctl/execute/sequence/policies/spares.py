"""Which spare takes over a track whose drone has left the show (issue 29), and in what
order the others try if its join cannot be planned or it fails on its way in.

A spare may go if it is ready (it passed pre-flight and is heard), not already flying
into or flying a track, and has not failed to join this track already.  The one that
can be there first goes first: its straight-line distance to the track's next slot at
the show's horizontal speed, plus, for one waiting on its pad, the time to arm and
climb (:func:`groundctl.execute.leaving.climb_time` is the planner's own figure; here
the caller passes it in).  Ties go to the lower system id, so the choice is
repeatable.  Pure: the caller has the fleet's view; the join itself is planned
elsewhere (:func:`groundctl.flight.joining.plan_join`) and may still find no window.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class SpareView:
    """What the choice needs of one spare."""

    sysid: int
    """Its system id (vehicle id)."""
    position: tuple[float, float, float]
    """Where it waits, show frame, m (its standby point, or its pad)."""
    ready: bool
    """Passed pre-flight and heard now."""
    busy: bool = False
    """Already flying into a track, or flying one."""
    on_ground: bool = False
    """Waiting on its pad: it must arm and climb before it can go."""


@dataclass(frozen=True)
class Replacement:
    """The spares to try for one track, in order, and why (for the operator)."""

    order: tuple[int, ...]
    """System ids, the first to go first; empty: none can."""
    why: str
    """One line: which goes and why, or why none can."""

    @property
    def spare(self) -> int | None:
        """The one that goes, if any."""
        return self.order[0] if self.order else None


def choose_spares(slot: NDArray[np.float64] | Sequence[float], spares: Sequence[SpareView],
                  *, enabled: bool, max_speed_h: float, climb_s: float,
                  tried: Collection[int] = ()) -> Replacement:
    """The spares that may take over a track whose next slot is ``slot`` (show frame),
    quickest there first (module docstring).  ``enabled`` False: the flight was asked to
    fly without spares (``--no-spares``).  ``climb_s``: how long a spare on its pad
    takes to arm and climb; ``tried``: spares that already failed to join this track."""
    if not enabled:
        return Replacement((), "spares are off for this flight (--no-spares)")
    if not spares:
        return Replacement((), "the show has no spares")
    if not max_speed_h > 0:
        raise ValueError(f"`max_speed_h` must be positive, got {max_speed_h!r}")
    free = [s for s in spares if s.ready and not s.busy and s.sysid not in tried]
    if not free:
        busy = sum(s.busy for s in spares)
        unready = sum(not s.ready for s in spares)
        failed = sum(s.sysid in tried for s in spares if s.ready and not s.busy)
        parts = [f"{n} {what}" for n, what in ((busy, "already flying a track or into one"),
                                                (unready, "not ready"),
                                                (failed, "failed to join it already"))
                 if n]
        return Replacement((), f"no spare can go ({len(spares)} in all: "
                               f"{', '.join(parts)})")
    goal = np.asarray(slot, dtype=float)

    def eta(s: SpareView) -> float:
        flight = math.dist(s.position, goal) / max_speed_h
        return flight + (climb_s if s.on_ground else 0.0)

    ranked = sorted(free, key=lambda s: (eta(s), s.sysid))
    first = ranked[0]
    where = "from its pad" if first.on_ground else "from where it hovers"
    return Replacement(tuple(s.sysid for s in ranked),
                       f"spare {first.sysid} goes, {eta(first):.0f} s away {where} at the "
                       f"show's speed ({len(ranked) - 1} more to try)")
