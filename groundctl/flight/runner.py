"""ShowRunner: the async driver that flies a plan through a FleetLink.

The decisions live in the pure executor core (:mod:`groundctl.execute`);
this module only times them and carries them out:

1. :meth:`ShowRunner.connect` waits for the fleet's HEARTBEATs;
2. :meth:`ShowRunner.preflight` asks for the telemetry streams and the EKF
   origins, maps vehicles to tracks and repeats the pre-flight checks until
   every vehicle passes (or a check fails that waiting cannot fix: a low
   battery, a vehicle off its slot);
3. :meth:`ShowRunner.fly` runs one loop at ``rate_hz`` of the clock,
   scheduled on absolute deadlines so it never drifts: the sequence's
   actions become link commands (each in its own task, so a slow ACK never
   delays a setpoint), then every streamed vehicle gets its setpoint and,
   when due, its LED colour, then the monitor measures the tick.

Operator commands (:meth:`hold`, :meth:`resume`, :meth:`land_all`,
:meth:`land_one`, :meth:`land_here`, :meth:`kill`) may be called at any time
from the event loop (console, signal handler, test).  Everything notable is
sent to the event sink and to ``notify`` (the operator's screen).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Awaitable, Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import HELD_POLL_S, Clock, sleep_until
from groundctl.errors import (
    CommandRefused,
    FlightError,
    GroundctlError,
    LinkError,
    NoGo,
    PlanningTimeout,
    PreflightFailed,
)
from groundctl.execute.frames import ned_vel_to_show, show_positions
from groundctl.execute.guard import (
    GUARD_SHOW_HOLDS,
    FlightGuard,
    GuardConfig,
    Hold,
    LandAll,
    Release,
    TakeOut,
    TickFacts,
)
from groundctl.execute.lead import LeadConfig, LeadEstimator, late_vehicles
from groundctl.execute.leds import LedSchedule
from groundctl.execute.mapping import Assignment, auto_assign, explicit_assign
from groundctl.execute.paths import PathKind
from groundctl.execute.preflight import (
    WIND_FRESH_S,
    PreflightReport,
    Thresholds,
    remaining_plan_conflicts,
    run_preflight,
)
from groundctl.execute.sequence import (
    AIRBORNE_M,
    FLEET_HOLDS,
    HOVER_BEFORE_SHOW_S,
    Action,
    Arm,
    Command,
    Disarm,
    Kill,
    Land,
    Notice,
    SequenceConfig,
    SetMode,
    ShowPhase,
    ShowSequence,
    StreamRequest,
    Takeoff,
    VehiclePhase,
)
from groundctl.execute.setpoints import (
    LedTracker,
    Setpoints,
    SetpointStream,
    StreamTarget,
)
from groundctl.flight.monitor import FlightMonitor, nearest_pair, telemetry_positions
from groundctl.flight.replanning import Replanner
from groundctl.flight.returning import assign_landing, column
from groundctl.flight.workers import PlannerPool
from groundctl.link.flavours import Flavour
from groundctl.link.fleet import FleetLink
from groundctl.link.state import VehicleState
from groundctl.plan.plan import Plan
from groundctl.record.events import EventSink
from groundctl.record.logstreams import request_log_extras
from groundctl.show.model import VehicleSettings

log = logging.getLogger(__name__)

#: Checks a vehicle cannot pass by waiting (once their value is known).
PERMANENT_CHECKS = frozenset({"battery", "slot"})
#: More notices than this of one kind in one tick are folded into one line.
FOLD_AFTER = 3
#: Phases in which a vehicle is (or may be) in the air, for the guard's closest pair.
_AIRBORNE = frozenset({VehiclePhase.READY, VehiclePhase.SHOW, VehiclePhase.LEAVING,
                       VehiclePhase.RETURNING})

def _ids(ids: Sequence[int]) -> str:
    """System ids as a short list: "1-4, 7, 9"."""
    out: list[str] = []
    run: list[int] = []
    for i in sorted(ids):
        if run and i == run[-1] + 1:
            run.append(i)
            continue
        if run:
            out.append(f"{run[0]}-{run[-1]}" if len(run) > 2 else
                       ", ".join(map(str, run)))
        run = [i]
    if run:
        out.append(f"{run[0]}-{run[-1]}" if len(run) > 2 else ", ".join(map(str, run)))
    return "(" + ", ".join(out) + ")"


def _range_rate(pa: NDArray[np.float64], pb: NDArray[np.float64], a: VehicleState,
                b: VehicleState, plan: Plan) -> float:
    """How fast two vehicles at ``pa``, ``pb`` (show frame) close (negative) or part, m/s."""
    if a.velocity_ned is None or b.velocity_ned is None:
        return 0.0
    d = pb - pa
    dist = float(np.linalg.norm(d))
    if dist < 1e-9:
        return 0.0
    dv = ned_vel_to_show(plan.origin, np.array(b.velocity_ned) - np.array(a.velocity_ned))
    return float(np.dot(d, dv) / dist)


@dataclass(frozen=True)
class RunnerConfig:
    """How the runner flies; times are seconds of the runner's clock."""

    rate_hz: float = 10.0
    """Setpoint rate per vehicle (and the loop rate)."""
    lead_s: float | None = None
    """Setpoints are taken this far ahead of the show clock, to cover the link delay and
    the vehicle's response.  None: per vehicle, measured in flight from its own tracking
    (:mod:`groundctl.execute.lead`), starting from ``lead.initial_s``."""
    lead: LeadConfig = field(default_factory=LeadConfig)
    """The per-vehicle lead estimate's tuning (when ``lead_s`` is None)."""
    led_refresh_s: float = 1.0
    """An unchanged LED colour is re-sent this often (LED_CONTROL is never acknowledged)."""
    connect_timeout_s: float = 30.0
    """Every expected vehicle must send a HEARTBEAT within this."""
    preflight_timeout_s: float = 120.0
    """Every vehicle must pass its pre-flight checks within this."""
    settle_s: float = 3.0
    """A check that waiting cannot fix must fail this long before the pre-flight gives up."""
    excluded: frozenset[int] = frozenset()
    """System ids the operator keeps on the ground."""
    tracks: Mapping[int, int] | None = None
    """System id -> plan track from a fleet file; None maps vehicles by position."""
    thresholds: Thresholds = field(default_factory=Thresholds)
    """Pre-flight limits."""
    sequence: SequenceConfig = field(
        default_factory=lambda: SequenceConfig(hover_before_show_s=HOVER_BEFORE_SHOW_S))
    """Sequence tolerances and timeouts."""
    landing_timeout_s: float = 180.0
    """After the show ends (or land-all), every vehicle must be down within this."""
    lost_wait_s: float = 60.0
    """Once every other vehicle is down, lost ones are waited for this long (they may be
    airborne under their own failsafe) before the flight ends as unaccounted for."""
    guard: GuardConfig = field(default_factory=GuardConfig)
    """When the show holds for our own lag, a fleet-wide silence or a safety response."""
    return_deadline_s: float = 20.0
    """A return (or a way out planned while the show holds) must be planned within this
    many *wall* seconds: the fleet hovers meanwhile, so planning time costs battery, not
    safety, whatever the dry-run's speed."""
    planning_attempts: int = 2
    """Attempts at a return before flying straight to the landing points."""
    progress_every_s: float = 15.0
    """A progress line this often during the flight."""
    mpc: bool | None = None
    """Replan a vehicle off its path with MPC (None: as the plan's ``[mpc]`` says)."""
    guided_timeout_s: float | None = 1.0
    """ArduPilot: GUID_TIMEOUT set before arming, s (None: left as it is).  Given
    position + velocity + acceleration, GUIDED flies on along the last setpoint's
    velocity and acceleration until this long without one (the default 3 s): through a
    link drop the fleet would fly straight lines off its curved paths into each other.
    Shorter, a vehicle that stops hearing us stops sooner and holds where it is."""
    vehicle: VehicleSettings | None = None
    """The show's ``[vehicle]`` table: parameters read, set (when allowed) and the fence
    uploaded before arming (:mod:`groundctl.execute.vehset`); None: nothing checked."""
    mpc_deadline_s: float = 0.2
    """An MPC batch not back within this many wall seconds is discarded (the vehicles
    keep flying their last trajectory, then their path)."""

    def __post_init__(self) -> None:
        if not self.rate_hz >= 1.0:
            raise ValueError(f"`rate_hz` must be at least 1, got {self.rate_hz}")
        if self.lead_s is not None and self.lead_s < 0:
            raise ValueError(f"`lead_s` must be non-negative, got {self.lead_s}")

    @property
    def initial_lead_s(self) -> float:
        """The lead every vehicle starts with."""
        return self.lead.initial_s if self.lead_s is None else self.lead_s


