"""Which vehicle flies which plan track.

Either explicit (a fleet file says system id -> track) or automatic: every
vehicle standing on the ground is matched to the takeoff slot nearest to it
(an optimal assignment, so two vehicles never claim one slot), and refused if
it stands farther than a tolerance from that slot: a drone that is not where
the plan expects it would take off into its neighbours.

Distances are horizontal: GPS altitude wanders by metres on the ground while
the horizontal position is good to tens of centimetres, and every slot is on
the ground anyway.
"""

from __future__ import annotations

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
    """System id -> horizontal distance to its slot, m (where its position is known)."""
    refused: dict[int, str] = field(default_factory=dict)
    """System id -> why it may not fly (off its slot, no position, unknown track)."""
    unassigned_tracks: tuple[int, ...] = ()
    """Tracks no vehicle will fly."""
    extra_vehicles: tuple[int, ...] = ()
    """Vehicles left over once every slot had a vehicle (or not in the fleet file)."""
    heights: dict[int, float] = field(default_factory=dict)
    """System id -> its height above its slot, m (show frame: from its EKF origin's
    altitude and the show origin's), for every vehicle given a track."""

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


def auto_assign(home: ArrayLike, positions: MappingABC[int, ArrayLike | None],
                tolerance_m: float = DEFAULT_SLOT_TOLERANCE_M) -> Assignment:
    """Match vehicles to the takeoff slots they stand on.

    ``home`` is the plan's (n, 3) takeoff slots and ``positions`` each
    vehicle's current show-frame position (None when it has no estimate yet).
    """
    _check_tolerance(tolerance_m)
    slots = np.asarray(home, dtype=float)
    if slots.ndim != 2 or slots.shape[1] != 3:
        raise ValueError(f"`home` must have shape (n, 3), got {slots.shape}")
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
    # Vehicles far from every slot are refused before the assignment, so they
    # cannot push a well-placed vehicle off its slot.
    ok = nearest <= tolerance_m
    for i in np.flatnonzero(~ok):
        refused[known[i]] = (f"vehicle {known[i]} is {nearest[i]:.1f} m from the nearest "
                             f"takeoff slot (tolerance {tolerance_m:.1f} m)")
    cand = [known[i] for i in np.flatnonzero(ok)]
    tracks: dict[int, int] = {}
    distances: dict[int, float] = {}
    extra: list[int] = []
    if cand:
        sub = dist[ok]
        from scipy.optimize import linear_sum_assignment  # scipy only once vehicles are seen

        rows, cols = linear_sum_assignment(sub)
        for r, c in zip(rows, cols, strict=True):
            sysid, d = cand[r], float(sub[r, c])
            if d > tolerance_m:
                refused[sysid] = (f"vehicle {sysid}: its nearest takeoff slot is taken; the "
                                  f"free one (track {c}) is {d:.1f} m away "
                                  f"(tolerance {tolerance_m:.1f} m)")
            else:
                tracks[sysid] = int(c)
                distances[sysid] = d
        extra = sorted(set(cand) - {cand[r] for r in rows})
    unassigned = tuple(sorted(set(range(len(slots))) - set(tracks.values())))
    return Assignment(tracks, distances, refused, unassigned, tuple(extra),
                      _heights(tracks, pos, slots))


def _heights(tracks: MappingABC[int, int], pos: MappingABC[int, np.ndarray | None],
             slots: np.ndarray) -> dict[int, float]:
    return {s: float(p[2] - slots[t, 2]) for s, t in tracks.items()
            if (p := pos.get(s)) is not None}


def explicit_assign(assignments: MappingABC[int, int], home: ArrayLike,
                    positions: MappingABC[int, ArrayLike | None],
                    tolerance_m: float = DEFAULT_SLOT_TOLERANCE_M) -> Assignment:
    """Use the fleet file's system id -> track table, checking each vehicle is on its slot.

    Vehicles in ``positions`` but not in ``assignments`` are extra; table
    entries for vehicles not heard from are refused.
    """
    _check_tolerance(tolerance_m)
    slots = np.asarray(home, dtype=float)
    if slots.ndim != 2 or slots.shape[1] != 3:
        raise ValueError(f"`home` must have shape (n, 3), got {slots.shape}")
    seen: dict[int, int] = {}
    for sysid, track in assignments.items():
        if not 0 <= track < len(slots):
            raise ValueError(f"`assignments`: vehicle {sysid} -> track {track}, but the plan "
                             f"has tracks 0..{len(slots) - 1}")
        if track in seen:
            raise ValueError(f"`assignments`: track {track} is given to both vehicle "
                             f"{seen[track]} and vehicle {sysid}")
        seen[track] = sysid
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
    unassigned = tuple(sorted(set(range(len(slots))) - set(tracks.values())))
    extra = tuple(sorted(set(pos) - set(assignments)))
    return Assignment(tracks, distances, refused, unassigned, extra,
                      _heights(tracks, pos, slots))
