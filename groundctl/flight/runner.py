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
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import Clock
from groundctl.errors import (
    CommandRefused,
    FlightError,
    GroundctlError,
    LinkError,
    PreflightFailed,
)
from groundctl.execute.frames import show_positions
from groundctl.execute.mapping import Assignment, auto_assign, explicit_assign
from groundctl.execute.preflight import (
    PreflightReport,
    Thresholds,
    remaining_plan_conflicts,
    run_preflight,
)
from groundctl.execute.sequence import (
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
    Takeoff,
    VehiclePhase,
)
from groundctl.execute.setpoints import DEFAULT_LEAD_S, LedTracker, SetpointStream, StreamTarget
from groundctl.flight.monitor import FlightMonitor
from groundctl.flight.returning import column, plan_leave, plan_return
from groundctl.link.flavours import Flavour
from groundctl.link.fleet import FleetLink
from groundctl.plan.plan import Plan
from groundctl.record.events import EventSink

log = logging.getLogger(__name__)

#: Checks a vehicle cannot pass by waiting (once their value is known).
PERMANENT_CHECKS = frozenset({"battery", "slot"})


@dataclass(frozen=True)
class RunnerConfig:
    """How the runner flies; times are seconds of the runner's clock."""

    rate_hz: float = 10.0
    """Setpoint rate per vehicle (and the loop rate)."""
    lead_s: float = DEFAULT_LEAD_S
    """Setpoints are taken this far ahead of the show clock to cover the link latency."""
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
    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    """Sequence tolerances and timeouts."""
    landing_timeout_s: float = 180.0
    """After the show ends (or land-all), every vehicle must be down within this."""

    def __post_init__(self) -> None:
        if not self.rate_hz >= 1.0:
            raise ValueError(f"`rate_hz` must be at least 1, got {self.rate_hz}")
        if self.lead_s < 0:
            raise ValueError(f"`lead_s` must be non-negative, got {self.lead_s}")


@dataclass
class VehicleRecord:
    """What the runner itself counted for one vehicle."""

    commands_refused: int = 0
    """Commands refused or unanswered."""
    last_refusal: str | None = None
    """The last refusal's reason."""
    late: bool = False
    """Flagged: its round trip is longer than twice the setpoint lead."""


