"""Spares in flight (issue 29): when a show drone leaves its track mid-show, a spare
waiting on its pad takes the track over -- asked for, planned by the driver, flown.

A track is *vacated* once the show runs and the drone flying it is out of it for good:
on its planned way out (from the way out's instant: the join is planned around it), or
coming down, down, given up or killed.  A lost drone is not replaced: it may still be on
its plan.  :attr:`Spares.join_needed` names the track and the spare to send
(:func:`~.policies.spares.choose_spares`: ready, not tried on this track, quickest
there); the driver plans the way in (:func:`groundctl.flight.joining.plan_join`) in a
worker and hands it over with :meth:`Spares.set_join` or :meth:`Spares.join_failed`.

The spare then becomes an ordinary run of the track, through the same lifecycle
table: at the way in's show time less its climb it arms and takes off over its pad
(ready), flies its way in dark (``joining``) and is on the track's plan from
:attr:`~groundctl.execute.leaving.Join.until` (``show``).  A spare not up in time
lands back on its pad and the next one tries; one that fails on its way in is handled
like any drone in the air (its way out, a fall, lost), and its track is vacated again.
Spares never hold the show's landing: waiting ones stand down when it ends.
"""

from __future__ import annotations

import numpy as np

from groundctl.execute.leaving import Join, climb_time
from groundctl.execute.sequence.failsafes import Failsafes
from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.policies.spares import SpareView, choose_spares
from groundctl.execute.sequence.standby import Replacement
from groundctl.execute.sequence.types import (
    Action,
    Arm,
    Command,
    Disarm,
    Land,
    Notice,
    SetMode,
    VehiclePhase,
    VehicleRun,
)
from groundctl.link.flavours import Flavour

#: A join's planning is tried this many times (timeouts) per spare and track.
MAX_JOIN_TRIES = 3
#: A spare not ready over its pad this long after its way in should have begun has
#: missed it, s of show time: it lands back on its pad.
JOIN_LATE_S = 1.0
#: A spare is given this many times the fleet's slow takeoffs (90th percentile) to get up,
TAKEOFF_MARGIN = 1.3
#: ... counting one at most this long, s.
MAX_TAKEOFF_S = 60.0
#: Phases of a vehicle that is out of its track for good (the track is vacated).
_OUT = frozenset({VehiclePhase.LANDING, VehiclePhase.LANDED, VehiclePhase.FAILED,
                  VehiclePhase.KILLED})
#: Phases of a show drone that will not fly the show any more.
_GONE = frozenset({VehiclePhase.LANDED, VehiclePhase.FAILED, VehiclePhase.KILLED,
                   VehiclePhase.LANDING, VehiclePhase.RETURNING})
#: Phases of a spare still on its way in (before it flies the track's plan).
_ON_ITS_WAY = frozenset({VehiclePhase.PREFLIGHT, VehiclePhase.ARMING, VehiclePhase.TAKEOFF,
                         VehiclePhase.READY, VehiclePhase.JOINING})