@dataclass
class VehicleRecord:
    """What the runner itself counted for one vehicle."""

    commands_refused: int = 0
    """Commands refused or unanswered."""
    last_refusal: str | None = None
    """The last refusal's reason."""
    late: bool = False
    """Flagged now: its recent one-way link delay exceeds the lead it is streamed with."""
    late_count: int = 0
    """Times it was flagged late during the flight."""


@dataclass
class FlightBudget:
    """How long the flight may take: ``seconds`` of the runner's clock, not counting the
    time the show is held (the operator's hold, the guard's)."""

    seconds: float
    """The budget."""
    started: float
    """Clock time it started."""
    held_s: float = 0.0
    """Time held so far, not counted."""
    _last: float | None = field(default=None, init=False, repr=False)

    def tick(self, now: float, held: bool) -> None:
        """A tick of the loop at ``now``; ``held``: the show has been held since the last
        one.  All the time since the last tick counts as held, not one period: a loop
        late by many periods skips ticks, and a budget that ran on through them while
        the show was held ended the flight with the fleet in the air (measured: the demo
        at x6 beside two busy processes, ``--no-pace``: "did not finish within 399 s"
        with all 64 drones in the show)."""
        last = self.started if self._last is None else self._last
        if held:
            self.held_s += max(now - last, 0.0)
        self._last = now

    def expired(self, now: float) -> bool:
        """Whether the flight has run past its budget at ``now``."""
        return now > self.started + self.seconds + self.held_s


