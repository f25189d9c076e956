"""The state every layer of the runner reads and changes (its fields, as the
constructor sets them) and the helpers all of them share: saying and notifying,
each vehicle's record and lead, spawning a task."""

from __future__ import annotations

import asyncio
import functools
import math
from collections.abc import Awaitable, Callable, Collection
from dataclasses import replace
from typing import Any

from groundctl.clock import Clock
from groundctl.execute.guard import FlightGuard
from groundctl.execute.lead import LateWatch, LeadEstimator
from groundctl.execute.mapping import Assignment
from groundctl.execute.preflight import PreflightReport
from groundctl.execute.sequence import Notice, ShowSequence, StreamRequest
from groundctl.execute.setpoints import SetpointStream
from groundctl.flight.monitor import FlightMonitor
from groundctl.flight.replanning import Replanner
from groundctl.flight.runner.config import RunnerConfig, VehicleRecord, log
from groundctl.flight.runner.leds import LedSends, link_delays
from groundctl.flight.runner.slots import SendSlots
from groundctl.flight.workers import PlannerPool
from groundctl.link.fleet import FleetLink
from groundctl.plan.plan import Plan
from groundctl.record.events import EventSink


class RunnerState:
    """The runner's fields and the few helpers every layer of
    :class:`~groundctl.flight.runner.ShowRunner` shares (saying, recording, spawning
    a task)."""

    def __init__(self, plan: Plan, link: FleetLink, clock: Clock,
                 config: RunnerConfig | None = None, *, events: EventSink | None = None,
                 notify: Callable[[str], None] | None = None,
                 expected_ids: Collection[int] | None = None,
                 confirm_go: Callable[[PreflightReport], Awaitable[bool]] | None = None
                 ) -> None:
        self.plan = plan
        self.link = link
        self.clock = clock
        config = config or RunnerConfig()
        if config.thresholds.max_wind is None:
            config = replace(config, thresholds=replace(config.thresholds,
                                                        max_wind=plan.limits.max_wind))
        self.config = config
        self.events = events
        self.notify = notify
        self.expected_ids = None if expected_ids is None else sorted(expected_ids)
        self.assignment: Assignment | None = None
        self.preflight_report: PreflightReport | None = None
        self.spares: dict[int, int] = {}
        """System id -> spare pad index of the spares ready when the pre-flight passed
        (every check passed, not excluded): the ones that may take over a track."""
        self.sequence: ShowSequence | None = None
        self.monitor: FlightMonitor | None = None
        self.records: dict[int, VehicleRecord] = {}
        self.lateness_s: list[float] = []
        """Per tick: how long after its scheduled instant the tick's last setpoint left, s."""
        self.overruns = 0
        """Ticks skipped because the loop fell a whole period behind."""
        self.rtk: Any = None
        """The RTK forwarder (:class:`groundctl.rtk.forwarder.RtkForwarder`) when
        ``--rtk`` is given: the report and the console read its counts and ages."""
        self.on_tick: Callable[[float, float], None] | None = None
        """Called after every tick with (now, show time): the dry-run's truth probe."""
        self.loop_lag_s: list[float] = []
        """Per tick: how late the tick started against its scheduled instant."""
        self.guard = FlightGuard(self.config.guard, self.config.thresholds.max_wind)
        """Holds for our own lag, fleet-wide silence and safety responses."""
        self._stream: SetpointStream | None = None
        self._slots: SendSlots | None = None
        self._next_tick = math.inf
        self._leds = LedSends(
            clock, link.send_led_rgb,
            functools.partial(link_delays, self._median_rtt),
            lambda: self.clock.idle_until(self._idle_due()),
            period_s=1.0 / self.config.rate_hz, refresh_s=self.config.led_refresh_s)
        """The tick's LED stage (its colour changes sent ahead, on timers between ticks)."""
        self._tasks: set[asyncio.Task[None]] = set()
        self._return_task: asyncio.Task[None] | None = None
        self._leave_tasks: dict[int, asyncio.Task[None]] = {}
        self._join_tasks: dict[int, asyncio.Task[None]] = {}  # by track
        self._clock_state: tuple[int, ...] = ()
        """The clocks' revisions the MPC trajectories were last kept for."""
        self._pool: PlannerPool | None = None
        self._pending_notices: list[Notice] = []
        self._last_show_time: float | None = None
        self._finished = False
        self._request: tuple[float, StreamRequest] | None = None
        self.leads: LeadEstimator | None = None
        """Per-vehicle leads measured in flight (None: a fixed lead, ``config.lead_s``)."""
        self.replanner: Replanner | None = None
        """MPC replanning (None: off, or the flight is over)."""
        self.mpc_summary: dict[str, Any] | None = None
        """What the MPC did, kept once the flight is over (the report's ``mpc``)."""
        self._lead_at: float | None = None
        self._late = LateWatch()
        self._delays: tuple[float, dict[int, float | None]] | None = None
        self.confirm_go = confirm_go
        """The operator's go gate (the console): awaited with the pre-flight report once
        every check passed, before anything is armed; False is a no-go.  None: the show
        arms as soon as the pre-flight passes."""
        self.awaiting_go = False
        """True while :attr:`confirm_go` is being awaited."""

    # -- reporting -------------------------------------------------------------------
    def _say(self, text: str, event: str = "notice", **fields: Any) -> None:
        log.info("%s", text)
        if self.events is not None:
            self.events.emit(event, text=text, **fields)
        self._notify(text)

    def _notify(self, text: str) -> None:
        if self.notify is not None:
            self.notify(text)

    def lead_of(self, sysid: int) -> float | None:
        """The lead ``sysid`` is streamed with now, s (None: not streamed)."""
        if self._stream is None or sysid not in self._stream.sysids:
            return None
        return self._stream.lead_of(sysid)

    def response_of(self, sysid: int) -> float | None:
        """``sysid``'s measured response delay, s (None: fixed lead, or not known yet)."""
        if self.leads is None or sysid not in self.leads.sysids:
            return None
        return self.leads.estimate(sysid).response_s

    def _median_rtt(self, sysid: int) -> float | None:
        state = self.link.vehicles.get(sysid)
        return state.median_rtt_s if state is not None else None

    def _idle_due(self) -> float:
        """The next clock instant this loop must act at: its next tick, or a setpoint slot
        or an LED send scheduled before it (a paced clock waits for us no further than
        that)."""
        slots = self._slots.dues() if self._slots is not None else []
        return min(self._next_tick, min(self._leds.dues(), default=math.inf),
                   min(slots, default=math.inf))

    def _record(self, sysid: int) -> VehicleRecord:
        return self.records.setdefault(sysid, VehicleRecord())

    def _spawn(self, coro: Any) -> None:
        task = asyncio.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
