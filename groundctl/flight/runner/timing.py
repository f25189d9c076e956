"""What each vehicle's link delay asks of the tick: the lead its setpoints are
taken with, its LED colours sent ahead of their instant, and whether it is late."""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from groundctl.clock import HELD_POLL_S
from groundctl.errors import LinkError
from groundctl.execute.lead import late_vehicles
from groundctl.execute.paths import PathKind
from groundctl.execute.sequence import FLEET_HOLDS, ShowSequence, StreamRequest, VehiclePhase
from groundctl.execute.setpoints import Setpoints
from groundctl.flight.runner.planning import Planning

#: LED changes due within this much real time of one another leave together (sent at
#: the earliest one's instant), s.
LED_SEND_QUANTUM_S = 0.001


class LinkTiming(Planning):
    """Leads, LED sends and late vehicles (a layer of :class:`ShowRunner`)."""

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
                   in_show: list[int]) -> None:
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

    def _leds_tick(self, seq: ShowSequence, now: float, sp: Setpoints, rows: list[int]) -> None:
        """LED colours on the show clock *at the vehicle*: each change is sent its own
        one-way link delay before it is due, at its own instant between ticks (LED_CONTROL
        is applied on arrival), and every colour is refreshed once a second (it is never
        acknowledged).  While the show clock is not running, the colours of the tick."""
        streamed = [sp.sysids[i] for i in rows]
        schedule = self._led_schedule
        running = seq.started_at is not None and not seq.ended \
            and seq.clock.at(now).rate >= 1.0 and schedule is not None
        if not running or schedule is None:
            self._cancel_led_sends()
            for sysid, (r, g, b) in self._leds.due(streamed, sp.rgb[rows], now):
                self.link.send_led_rgb(sysid, r, g, b)
            return
        delays = self._led_delays([int(x) for x in schedule.sysids])
        t = seq.show_time(now)
        period = 1.0 / self.config.rate_hz
        # Changes whose send instant falls in the next period, sent at that instant.
        wanted = set(streamed)
        start = self._led_window_end if math.isfinite(self._led_window_end) else t
        batch = schedule.window(min(start, t + period), t + period, delays)
        self._led_window_end = t + period
        loop = asyncio.get_running_loop()
        # Grouped by send instant (LED_SEND_QUANTUM_S of real time, never later): one
        # timer and one look at the clock per group, not per vehicle.
        groups: dict[float, tuple[list[float], list[tuple[int, tuple[int, int, int]]]]] = {}
        per_second = self.clock.wall_interval(1.0)  # 0: a clock real time does not move
        quantum = LED_SEND_QUANTUM_S / per_second if per_second > 0 else 0.0
        for k in range(len(batch.sysids)):
            sysid = int(batch.sysids[k])
            if sysid not in wanted:
                continue
            colour = (int(batch.rgb[k][0]), int(batch.rgb[k][1]), int(batch.rgb[k][2]))
            wait = max(float(batch.send_at[k]) - t, 0.0)
            key = math.floor(wait / quantum) if quantum > 0 else wait
            waits, items = groups.setdefault(key, ([], []))
            waits.append(wait)
            items.append((sysid, colour))
        for waits, items in groups.values():
            wait = min(waits)
            handle = loop.call_later(self.clock.wall_interval(wait), self._send_led_at,
                                     items, now + wait)
            self._led_handles.append(handle)
            self._led_dues.append(now + wait)
        self._led_handles = [h for h in self._led_handles if not h.cancelled()
                             and h.when() >= loop.time()]
        # The periodic refresh, of the colour the vehicle should show when it arrives.
        colours = schedule.colour_at(t, delays)
        rows_of = {int(s): i for i, s in enumerate(schedule.sysids)}
        for sysid in streamed:
            last = self._leds.last(sysid)
            if last is None or now - last[1] >= self.config.led_refresh_s:
                c = colours[rows_of[sysid]]
                self._send_led(sysid, (int(c[0]), int(c[1]), int(c[2])), now)

    def _led_delays(self, sysids: Sequence[int]) -> NDArray[np.float64]:
        out = np.zeros(len(sysids))
        for i, sysid in enumerate(sysids):
            state = self.link.vehicles.get(sysid)
            rtt = state.median_rtt_s if state is not None else None
            out[i] = 0.0 if rtt is None else min(max(rtt / 2.0, 0.0), 1.0)
        return out

    def _send_led_at(self, items: list[tuple[int, tuple[int, int, int]]], due: float
                     ) -> None:
        """Send ``items`` (system id, colour) at clock time ``due``: again later if the
        clock is not there yet (a paced dry-run clock that waited for a late loop runs
        slower than real time)."""
        wait = due - self.clock.now()
        if wait > 1e-3:
            handle = asyncio.get_running_loop().call_later(
                max(self.clock.wall_interval(wait), HELD_POLL_S), self._send_led_at, items,
                due)
            self._led_handles.append(handle)
            return
        now = self.clock.now()  # once for the group, not once per vehicle
        for sysid, colour in items:
            self._send_led(sysid, colour, now)
        with contextlib.suppress(ValueError):
            self._led_dues.remove(due)
        self.clock.idle_until(self._idle_due())

    def _idle_due(self) -> float:
        """The next clock instant this loop must act at: its next tick, or an LED send
        scheduled before it (a paced clock waits for us no further than that)."""
        slots = self._slots.dues() if self._slots is not None else []
        return min(self._next_tick, min(self._led_dues, default=math.inf),
                   min(slots, default=math.inf))

    def _send_led(self, sysid: int, colour: tuple[int, int, int],
                  now: float | None = None) -> None:
        self._leds.sent(sysid, colour, self.clock.now() if now is None else now)
        with contextlib.suppress(LinkError):
            self.link.send_led_rgb(sysid, *colour)

    def _cancel_led_sends(self) -> None:
        for handle in self._led_handles:
            handle.cancel()
        self._led_handles.clear()
        self._led_dues.clear()
        self._led_window_end = -math.inf

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
        newly, cleared = late_vehicles(leads, delays, late)
        # Flagged only when it holds on two checks in a row (a second apart): one TIMESYNC
        # step in the recent median, which a measured lead follows within the second,
        # flags nobody.
        confirmed = newly & self._late_suspects
        self._late_suspects = newly - confirmed
        newly = confirmed
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
