"""The tick's stream and what it measures (the closest pair's commanded
distance, the MPC replan), and the guard judging the tick: our own lag, a
fleet-wide silence, safety responses, the wind."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from groundctl.execute.frames import ned_vel_to_show
from groundctl.execute.guard import GUARD_SHOW_HOLDS, Hold, LandAll, Release, TakeOut, TickFacts
from groundctl.execute.preflight import WIND_FRESH_S
from groundctl.execute.sequence import AIRBORNE_M, ShowSequence, StreamRequest, VehiclePhase
from groundctl.flight.monitor import nearest_pair, telemetry_positions
from groundctl.flight.runner.config import _AIRBORNE, _WIND_PHASES, _range_rate
from groundctl.flight.runner.slots import Send, SendSlots, slot_delays
from groundctl.flight.runner.timing import LinkTiming


class Streaming(LinkTiming):
    """The stream, the MPC replan and the guard (a layer of :class:`ShowRunner`)."""

    # -- streaming --------------------------------------------------------------------
    def _stream_tick(self, seq: ShowSequence, now: float, scheduled: float) -> None:
        assert self._stream is not None and self.monitor is not None
        if seq.clock_state != self._clock_state:
            self._clock_state = seq.clock_state
            if self.replanner is not None:
                # Held, released, put back after a stall, a return set off: the MPC
                # trajectories were checked against the neighbours on the clocks as they
                # were; the next batch is solved on the clocks as they are now.
                self.replanner.drop_trajectories()
        req = seq.stream_request(now)
        self._request = (now, req)  # the guard reads the same request this tick
        if not req.sysids:
            self.lateness_s.append(self.clock.now() - scheduled)
        else:
            offsets = {s: self.link.vehicles[s].clock_offset_s for s in req.sysids}
            stream = self._stream
            delays = slot_delays(len(stream.sysids), self.config.send_slot_vehicles,
                                 1.0 / self.config.rate_hz)
            index = {s: i for i, s in enumerate(stream.sysids)}

            def lead_of(sysid: int) -> float:
                return stream.lead_of(sysid) + float(delays[index[sysid]])

            replanned = self.replanner.overrides(now, lead_of) \
                if self.replanner is not None else None
            sp = stream.at(now, offsets, paths=req.paths, clocks=req.clocks(self.plan),
                           replanned=replanned, delays=delays)
            rows = [i for i, s in enumerate(sp.sysids) if s in req.sysids]
            slots: dict[float, list[Send]] = {}
            for i in rows:
                slots.setdefault(float(delays[i]), []).append(
                    (sp.sysids[i], int(sp.time_boot_ms[i]), sp.pos_ned[i].tolist(),
                     sp.vel_ned[i].tolist(), sp.acc_ned[i].tolist()))
            if self._slots is None:
                self._slots = SendSlots(
                    self.clock, self.link.send_position_target_local_ned,
                    self.lateness_s.append,
                    lambda: self.clock.idle_until(self._idle_due()))
            # The tick's lateness: its last slot's, against that slot's own instant.
            self._slots.start(scheduled, now, sorted(slots.items()))
            seq.streamed([sp.sysids[i] for i in rows], now)
            self._last_show_time = (min(req.clock.show_time(now + self._stream.typical_lead),
                                        self.plan.duration)
                                    if req.clock is not None and not req.ended else None)
            # LED colours on the show clock at the vehicle while it runs at full rate;
            # otherwise the tick's own.
            dark = seq.dark(now)
            self.monitor.dark = dark
            running = seq.started_at is not None and not seq.ended \
                and seq.clock.at(now).rate >= 1.0
            self._leds.tick(now, seq.show_time(now) if running else None,
                            [sp.sysids[i] for i in rows], sp.rgb[rows],
                            dark)
        # A set: the monitor and the leads ask it of every vehicle (a list was O(n²)).
        in_show = frozenset(s for s, v in seq.vehicles.items()
                            if v.phase is VehiclePhase.SHOW) \
            if seq.started_at is not None and not seq.ended else frozenset()
        rate = req.clock.at(now).rate if req.clock is not None and not req.ended else 0.0
        self.monitor.observe(now, req.show_time, in_show, self.link.vehicles, rate)
        self._commanded_at_closest(seq, req, now)
        self._replan_tick(seq, req, now)
        self._lead_tick(seq, req, now, in_show)

    def _commanded_at_closest(self, seq: ShowSequence, req: StreamRequest, now: float) -> None:
        """A new closest approach this tick: how far apart their paths put the pair (the
        report tells a pair pushed together from one flown so)."""
        assert self.monitor is not None
        sep = self.monitor.separation
        last = self.monitor.last_positions
        if sep.at_s != now or sep.pair is None or last is None:
            return
        streamed = [s for s in sep.pair if s in req.paths]
        wanted = seq.commanded_all(replace(req, sysids=frozenset(streamed),
                                           paths={s: req.paths[s] for s in streamed}), now)
        for s in sep.pair:
            v = seq.vehicles.get(s)
            if s in wanted or v is None or v.phase is not VehiclePhase.LANDING \
                    or s not in last[1]:
                continue
            # Told to land: over the point it was sent down from (the last resort's
            # column: where it held; otherwise where it was when told), at the height it
            # is at.
            over = v.hold_point[:2] if v.column and v.hold_point is not None else v.land_from
            if over is not None:
                z = last[2][last[1].index(s)][2]
                wanted[s] = np.array([over[0], over[1], z])
        a, b = sep.pair
        wind = self.guard.wind.wind
        if a in wanted and b in wanted:
            sep = replace(sep, commanded_m=float(np.linalg.norm(wanted[a] - wanted[b])))
        self.monitor.separation = replace(sep, wind_m_s=wind)

    def _replan_tick(self, seq: ShowSequence, req: StreamRequest, now: float) -> None:
        """MPC: who is replanned this tick, and their next batch (see flight.replanning)."""
        if self.replanner is None or self.monitor is None:
            return
        if seq.started_at is None:
            # Hovering at the take-off altitude before the show: each one's hover throttle
            # (its authority) is known before its path asks anything of it.
            for sysid, v in seq.vehicles.items():
                st = self.link.vehicles[sysid]
                if v.phase is VehiclePhase.READY and st.throttle_pct is not None \
                        and st.throttle_at is not None:
                    self.replanner.authority.sample(st.throttle_at, sysid, st.throttle_pct,
                                                    np.zeros(3))
            return
        last = self.monitor.last_positions
        if last is None or last[0] != now:
            return
        _, ids, pos = last
        positions = dict(zip(ids, pos, strict=True))
        eligible = {s: p for s, p in req.paths.items()
                    if seq.vehicles[s].phase in (VehiclePhase.SHOW, VehiclePhase.LEAVING,
                                                 VehiclePhase.RETURNING)
                    and s in positions}
        measured = [(s, ned) for s in eligible
                    if (ned := self.link.vehicles[s].velocity_ned) is not None]
        velocities = dict(zip((s for s, _ in measured),
                              ned_vel_to_show(self.plan.origin,  # one rotation for all
                                              np.array([ned for _, ned in measured])),
                              strict=True)) if measured else {}
        obstacles = {s: p for s, p in positions.items() if s not in eligible
                     and s in seq.vehicles and p[2] > AIRBORNE_M}
        throttles = {s: (st.throttle_pct, st.throttle_at) for s in eligible
                     if (st := self.link.vehicles[s]).throttle_pct is not None
                     and st.throttle_at is not None}
        for event, text, fields in self.replanner.tick(now, eligible, req.clocks(self.plan),
                                                       positions, velocities, obstacles,
                                                       throttles):
            self._say(text, event, **fields)

    # -- the guard: our own lag, fleet-wide silence, safety responses ------------------
    def _stop_at_last_setpoints(self, seq: ShowSequence, now: float, reason: str,
                                show_time: float | None = None) -> bool:
        """Put the show clock back where the drones are along the plan after flying on
        stale setpoints (between the last setpoints' show time and the clock now); False
        if there is nothing to put back (no setpoints sent on the show clock yet)."""
        at_sent = self._last_show_time if show_time is None else show_time
        if at_sent is None or seq.started_at is None or seq.ended:
            return False
        lead = self._stream.typical_lead if self._stream is not None else 0.0
        ids, pos = telemetry_positions(self.plan, self.link.vehicles, now)
        vel = {sid: ned_vel_to_show(self.plan.origin, np.array(st.velocity_ned))
               for sid, st in self.link.vehicles.items() if st.velocity_ned is not None}
        at, rate = seq.fit_show_time(at_sent - lead, seq.clock.show_time(now),
                                     dict(zip(ids, pos, strict=True)), vel)
        seq.stop_for(reason, now, at, rate)
        return True

    def _guard_tick(self, seq: ShowSequence, now: float, lag: float, period: float) -> bool:
        """The guard's tick; True if it put the show clock back after a stall."""
        assert self.monitor is not None
        resynced = False
        in_show = seq.started_at is not None and not seq.ended
        req = self._request
        streamed = (req[1] if req is not None and req[0] == now
                    else seq.stream_request(now)).sysids
        flying = bool(streamed) and seq.started_at is not None
        errors: dict[int, float] = {}
        closest, pair, closing, planned = math.inf, None, 0.0, math.inf
        last = self.monitor.last_positions
        if last is not None and last[0] == now:
            _, ids, pos = last  # measured by the monitor this tick
        else:
            ids, pos = telemetry_positions(self.plan, self.link.vehicles, now)
        ids_pos = dict(zip(ids, pos, strict=True))
        if in_show:
            wanted = seq.commanded_all(req[1] if req is not None and req[0] == now
                                       else seq.stream_request(now), now)
            for sysid, v in seq.vehicles.items():
                if v.phase not in (VehiclePhase.SHOW, VehiclePhase.LEAVING) \
                        or sysid not in ids_pos:
                    continue
                # Judged against its path, MPC or not: the plan keeps the fleet apart
                # along the paths, and a drone far off its own is held for (its MPC
                # trajectory starts where it is, so it would never look off).
                want = wanted.get(sysid)
                if want is not None:
                    errors[sysid] = float(np.linalg.norm(ids_pos[sysid] - want))
            # Everything in the air counts, a drone descending through the show included.
            airborne = [k for k, s in enumerate(ids) if s in seq.vehicles
                        and (seq.vehicles[s].phase in _AIRBORNE
                             or (seq.vehicles[s].phase is VehiclePhase.LANDING
                                 and pos[k][2] > AIRBORNE_M))]
            sep = nearest_pair([ids[k] for k in airborne], pos[airborne])
            closest, pair = sep.distance_m, sep.pair
            if pair is not None:
                closing = _range_rate(ids_pos[pair[0]], ids_pos[pair[1]],
                                      self.link.vehicles[pair[0]],
                                      self.link.vehicles[pair[1]], self.plan)
                a, b = wanted.get(pair[0]), wanted.get(pair[1])
                if a is not None and b is not None:
                    planned = float(np.linalg.norm(a - b))
        show_airborne = not seq.ended and any(v.phase in _AIRBORNE
                                              for v in seq.vehicles.values())
        # Every drone in the air estimates the wind, a landing one included; one on the
        # ground (landed, given up, kept there) repeats its last estimate from the air.
        winds = tuple(w for s, p in ids_pos.items() if p[2] > AIRBORNE_M
                      and s in seq.vehicles and s in self.link.vehicles
                      and seq.vehicles[s].phase in _WIND_PHASES
                      and (w := self.link.vehicles[s].wind_speed(now, WIND_FRESH_S))
                      is not None)
        # The link judges a fleet-wide silence over the drones in the air only.
        self.link.silence_ids = set(streamed) if flying else None
        facts = TickFacts(
            now=now, lag_s=lag, period_s=period, last_sent_show_time=self._last_show_time,
            fleet_silent=self.link.fleet_silent, errors_m=errors, closest_m=closest,
            closest_pair=pair, closing_mps=closing, closest_planned_m=planned,
            unheard=sum(1 for s in streamed if s not in ids_pos),
            limit_m=self.plan.limits.min_separation, in_show=in_show, flying=flying,
            stopped=seq.clock.stopped(now), show_airborne=show_airborne, wind_mps=winds)
        for action in self.guard.tick(facts):
            if isinstance(action, Hold):
                if action.show_time is not None and in_show:
                    # Where along the plan are the drones, after flying on stale setpoints
                    # (between the last setpoints' show time and where the clock is now)?
                    resynced = self._stop_at_last_setpoints(seq, now, action.reason,
                                                            action.show_time)
                else:
                    seq.hold_for(action.reason, now)
                self._say(action.text, "show_held", reason=action.reason,
                          show_time=round(seq.show_time(now), 2))
            elif isinstance(action, Release):
                resumed = seq.release(action.reason, now)
                others = sorted(seq.holds)
                text = action.text if resumed or not others else \
                    f"{action.text.split(':')[0]}; still holding for {', '.join(others)}"
                self._say(text, "show_released", reason=action.reason, resumed=resumed)
            elif isinstance(action, TakeOut):
                self._say(action.text, "taken_out", system_id=action.sysid,
                          distance_m=round(action.distance_m, 2))
                self._perform(seq.take_out(action.sysid, now, action.distance_m,
                                           "off its path in a safety hold,"))
            elif isinstance(action, LandAll):
                self._say(action.text, "guard_land_all")
                self._perform(seq.land_all(now))
                for reason in GUARD_SHOW_HOLDS:  # the land-all's own hold stops the show
                    seq.release(reason, now)
        return resynced
