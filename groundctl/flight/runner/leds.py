"""The tick's LED stage: each vehicle's colour changes sent ahead of their instant by its
own one-way link delay, on timers between ticks, every colour refreshed once a second
(LED_CONTROL is never acknowledged), and the tick's own colours while the show clock is
not running."""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Callable, Collection, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from groundctl.clock import Clock
from groundctl.errors import LinkError
from groundctl.execute.leds import LedSchedule
from groundctl.execute.setpoints import LedTracker
from groundctl.flight.runner.timers import ClockTimers

#: LED changes due within this much real time of one another leave together (sent at
#: the earliest one's instant), s.
LED_SEND_QUANTUM_S = 0.001

Colour = tuple[int, int, int]


class LedSends:
    """The LED stage of the runner's tick.

    ``send(sysid, r, g, b)`` sends one colour (a :class:`LinkError`, a vehicle whose
    address is not known yet, costs that one send); ``delays(sysids)`` is each vehicle's
    one-way link delay, s; ``idle()`` is called after each group scheduled between ticks
    has left (a paced clock waits for the loop no further than its next due instant,
    :meth:`dues`).  :attr:`schedule` is the show's colour changes by vehicle, set once the
    vehicles are mapped to their tracks.
    """

    def __init__(self, clock: Clock, send: Callable[[int, int, int, int], None],
                 delays: Callable[[Sequence[int]], NDArray[np.float64]],
                 idle: Callable[[], None], *, period_s: float, refresh_s: float) -> None:
        self.clock = clock
        self.schedule: LedSchedule | None = None
        self.tracker = LedTracker(refresh_s)
        """What was last sent to each vehicle, and when."""
        self._send_rgb = send
        self._delays = delays
        self._idle = idle
        self._period = period_s
        self._timers = ClockTimers(clock)  # the groups scheduled and not sent yet
        self._window_end = -math.inf

    def tick(self, now: float, show_time: float | None, streamed: Sequence[int],
             rgb: ArrayLike, dark: Collection[int] = ()) -> None:
        """One tick at clock time ``now``: ``streamed`` are the vehicles streamed this
        tick, ``rgb`` their colours of the tick (n, 3, 0..255); ``show_time`` is the show
        clock's time when it runs at full rate (None: held, braking, before the show or
        after it, when the tick's own colours are sent as they change); ``dark``: vehicles
        whose LEDs stay off whatever their track shows (spares on their way in, drones
        that left the show), streamed or not."""
        schedule = self.schedule
        if dark:
            rgb = np.array(rgb, dtype=np.uint8, copy=True)
            rgb[[i for i, s in enumerate(streamed) if s in dark]] = 0
            self._dark_unstreamed(dark, streamed, now)
        if show_time is None or schedule is None:
            self.cancel()
            for sysid, (r, g, b) in self.tracker.due(streamed, rgb, now):
                self._send_rgb(sysid, r, g, b)
            return
        delays = self._delays([int(x) for x in schedule.sysids])
        t = show_time
        # Changes whose send instant falls in the next period, sent at that instant.
        wanted = set(streamed) - set(dark)
        start = self._window_end if math.isfinite(self._window_end) else t
        batch = schedule.window(min(start, t + self._period), t + self._period, delays)
        self._window_end = t + self._period
        # Grouped by send instant (LED_SEND_QUANTUM_S of real time, never later): one
        # timer and one look at the clock per group, not per vehicle.
        groups: dict[float, tuple[list[float], list[tuple[int, Colour]]]] = {}
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
            key = self._timers.add(now + wait, wait, functools.partial(self._send_group, items))
            if wait <= 0.0:
                self._timers.fire(key, force=True)  # due already
        # The periodic refresh, of the colour the vehicle should show when it arrives.
        colours = schedule.colour_at(t, delays)
        rows_of = {int(s): i for i, s in enumerate(schedule.sysids)}
        for sysid in streamed:
            last = self.tracker.last(sysid)
            if last is None or now - last[1] >= self.tracker.refresh_s \
                    or (sysid in dark and last[0] != (0, 0, 0)):
                c = (0, 0, 0) if sysid in dark else colours[rows_of[sysid]]
                self._send(sysid, (int(c[0]), int(c[1]), int(c[2])), now)

    def _dark_unstreamed(self, dark: Collection[int], streamed: Sequence[int],
                         now: float) -> None:
        """Off, for the dark vehicles no longer streamed that were lit (down, coming down
        in their own land mode): sent as they go dark, then refreshed like any colour.
        One never lit (a spare waiting on its pad) is left to its autopilot."""
        if len(dark) == 0:
            return
        on = set(streamed)
        for sysid in dark:
            if sysid in on:
                continue
            last = self.tracker.last(sysid)
            if last is not None and (last[0] != (0, 0, 0)
                                     or now - last[1] >= self.tracker.refresh_s):
                self._send(sysid, (0, 0, 0), now)

    def _send_group(self, items: list[tuple[int, Colour]]) -> None:
        """Send ``items`` (system id, colour), their instant come."""
        now = self.clock.now()  # once for the group, not once per vehicle
        for sysid, colour in items:
            self._send(sysid, colour, now)
        self._idle()

    def _send(self, sysid: int, colour: Colour, now: float) -> None:
        self.tracker.sent(sysid, colour, now)
        with contextlib.suppress(LinkError):
            self._send_rgb(sysid, *colour)

    def forget(self, sysid: int) -> None:
        """``sysid`` is back from a silence (or rebooted): its colour is sent afresh."""
        self.tracker.forget(sysid)

    def dues(self) -> list[float]:
        """Clock instants of the sends scheduled between ticks, still to leave."""
        return self._timers.dues()

    def cancel(self) -> None:
        """Drop every send scheduled between ticks (the show clock stopped, or the flight
        is over); the next running tick starts a new window."""
        self._timers.cancel()
        self._window_end = -math.inf


def link_delays(rtt_of: Callable[[int], float | None], sysids: Sequence[int]
                ) -> NDArray[np.float64]:
    """One-way delay per vehicle, s: half its median round trip, 0 unknown, at most 1."""
    out = np.zeros(len(sysids))
    for i, sysid in enumerate(sysids):
        rtt = rtt_of(sysid)
        out[i] = 0.0 if rtt is None else min(max(rtt / 2.0, 0.0), 1.0)
    return out
