"""The last resort: no return and drones off their plans, so every drone holds
where it is (pushed apart) and they land straight down, one clear column at a time."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.policies.lastresort import column_clear, say_blocked
from groundctl.execute.sequence.returns import Returns
from groundctl.execute.sequence.types import (
    _DONE,
    AIRBORNE_M,
    COLUMN_MARGIN_M,
    COLUMN_WAIT_S,
    GROUND_CLEARANCE_M,
    HOLD_APART_MARGIN_M,
    HOLD_APART_MAX_M,
    Action,
    Land,
    Notice,
    VehiclePhase,
    VehicleRun,
)
from groundctl.execute.spread import spread_apart


class Columns(Returns):
    """The last resort in columns (a layer of :class:`ShowSequence`)."""

    # -- the last resort: straight down, one column at a time ------------------------------
    @property
    def in_columns(self) -> bool:
        """The fleet is landing by the last resort (:meth:`_land_in_columns`)."""
        return self._columns

    def _land_in_columns(self, reason: str, now: float) -> list[Action]:
        """No collision-free return, and drones off their plans: every airborne drone
        holds where its path stopped, and they go straight down one column at a time
        (:meth:`_descend_columns`).  It always exists and plans nothing: nothing more
        can fail, and a stop signal meanwhile changes nothing (:meth:`land_all`)."""
        # Where each path stopped, read before anything changes (return_start).
        starts = {v.sysid: self.return_start(v.sysid, now) for v in self.vehicles.values()
                  if self.streamed_as(v) is VehiclePhase.RETURNING}
        off = [v.sysid for v in self.vehicles.values()
               if v.hold_point is not None and v.before_return is VehiclePhase.LEAVING]
        points = self._held_apart({s: (float(p[0]), float(p[1]), float(p[2]))
                                    for s, p in starts.items()}, now)
        self._columns = True
        self._return_wanted = False
        for v in self.vehicles.values():
            if v.sysid not in points:
                continue
            v.hold_point = points[v.sysid]
            v.column_since = now
            v.leave, v.leave_at, v.before_return = None, None, None
            if v.phase is VehiclePhase.LOST:
                self._lost_to(v, Event.LAST_RESORT)
            else:
                self._to(v, Event.LAST_RESORT)
        actions: list[Action] = [Notice(
            None, f"no collision-free return could be planned ({reason}) and "
                  f"{'vehicles' if len(off) != 1 else 'vehicle'} "
                  f"{', '.join(str(s) for s in off)} {'are' if len(off) != 1 else 'is'} off "
                  "the plan: every drone holds where it is and they land straight down, one "
                  "column at a time (the lowest first; nobody descends with a drone below it)",
            "land_in_columns")]
        return actions + self._descend_columns(now)

    def _held_apart(self, points: Mapping[int, tuple[float, float, float]], now: float
                    ) -> dict[int, tuple[float, float, float]]:
        """``points`` (system id -> where it would hold) pushed sideways until each is the
        separation limit from the others and from every other drone in the air (where it
        holds, or is and will hover once the braking show clock stops): the wind or a
        fault may have pushed them together
        (:func:`~groundctl.execute.spread.spread_apart`)."""
        others: list[tuple[float, ...]] = []
        for u in self.vehicles.values():
            if u.sysid in points or u.phase in _DONE or u.never_flew:
                continue
            pos = self._positions.get(u.sysid)
            if pos is None or pos[2] <= AIRBORNE_M:
                continue
            if u.hold_point is not None:
                others += [u.hold_point, tuple(pos)]  # where it holds, and where it is
                continue
            # Where it is, and where it will hover once the braking clock stops.
            others += [tuple(pos), tuple(self.return_start(u.sysid, now))]
        ids = list(points)
        if not ids:
            return {}
        pts = np.array([points[s] for s in ids] + others, dtype=float).reshape(-1, 3)
        movable = np.arange(len(pts)) < len(ids)
        limit = self.plan.limits.min_separation
        # To the limit plus the guard's margin: a pair held at the limit itself reads
        # below it with a little position noise.
        spread = spread_apart(pts, movable, limit + HOLD_APART_MARGIN_M,
                              HOLD_APART_MAX_M * limit)
        return {s: (float(p[0]), float(p[1]), float(p[2]))
                for s, p in zip(ids, spread[:len(ids)], strict=True)}

    def _descend_columns(self, now: float) -> list[Action]:
        """Send down each held drone whose column is clear (no airborne drone within the
        separation limit below it, no drone on the ground within
        :data:`GROUND_CLEARANCE_M` of where it lands); re-checked every update, so a
        drone waits while another drifts under it."""
        if not self._columns:
            return []
        waiting = [v for v in self.vehicles.values()
                   if v.phase is VehiclePhase.LEAVING and v.hold_point is not None
                   and v.pending is None]
        actions: list[Action] = []
        for v in sorted(waiting, key=lambda u: self._height(u)):
            # Only drones below count: one above is left behind by the descent.
            if not self._column_clear(v, ground_m=GROUND_CLEARANCE_M, above_m=0.0,
                                      margin_m=COLUMN_MARGIN_M):
                if say_blocked(v.column_since, now, v.column_waited):
                    v.column_waited = True
                    actions.append(Notice(
                        v.sysid, f"vehicle {v.sysid} has waited {COLUMN_WAIT_S:.0f} s to "
                                 "descend: a drone is below it (lost, or still landing); it "
                                 f"holds (land-here {v.sysid} brings it straight down now)",
                        "column_blocked", "waiting to descend: a drone below it"))
                continue
            v.column = True
            self._to(v, Event.LAND)
            v.reason = "landed by the last resort (columns)"
            actions += [Notice(v.sysid, f"vehicle {v.sysid}: its column is clear: landing "
                                        "straight down", "column_landing",
                               "landing straight down (last resort)"),
                        self._send(v, Land(v.sysid), now)]
            # The ones above it wait for it: their columns are rechecked next update.
        return actions

    def _height(self, v: VehicleRun) -> float:
        pos = self._positions.get(v.sysid)
        if pos is not None:
            return float(pos[2])
        return v.hold_point[2] if v.hold_point is not None else math.inf

    def _column_clear(self, v: VehicleRun, ground_m: float | None = None,
                      above_m: float | None = None, margin_m: float = 0.0) -> bool:
        """Whether no other drone is within the separation limit, horizontally, of the
        column below ``v`` (descending there would not pass through anyone), counting
        drones up to ``above_m`` (default: the limit) above it, and ``margin_m`` beyond
        the limit sideways.  With ``ground_m``, drones down on the ground (and the slots
        of those that never flew) count only within that distance of where ``v`` lands:
        a landed drone is not flying into anyone."""
        here = self._positions.get(v.sysid)
        if here is None:
            return False
        limit = self.plan.limits.min_separation
        above = limit if above_m is None else above_m
        others: list[tuple[np.ndarray, bool]] = []  # (position, down on the ground)
        for u in self.vehicles.values():
            pos = self._positions.get(u.sysid)
            if u is v or pos is None or u.phase in (VehiclePhase.PREFLIGHT,):
                continue
            # Down is what telemetry says, not the phase: a FAILED drone may be airborne.
            others.append((pos, u.phase in _DONE and float(pos[2]) <= AIRBORNE_M))
        if ground_m is not None:  # excluded drones, and those never airborne, on slots
            others += [(self.plan.home[t], True) for t in self.grounded_tracks
                       if t != v.track]
        return column_clear(here, others, limit_m=limit, above_m=above, margin_m=margin_m,
                            ground_m=ground_m)
