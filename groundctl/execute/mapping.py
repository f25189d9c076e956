"""Which vehicle flies which plan track.

Either explicit (a fleet file says system id -> track) or automatic: every
vehicle standing on the ground is matched to the takeoff slot nearest to it
(an optimal assignment, so two vehicles never claim one slot), and refused if
it stands farther than a tolerance from that slot: a drone that is not where
the plan expects it would take off into its neighbours.

A plan with spare drones (:attr:`Plan.spares <groundctl.plan.plan.Plan.spares>`) has
a pad for each: a vehicle left without a track that stands on a pad is that pad's
spare (the same optimal assignment over the pads), checked before the show like every
other vehicle but never given a track.  A vehicle nearer a pad than every takeoff slot
is matched to the pads only: laid-out pads stand one takeoff spacing beside the grid,
often within the slot tolerance of its edge, and a spare that took a free slot while a
show drone's position was still unknown would fly that drone's track from its pad.

Distances are horizontal: GPS altitude wanders by metres on the ground while
the horizontal position is good to tens of centimetres, and every slot is on
the ground anyway.
"""

from __future__ import annotations

from collections.abc import Collection
from collections.abc import Mapping as MappingABC
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

DEFAULT_SLOT_TOLERANCE_M = 3.0
#: Largest height of a vehicle on the ground above (or below) its slot, m: GPS and
#: barometer put a vehicle a few metres off; a show whose origin altitude is not the
#: field's puts every vehicle tens or hundreds of metres off, and its show there.
DEFAULT_SLOT_HEIGHT_TOLERANCE_M = 10.0


@dataclass(frozen=True)
class Assignment:
    """The result of matching vehicles to plan tracks."""

    tracks: dict[int, int]
    """System id -> plan track index, for every vehicle allowed to fly."""
    distances: dict[int, float]
    """System id -> horizontal distance to its slot (a spare's: to its pad), m (where its
    position is known)."""
    refused: dict[int, str] = field(default_factory=dict)
    """System id -> why it may not fly (off its slot, no position, unknown track)."""
    unassigned_tracks: tuple[int, ...] = ()
    """Tracks no vehicle will fly."""
    extra_vehicles: tuple[int, ...] = ()
    """Vehicles left over once every slot had a vehicle (or not in the fleet file)."""
    heights: dict[int, float] = field(default_factory=dict)
    """System id -> its height above its slot (a spare's: its pad), m (show frame: from
    its EKF origin's altitude and the show origin's), for every vehicle given a track or
    a pad."""
    spares: dict[int, int] = field(default_factory=dict)
    """System id -> spare pad index (0-based, into ``Plan.spares.pads``), for every
    vehicle standing by as a spare: no track, checked, never blocking the show."""

    def problems(self) -> list[str]:
        """Every issue as one line for the operator (empty when all is well)."""
        lines = [self.refused[s] for s in sorted(self.refused)]
        if self.unassigned_tracks:
            lines.append("no vehicle for track(s) " + ", ".join(map(str, self.unassigned_tracks)))
        if self.extra_vehicles:
            lines.append("vehicle(s) " + ", ".join(map(str, self.extra_vehicles))
                         + " have no track and stay on the ground")
        return lines


def _positions(positions: MappingABC[int, ArrayLike | None]) -> dict[int, np.ndarray | None]:
    out: dict[int, np.ndarray | None] = {}
    for sysid, p in positions.items():
        if p is None:
            out[sysid] = None
            continue
        arr = np.asarray(p, dtype=float)
        if arr.shape != (3,):
            raise ValueError(f"`positions` entry for vehicle {sysid} must have shape (3,), "
                             f"got {arr.shape}")
        out[sysid] = arr
    return out


def _check_tolerance(tolerance_m: float) -> None:
    if not tolerance_m > 0:
        raise ValueError(f"`tolerance_m` must be positive, got {tolerance_m}")


def _pads(pads: ArrayLike | None) -> np.ndarray:
    """The spare pads as (k, 3) (none: (0, 3))."""
    if pads is None:
        return np.zeros((0, 3))
    arr = np.asarray(pads, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"`pads` must have shape (k, 3), got {arr.shape}")
    return arr


def _match(ids: list[int], xy: np.ndarray, spots: np.ndarray
           ) -> list[tuple[int, int, float]]:
    """(system id, spot index, horizontal distance) of the optimal assignment of the
    vehicles at ``xy`` to ``spots`` (each spot one vehicle at most)."""
    if not ids or len(spots) == 0:
        return []
    from scipy.optimize import linear_sum_assignment  # scipy only once vehicles are seen

    dist = np.linalg.norm(xy[:, None, :] - spots[None, :, :2], axis=2)
    rows, cols = linear_sum_assignment(dist)
    return [(ids[r], int(c), float(dist[r, c])) for r, c in zip(rows, cols, strict=True)]