class Spares(Failsafes):
    """Spares taking over vacated tracks (a layer of :class:`ShowSequence`)."""

    # -- what the driver asks -----------------------------------------------------------
    @property
    def join_needed(self) -> list[tuple[int, int, tuple[float, float, float]]]:
        """(track, spare system id, where it waits) of the first vacated track a spare can
        go to, as of the last update (its pad, from which it climbs :meth:`spare_climb`,
        or its standby point in the air); empty when none (the driver plans one join at
        a time, each around the joins already set, leaving no sooner than it can be
        planned)."""
        return list(self._join_queue[:1])

    @property
    def joins(self) -> dict[int, Join]:
        """Ways in being flown or awaited, by track (obstacles for the next plans)."""
        return {v.track: v.join for v in self.vehicles.values()
                if v.join is not None and v.phase in _ON_ITS_WAY}

    def picture(self) -> tuple[object, ...]:
        """What a join or a way out is planned around, as a value: who is out of the show
        without a way out (where it is down, descending or lost), who holds off its plan,
        and every way out and way in set.  Planned on one picture and handed over on
        another, a plan may not have seen a drone that fell meanwhile: it is planned
        again."""
        return tuple((v.sysid, v.phase in _OUT and v.leave is None,
                      v.phase is VehiclePhase.LOST, v.hold_point, id(v.leave), id(v.join))
                     for v in self.vehicles.values())

    def dark(self, now: float) -> set[int]:
        """Vehicles whose LEDs stay off whatever their track shows: spares until they are
        on the plan, and every drone that left the show while it ran (from its way out's
        instant, or as it came down, fell or was killed) for the rest of the flight -- a
        drone on its way out lit in its track's colours is a stray pixel, and two when a
        spare takes the track over.  At the show's end or at land-all the fleet lands in
        its colours, as it always has."""
        if self.started_at is not None and not self._ended:
            t: float | None = None
            for v in self.vehicles.values():
                if v.sysid in self._gone_dark or v.track < 0 \
                        or v.track in self.grounded_tracks:
                    continue
                if v.phase in _OUT:
                    self._gone_dark.add(v.sysid)
                elif v.leave is not None:
                    t = self.show_time(now) if t is None else t
                    if t >= v.leave.at:
                        self._gone_dark.add(v.sysid)
        spares = {v.sysid for v in self.vehicles.values()
                  if v.pad is not None and (v.standing_by or v.phase in _ON_ITS_WAY)} \
            if self.standby else set()
        return spares | self._gone_dark

    def set_join(self, track: int, spare: int, join: Join, now: float) -> list[Action]:
        """Send ``spare`` into ``track`` on ``join``: it arms ``join.climb_s`` before
        ``join.at``."""
        s = self.standby.get(spare)
        owner = self._owner(track)
        t = self.show_time(now)
        if s is None or s.sent or owner is None or self._ended \
                or track not in {tr for tr, _ in self._vacated()}:
            return []
        if join.at - join.climb_s < t:
            return self.join_failed(track, spare, f"its way in was ready too late (it had "
                                                  f"to arm at show time "
                                                  f"{join.at - join.climb_s:.1f} s)", now,
                                    retry=True)
        waiting = self.vehicles.get(spare)
        if self.air_spares and (waiting is None or waiting.phase is not VehiclePhase.READY):
            what = "gone" if waiting is None else str(waiting.phase)
            return self.join_failed(track, spare, "it is not hovering at its standby point "
                                                  f"({what})", now)
        s.sent = True
        self._join_queue = [q for q in self._join_queue if q[0] != track and q[1] != spare]
        if waiting is not None:
            # In the air at its standby point: the same run, now of the track.
            run = waiting
            run.track, run.join, run.hold_point = track, join, None
        else:
            run = VehicleRun(spare, track, s.flavour, join=join, pad=s.pad)
            pads = self.plan.spares.pads if self.plan.spares is not None else None
            assert pads is not None
            over = pads[s.pad] + np.array([0.0, 0.0, self.plan.takeoff_altitude])
            run.landing_point = (float(over[0]), float(over[1]), float(over[2]))
            self.vehicles[spare] = run
        owner.replaced_by = spare
        self.replacements.append(Replacement(track, owner.sysid, spare, self._left_at(owner, t),
                                             plan_ms=join.plan_ms))
        return [Notice(spare, f"spare {spare} takes over track {track + 1} from vehicle "
                              f"{owner.sysid}: it arms at show time "
                              f"{join.at - join.climb_s:.1f} s and is on the track at "
                              f"{join.until:.1f} s (planned in {join.plan_ms:.0f} ms)",
                       "spare_planned", "spare on its way")]

    def join_tries(self, track: int, spare: int) -> int:
        """Times planning ``spare``'s way into ``track`` was tried again (too late, or
        the fleet changed meanwhile)."""
        return self._join_tries.get((track, spare), 0)

    def join_failed(self, track: int, spare: int, reason: str, now: float, *,
                    retry: bool = False) -> list[Action]:
        """No way in for ``spare`` (``retry``: not in time; it is tried again, a bounded
        number of times): the next spare tries, or the track stays dark."""
        s = self.standby.get(spare)
        if s is None:
            return []
        key = (track, spare)
        self._join_tries[key] = self._join_tries.get(key, 0) + 1
        self._join_queue = [q for q in self._join_queue if q[:2] != key]
        if not retry or self._join_tries[key] >= MAX_JOIN_TRIES:
            s.tried.add(track)
        return [Notice(spare, f"spare {spare} cannot take over track {track + 1}: {reason}",
                       "spare_failed", "spare could not join")]

    @property
    def spare_climb(self) -> float:
        """How far a spare climbs from where it waits before its way in begins, m: the
        takeoff altitude from its pad, nothing from its standby point in the air."""
        return 0.0 if self.air_spares else self.plan.takeoff_altitude

    def spare_climb_s(self) -> float:
        """How long a spare sent in is given from being told to arm to hovering over its
        pad, s: the planner's figure for the climb, or, once the fleet has taken off,
        :data:`TAKEOFF_MARGIN` times the slowest takeoff seen (a busy machine, a slow
        autopilot: what this fleet really takes), whichever is longer."""
        planned = climb_time(self.plan, self.plan.takeoff_altitude)
        if not self.takeoffs_s:
            return planned
        # The 90th percentile, not the slowest: one drone that needed its arming retried
        # would hold every join back by its retries.
        slow = min(float(np.percentile(self.takeoffs_s, 90)), MAX_TAKEOFF_S)
        return max(planned, TAKEOFF_MARGIN * slow + JOIN_LATE_S)

    def replace(self, sysid: int, now: float) -> list[Action]:
        """The operator's ``replace SYSID``: the vehicle leaves the show as with ``land
        SYSID`` (on a way out from its next formation), and a spare takes its track over.
        Refused (nothing changes) when no spare can go: ``land SYSID`` lands it without."""
        v = self.vehicles.get(sysid)
        if v is None:
            return [Notice(None, f"no vehicle {sysid} in this show")]
        if v.pad is not None and (v.standing_by or v.phase in _ON_ITS_WAY):
            return [Notice(sysid, f"replace {sysid}: it is a spare, not in the show yet; "
                                  f"land-here {sysid} brings it down")]
        free = [s for s in self.standby.values()
                if not s.sent and s.sysid in self._spares_heard and v.track not in s.tried
                and self._up_if_air(s.sysid)]
        if not self.use_spares or not free:
            why = "spares are off for this flight (--no-spares)" if not self.use_spares \
                else "no spare is ready" if self.standby else "this show has no spares"
            return [Notice(sysid, f"replace {sysid}: {why}; land {sysid} takes it out "
                                  "without one")]
        # A healthy drone: it holds the formation it is on (or flies to) whole and leaves
        # at the end of its hold; the spare takes over on the way to the next.
        actions = self.land_one(sysid, now, after_hold=True)
        if v.leave_at is None and not self._ended:
            return actions  # land-one refused (said why)
        return [*actions, Notice(sysid, f"vehicle {sysid} leaves the show; a spare takes its "
                                        f"track {v.track + 1} over", "replace",
                                 "replaced by a spare")]

    def spares_report(self) -> dict[str, object]:
        """The report's ``spares`` key."""
        return {"ready": len(self.standby), "used": sum(s.sent for s in self.standby.values()),
                "replacements": [r.as_dict() for r in self.replacements]}

    # -- each update ----------------------------------------------------------------------
    def _advance_spares(self, now: float) -> list[Action]:
        """Spares sent in: armed at their instant, joining once ready, on the plan at the
        way in's end; late ones landed back on their pads; waiting ones stood down once
        the show is over."""
        if not self.standby:
            return []
        actions: list[Action] = []
        t = self.show_time(now)
        # Before the start, no show drone left that could still start it: nothing to wait
        # for in the air.
        no_show = self.started_at is None and self._started and all(
            u.phase in _GONE for u in self.vehicles.values() if u.pad is None)
        self._join_queue = []
        if self.started_at is not None and not self._ended:
            for track, owner in self._vacated():
                if any(r.track == track and r.outcome == "planned"
                       for r in self.replacements):
                    continue
                choice = self._choose(track, owner, t, actions)
                if choice is not None and self.plan.spares is not None:
                    k = self.standby[choice].pad
                    at = (self.plan.spares.points if self.air_spares
                          else self.plan.spares.pads)[k]
                    self._join_queue.append(
                        (track, choice, (float(at[0]), float(at[1]), float(at[2]))))
        for v in list(self.vehicles.values()):
            join = v.join
            if join is None:
                why = "the show is over" if self._ended or no_show else \
                    "its battery is below the show's minimum" if v.sysid in self._spares_low \
                    else None
                if v.standing_by and why is not None and v.phase is VehiclePhase.READY:
                    # An air spare not sent in: straight down onto its pad (its column is
                    # verified clear of every takeoff and landing column).
                    self._to(v, Event.LAND)
                    v.pending = None
                    actions += [Notice(v.sysid, f"spare {v.sysid} lands on its pad: {why}",
                                       "spare_lands", "spare landing on its pad"),
                                self._send(v, Land(v.sysid), now)]
                continue
            if v.phase is VehiclePhase.PREFLIGHT:
                if self._ended:
                    self._to(v, Event.STAND_DOWN)
                    actions += self._spare_out(v, "the show ended before it armed")
                elif t >= join.at - join.climb_s and self.started_at is not None:
                    self._to(v, Event.START)
                    v.started_at = now
                    first: Command = SetMode(v.sysid, "GUIDED") \
                        if v.flavour is Flavour.ARDUPILOT else Arm(v.sysid)
                    actions.append(self._send(v, first, now))
            elif v.phase in (VehiclePhase.ARMING, VehiclePhase.TAKEOFF) \
                    and t > join.at + JOIN_LATE_S:
                actions += self._late_spare(v, now)
            elif v.phase is VehiclePhase.READY and v.pending is None:
                if t > join.at + JOIN_LATE_S:
                    # Up, but its way in began too long ago (a hold braked past it, a
                    # stall): its first setpoint would be well along a path it never
                    # flew the start of.
                    actions += self._late_spare(v, now)
                else:
                    self._to(v, Event.JOINS)
            elif v.phase is VehiclePhase.JOINING and t >= join.until:
                self._to(v, Event.JOINED)
                v.landing_point = None  # it lands where its track lands
                if (r := self._planned(v.sysid)) is not None:
                    r.joined_at, r.outcome = t, "joined"
                actions.append(Notice(v.sysid, f"spare {v.sysid} joined track {v.track + 1} "
                                               f"at show time {t:.1f} s",
                                      "spare_joined", "spare joined its track"))
        for r in self.replacements:
            if r.outcome != "planned":
                continue
            run = self.vehicles.get(r.spare)
            if run is None:
                continue
            # Lost on its pad (before its takeoff was sent), it cannot be on its way: the
            # next spare may go.  Lost in the air, it may still fly its way in (it is
            # streamed it): nobody else is sent into that track meanwhile.
            grounded_lost = run.phase is VehiclePhase.LOST and run.lost_from in (
                VehiclePhase.PREFLIGHT, VehiclePhase.ARMING)
            if (run.phase not in _ON_ITS_WAY and run.phase is not VehiclePhase.LOST) \
                    or grounded_lost:
                what = "lost on its pad" if grounded_lost else str(run.phase)
                then = "the show is over" if self._ended else "the next spare tries"
                actions.append(self._replacement_failed(r, what, then))
        return actions

    def _late_spare(self, v: VehicleRun, now: float) -> list[Action]:
        """Not up over its pad when its way in began: it comes back down on its pad."""
        v.reason = "not up in time for its way in"
        if v.phase is VehiclePhase.ARMING:
            self._to(v, Event.GIVE_UP)
            v.pending, v.never_flew = None, True  # still on its pad
            # An Arm already sent may still be carried out: disarmed on the ground.
            return [*self._spare_out(v, v.reason), Disarm(v.sysid)]
        self._to(v, Event.LAND)
        return [*self._spare_out(v, v.reason), self._send(v, Land(v.sysid), now)]

    def _spare_out(self, v: VehicleRun, why: str) -> list[Action]:
        r = self._planned(v.sysid)
        return [] if r is None else [self._replacement_failed(r, why, "the next spare tries")]

    def _planned(self, spare: int) -> Replacement | None:
        """The replacement ``spare`` is on its way into, if any."""
        return next((r for r in self.replacements
                     if r.spare == spare and r.outcome == "planned"), None)

    def _replacement_failed(self, r: Replacement, why: str, then: str) -> Notice:
        """``r``'s spare will not join: said, and never tried on that track again."""
        r.outcome = f"failed ({why})"
        self.standby[r.spare].tried.add(r.track)
        return Notice(r.spare, f"spare {r.spare} did not join track {r.track + 1} ({why}): "
                               f"{then}", "spare_failed", "spare could not join")

    # -- which tracks, which spare ---------------------------------------------------------
    def _up_if_air(self, sysid: int) -> bool:
        """An air spare can go only from where it waits: hovering at its point."""
        if not self.air_spares:
            return True
        run = self.vehicles.get(sysid)
        return run is not None and run.phase is VehiclePhase.READY and run.standing_by \
            and sysid not in self._spares_low

    def _owner(self, track: int) -> VehicleRun | None:
        """The run flying ``track`` (or last flying it): the one not replaced."""
        owner = None
        for v in self.vehicles.values():
            if v.track == track and v.replaced_by is None:
                owner = v
        return owner

    def _vacated(self) -> list[tuple[int, VehicleRun]]:
        out = []
        for v in self.vehicles.values():
            if v.replaced_by is not None or v.track in self.grounded_tracks or v.standing_by:
                continue
            if v.join is not None and v.phase in _ON_ITS_WAY:
                continue
            if v.leave is not None or v.phase in _OUT:
                out.append((v.track, v))
        return out

    def _left_at(self, owner: VehicleRun, t: float) -> float:
        return owner.leave.at if owner.leave is not None else t

    def _choose(self, track: int, owner: VehicleRun, t: float,
                notices: list[Action]) -> int | None:
        assert self.plan.spares is not None
        where = self.plan.spares.points if self.air_spares else self.plan.spares.pads
        views = [SpareView(s.sysid, (float(where[s.pad][0]), float(where[s.pad][1]),
                                     float(where[s.pad][2])),
                           ready=s.sysid in self._spares_heard and self._up_if_air(s.sysid)
                           and s.sysid not in self._spares_low,
                           busy=s.sent, on_ground=not self.air_spares)
                 for s in self.standby.values()]
        tried = {s.sysid for s in self.standby.values() if track in s.tried}
        w = next((w for w in self.plan.formations if w.end > t), None)
        slot = (w.goals[track] if w is not None else self.plan.landing_hover[track])
        choice = choose_spares(slot, views, enabled=self.use_spares,
                               max_speed_h=self.plan.limits.max_speed_h,
                               climb_s=self.spare_climb_s(),
                               tried=tried)
        if choice.spare is None:
            if track not in self._said_no_spare:
                self._said_no_spare.add(track)
                notices.append(Notice(
                    owner.sysid, f"track {track + 1} stays dark: {choice.why}",
                    "no_spare", "no spare for its track"))
            return None
        return choice.spare

