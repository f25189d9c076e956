"""The runner itself, :class:`ShowRunner`: :meth:`~ShowRunner.run` connects,
runs the pre-flight and flies; :meth:`~ShowRunner.fly` is the loop that
composes the tick's stages from the layers it is built from."""

from __future__ import annotations

import asyncio
import math

from groundctl.clock import sleep_until
from groundctl.errors import FlightError, NoGo
from groundctl.execute.sequence import ShowPhase, VehiclePhase
from groundctl.flight.runner.config import FlightBudget, _ids
from groundctl.flight.runner.stream import Streaming


class ShowRunner(Streaming):
    """Flies ``plan`` with the vehicles on ``link``; see the :mod:`groundctl.flight.runner`
    docstring."""

    async def run(self) -> None:
        """Connect, pre-flight, fly; commands in flight are cancelled on the way out.

        Cancelling the task that runs this means the operator abandoned the
        flight (a second Ctrl-C): that becomes a FlightError, so the caller
        still reports and records instead of unwinding past its ``finally``;
        before the show (nothing armed yet) it is a :class:`NoGo` (exit 5).
        """
        try:
            self._start_workers()  # they load while the link comes up
            await self.connect()
            await self.preflight()
            if self.confirm_go is not None:
                await self._go_gate()
            await self.fly()
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()
            if self.sequence is None:  # stopped in pre-flight (Ctrl-C, a closed terminal)
                raise NoGo("stopped before the show: nothing was armed") from None
            raise FlightError("flight abandoned by the operator") from None
        finally:
            await self._drain()
            self._finished = True
            if self._pool is not None:
                self._pool.close()
                self._pool = None
            if self.replanner is not None:
                self.replanner.close()
                self.mpc_summary = self.replanner.report()
                self.replanner = None

    async def fly(self) -> None:
        """Arm, take off, fly the show, land; returns once every vehicle is down."""
        await self._vehicle_settings()
        seq = self._build()
        cfg = self.config
        period = 1.0 / cfg.rate_hz
        self._start_workers()
        await self._configure(seq)
        await self._planner_ready()
        now = self.clock.now()
        # The first tick is due now: a dry-run's paced clock waits for it from here, not
        # from the loop's first look (the arming commands below took 120 ms of a x60
        # clock on a busy machine, and that tick was as late).
        self.clock.idle_until(now)
        self._say(f"arming {len(seq.vehicles)} vehicle(s)", "sequence_started")
        self._perform(seq.start(now))
        budget = (cfg.sequence.takeoff_timeout_s + 2 * cfg.sequence.step_timeout_s
                  * cfg.sequence.max_attempts + self.plan.duration + cfg.landing_timeout_s)
        clock_budget = FlightBudget(budget, now)
        next_tick = now
        next_check = now
        next_progress = now + cfg.progress_every_s
        lost_since: float | None = None
        try:
            while seq.phase is not ShowPhase.LANDED:
                # Nothing to do before the next tick (a dry-run's paced clock waits for
                # us no further than that); a clock that waited for someone else is
                # slower than its pace, so the sleep is repeated until the tick is due.
                self._next_tick = next_tick
                self.clock.idle_until(self._idle_due())
                await sleep_until(self.clock, next_tick)
                self.link.drain()  # decide on every packet that has arrived, not a backlog
                now = self.clock.now()
                scheduled = next_tick
                lag = now - scheduled
                self.loop_lag_s.append(lag)
                next_tick += period
                if next_tick < now:
                    skipped = int((now - next_tick) / period) + 1
                    self.overruns += skipped
                    next_tick += skipped * period
                clock_budget.tick(now, held=bool(seq.holds - {"land-all"}))
                self.link.check_lost(now)
                self._perform(seq.update(now, self.link.vehicles))
                stalled = lag > cfg.guard.stall_s and seq.started_at is not None
                if not stalled:
                    self._stream_tick(seq, now, scheduled)
                resynced = self._guard_tick(seq, now, lag, period)
                if stalled:
                    if not resynced and "stall" in seq.holds:
                        # Stalled again while the first stall's hold brakes: back at the
                        # last setpoints once more (where the drones stand now).
                        self._stop_at_last_setpoints(seq, now, "stall")
                    # We stalled: setpoints on the clock as it stood would send the fleet
                    # where it never went, so the guard put the show clock back at the last
                    # setpoints' show time first.  Streaming goes on: a PX4 vehicle left
                    # without setpoints for COM_OF_LOSS_T (1 s) drops out of OFFBOARD into
                    # its failsafe, so a loop that stalls tick after tick must still send.
                    self._stream_tick(seq, now, scheduled)
                self._start_planning(seq)
                if now >= next_check:
                    next_check = now + 1.0
                    self._flag_late(seq, now)
                if now >= next_progress:
                    next_progress = now + cfg.progress_every_s
                    self._say(self.status_line(), "progress")
                if self.on_tick is not None:
                    self.on_tick(now, seq.show_time(now))
                self._flush_notices()
                if seq.settled and seq.lost:
                    # Everyone else is down; the lost may be airborne under their own
                    # failsafes.  Keep listening (and streaming) for a while.
                    if lost_since is None:
                        lost_since = now
                        self._say(f"every vehicle is down but {_ids(seq.lost)}, lost: "
                                  f"waiting up to {cfg.lost_wait_s:.0f} s to hear from "
                                  f"{'it' if len(seq.lost) == 1 else 'them'} (Ctrl-C twice "
                                  "abandons the flight)", "waiting_for_lost",
                                  system_ids=seq.lost)
                    elif now - lost_since > cfg.lost_wait_s:
                        raise FlightError(
                            f"vehicle(s) {seq.lost} lost and never seen down within "
                            f"{cfg.lost_wait_s:.0f} s of the others landing: they may still be "
                            "airborne, under their own failsafe")
                else:
                    lost_since = None
                if clock_budget.expired(now):
                    left = {s: str(v.phase) for s, v in seq.vehicles.items()
                            if v.phase not in (VehiclePhase.LANDED, VehiclePhase.FAILED,
                                               VehiclePhase.KILLED)}
                    raise FlightError(f"the flight did not finish within {budget:.0f} s: "
                                      f"vehicles still flying or unaccounted for {left}")
        finally:
            self._flush_notices()
            self._leds.cancel()
            if self._slots is not None:
                self._slots.cancel()
            self._next_tick = math.inf
            self.clock.idle_until(math.inf)  # no more ticks: nobody waits for this loop
        self._say("every vehicle is down", "sequence_finished",
                  phases={str(s): str(v.phase) for s, v in seq.vehicles.items()})
        await self._drain()
