"""What each vehicle's link delay asks of the tick: the lead its setpoints are
taken with, and whether it is late (its LED colours, sent ahead by the same delay, are
the LED stage's: :mod:`groundctl.flight.runner.leds`)."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from groundctl.execute.paths import PathKind
from groundctl.execute.sequence import FLEET_HOLDS, ShowSequence, StreamRequest, VehiclePhase
from groundctl.flight.runner.planning import Planning


class LinkTiming(Planning):
    """Leads and late vehicles (a layer of :class:`ShowRunner`)."""

    def _link_delays(self, now: float) -> dict[int, float | None]:
        """Recent one-way link delay per vehicle (half the recent median round trip),
        worked out once a second: TIMESYNC answers come at 1 Hz."""
        if self._delays is None or now - self._delays[0] >= 1.0 or now < self._delays[0]:
            out: dict[int, float | None] = {}
            for sysid, state in self.link.vehicles.items():
                rtt = state.timesync.recent_rtt_s(now)
                out[sysid] = None if rtt is None else rtt / 2.0
            self._delays = (now, out)
        return self._delays[1]

    def _lead_tick(self, seq: ShowSequence, req: StreamRequest, now: float,
                   in_show: Collection[int]) -> None:
        """Feed the lead estimate with the vehicles flying their plan on a steady clock,
        and stream each with its lead."""
        if self.leads is None or self._stream is None or self.monitor is None:
            return
        # After a stall the lead moves no more than over two ticks.
        dt = 0.0 if self._lead_at is None else min(max(now - self._lead_at, 0.0),
                                                   2.0 / self.config.rate_hz)
        self._lead_at = now
        steady = req.clock is not None and not req.ended and not seq.holds \
            and req.clock.at(now).rate == 1.0 \
            and req.clock.at(now - 2 * self.config.lead.max_s).rate == 1.0
        sysids: list[int] = []
        rows: list[int] = []
        last = self.monitor.last_positions
        if steady and last is not None and last[0] == now:
            _, ids, _ = last
            replanned = self.replanner.active if self.replanner is not None else set()
            for k, sysid in enumerate(ids):
                path = req.paths.get(sysid)
                if sysid in in_show and path is not None and path.kind is PathKind.PLAN \
                        and sysid not in replanned:
                    sysids.append(sysid)
                    rows.append(k)
        if sysids:
            assert last is not None
            tracks = np.array([seq.vehicles[s].track for s in sysids])
            planned, pvel, _ = self.plan.trajectories.evaluate(req.show_time, tracks)
            self.leads.observe(now, sysids, last[2][rows] - planned, pvel)
        else:
            self.leads.observe(now, [], np.zeros((0, 3)), np.zeros((0, 3)))
        self.leads.update(dt, self._link_delays(now))
        self._stream.set_leads(self.leads.as_dict())

    def _flag_late(self, seq: ShowSequence, now: float) -> None:
        """Late: a vehicle's recent one-way link delay exceeds the lead it is streamed with
        (its setpoints arrive after the instant they are for).  Judged on recent TIMESYNC
        answers, so one answer queued behind a freeze of ours flags nobody for good; the
        flag clears when the delay is back within the lead."""
        if seq.holds & FLEET_HOLDS or self._stream is None:
            return  # our own trouble: its round trips say nothing about the vehicles
        delays = self._link_delays(now)
        leads = {s: self._stream.lead_of(s) for s, v in seq.vehicles.items()
                 if v.phase in (VehiclePhase.READY, VehiclePhase.SHOW)
                 and s in self._stream.sysids
                 and len(self.link.vehicles[s].timesync.samples) >= 3}
        late = {s for s, r in self.records.items() if r.late}
        for sysid in late - set(leads):  # out of the show (or not judged now): not late now
            if seq.vehicles.get(sysid) is not None \
                    and seq.vehicles[sysid].phase not in (VehiclePhase.READY, VehiclePhase.SHOW):
                self._record(sysid).late = False
        newly, cleared = self._late.check(leads, delays, late)
        for sysid in sorted(newly):
            rec = self._record(sysid)
            rec.late, rec.late_count = True, rec.late_count + 1
            delay, lead = delays[sysid] or 0.0, leads[sysid]
            self._say(f"vehicle {sysid} is late: one-way delay ~{delay * 1000:.0f} ms (recent "
                      f"round trips) exceeds its setpoint lead of {lead * 1000:.0f} ms",
                      "vehicle_late", system_id=sysid, delay_ms=round(delay * 1000, 1),
                      lead_ms=round(lead * 1000, 1), kind="late",
                      summary="late: one-way delay exceeds the setpoint lead")
        for sysid in sorted(cleared):
            self._record(sysid).late = False
            delay = delays[sysid] or 0.0
            self._say(f"vehicle {sysid} is no longer late: one-way delay ~{delay * 1000:.0f} "
                      f"ms, within its setpoint lead of {leads[sysid] * 1000:.0f} ms",
                      "vehicle_late_cleared", system_id=sysid,
                      delay_ms=round(delay * 1000, 1), lead_ms=round(leads[sysid] * 1000, 1),
                      kind="late_cleared", summary="no longer late")