class ShowRunner:
    """Flies ``plan`` with the vehicles on ``link``; see the module docstring."""

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
        self._led_schedule: LedSchedule | None = None
        self._led_handles: list[asyncio.TimerHandle] = []
        self._led_window_end = -math.inf
        self._led_dues: list[float] = []  # clock instants of the LED sends scheduled
        self._next_tick = math.inf
        self._leds = LedTracker(self.config.led_refresh_s)
        self._tasks: set[asyncio.Task[None]] = set()
        self._return_task: asyncio.Task[None] | None = None
        self._leave_tasks: dict[int, asyncio.Task[None]] = {}
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
        self._late_suspects: set[int] = set()
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

    def _record(self, sysid: int) -> VehicleRecord:
        return self.records.setdefault(sysid, VehicleRecord())

    # -- phase 1: connect -----------------------------------------------------------
    async def connect(self) -> None:
        """Wait until every expected vehicle (or as many as the plan has) sent a HEARTBEAT."""
        want: list[int] | int = self.expected_ids if self.expected_ids is not None \
            else self.plan.drones
        self._say(f"waiting for {want if isinstance(want, int) else len(want)} vehicle(s)",
                  "connecting")
        await self.link.wait_for_vehicles(want, timeout=self.config.connect_timeout_s)
        self._say(f"{len(self.link.vehicles)} vehicle(s) heard", "connected",
                  system_ids=sorted(self.link.vehicles))

    # -- phase 2: pre-flight --------------------------------------------------------
    def _fleet(self) -> dict[int, Any]:
        ids = self.expected_ids if self.expected_ids is not None else sorted(self.link.vehicles)
        return {s: self.link.vehicles[s] for s in ids if s in self.link.vehicles}

    def _assign(self) -> Assignment:
        positions = show_positions(self.plan.origin, self._fleet())
        tol = self.config.thresholds.slot_tolerance_m
        if self.config.tracks is not None:
            return explicit_assign(self.config.tracks, self.plan.home, positions, tol)
        return auto_assign(self.plan.home, positions, tol)

    def _spawn(self, coro: Any) -> None:
        task = asyncio.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _ask(self, sysid: int, what: str, call: Any) -> None:
        try:
            await call
        except LinkError as exc:
            log.debug("vehicle %s: %s not answered yet: %s", sysid, what, exc)

    async def preflight(self) -> PreflightReport:
        """Streams, EKF origins, assignment and checks; raises PreflightFailed or FlightError."""
        cfg = self.config
        start = self.clock.now()
        streams_ok: set[int] = set()
        asked: dict[tuple[int, str], float] = {}
        failing_since: dict[tuple[int, str], float] = {}
        last_lines: list[str] = []
        next_progress = start + cfg.progress_every_s
        while True:
            cfg = self.config  # the operator may exclude a vehicle meanwhile (the console)
            now = self.clock.now()
            fleet = self._fleet()
            def due(sysid: int, what: str, every: float, now: float = now) -> bool:
                key = (sysid, what)
                if now - asked.get(key, -math.inf) < every:
                    return False
                asked[key] = now
                return True

            for sysid, state in fleet.items():
                if sysid not in streams_ok and due(sysid, "streams", 3.0):
                    self._spawn(self._request_streams(sysid, streams_ok))
                if state.ekf_origin is None and due(sysid, "origin", 2.0):
                    self._spawn(self._ask(sysid, "GPS_GLOBAL_ORIGIN", self.link.request_message(
                        sysid, mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, retries=0)))
                if state.home is None and due(sysid, "home", 2.0):
                    self._spawn(self._ask(sysid, "HOME_POSITION", self.link.request_message(
                        sysid, mavlink.MAVLINK_MSG_ID_HOME_POSITION, retries=0)))
            self.assignment = self._assign()
            report = run_preflight(fleet, self.assignment, now, cfg.thresholds)
            self.preflight_report = report
            failures = report.failures(cfg.excluded)
            lines = report.lines(cfg.excluded) + self.assignment.problems()
            if lines != last_lines:
                if self.events is not None:
                    self.events.emit("preflight", lines=lines)
                last_lines = lines
            missing = [t for t in self.assignment.unassigned_tracks
                       if t not in self._excluded_tracks()]
            if not failures and not missing:
                break
            # Give up early on what waiting cannot fix.
            permanent: dict[int, list[str]] = {}
            for sysid, results in report.results.items():
                if sysid in cfg.excluded:
                    continue
                for r in results:
                    key = (sysid, r.name)
                    if r.ok or r.name not in PERMANENT_CHECKS or not self._known(sysid, r.name):
                        failing_since.pop(key, None)
                        continue
                    since = failing_since.setdefault(key, now)
                    if now - since >= cfg.settle_s:
                        permanent.setdefault(sysid, []).append(str(r))
            if permanent:
                self._say("pre-flight refused: " + report.summary(cfg.excluded) + "\n"
                          + "\n".join(report.failing_by_check(cfg.excluded)), "preflight_failed",
                          failures=permanent)
                raise PreflightFailed(permanent)
            if now - start >= cfg.preflight_timeout_s:
                if failures:
                    self._say("pre-flight timed out: " + report.summary(cfg.excluded) + "\n"
                              + "\n".join(report.failing_by_check(cfg.excluded)),
                              "preflight_failed", failures=failures)
                    raise PreflightFailed(failures)
                raise FlightError(f"pre-flight: no vehicle for track(s) {missing} after "
                                  f"{cfg.preflight_timeout_s:.0f} s; exclude or add vehicles")
            if now >= next_progress:
                next_progress = now + cfg.progress_every_s
                self._say("pre-flight: " + report.summary(cfg.excluded), "progress")
            await asyncio.sleep(max(self.clock.wall_interval(0.5), 0.001))
        grounded = self._excluded_tracks()
        conflicts = remaining_plan_conflicts(self.plan, grounded) if grounded else []
        if conflicts:
            raise FlightError(f"excluding vehicle(s) {sorted(cfg.excluded)} leaves the show "
                              f"unsafe: {conflicts[0]}")
        self._say("pre-flight passed: " + report.summary(cfg.excluded), "preflight_passed",
                  tracks={str(k): v for k, v in self._tracks().items()},
                  lines=report.lines(cfg.excluded))
        return report

    def _known(self, sysid: int, check: str) -> bool:
        state = self.link.vehicles.get(sysid)
        if state is None:
            return False
        if check == "battery":
            return state.battery_remaining_pct is not None
        return state.ekf_origin is not None and state.position_ned is not None

    async def _request_streams(self, sysid: int, done: set[int]) -> None:
        try:
            await self.link.request_streams(sysid)
        except LinkError as exc:
            log.debug("vehicle %s: streams not set yet: %s", sysid, exc)
        else:
            done.add(sysid)
            self._spawn(request_log_extras(self.link, sysid))  # the tlog's extras, once

    def _tracks(self) -> dict[int, int]:
        assert self.assignment is not None
        return {s: t for s, t in self.assignment.tracks.items() if s not in self.config.excluded}

    def _excluded_tracks(self) -> set[int]:
        if self.assignment is None:
            return set()
        excluded = {t for s, t in self.assignment.tracks.items() if s in self.config.excluded}
        if self.config.tracks is not None:
            excluded |= {t for s, t in self.config.tracks.items() if s in self.config.excluded}
        return excluded

    # -- phase 3: fly ---------------------------------------------------------------
    def _build(self) -> ShowSequence:
        tracks = self._tracks()
        states = self.link.vehicles
        flavours: dict[int, Flavour] = {}
        targets = []
        for sysid, track in sorted(tracks.items()):
            state = states[sysid]
            assert state.flavour is not None and state.ekf_origin is not None  # pre-flight
            flavours[sysid] = state.flavour
            targets.append(StreamTarget(sysid, track, state.ekf_origin))
            self._record(sysid)
        self._stream = SetpointStream(self.plan, targets, self.config.initial_lead_s)
        self.leads = LeadEstimator([t.sysid for t in targets], self.config.lead) \
            if self.config.lead_s is None else None
        self._led_schedule = LedSchedule.from_targets(self.plan, targets)
        self.monitor = FlightMonitor(self.plan, tracks)
        self.sequence = ShowSequence(self.plan, tracks, flavours, self.config.sequence,
                                     grounded_tracks=self._excluded_tracks())
        return self.sequence

    async def _vehicle_settings(self) -> None:
        """The show's ``[vehicle]`` table on every vehicle, before arming; PreflightFailed
        with each refused vehicle's reasons."""
        if self.config.vehicle is None:
            return
        from groundctl.execute.vehset import enforce
        flavours: dict[int, Flavour] = {}
        for sysid in self._tracks():
            flavour = self.link.vehicles[sysid].flavour
            assert flavour is not None  # the pre-flight's autopilot check
            flavours[sysid] = flavour
        self._say(f"vehicle settings: checking {len(flavours)} vehicle(s)", "vehicle_settings")
        outcomes = await enforce(self.link, self.clock, flavours, self.config.vehicle,
                                 self.plan.origin, self.plan.limits)
        for sysid, out in sorted(outcomes.items()):
            if out.changed or out.fence:
                self._say(f"vehicle {sysid}: " + ", ".join(
                    [*(["fence uploaded"] if out.fence else []), *out.changed]),
                    "vehicle_settings_set", system_id=sysid, changed=out.changed,
                    fence=out.fence)
        failures = {s: o.problems for s, o in outcomes.items() if o.problems}
        if failures:
            self._say("pre-flight refused: vehicle settings\n" + "\n".join(
                f"vehicle {s}: " + "; ".join(why) for s, why in sorted(failures.items())),
                "preflight_failed", failures=failures)
            raise PreflightFailed(failures)

    async def _configure(self, seq: ShowSequence) -> None:
        """Parameters the show relies on, set before arming (ArduPilot GUID_TIMEOUT)."""
        timeout = self.config.guided_timeout_s
        if timeout is None:
            return
        ardu = [s for s, v in seq.vehicles.items() if v.flavour is Flavour.ARDUPILOT]
        if not ardu:
            return
        done = await asyncio.gather(*(self.link.set_param(s, "GUID_TIMEOUT", timeout)
                                      for s in ardu), return_exceptions=True)
        failed = [s for s, ok in zip(ardu, done, strict=True) if ok is not True]
        if failed:
            self._say(f"GUID_TIMEOUT {timeout:g} s not confirmed by vehicle(s) {_ids(failed)}: "
                      "through a link drop they fly on along their last setpoint for up to "
                      "their own GUID_TIMEOUT (3 s by default)", "param_not_set",
                      system_ids=failed, name="GUID_TIMEOUT")

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
            self._cancel_led_sends()
            self._next_tick = math.inf
            self.clock.idle_until(math.inf)  # no more ticks: nobody waits for this loop
        self._say("every vehicle is down", "sequence_finished",
                  phases={str(s): str(v.phase) for s, v in seq.vehicles.items()})
        await self._drain()

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
        # Every drone in the air estimates the wind, a landing one included.
        winds = tuple(w for s, p in ids_pos.items() if p[2] > AIRBORNE_M
                      and s in self.link.vehicles
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

    # -- planning in worker processes ---------------------------------------------------
    def _start_workers(self) -> None:
        """Start the planning (and MPC) workers loading numpy, scipy, OSQP and the plan
        in their own processes, while the link comes up and pre-flight runs."""
        if self.plan.model != "quadrotor" or self._finished:
            return
        if self._pool is None:
            self._pool = PlannerPool(self.plan)
            self._pool.start()
        cfg = self.config
        mpc_on = self.plan.mpc.enabled if cfg.mpc is None else cfg.mpc
        if mpc_on and self.replanner is None:
            self.replanner = Replanner(self.plan, self.plan.mpc, cfg.rate_hz,
                                       cfg.mpc_deadline_s, self.clock)
            self.replanner.start()

    async def _planner_ready(self) -> None:
        """Wait, before arming, until the planning worker can answer at once: a way out
        (land-one) or a way home asked for early in the show has only seconds to be
        planned, and a worker still importing numpy (nice, on a busy machine) spent them
        all (a land-one 7 s ahead missed its formation and landed after the show)."""
        if self._pool is None:
            return
        started = self.clock.now()
        try:
            await self._pool.warm_up()
        except PlanningTimeout as exc:
            raise FlightError(f"the planning worker did not start: {exc}; nothing "
                              "armed") from None
        waited = self.clock.now() - started
        if waited >= 1.0:
            self._say(f"waited {waited:.1f} s for the planning worker to load before arming",
                      "planner_wait", wait_s=round(waited, 2))

    def _start_planning(self, seq: ShowSequence) -> None:
        if seq.return_needed is not None and self._return_task is None:
            self._return_task = asyncio.create_task(self._plan_return(seq))
            self._own(self._return_task)
        # One way out at a time: each is planned around the ways out already set, so
        # several planned at once would each take the others for drones that stay
        # where they are (a link cut stranded all nine of a PX4 fleet at once under
        # load, and their nine ways out, planned side by side, crossed at 0.58 m).
        needed = seq.leave_needed
        if needed and not self._leave_tasks:
            sysid, track, at, start = needed[0]
            self._leave_tasks[sysid] = task = asyncio.create_task(
                self._plan_leave(seq, sysid, track, at, start))
            self._own(task)

    def _own(self, task: asyncio.Task[None]) -> None:
        # Cancelled with the rest on the way out (see _drain).
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _planner(self) -> PlannerPool:
        if self._finished:
            raise FlightError("the flight is over: nothing more is planned")
        if self._pool is None:
            self._pool = PlannerPool(self.plan)
            self._pool.start()
        return self._pool

    async def _plan_return(self, seq: ShowSequence) -> None:
        cfg = self.config
        try:
            for attempt in range(1, cfg.planning_attempts + 1):
                needed = seq.return_needed
                if not needed:
                    return
                sysids = [s for s, _ in needed]
                tracks = [t for _, t in needed]
                now = self.clock.now()
                start = np.array([seq.return_start(s, now) for s in sysids])
                down = np.array(seq.down_positions()).reshape(-1, 3)
                # Drones descending on their own spots are no spot thieves, but their
                # columns are in the way of a path that crosses them.
                descending = [p for p in seq.landing_positions() if len(down) == 0
                              or np.min(np.linalg.norm(down - p, axis=1)) > 0.01]
                reserved = np.array(seq.reserved_spots(sysids)).reshape(-1, 3)
                try:
                    goals = assign_landing(self.plan, tracks, start, down, reserved)
                    obstacles = list(down) + descending
                    static = np.concatenate([column(p) for p in obstacles]) if obstacles \
                        else None
                    authority, weakest = (1.0, None) if self.replanner is None \
                        else self.replanner.weakest(sysids)
                    self._say(f"planning a collision-free return for {len(sysids)} "
                              "vehicle(s); they brake along their paths and hover meanwhile"
                              + (f" ({len(down)} drone(s) down kept clear)" if len(down)
                                 else "")
                              + (f" (within {authority:.0%} of the limits: vehicle "
                                 f"{weakest} is weak)" if weakest is not None else ""),
                              "return_planning", attempt=attempt,
                              authority=round(authority, 2))
                    traj = await self._planner().plan_return(
                        tracks, start, cfg.return_deadline_s, static, goals=goals,
                        authority=authority)
                except PlanningTimeout as exc:
                    self._say(f"return planning attempt {attempt}: {exc}", "return_late")
                    continue
                except GroundctlError as exc:
                    self._perform(seq.return_failed(str(exc), self.clock.now()))
                    return
                self._perform(seq.set_return(traj, sysids, self.clock.now(), goals))
                return
            self._perform(seq.return_failed(f"no plan within {cfg.planning_attempts} attempts "
                                            f"of {cfg.return_deadline_s:.0f} s",
                                            self.clock.now()))
        finally:
            self._return_task = None

    async def _plan_leave(self, seq: ShowSequence, sysid: int, track: int, at: float,
                          start: tuple[float, float, float] | None) -> None:
        """Plan ``sysid``'s way out of the show (land-one mid-show, or heard again off its
        plan: from ``start``) around everyone else, in a worker, before its instant."""
        try:
            absent, static = self._not_on_plan(seq, sysid)
            now = self.clock.now()
            # It must be ready before its instant comes on the show clock (which stands
            # still while the show holds: then the planner has all the time it needs).
            ahead = max(at - seq.show_time(now), 0.0)
            wall = max(self.clock.wall_interval(max(ahead - 0.3, 0.5)), 0.05) \
                if not seq.paused else self.config.return_deadline_s
            self._say(f"planning vehicle {sysid}'s way out of the show (leaving at show time "
                      f"{at:.1f} s)", "leave_planning", system_id=sysid, at=round(at, 2))
            try:
                leave = await self._planner().plan_leave(
                    track, at, seq.leaves, absent, static,
                    None if start is None else np.asarray(start, dtype=float),
                    wall,
                    what=f"planning vehicle {sysid}'s way out")
            except PlanningTimeout as exc:
                self._perform(seq.leave_late(sysid, str(exc), self.clock.now()))
                return
            except GroundctlError as exc:
                self._perform(seq.leave_failed(sysid, str(exc), self.clock.now()))
                return
            self._perform(seq.set_leave(sysid, leave, self.clock.now()))
        finally:
            self._leave_tasks.pop(sysid, None)

    def _not_on_plan(self, seq: ShowSequence, leaving: int
                     ) -> tuple[list[int], NDArray[np.float64]]:
        """Tracks nobody flies (excluded, down, descending, killed) and the columns where
        those drones really are, from telemetry (or their slot, for one never airborne)."""
        absent: list[int] = []
        columns: list[NDArray[np.float64]] = []
        for track in self._excluded_tracks():
            absent.append(track)
            columns.append(column(self.plan.home[track]))
        positions = show_positions(self.plan.origin, self.link.vehicles)
        now = self.clock.now()
        for sysid, v in seq.vehicles.items():
            phase = seq.streamed_as(v)  # a lost one is still streamed what it was
            if sysid == leaving:
                continue
            path = seq.path(sysid, now)
            if path is not None and path.kind is PathKind.HOLD:
                assert path.point is not None
                absent.append(v.track)  # hovering where it was heard again, not on its plan
                columns.append(np.array([path.point]))
            elif phase not in (VehiclePhase.READY, VehiclePhase.SHOW, VehiclePhase.LEAVING,
                               VehiclePhase.RETURNING):
                absent.append(v.track)  # down, descending, killed, or never airborne
                pos = positions.get(sysid)
                columns.append(column(self.plan.home[v.track] if pos is None else pos))
        static = np.concatenate(columns) if columns else np.empty((0, 3))
        return absent, static

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
            replanned = self.replanner.overrides(now, self._stream.lead_of) \
                if self.replanner is not None else None
            sp = self._stream.at(now, offsets, paths=req.paths, clocks=req.clocks(self.plan),
                                 replanned=replanned)
            send = self.link.send_position_target_local_ned
            rows = [i for i, s in enumerate(sp.sysids) if s in req.sysids]
            for i in rows:
                send(sp.sysids[i], int(sp.time_boot_ms[i]), sp.pos_ned[i].tolist(),
                     sp.vel_ned[i].tolist(), sp.acc_ned[i].tolist())
            seq.streamed([sp.sysids[i] for i in rows], now)
            # The tick's last setpoint has left: how late against its scheduled instant.
            self.lateness_s.append(self.clock.now() - scheduled)
            self._last_show_time = (min(req.clock.show_time(now + self._stream.typical_lead),
                                        self.plan.duration)
                                    if req.clock is not None and not req.ended else None)
            self._leds_tick(seq, now, sp, rows)
        in_show = [s for s, v in seq.vehicles.items() if v.phase is VehiclePhase.SHOW] \
            if seq.started_at is not None and not seq.ended else []
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
            if s not in wanted and v is not None and v.phase is VehiclePhase.LANDING \
                    and v.column and v.hold_point is not None and s in last[1]:
                # Sent straight down by the last resort from where it held: told to stay
                # over that point (at the height it is at).
                z = last[2][last[1].index(s)][2]
                wanted[s] = np.array([v.hold_point[0], v.hold_point[1], z])
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
        velocities = {}
        for sysid in eligible:
            vel = self.link.vehicles[sysid].velocity_ned
            if vel is not None:
                velocities[sysid] = ned_vel_to_show(self.plan.origin, np.array(vel))
        obstacles = {s: p for s, p in positions.items() if s not in eligible
                     and s in seq.vehicles and p[2] > AIRBORNE_M}
        throttles = {s: (st.throttle_pct, st.throttle_at) for s in eligible
                     if (st := self.link.vehicles[s]).throttle_pct is not None
                     and st.throttle_at is not None}
        for event, text, fields in self.replanner.tick(now, eligible, req.clocks(self.plan),
                                                       positions, velocities, obstacles,
                                                       throttles):
            self._say(text, event, **fields)

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
        for k in range(len(batch.sysids)):
            sysid = int(batch.sysids[k])
            if sysid not in wanted:
                continue
            colour = (int(batch.rgb[k][0]), int(batch.rgb[k][1]), int(batch.rgb[k][2]))
            wait = max(float(batch.send_at[k]) - t, 0.0)
            handle = loop.call_later(self.clock.wall_interval(wait), self._send_led_at,
                                     sysid, colour, now + wait)
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
                self._send_led(sysid, (int(c[0]), int(c[1]), int(c[2])))

    def _led_delays(self, sysids: Sequence[int]) -> NDArray[np.float64]:
        out = np.zeros(len(sysids))
        for i, sysid in enumerate(sysids):
            state = self.link.vehicles.get(sysid)
            rtt = state.median_rtt_s if state is not None else None
            out[i] = 0.0 if rtt is None else min(max(rtt / 2.0, 0.0), 1.0)
        return out

    def _send_led_at(self, sysid: int, colour: tuple[int, int, int], due: float) -> None:
        """Send at clock time ``due``: again later if the clock is not there yet (a paced
        dry-run clock that waited for a late loop runs slower than real time)."""
        wait = due - self.clock.now()
        if wait > 1e-3:
            handle = asyncio.get_running_loop().call_later(
                max(self.clock.wall_interval(wait), HELD_POLL_S), self._send_led_at, sysid,
                colour, due)
            self._led_handles.append(handle)
            return
        self._send_led(sysid, colour)
        with contextlib.suppress(ValueError):
            self._led_dues.remove(due)
        self.clock.idle_until(self._idle_due())

    def _idle_due(self) -> float:
        """The next clock instant this loop must act at: its next tick, or an LED send
        scheduled before it (a paced clock waits for us no further than that)."""
        return min(self._next_tick, min(self._led_dues, default=math.inf))

    def _send_led(self, sysid: int, colour: tuple[int, int, int]) -> None:
        self._leds.sent(sysid, colour, self.clock.now())
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

    def _perform(self, actions: list[Action]) -> None:
        for a in actions:
            if isinstance(a, Notice):
                if a.kind in ("heard_again", "retaken") and a.sysid is not None:
                    self._leds.forget(a.sysid)  # back from a silence: its colour afresh
                if a.kind and a.sysid is not None:
                    self._pending_notices.append(a)  # folded per kind at the tick's end
                else:
                    self._say(a.text, "sequence", system_id=a.sysid)
            else:
                self._spawn(self._command(a))

    def _flush_notices(self) -> None:
        """Notices of one kind for many vehicles in one tick become one line (each is
        still one event)."""
        pending, self._pending_notices = self._pending_notices, []
        by_kind: dict[str, list[Notice]] = {}
        for n in pending:
            by_kind.setdefault(n.kind, []).append(n)
        for kind, notes in by_kind.items():
            if len(notes) <= FOLD_AFTER:
                for n in notes:
                    self._say(n.text, "sequence", system_id=n.sysid, kind=kind)
                continue
            ids = sorted({n.sysid for n in notes if n.sysid is not None})
            for n in notes:
                if self.events is not None:
                    self.events.emit("sequence", text=n.text, system_id=n.sysid, kind=kind)
            self._notify(f"{len(ids)} vehicles {_ids(ids)}: {notes[0].summary or kind}")

    async def _command(self, a: Command) -> None:
        link = self.link
        if self.events is not None:
            self.events.emit("command", system_id=a.sysid, action=type(a).__name__,
                             **{k: v for k, v in vars(a).items() if k != "sysid"})
        try:
            if isinstance(a, SetMode):
                await link.set_mode(a.sysid, a.mode)
            elif isinstance(a, Arm):
                await link.arm(a.sysid)
            elif isinstance(a, Takeoff):
                await link.takeoff(a.sysid, a.alt_m)
            elif isinstance(a, Land):
                await link.land(a.sysid)
            elif isinstance(a, Disarm):
                await link.disarm(a.sysid)
            elif isinstance(a, Kill):
                await link.disarm(a.sysid, force=True)
        except LinkError as exc:
            reason = (exc.reason or exc.result) if isinstance(exc, CommandRefused) else str(exc)
            rec = self._record(a.sysid)
            rec.commands_refused += 1
            rec.last_refusal = reason
            self._perform([Notice(a.sysid, f"vehicle {a.sysid}: {type(a).__name__.lower()} "
                                           f"not done: {reason}", "command_failed",
                                  f"{type(a).__name__.lower()} not done: {reason}")])
            if self.events is not None:
                self.events.emit("command_failed", system_id=a.sysid, reason=reason)
            if self.sequence is not None:
                self._perform(self.sequence.command_failed(a, reason, self.clock.now()))
            self._flush_notices()

    async def _drain(self) -> None:
        # Commands still in flight (a final disarm's ACK): give them a moment, then cancel.
        if self._tasks:
            await asyncio.wait(list(self._tasks), timeout=max(self.clock.wall_interval(2.0),
                                                              0.01))
        for task in list(self._tasks):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

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

    # -- the operator's go gate and pre-flight exclusion (the console) -----------------
    async def _go_gate(self) -> None:
        """Wait for the operator's go (:attr:`confirm_go`), keeping the pre-flight report
        fresh meanwhile; then the checks once more, as they stand now, before arming."""
        assert self.confirm_go is not None and self.preflight_report is not None
        self._say("pre-flight passed: waiting for the operator's go", "go_waiting")
        decision = asyncio.ensure_future(self.confirm_go(self.preflight_report))
        self.awaiting_go = True
        try:
            while not decision.done():
                await asyncio.wait([decision], timeout=max(self.clock.wall_interval(0.5),
                                                           0.001))
                if not decision.done() and self.assignment is not None:
                    self.assignment = self._assign()
                    self.preflight_report = run_preflight(self._fleet(), self.assignment,
                                                          self.clock.now(),
                                                          self.config.thresholds)
        finally:
            self.awaiting_go = False
            if not decision.done():
                decision.cancel()
        if not decision.result():
            if self.events is not None:
                self.events.emit("operator", command="no-go")
            raise NoGo()
        if self.events is not None:
            self.events.emit("operator", command="go")
        # What was shown may be a moment old, and exclusions may have changed: the checks
        # (and the exclusion safety check) once more, as they stand now.
        await self.preflight()

    def exclude(self, sysid: int) -> None:
        """Keep ``sysid`` on the ground (before arming only).  Refused with a FlightError
        when the show is already flying, the vehicle is not in it, or the others would
        pass too close to it on its slot (:func:`remaining_plan_conflicts`)."""
        if self.sequence is not None:
            raise FlightError(f"exclude {sysid}: the show is already armed; land it instead")
        if self.assignment is None or sysid not in self.assignment.tracks:
            heard = sysid in self.link.vehicles
            raise FlightError(f"exclude {sysid}: " + (
                "no track assigned to it yet (it is not known on a takeoff slot); wait for "
                "its position" if heard else "not a vehicle of this show"))
        if sysid in self.config.excluded:
            raise FlightError(f"exclude {sysid}: already excluded")
        excluded = self.config.excluded | {sysid}
        tracks = {t for s, t in self.assignment.tracks.items() if s in excluded}
        conflicts = remaining_plan_conflicts(self.plan, tracks)
        if conflicts:
            raise FlightError(f"exclude {sysid}: the rest of the show would be unsafe: "
                              f"{conflicts[0]}")
        self.config = replace(self.config, excluded=frozenset(excluded))
        self._say(f"vehicle {sysid} excluded by the operator: it stays on the ground",
                  "operator", command=f"exclude {sysid}", system_id=sysid)

    def commanded_now(self) -> tuple[float, dict[int, NDArray[np.float64]]] | None:
        """(the last tick's time, where its paths put every streamed vehicle then, show
        frame): what the guard measures tracking errors against.  For the console."""
        if self.sequence is None or self._request is None:
            return None
        at, req = self._request
        return at, self.sequence.commanded_all(req, at)

    # -- operator ---------------------------------------------------------------------
    def _operator(self, name: str, call: Callable[[float], list[Action]]) -> None:
        if self.sequence is None:
            self._say(f"{name}: the flight has not started", "operator", command=name)
            return
        if self.events is not None:
            self.events.emit("operator", command=name)
        self._perform(call(self.clock.now()))

    def hold(self) -> None:
        """Every drone hovers at its current plan point; the show clock stops."""
        self._operator("hold", lambda now: self.sequence.hold(now))  # type: ignore[union-attr]

    def resume(self) -> None:
        """The show clock runs again from where it was held."""
        self._operator("resume", lambda now: self.sequence.resume(now))  # type: ignore[union-attr]

    def land_all(self) -> None:
        """Every vehicle to its landing slot and down; the show is over."""
        self._operator("land all",
                       lambda now: self.sequence.land_all(now))  # type: ignore[union-attr]

    def land_one(self, sysid: int) -> None:
        """Vehicle ``sysid`` back to its landing slot and down."""
        self._operator(f"land {sysid}",
                       lambda now: self.sequence.land_one(sysid, now))  # type: ignore[union-attr]

    def land_here(self, sysid: int) -> None:
        """Vehicle ``sysid`` straight down where it is."""
        self._operator(f"land {sysid} here",
                       lambda now: self.sequence.land_here(sysid, now))  # type: ignore[union-attr]

    def kill(self, sysid: int, confirm: bool = False) -> None:
        """Stop ``sysid``'s motors (only with ``confirm``: the drone falls)."""
        self._operator(f"kill {sysid}", lambda now: self.sequence.kill(  # type: ignore[union-attr]
            sysid, now, confirm))

    # -- status -------------------------------------------------------------------------
    def status_line(self) -> str:
        """One line for a plain terminal: phase, show clock, vehicle phases, separation;
        before the show, the pre-flight checks still pending, fleet-wide (and with
        ``--rtk`` the vehicles' fix types and correction age)."""
        line = self._status_text()
        if self.rtk is not None:
            line += "; " + self.rtk.summary(
                {s: v.gps_fix_type for s, v in sorted(self.link.vehicles.items())})
        return line

    def _status_text(self) -> str:
        seq = self.sequence
        if seq is None:
            n = len(self.link.vehicles)
            report = self.preflight_report
            if report is None:
                return f"pre-flight: {n} vehicle(s) heard"
            return "pre-flight: " + report.summary(self.config.excluded)
        now = self.clock.now()
        counts: dict[str, int] = {}
        for v in seq.vehicles.values():
            counts[str(v.phase)] = counts.get(str(v.phase), 0) + 1
        phases = " ".join(f"{k}:{n}" for k, n in sorted(counts.items()))
        mon = self.monitor
        sep = mon.separation.distance_m if mon is not None else math.inf
        err = mon.max_tracking_error() if mon is not None else 0.0
        held = f" HOLD ({', '.join(sorted(seq.holds))})" if seq.paused else ""
        return (f"{seq.phase}{held} t={seq.show_time(now):6.1f}/{self.plan.duration:.0f} s "
                f"[{phases}] min sep {sep:.2f} m, max err {err:.2f} m")