def auto_assign(home: ArrayLike, positions: MappingABC[int, ArrayLike | None],
                tolerance_m: float = DEFAULT_SLOT_TOLERANCE_M,
                pads: ArrayLike | None = None, spares: Collection[int] = ()) -> Assignment:
    """Match vehicles to the takeoff slots they stand on, then the rest to spare pads.

    ``home`` is the plan's (n, 3) takeoff slots and ``positions`` each
    vehicle's current show-frame position (None when it has no estimate yet).
    ``pads`` are the plan's (k, 3) spare pads (None: the plan has no spares): a
    vehicle left without a track within ``tolerance_m`` of a pad stands by as its
    spare (module docstring).  ``spares`` are the vehicles a fleet file marks as
    spares: matched to the pads only, never to a takeoff slot.
    """
    _check_tolerance(tolerance_m)
    slots = np.asarray(home, dtype=float)
    if slots.ndim != 2 or slots.shape[1] != 3:
        raise ValueError(f"`home` must have shape (n, 3), got {slots.shape}")
    spots = _pads(pads)
    pos = _positions(positions)
    refused: dict[int, str] = {}
    known = sorted(s for s, p in pos.items() if p is not None)
    for sysid in sorted(s for s, p in pos.items() if p is None):
        refused[sysid] = f"vehicle {sysid} has no position estimate"
    if not known or len(slots) == 0:
        return Assignment({}, {}, refused, tuple(range(len(slots))), tuple(known))
    xy = np.array([pos[s][:2] for s in known])  # type: ignore[index]
    dist = np.linalg.norm(xy[:, None, :] - slots[None, :, :2], axis=2)
    nearest = dist.min(axis=1)
    pad_dist = _nearest(xy, spots)
    marked = np.array([s in spares for s in known], dtype=bool)
    by_pad = marked | (pad_dist < nearest)
    # Vehicles far from every slot are refused before the assignment, so they cannot
    # push a well-placed vehicle off its slot; spares (marked, or nearer a pad) are kept
    # out of it too, so that one never takes the slot of a show drone not yet located.
    ok = (nearest <= tolerance_m) & ~by_pad

    def far(i: int) -> str:
        pad = f" and {pad_dist[i]:.1f} m from the nearest spare pad" if len(spots) else ""
        return (f"vehicle {known[i]} is {nearest[i]:.1f} m from the nearest takeoff slot"
                f"{pad} (tolerance {tolerance_m:.1f} m)")

    for i in np.flatnonzero(~ok & ~by_pad):
        refused[known[i]] = far(int(i))
    cand = [known[i] for i in np.flatnonzero(ok)]
    tracks: dict[int, int] = {}
    distances: dict[int, float] = {}
    taken: set[int] = set()
    matched = _match(cand, xy[ok], slots)
    for sysid, c, d in matched:
        if d > tolerance_m:
            taken.add(sysid)
            refused[sysid] = (f"vehicle {sysid}: its nearest takeoff slot is taken; the "
                              f"free one (track {c}) is {d:.1f} m away "
                              f"(tolerance {tolerance_m:.1f} m)")
        else:
            tracks[sysid] = c
            distances[sysid] = d
    extra = sorted(set(cand) - {m[0] for m in matched})
    # The pads: marked spares first, wherever they stand (their slot check says how far
    # off they are); then whoever is left without a track within the tolerance of one,
    # far from every slot or not (not one refused a taken slot: it stands in the grid).
    onpad = [known[i] for i in np.flatnonzero(~marked & (pad_dist <= tolerance_m))
             if known[i] not in tracks and known[i] not in taken]
    spare_of = _spares([known[i] for i in np.flatnonzero(marked)], onpad, pos, spots,
                       tolerance_m, distances)
    for sysid in spare_of:
        refused.pop(sysid, None)
    extra = [s for s in extra if s not in spare_of]
    for i in np.flatnonzero(by_pad):
        sysid = known[i]
        if sysid in spare_of:
            continue
        if len(spots) == 0:  # a marked spare, and the plan has none: it stays down
            extra.append(sysid)
        elif pad_dist[i] <= tolerance_m:
            refused[sysid] = f"vehicle {sysid}: its nearest spare pad is taken"
        else:
            refused[sysid] = far(int(i))
    unassigned = tuple(sorted(set(range(len(slots))) - set(tracks.values())))
    return Assignment(tracks, distances, refused, unassigned, tuple(sorted(extra)),
                      _heights(tracks, pos, slots) | _heights(spare_of, pos, spots),
                      spare_of)