class ShowRunner:
    """Flies ``plan`` with the vehicles on ``link``; see the module docstring."""

    def __init__(self, plan: Plan, link: FleetLink, clock: Clock,
                 config: RunnerConfig | None = None, *, events: EventSink | None = None,
                 notify: Callable[[str], None] | None = None,
                 expected_ids: Collection[int] | None = None) -> None:
        self.plan = plan
        self.link = link
        self.clock = clock
        self.config = config or RunnerConfig()
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
        self.on_tick: Callable[[float, float], None] | None = None
        """Called after every tick with (now, show time): the dry-run's truth probe."""
        self._stream: SetpointStream | None = None
        self._leds = LedTracker(self.config.led_refresh_s)
        self._tasks: set[asyncio.Task[None]] = set()
        self._return_task: asyncio.Task[None] | None = None
        self._leave_tasks: dict[int, asyncio.Task[None]] = {}

    # -- reporting -------------------------------------------------------------------
    def _say(self, text: str, event: str = "notice", **fields: Any) -> None:
        log.info("%s", text)
        if self.events is not None:
            self.events.emit(event, text=text, **fields)
        if self.notify is not None:
            self.notify(text)

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
        while True:
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
                self._say("pre-flight refused:\n" + report.render(cfg.excluded), "preflight_failed",
                          failures=permanent)
                raise PreflightFailed(permanent)
            if now - start >= cfg.preflight_timeout_s:
                if failures:
                    self._say("pre-flight timed out:\n" + report.render(cfg.excluded),
                              "preflight_failed", failures=failures)
                    raise PreflightFailed(failures)
                raise FlightError(f"pre-flight: no vehicle for track(s) {missing} after "
                                  f"{cfg.preflight_timeout_s:.0f} s; exclude or add vehicles")
            await asyncio.sleep(max(self.clock.wall_interval(0.5), 0.001))
        grounded = self._excluded_tracks()
        conflicts = remaining_plan_conflicts(self.plan, grounded) if grounded else []
        if conflicts:
            raise FlightError(f"excluding vehicle(s) {sorted(cfg.excluded)} leaves the show "
                              f"unsafe: {conflicts[0]}")
        self._say("pre-flight passed:\n" + report.render(cfg.excluded), "preflight_passed",
                  tracks={str(k): v for k, v in self._tracks().items()})
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
        self._stream = SetpointStream(self.plan, targets, self.config.lead_s)
        self.monitor = FlightMonitor(self.plan, tracks)
        self.sequence = ShowSequence(self.plan, tracks, flavours, self.config.sequence,
                                     grounded_tracks=self._excluded_tracks())
        return self.sequence

    async def fly(self) -> None:
        """Arm, take off, fly the show, land; returns once every vehicle is done."""
        seq = self._build()
        cfg = self.config
        period = 1.0 / cfg.rate_hz
        now = self.clock.now()
        self._say(f"arming {len(seq.vehicles)} vehicle(s)", "sequence_started")
        self._perform(seq.start(now))
        budget = (cfg.sequence.takeoff_timeout_s + 2 * cfg.sequence.step_timeout_s
                  * cfg.sequence.max_attempts + self.plan.duration + cfg.landing_timeout_s)
        deadline = now + budget
        next_tick = now
        next_check = now
        while seq.phase is not ShowPhase.LANDED:
            wait = next_tick - self.clock.now()
            if wait > 0:
                await asyncio.sleep(self.clock.wall_interval(wait))
            now = self.clock.now()
            scheduled = next_tick
            next_tick += period
            if next_tick < now:
                skipped = int((now - next_tick) / period) + 1
                self.overruns += skipped
                next_tick += skipped * period
            if seq.paused:
                deadline += period
            self._perform(seq.update(now, self.link.vehicles))
            if seq.return_needed is not None and self._return_task is None:
                self._return_task = asyncio.create_task(self._plan_return(seq))
            for sysid, track, at, start in seq.leave_needed:
                if sysid not in self._leave_tasks:
                    self._leave_tasks[sysid] = asyncio.create_task(
                        self._plan_leave(seq, sysid, track, at, start))
            self._stream_tick(seq, now, scheduled)
            if now >= next_check:
                next_check = now + 1.0
                self._flag_late(seq)
            if self.on_tick is not None:
                self.on_tick(now, seq.show_time(now))
            if now > deadline:
                left = {s: str(v.phase) for s, v in seq.vehicles.items()
                        if v.phase not in (VehiclePhase.LANDED, VehiclePhase.LOST,
                                           VehiclePhase.FAILED, VehiclePhase.KILLED)}
                raise FlightError(f"the flight did not finish within {budget:.0f} s: "
                                  f"vehicles still flying {left}")
        self._say("every vehicle is down", "sequence_finished",
                  phases={str(s): str(v.phase) for s, v in seq.vehicles.items()})
        await self._drain()

    async def _plan_return(self, seq: ShowSequence) -> None:
        needed = seq.return_needed or []
        sysids = [s for s, _ in needed]
        tracks = [t for _, t in needed]
        t = seq.show_time(self.clock.now())
        start = self.plan.state_at(t).pos[tracks]
        holds = {v.track: v.hold_point for v in seq.vehicles.values()
                 if v.hold_point is not None}
        for row, track in enumerate(tracks):
            leave = seq.leaves.get(track)
            if leave is not None and t >= leave.at:  # on its way out of the show already
                start[row] = leave.state(t)[0]
            elif track in holds:  # hovering where it was heard again
                start[row] = holds[track]
        self._say(f"planning a collision-free return for {len(sysids)} vehicle(s); they "
                  "hover meanwhile", "return_planning")
        try:
            traj = await asyncio.to_thread(plan_return, self.plan, tracks, start)
        except GroundctlError as exc:
            self._perform(seq.return_failed(str(exc)))
            return
        self._perform(seq.set_return(traj, sysids, self.clock.now()))

    async def _plan_leave(self, seq: ShowSequence, sysid: int, track: int, at: float,
                          start: tuple[float, float, float] | None) -> None:
        """Plan ``sysid``'s way out of the show (land-one mid-show, or heard again off its
        plan: from ``start``) around everyone else."""
        try:
            absent, static = self._not_on_plan(seq, sysid)
            self._say(f"planning vehicle {sysid}'s way out of the show (leaving at show time "
                      f"{at:.1f} s)", "leave_planning", system_id=sysid, at=round(at, 2))
            try:
                leave = await asyncio.to_thread(
                    plan_leave, self.plan, track, at, seq.leaves, absent, static,
                    None if start is None else np.asarray(start, dtype=float))
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
        for sysid, v in seq.vehicles.items():
            phase = seq.streamed_as(v)  # a lost one is still streamed what it was
            if sysid == leaving:
                continue
            if phase is VehiclePhase.LEAVING and v.hold_point is not None and v.leave is None:
                absent.append(v.track)  # hovering where it was heard again, not on its plan
                columns.append(np.array([v.hold_point]))
            elif phase not in (VehiclePhase.READY, VehiclePhase.SHOW, VehiclePhase.LEAVING,
                               VehiclePhase.RETURNING):
                absent.append(v.track)  # down, descending, killed, or never airborne
                pos = positions.get(sysid)
                columns.append(column(self.plan.home[v.track] if pos is None else pos))
        static = np.concatenate(columns) if columns else np.empty((0, 3))
        return absent, static

    def _stream_tick(self, seq: ShowSequence, now: float, scheduled: float) -> None:
        assert self._stream is not None and self.monitor is not None
        req = seq.stream_request(now)
        if not req.sysids:
            self.lateness_s.append(self.clock.now() - scheduled)
        else:
            offsets = {s: self.link.vehicles[s].clock_offset_s for s in req.sysids}
            sp = self._stream.at(req.show_time, now, offsets, req.moving, req.fixed,
                                 req.follow, req.follow_trajectories, req.follow_time,
                                 req.leaves)
            send = self.link.send_position_target_local_ned
            rows = [i for i, s in enumerate(sp.sysids) if s in req.sysids]
            for i in rows:
                send(sp.sysids[i], int(sp.time_boot_ms[i]), sp.pos_ned[i].tolist(),
                     sp.vel_ned[i].tolist(), sp.acc_ned[i].tolist())
            # The tick's last setpoint has left: how late against its scheduled instant.
            self.lateness_s.append(self.clock.now() - scheduled)
            ids = [sp.sysids[i] for i in rows]
            for sysid, (r, g, b) in self._leds.due(ids, sp.rgb[rows], now):
                self.link.send_led_rgb(sysid, r, g, b)
        in_show = [s for s, v in seq.vehicles.items() if v.phase is VehiclePhase.SHOW] \
            if req.moving or seq.paused else []
        self.monitor.observe(now, req.show_time, in_show, self.link.vehicles)

    def _flag_late(self, seq: ShowSequence) -> None:
        for sysid, v in seq.vehicles.items():
            if v.phase not in (VehiclePhase.READY, VehiclePhase.SHOW):
                continue
            rec = self._record(sysid)
            rtt = self.link.vehicles[sysid].rtt_s
            if rec.late or rtt is None or rtt / 2 <= self.config.lead_s:
                continue
            rec.late = True
            self._say(f"vehicle {sysid} is late: one-way delay ~{rtt * 500:.0f} ms exceeds the "
                      f"setpoint lead of {self.config.lead_s * 1000:.0f} ms", "vehicle_late",
                      system_id=sysid, rtt_ms=round(rtt * 1000, 1))

    def _perform(self, actions: list[Action]) -> None:
        for a in actions:
            if isinstance(a, Notice):
                self._say(a.text, "sequence", system_id=a.sysid)
            else:
                self._spawn(self._command(a))

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
            self._say(f"vehicle {a.sysid}: {type(a).__name__.lower()} not done: {reason}",
                      "command_failed", system_id=a.sysid, reason=reason)
            if self.sequence is not None:
                self._perform(self.sequence.command_failed(a, reason, self.clock.now()))

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
        still reports and records instead of unwinding past its ``finally``.
        """
        try:
            await self.connect()
            await self.preflight()
            await self.fly()
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()
            raise FlightError("flight abandoned by the operator") from None
        finally:
            await self._drain()

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
        """One line for a plain terminal: phase, show clock, vehicle phases, separation."""
        seq = self.sequence
        if seq is None:
            n = len(self.link.vehicles)
            return f"pre-flight: {n} vehicle(s) heard"
        now = self.clock.now()
        counts: dict[str, int] = {}
        for v in seq.vehicles.values():
            counts[str(v.phase)] = counts.get(str(v.phase), 0) + 1
        phases = " ".join(f"{k}:{n}" for k, n in sorted(counts.items()))
        mon = self.monitor
        sep = mon.separation.distance_m if mon is not None else math.inf
        err = mon.max_tracking_error() if mon is not None else 0.0
        held = " HOLD" if seq.paused else ""
        return (f"{seq.phase}{held} t={seq.show_time(now):6.1f}/{self.plan.duration:.0f} s "
                f"[{phases}] min sep {sep:.2f} m, max err {err:.2f} m")
