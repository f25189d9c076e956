"""Who is streamed and the one path each follows, and where each lands: landing
spots kept clear of the drones that are down, and a returning vehicle's arrival over
its spot (new spots planned, or the nearest free one, when it is taken)."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from groundctl.execute.leaving import clear_spot_near, free_spots, landing_candidates
from groundctl.execute.paths import Path, PathKind, plan_path
from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.state import SequenceState
from groundctl.execute.sequence.types import (
    _STREAMED,
    LINK_FAILSAFE_GAP_S,
    MAX_REPLANS,
    Action,
    Land,
    Notice,
    StreamRequest,
    VehiclePhase,
    VehicleRun,
)
from groundctl.link.state import VehicleState

#: A spare follows its way in (holding at its start before it begins) in these phases.
_JOIN_PATH = frozenset({VehiclePhase.TAKEOFF, VehiclePhase.READY, VehiclePhase.JOINING})


class PathsAndSpots(SequenceState):
    """Streaming, paths and landing spots (a layer of :class:`ShowSequence`)."""

    # -- landing spots ---------------------------------------------------------------------
    def down_positions(self, asking: VehicleRun | None = None) -> list[np.ndarray]:
        """Show-frame positions of the drones that are down, descending or given up
        somewhere the plan did not put them (land-here, a crash, a failsafe landing, a
        drone that never took off), from this update's telemetry (else their slot):
        obstacles for every landing.  A drone descending over its own landing point is
        not one: landing points are separated by the plan."""
        # Excluded drones, and drones that never took off, stand on their slots (not the
        # one ``asking``: a drone sent back to its own slot does not block itself).
        out: list[np.ndarray] = [self.plan.home[t] for t in sorted(self.grounded_tracks)
                                 if asking is None or t != asking.track]
        out += self.pads_taken(None if asking is None else asking.sysid)
        for v in self.vehicles.values():
            if v is asking:
                continue
            if v.phase in (VehiclePhase.LANDING, VehiclePhase.LANDED, VehiclePhase.FAILED,
                           VehiclePhase.KILLED) or (v.phase is VehiclePhase.LOST
                                                    and v.lost_from is VehiclePhase.LANDING):
                pos = self._positions.get(v.sysid)
                if pos is None or (v.track in self.grounded_tracks and v.phase
                                   is not VehiclePhase.FAILED):
                    continue
                spot = self._landing_point(v)
                if v.phase is not VehiclePhase.FAILED and v.phase is not VehiclePhase.KILLED \
                        and v.replaced_by is None \
                        and float(np.hypot(*(pos[:2] - spot[:2]))) \
                        <= self.config.arrive_tolerance_m:
                    continue  # down on its own landing point, as planned (a drone whose
                    # track a spare took over is not: the spare lands there)
                out.append(np.asarray(pos, dtype=float))
        return out

    def pads_taken(self, but: int | None = None) -> list[np.ndarray]:
        """The spare pads a spare stands on (or may: a pad without a ready spare may hold
        one that failed pre-flight, was excluded or was never located), but ``but``'s:
        obstacles like any drone on the ground (a pad is a landing candidate too)."""
        spares = self.plan.spares
        if spares is None:
            return []
        ready = {s.pad: s for s in self.standby.values()}
        out = []
        for k in range(spares.count):
            s = ready.get(k)
            run = None if s is None else self.vehicles.get(s.sysid)
            on_pad = s is None or not s.sent or run is None \
                or run.phase is VehiclePhase.PREFLIGHT
            if on_pad and (s is None or s.sysid != but):
                out.append(spares.pads[k])
        return out

    def landing_positions(self) -> list[np.ndarray]:
        """Show-frame positions of the drones descending (LANDING) now."""
        out = []
        for v in self.vehicles.values():
            pos = self._positions.get(v.sysid)
            if v.phase is VehiclePhase.LANDING and pos is not None:
                out.append(np.asarray(pos, dtype=float))
        return out

    def reserved_spots(self, returning: Collection[int]) -> list[np.ndarray]:
        """Landing points of the vehicles outside ``returning`` (system ids) that are
        landing, or will land, on them: nobody else may be sent there."""
        out = []
        for v in self.vehicles.values():
            if v.sysid in returning or v.phase in (VehiclePhase.FAILED, VehiclePhase.KILLED,
                                                   VehiclePhase.PREFLIGHT):
                continue
            if v.track in self.grounded_tracks and v.landing_point is None:
                continue  # standing on its slot: in down_positions
            pos = self._positions.get(v.sysid)
            spot = self._landing_point(v)
            if v.phase in (VehiclePhase.LANDING, VehiclePhase.LANDED) and pos is not None \
                    and float(np.hypot(*(pos[:2] - spot[:2]))) > self.config.arrive_tolerance_m:
                continue  # down elsewhere: in down_positions, its spot is free
            out.append(spot)
        return out

    def spot_blocked(self, v: VehicleRun) -> bool:
        """Whether the column under ``v``'s landing point comes within the separation
        limit of a drone that is down or descending."""
        point = np.asarray(self._landing_point(v), dtype=float)[None, :]
        down = np.array(self.down_positions(v)).reshape(-1, 3)
        return len(free_spots(self.plan, point, down=down)) == 0

    def streamed(self, sysids: Collection[int], now: float) -> None:
        """The driver sent setpoints to ``sysids`` at ``now``: a vehicle that had had none
        for LINK_FAILSAFE_GAP_S (our loop starved) may be in its offboard-loss failsafe
        for our doing, and is taken back from it
        (:func:`~groundctl.execute.sequence.policies.modes.link_failsafe`)."""
        for sysid in sysids:
            v = self.vehicles.get(sysid)
            if v is None:
                continue
            if v.streamed_at is not None and now - v.streamed_at >= LINK_FAILSAFE_GAP_S:
                v.starved_at = now
            v.streamed_at = now

    def stream_request(self, now: float) -> StreamRequest:
        """Whom to send setpoints to this tick, and the path each follows."""
        sysids = frozenset(v.sysid for v in self.vehicles.values()
                           if self.streamed_as(v) in _STREAMED
                           or (v.phase is VehiclePhase.TAKEOFF and v.stream_since is not None))
        paths: dict[int, Path] = {}
        for sysid in sysids:
            path = self.path(sysid, now)
            if path is not None:
                paths[sysid] = path
        flying_return = any(p.kind is PathKind.RETURN for p in paths.values())
        moving = self.started_at is not None and not self._ended and self.clock.at(now).moving
        # After land-all the show clock is still braking: keep sampling it (with its
        # feed-forward) until it is at rest.
        braking = self._ended and self.started_at is not None and self.clock.at(now).rate > 0 \
            and self.clock.show_time(now) < self.plan.duration
        return StreamRequest(self.show_time(now), moving, sysids,
                             self.clock if self.started_at is not None else None,
                             self.started_at is None or (self._ended and not braking),
                             paths, self._return[0] if flying_return and self._return else None,
                             self._return_clock if flying_return else None)

    def path(self, sysid: int, now: float) -> Path | None:
        """The one path vehicle ``sysid`` follows now (None: it is not streamed).

        The only place that decides it, from where the vehicle is in the sequence:
        returning, it flies the land-all return while there is one (else it holds over
        its landing point, or, while a return is awaited, brakes on what it flew); held
        off its plan, its point (then its way out); leaving, its way out; else its plan.
        """
        v = self.vehicles.get(sysid)
        if v is None:
            return None
        phase = self.streamed_as(v)
        if phase not in _STREAMED and not (v.phase is VehiclePhase.TAKEOFF
                                           and v.stream_since is not None):
            return None
        if phase is VehiclePhase.RETURNING:
            if self._return is not None and self._return_clock is not None:
                traj, rows = self._return
                if sysid in rows and self._return_clock.show_time(now) < traj.end:
                    return Path(PathKind.RETURN, "the land-all return", v.track,
                                row=rows[sysid])
            if not (self._return_wanted and self._return is None and v.landing_point is None):
                point = tuple(float(x) for x in self._landing_point(v))
                return Path(PathKind.LANDING_POINT, "over its landing spot", v.track,
                            point=point)  # type: ignore[arg-type]
        if v.standing_by and v.hold_point is not None:
            return Path(PathKind.HOLD, "standing by at its point", v.track, point=v.hold_point)
        if v.join is not None and phase in _JOIN_PATH:
            return Path(PathKind.JOIN, "its way into the track it takes over", v.track,
                        join=v.join)
        if v.leave is not None:
            return Path(PathKind.WAY_OUT, "its way out of the show", v.track,
                        point=v.hold_point, leave=v.leave)
        if v.hold_point is not None:
            return Path(PathKind.HOLD, "holding off its plan until its way out", v.track,
                        point=v.hold_point)
        return plan_path(v.track)

    def _landing_point(self, v: VehicleRun) -> np.ndarray:
        """Where ``v`` descends from.

        Once the show has started, above the plan's landing spot (or the spot a
        return re-assigned it, when that one was blocked).  Before (an abort
        during takeoff), straight back down its own takeoff column: the plan's
        landing spot may be another drone's takeoff spot, and that drone may
        still be standing on it (the very reason for the abort).
        """
        if v.landing_point is not None:
            return np.asarray(v.landing_point, dtype=float)
        if self.started_at is None:
            return self._home_hover[v.track]
        return self._slots[v.track]

    def _returning(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        pos = self._positions.get(v.sysid)
        if pos is None:
            return []
        if v.returning_since is None:
            v.returning_since = now
        if self._return_wanted and self._return is None:
            v.returning_since = now  # waiting for a return plan (bounded by the driver)
            return []
        if self._return is not None and self._return_clock is not None \
                and self._return_clock.show_time(now) < self._return[0].end:
            return []  # still flying the return
        if self.paused and self.holds - {"land-all"}:
            v.returning_since = now  # held: the time to reach its spot does not run
        if np.linalg.norm(pos - self._landing_point(v)) <= self.config.arrive_tolerance_m:
            if self._ended and self.spot_blocked(v):
                return self._blocked(v, now)
            self._to(v, Event.ARRIVED)
            return [self._send(v, Land(v.sysid), now)]
        if now - v.returning_since > self.config.return_timeout_s:
            self._to(v, Event.LAND)
            v.reason = (
                f"did not reach its landing point within {self.config.return_timeout_s:.0f} s "
                f"({float(np.linalg.norm(pos - self._landing_point(v))):.1f} m away)")
            return [Notice(v.sysid, f"vehicle {v.sysid} {v.reason}: landing where it is",
                           "land_here_timeout", "did not reach its landing point: landing "
                                                "where it is"),
                    self._send(v, Land(v.sysid), now)]
        return []

    def _blocked(self, v: VehicleRun, now: float) -> list[Action]:
        """Over its landing point, but a drone came down under it (land-here, a failsafe,
        a crash): descending now would land on it.  Once every return in flight is over,
        a new one re-assigns the spots from where the drones hover, a bounded number of
        times; after that the drone moves to the nearest free spot and lands there."""
        if self._replans < MAX_REPLANS:
            self._replans += 1
            self._return_wanted, self._return, self._return_clock = True, None, None
            self._after_return = True
            return [Notice(v.sysid, f"vehicle {v.sysid}: its landing spot is taken by a drone "
                                    "that is down; planning new spots", "spot_taken",
                           "landing spot taken by a drone that is down: planning new spots")]
        spot, of_plan = self.free_ground(v)
        if spot is None:
            self._to(v, Event.LAND)
            v.reason = "no free landing spot left"
            return [Notice(v.sysid, f"vehicle {v.sysid}: no free landing spot left: "
                                    "landing where it is; watch it"),
                    self._send(v, Land(v.sysid), now)]
        v.landing_point, v.returning_since = spot, now
        if not of_plan:
            return [Notice(v.sysid, f"vehicle {v.sysid}: no landing spot of the plan is free; "
                                    f"moving to the nearest clear ground ({spot[0]:.1f}, "
                                    f"{spot[1]:.1f}) to land", "clear_spot",
                           "no free landing spot: landing on the nearest clear ground")]
        return [Notice(v.sysid, f"vehicle {v.sysid}: its landing spot is taken; moving to the "
                                f"nearest free spot ({spot[0]:.1f}, {spot[1]:.1f}) to land")]

    def free_ground(self, v: VehicleRun) -> tuple[tuple[float, float, float] | None, bool]:
        """Where ``v`` lands when its spot is taken, and whether it is one of the plan's:
        the closest landing candidate (plan landing spots, then takeoff slots, then pads)
        clear of every drone down and every spot someone else lands on; with none free,
        the nearest clear ground to where it hovers (:func:`clear_spot_near`); None when
        there is none."""
        down = np.array(self.down_positions(v)).reshape(-1, 3)
        reserved = np.array(self.reserved_spots({v.sysid})).reshape(-1, 3)
        candidates = landing_candidates(self.plan)
        free = candidates[free_spots(self.plan, candidates, reserved, down)]
        if len(free):
            best = free[np.argmin(np.linalg.norm(free - self._landing_point(v), axis=1))]
            return (float(best[0]), float(best[1]), float(best[2])), True
        pos = self._positions.get(v.sysid)
        here = self._landing_point(v) if pos is None else \
            np.array([pos[0], pos[1], self._landing_point(v)[2]])
        spot = clear_spot_near(self.plan, here, reserved, down)
        return (None if spot is None else (float(spot[0]), float(spot[1]), float(spot[2])),
                False)