def _nearest(xy: np.ndarray, spots: np.ndarray) -> np.ndarray:
    """Each of the vehicles at ``xy``'s horizontal distance to the nearest of ``spots``
    (infinite: there are none)."""
    if len(spots) == 0:
        return np.full(len(xy), np.inf)
    return np.linalg.norm(xy[:, None, :] - spots[None, :, :2], axis=2).min(axis=1)


def _spares(marked: list[int], standing: list[int],
            pos: MappingABC[int, np.ndarray | None], spots: np.ndarray, tolerance_m: float,
            distances: dict[int, float]) -> dict[int, int]:
    """System id -> pad of the spares: the ``marked`` ones (with a position) matched to
    the nearest pads whatever the distance, then the ``standing`` ones (within the
    tolerance of a pad) to the pads still free; their distances go in ``distances``."""
    spare_of: dict[int, int] = {}
    for group, limit in ((marked, np.inf), (standing, tolerance_m)):
        ids = [s for s in group if pos.get(s) is not None]
        free = [k for k in range(len(spots)) if k not in spare_of.values()]
        xy = np.array([pos[s][:2] for s in ids]).reshape(-1, 2)  # type: ignore[index]
        for sysid, j, d in _match(ids, xy, spots[free]):
            if d <= limit:
                spare_of[sysid] = free[j]
                distances[sysid] = d
    return spare_of


def _heights(tracks: MappingABC[int, int], pos: MappingABC[int, np.ndarray | None],
             slots: np.ndarray) -> dict[int, float]:
    return {s: float(p[2] - slots[t, 2]) for s, t in tracks.items()
            if (p := pos.get(s)) is not None}


def explicit_assign(assignments: MappingABC[int, int], home: ArrayLike,
                    positions: MappingABC[int, ArrayLike | None],
                    tolerance_m: float = DEFAULT_SLOT_TOLERANCE_M,
                    pads: ArrayLike | None = None, spares: Collection[int] = ()
                    ) -> Assignment:
    """Use the fleet file's system id -> track table, checking each vehicle is on its slot.

    Vehicles in ``positions`` but not in ``assignments`` are extra; table
    entries for vehicles not heard from are refused.  ``spares`` are the vehicles the
    fleet file marks as spares: each heard one with a position is matched to the
    nearest free pad of ``pads`` (the plan's (k, 3) spare pads) by the same optimal
    assignment, whatever the distance (its slot check says how far off it stands); one
    not heard from is no failure (a spare fewer), one that finds no pad is extra.
    """
    _check_tolerance(tolerance_m)
    slots = np.asarray(home, dtype=float)
    if slots.ndim != 2 or slots.shape[1] != 3:
        raise ValueError(f"`home` must have shape (n, 3), got {slots.shape}")
    spots = _pads(pads)
    seen: dict[int, int] = {}
    for sysid, track in assignments.items():
        if not 0 <= track < len(slots):
            raise ValueError(f"`assignments`: vehicle {sysid} -> track {track}, but the plan "
                             f"has tracks 0..{len(slots) - 1}")
        if track in seen:
            raise ValueError(f"`assignments`: track {track} is given to both vehicle "
                             f"{seen[track]} and vehicle {sysid}")
        seen[track] = sysid
    both = sorted(set(spares) & set(assignments))
    if both:
        raise ValueError(f"`spares`: vehicle {both[0]} is marked a spare but also given "
                         f"track {assignments[both[0]]}")
    pos = _positions(positions)
    tracks: dict[int, int] = {}
    distances: dict[int, float] = {}
    refused: dict[int, str] = {}
    for sysid, track in sorted(assignments.items()):
        if sysid not in pos:
            refused[sysid] = f"vehicle {sysid} (track {track}) has not been heard from"
            continue
        p = pos[sysid]
        if p is None:
            refused[sysid] = f"vehicle {sysid} has no position estimate"
            continue
        d = float(np.linalg.norm(p[:2] - slots[track, :2]))
        distances[sysid] = d
        if d > tolerance_m:
            refused[sysid] = (f"vehicle {sysid} is {d:.1f} m from its takeoff slot "
                              f"(track {track}, tolerance {tolerance_m:.1f} m)")
        else:
            tracks[sysid] = track
    marked = sorted(s for s in spares if s in pos)
    spare_of = _spares(marked, [], pos, spots, tolerance_m, distances)
    for sysid in marked:
        if pos[sysid] is None:
            refused[sysid] = f"vehicle {sysid} (a spare) has no position estimate"
    unassigned = tuple(sorted(set(range(len(slots))) - set(tracks.values())))
    extra = tuple(sorted(set(pos) - set(assignments) - set(spare_of) - set(refused)))
    return Assignment(tracks, distances, refused, unassigned, extra,
                      _heights(tracks, pos, slots) | _heights(spare_of, pos, spots),
                      spare_of)
