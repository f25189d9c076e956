"""The pre-flight dry-run: the real executor against the built-in simulator, over UDP.

Nothing is mocked: the ground station binds a loopback socket, the
simulated fleet (one socket per vehicle, ArduPilot or PX4 behaviour) stands
on the plan's takeoff slots and talks to it, and :class:`ShowRunner` flies
the show exactly as it would fly real drones.  The one difference is the
clock: a :class:`~groundctl.clock.ScaledClock` shared by both sides lets the
rehearsal run faster than real time.  By default it is a
:class:`~groundctl.clock.PacedClock`: on a machine too busy to keep that pace
the clock waits for the late side (the simulator's physics or the ground
station's tick), so a busy rehearsal machine slows the rehearsal down instead of
flying the show on stale setpoints; the report says who held the clock and the
pace actually kept (``pacing``).  ``paced=False`` (``--no-pace``) lets it run
on regardless, as real vehicles do: a rehearsal of the ground station's own
load, where its overload guard is what keeps the show safe.

A plan with spares (:attr:`Plan.spares <groundctl.plan.plan.Plan.spares>`) has one
more simulated vehicle per spare, standing on its pad (an ``"air"`` spare too: it
takes off from there), with the system ids after the show's (:func:`fleet_stands`).

Besides the telemetry-based report the ground station can make for any
flight, the dry-run knows the truth: where the simulated drones really were
(true minimum separation), whether one crashed, and when each LED actually
changed colour (timing against the plan).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from groundctl.clock import Clock, PacedClock, ScaledClock, pace_slack
from groundctl.errors import GroundctlError, SimulatorError
from groundctl.execute.frames import enu_to_show, show_to_enu
from groundctl.flight.report import flight_report
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.link.flavours import Flavour
from groundctl.link.fleet import FleetLink
from groundctl.link.worker import LINK_WORKER_MODES, use_workers
from groundctl.plan.plan import Plan
from groundctl.record.recording import Recording
from groundctl.rtk.forwarder import RtkForwarder
from groundctl.rtk.sources import RtkSource, SourceSpec
from groundctl.sim import LinkFaults, SimConfig
from groundctl.sim.config import profile_for, wind_from
from groundctl.sim.faults import failed_battery
from groundctl.sim.group import SimGroup, split_config
from groundctl.sim.process import SimProcess
from groundctl.vehicleid import (
    MAX_NETWORKS,
    VehicleId,
    network_layout,
    networks_for,
    spell,
    spell_many,
    vehicle_id,
)

#: Loopback only: the dry-run never sends a packet off this machine.
LOOPBACK = "127.0.0.1"


@dataclass(frozen=True)
class Push:
    """A vehicle displaced mid-show (a gust, a bird, a GPS jump), ``--push``."""

    sysid: int
    """The vehicle."""
    show_time: float
    """Show time it starts, s."""
    offset: tuple[float, float, float]
    """Displacement, show-frame metres (east, north, up before the show's heading)."""
    duration: float = 1.0
    """Over this many seconds."""


@dataclass(frozen=True)
class Gust:
    """Wind on one vehicle mid-show, ``--gust-on``: a force through its airframe's drag,
    which its autopilot fights (up to its lean angle) -- unlike a :class:`Push`."""

    sysid: int
    """The vehicle."""
    show_time: float
    """Show time it starts, s."""
    speed: float
    """m/s."""
    from_deg: float
    """The compass direction it blows from, degrees."""
    duration: float
    """How long it blows, s."""

    @property
    def wind(self) -> tuple[float, float, float]:
        """The gust as a wind vector (east, north, up m/s)."""
        return wind_from(self.speed, self.from_deg)


@dataclass(frozen=True)
class Failure:
    """A vehicle that fails mid-show, ``--fail``."""

    sysid: int
    """The vehicle."""
    show_time: float
    """Show time it fails, s."""
    kind: str
    """motor (falls), battery (its pack drops to
    :func:`~groundctl.sim.faults.failed_battery`), link (goes silent)."""




@dataclass(frozen=True)
class DryRunOptions:
    """How to rehearse."""

    flavour: Flavour = Flavour.ARDUPILOT
    """Autopilot every simulated vehicle imitates."""
    speed: float = 1.0
    """Simulated seconds per real second."""
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Mean wind, east-north-up m/s (the direction the air moves to)."""
    gust_std: float = 0.0
    """Seeded random gusts, m/s per axis."""
    loss: float = 0.0
    """Packet loss probability, each way."""
    latency_ms: float = 0.0
    """One-way latency, ms."""
    jitter_ms: float = 0.0
    """Latency standard deviation, ms."""
    seed: int = 0
    """Seed of every random process of the simulator."""
    signing_key: bytes | None = None
    """MAVLink 2 signing on both sides with this key."""
    ekf_origin_delay_s: float = 20.0
    """Simulated time until the vehicles have an EKF origin (SITL: 20 s)."""
    ready_delay_s: float = 40.0
    """Simulated time until the vehicles accept arming (SITL: 40 s)."""
    runner: RunnerConfig = field(default_factory=RunnerConfig)
    """The executor's settings."""
    record_dir: Path | None = None
    """Where flight.tlog, events.jsonl and report.json go (None: nothing recorded)."""
    pushes: tuple[Push, ...] = ()
    """Vehicles displaced mid-show (``--push``)."""
    gusts: tuple[Gust, ...] = ()
    """Wind on single vehicles mid-show (``--gust-on``)."""
    failures: tuple[Failure, ...] = ()
    """Vehicles that fail mid-show (``--fail``)."""
    weak: tuple[tuple[int, float], ...] = ()
    """(system id, factor): vehicles whose speed and acceleration authority is scaled
    from the start (``--weak``)."""
    profile: str | None = None
    """The simulated vehicles' dynamics profile (None: the flavour's calibrated one)."""
    rtk: SourceSpec | None = None
    """``--rtk``: corrections forwarded to the simulated fleet (which then models each fix
    type's noise)."""
    gcs_sysid: int = 255
    """The ground station's system id (``--gcs-sysid``); the simulated ArduPilots'
    SYSID_MYGCS follows it."""
    networks: int = 0
    """MAVLink networks to spread the simulated fleet over (``--networks``; one UDP port
    of the ground station each); 0: as many as its size needs (254 vehicles each)."""
    sim_processes: int = 0
    """Simulator processes the fleet is split over (``--sim-processes``; one per network
    part, each a participant of the paced clock); 0: one, or one per network for fleets
    of more than :data:`SIM_PROCESS_VEHICLES`."""
    link_workers: str = "auto"
    """``--link-workers``: each network's receive path in a worker process (``on``,
    ``off``, ``auto``: from :data:`~groundctl.link.worker.WORKERS_FROM` vehicles)."""
    paced: bool = True
    """The clock waits for a late simulator or ground-station loop (a
    :class:`~groundctl.clock.PacedClock`); False (``--no-pace``): it runs on at
    ``speed`` whatever the machine keeps up with."""

    def __post_init__(self) -> None:
        if not self.speed > 0:
            raise SimulatorError(f"--speed must be positive, got {self.speed}")
        if not 0 <= self.loss < 1:
            raise SimulatorError(f"--loss must be in [0, 1), got {self.loss}")
        if self.latency_ms < 0 or self.jitter_ms < 0:
            raise SimulatorError("--latency and --jitter must be non-negative")
        if not 0 <= self.networks <= MAX_NETWORKS:
            raise SimulatorError(f"--networks must be in 1..{MAX_NETWORKS}, got "
                                 f"{self.networks}")
        if not 0 <= self.sim_processes <= 64:
            raise SimulatorError(f"--sim-processes must be in 1..64, got {self.sim_processes}")
        if self.link_workers not in LINK_WORKER_MODES:
            raise SimulatorError(f"--link-workers must be one of "
                                 f"{', '.join(LINK_WORKER_MODES)}, got {self.link_workers!r}")
        try:
            profile_for(self.flavour, self.profile)
        except ValueError as exc:
            raise SimulatorError(f"--profile: {exc}") from None


@dataclass
class DryRunResult:
    """The report, and the error that stopped the flight early (if one did)."""

    report: dict[str, Any]
    """The flight report (see :mod:`groundctl.flight.report`) plus the dry-run's truth."""
    error: GroundctlError | None
    """Why the run stopped before every vehicle was down, or None."""
    flown: bool
    """True once the sequence started (arming was commanded)."""


def network_count(drones: int, asked: int = 0) -> int:
    """How many MAVLink networks a simulated fleet of ``drones`` is spread over (see
    :func:`groundctl.vehicleid.networks_for`)."""
    try:
        return networks_for(drones, asked)
    except ValueError as exc:
        raise SimulatorError(str(exc)) from None


#: A fleet larger than this is simulated in one process per network (one process carries
#: about 600 vehicles at real time on the reference machine).
SIM_PROCESS_VEHICLES = 300


def sim_processes(drones: int, networks: int, asked: int = 0) -> int:
    """How many simulator processes fly a fleet of ``drones`` on ``networks``."""
    if asked:
        return min(asked, drones)
    return networks if drones > SIM_PROCESS_VEHICLES else 1


def fleet_stands(plan: Plan) -> np.ndarray:
    """(n + k, 3) where the simulated fleet stands, show frame: the plan's takeoff slots
    in track order, then each spare's pad (whatever its standby: an ``"air"`` spare takes
    off from its pad too).  Its length is the fleet's size, and the order the system
    ids': the spares' come after the show's."""
    if plan.spares is None:
        return plan.home
    return np.vstack([plan.home, plan.spares.pads])


def sim_config(plan: Plan, options: DryRunOptions,
               gcs: tuple[str, int] | Sequence[tuple[str, int]]) -> SimConfig:
    """A simulated fleet standing on the plan's takeoff slots and spare pads
    (:func:`fleet_stands`), talking to ``gcs`` (one address per network: see
    :func:`network_layout`)."""
    addresses = [gcs] if isinstance(gcs, tuple) else list(gcs)
    stands = fleet_stands(plan)
    nets, local = network_layout(len(stands), len(addresses))
    if 1 <= options.gcs_sysid <= max(local):
        raise SimulatorError(f"--gcs-sysid {options.gcs_sysid} is a simulated vehicle's "
                             f"system id (they are 1..{max(local)})")
    params = {"SYSID_MYGCS": float(options.gcs_sysid)} \
        if options.flavour is Flavour.ARDUPILOT and options.gcs_sysid != 255 else {}
    o = plan.origin
    return SimConfig(
        params=params, rtk_noise=options.rtk is not None,
        count=len(stands), flavour=options.flavour, origin=(o.lat, o.lon, o.alt),
        positions=show_to_enu(o, stands), system_ids=local,
        gcs=addresses[0], networks=nets if len(addresses) > 1 else None,
        gcs_networks=addresses if len(addresses) > 1 else None, bind_host=LOOPBACK,
        ekf_origin_delay_s=options.ekf_origin_delay_s,
        ready_delay_s=options.ready_delay_s, wind=options.wind,
        gust_std=options.gust_std, seed=options.seed, signing_key=options.signing_key,
        link_faults=LinkFaults(options.loss, options.latency_ms, options.jitter_ms, 0.0),
        dynamics=profile_for(options.flavour, options.profile))


def _check_named(options: DryRunOptions, ids: set[int]) -> None:
    """Every vehicle a push, a gust or a weakness names is in the fleet: one line before
    anything starts (a push of a vehicle the fleet did not have was left out, unsaid: the
    show flew and the dry-run exited 0)."""
    named = [("--push", p.sysid) for p in options.pushes] \
        + [("--gust-on", g.sysid) for g in options.gusts] \
        + [("--weak", w[0]) for w in options.weak] \
        + [("--fail", f.sysid) for f in options.failures]
    for option, sysid in named:
        if sysid not in ids:
            raise SimulatorError(f"{option} names vehicle {spell(sysid)}, which this fleet "
                                 f"does not have ({spell_many(sorted(ids))})")


During = Callable[[ShowRunner, Any], Coroutine[Any, Any, None]]
"""``during(runner, fleet)``: the fleet a :class:`SimProcess` (or a :class:`SimGroup`,
which answers as one)."""


async def fly_dry_run(plan: Plan, options: DryRunOptions, *,
                      customise: Callable[[SimConfig], SimConfig] | None = None,
                      during: During | None = None,
                      notify: Callable[[str], None] | None = None,
                      on_runner: Callable[[ShowRunner], None] | None = None,
                      on_simulator: Callable[[int], None] | None = None) -> DryRunResult:
    """Fly ``plan`` against a simulated fleet; always returns the report (and recordings).

    ``customise`` may change the simulator's configuration (a vehicle off its
    slot, other EKF origins); ``during`` runs alongside the flight (faults,
    operator commands) and is cancelled when the flight ends; ``on_runner``
    gets the runner before it starts (the CLI hooks Ctrl-C to it), ``on_simulator``
    the simulator's process id (a benchmark counts its CPU).
    """
    size = len(fleet_stands(plan))  # the show's vehicles and the spares
    networks = network_count(size, options.networks)
    nets, local = network_layout(size, networks)
    _check_named(options, {vehicle_id(n, s) for n, s in zip(nets, local, strict=True)})
    processes = sim_processes(size, networks, options.sim_processes)
    workers = use_workers(options.link_workers, size)
    # Participants: the ground station's loop, each simulator process, each network's
    # link worker (telemetry on its way to the ground station holds the clock too).
    paced = PacedClock(options.speed, participants=1 + processes
                       + (networks if workers else 0),
                       slack=pace_slack(options.speed)) if options.paced else None
    # The ground station's clock, and the simulator's.
    clock: ScaledClock | PacedClock
    sim_clock: ScaledClock | PacedClock
    sim_clocks: list[ScaledClock | PacedClock]
    if paced is not None:
        clock = paced.participant(0)
        sim_clocks = [paced.participant(1 + k) for k in range(processes)]
        sim_clock = sim_clocks[0]
    else:
        clock = sim_clock = ScaledClock(options.speed)
        sim_clocks = [sim_clock] * processes
    started = time.monotonic()
    record = options.record_dir
    recording = None if record is None else Recording(record, clock.now, plan,
                                                      wall=_recording_wall(clock, paced))
    tlogs = None if recording is None else recording.network_tlogs(networks)
    events = None if recording is None else recording.events
    link = FleetLink([(LOOPBACK, 0)] * networks, clock=clock,
                     expected_ids=[vehicle_id(n, s) for n, s in zip(nets, local, strict=True)],
                     signing_key=options.signing_key, tlog=tlogs, events=events,
                     system_id=options.gcs_sysid,
                     link_workers=workers,
                     worker_clocks=None if paced is None or not workers else
                     [paced.participant(1 + processes + k) for k in range(networks)])
    rtk: RtkForwarder | None = None
    fleet: SimProcess | SimGroup | None = None
    runner: ShowRunner | None = None
    helper: asyncio.Task[None] | None = None
    error: GroundctlError | None = None
    crashed: list[int] = []
    try:
        await link.start()
        assert link.local_address is not None
        config = sim_config(plan, options, link.local_addresses)
        if customise is not None:
            config = customise(config)
        if processes == 1:
            fleet = await asyncio.to_thread(SimProcess, config, sim_clock)  # flies now
        else:
            fleet = await asyncio.to_thread(SimGroup, split_config(config, processes),
                                            sim_clocks)
        # Only the simulator speaks for its vehicles: another fleet on this machine that
        # sends to our port (a `groundctl sim` left pointing at it, a port reused) is a
        # stranger, whoever was heard first.
        link.pin({sid: (LOOPBACK, port) for sid, port in zip(fleet.sysids, fleet.ports,
                                                              strict=True)})
        runner = ShowRunner(plan, link, clock, options.runner, events=events, notify=notify,
                            expected_ids=[VehicleId(s) for s in config.sysids()])
        runner.on_tick = _truth_probe(runner, fleet)
        if options.rtk is not None:
            field = (plan.origin.lat, plan.origin.lon, plan.origin.alt)  # for a caster's GGA
            rtk = RtkForwarder(RtkSource(options.rtk, clock, position=field), link, clock,
                               events=events, notify=notify)
            runner.rtk = rtk
            rtk.start()
        if recording is not None:
            recording.follow(runner)  # the show clock, for a replay
        if on_runner is not None:
            on_runner(runner)
        if on_simulator is not None:
            for pid in fleet.pids if isinstance(fleet, SimGroup) else [fleet.pid]:
                on_simulator(pid)
        if events is not None:
            events.emit("dry_run", show=plan.show_name, vehicles=plan.drones,
                        spares=0 if plan.spares is None else plan.spares.count,
                        autopilot=str(options.flavour), speed=options.speed,
                        loss=options.loss, latency_ms=options.latency_ms, seed=options.seed,
                        wind=list(options.wind), gcs=f"{link.local_address[0]}:"
                                                     f"{link.local_address[1]}",
                        **({"networks": [f"{h}:{p}" for h, p in link.local_addresses]}
                           if networks > 1 else {}))
        for sysid, factor in options.weak:
            fleet.call("weaken", factor, sysid)
        if during is not None or options.pushes or options.gusts or options.failures:
            helper = asyncio.create_task(_alongside(runner, fleet, options.pushes,
                                                    options.gusts, during,
                                                    options.failures))
        await runner.run()
    except GroundctlError as exc:
        error = exc
        if events is not None:
            events.emit("error", kind=type(exc).__name__, text=str(exc))
    finally:
        if helper is not None:
            helper.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await helper
        if rtk is not None:
            await rtk.stop()
        truth: dict[str, Any] = {}
        if fleet is not None:
            try:
                states = fleet.call("snapshot")
                crashed = [s.sysid for s in states if s.crashed]
                truth = {"crashed": crashed,
                         "down_and_disarmed": sum(s.landed and not s.armed for s in states),
                         "sim_overruns": fleet.get("overruns"),
                         "sim_max_lag_s": round(fleet.get("max_lag"), 3)}
                if rtk is not None:
                    truth["rtk"] = {str(k): v for k, v in fleet.call("rtk_stats").items()}
            except SimulatorError as exc:  # a dead child too: its first failure is kept
                truth["error"] = str(exc)
            try:
                fleet.stop()
            except SimulatorError as exc:
                truth.setdefault("error", str(exc))
                if error is None:
                    error = exc
            truth["exit_code"] = fleet.exitcode
        await link.close()
        report: dict[str, Any] = {
            "show": plan.show_name, "safe": False, "landed": False, "vehicles": [],
            "min_separation_m": None, "max_tracking_error_m": None,
            "unsafe_reasons": [str(error) if error is not None else "the flight never started"]}
        if runner is not None:
            mon = runner.monitor
            true_sep = mon.true_separation.distance_m if mon is not None else math.inf
            truth_reasons = [f"vehicle(s) {crashed} crashed"] if crashed else []
            if true_sep < plan.limits.min_separation:
                truth_reasons.append(
                    f"true separation {true_sep:.2f} m (limit {plan.limits.min_separation:.2f} m)")
            report = flight_report(runner, None if error is None else str(error), truth_reasons)
            report["true_min_separation_m"] = (round(true_sep, 3) if math.isfinite(true_sep)
                                               else None)
        report.update({"autopilot": str(options.flavour), "speed": options.speed,
                       "pacing": _pacing(paced, clock, started, processes),
                       "simulator": truth,
                       "record_dir": None if record is None else str(record)})
        if recording is not None:
            recording.finish(report)
    flown = runner is not None and runner.sequence is not None
    return DryRunResult(report, error, flown)


def _recording_wall(clock: Clock, paced: PacedClock | None) -> Callable[[], float]:
    """Unix time for the recording's stamps: real time, or for a paced clock that clock
    at its full pace from now (a tlog whose vehicles' clocks are lines in its stamps,
    as MAVExplorer and the replay expect; the clock's waits leave no gaps)."""
    if paced is None:
        return time.time
    speed = paced.speed
    unix0 = time.time() - clock.now() / speed
    return lambda: unix0 + clock.now() / speed


def _pacing(paced: PacedClock | None, clock: Clock, started: float,
            processes: int = 1) -> dict[str, Any]:
    """The report's ``pacing``: the pace kept, and who held the clock for how long
    (participants: the ground station, ``processes`` simulators, then link workers)."""
    wall = time.monotonic() - started
    out: dict[str, Any] = {"paced": paced is not None,
                           "effective_speed": round(clock.now() / wall, 2) if wall > 0 else None}
    if paced is not None:
        held = paced.held_s()
        behind = paced.left_behind()
        sims = slice(1, 1 + processes)
        links = slice(sims.stop, None)
        out.update({"held_by_ground_station_s": round(held[0], 2),
                    "held_by_simulator_s": round(sum(held[sims]), 2),
                    "held_by_link_workers_s": round(sum(held[links]), 2),
                    "left_behind": {"ground_station": behind[0],
                                    "simulator": sum(behind[sims]),
                                    "link_workers": sum(behind[links])}})
    return out


async def _alongside(runner: ShowRunner, fleet: SimProcess | SimGroup,
                     pushes: tuple[Push, ...], gusts: tuple[Gust, ...],
                     during: During | None, failures: tuple[Failure, ...] = ()) -> None:
    """The caller's ``during`` and the scheduled pushes, gusts and failures, side by
    side."""
    tasks = [asyncio.create_task(_push(runner, fleet, p)) for p in pushes]
    tasks += [asyncio.create_task(_gust(runner, fleet, g)) for g in gusts]
    tasks += [asyncio.create_task(_fail(runner, fleet, f)) for f in failures]
    if during is not None:
        tasks.append(asyncio.create_task(during(runner, fleet)))
    try:
        await asyncio.gather(*tasks)
    finally:
        for t in tasks:
            t.cancel()


async def _show_time(runner: ShowRunner, t: float) -> None:
    """Return once the show clock is at ``t``."""
    while True:
        seq = runner.sequence
        if seq is not None and seq.started_at is not None \
                and seq.show_time(runner.clock.now()) >= t:
            return
        await asyncio.sleep(0.01)


async def _gust(runner: ShowRunner, fleet: SimProcess | SimGroup, gust: Gust) -> None:
    """Wait for the gust's show time on the show clock, then blow (the simulator's wind is
    ENU, as the gust's compass direction is)."""
    await _show_time(runner, gust.show_time)
    fleet.call("gust", list(gust.wind), gust.duration, gust.sysid)
    if runner.events is not None:
        runner.events.emit("gust", system_id=gust.sysid, speed_ms=gust.speed,
                           from_deg=gust.from_deg, duration_s=gust.duration,
                           show_time=round(gust.show_time, 2))


async def _fail(runner: ShowRunner, fleet: SimProcess | SimGroup, failure: Failure) -> None:
    """Wait for the failure's show time on the show clock, then break the vehicle."""
    await _show_time(runner, failure.show_time)
    if failure.kind == "motor":
        fleet.call("motor_failure", failure.sysid)
    elif failure.kind == "battery":
        level = runner.config.sequence.land_battery_pct  # the level the show is flown with
        fleet.call("low_battery", failed_battery(runner.plan.limits.land_battery_pct
                                                 if level is None else level), failure.sysid)
    else:
        fleet.call("cut_link", failure.sysid)
    if runner.events is not None:
        runner.events.emit("failure", system_id=failure.sysid, kind=failure.kind,
                           show_time=round(failure.show_time, 2))


async def _push(runner: ShowRunner, fleet: SimProcess | SimGroup, push: Push) -> None:
    """Wait for the push's show time on the show clock, then push (rotated to ENU)."""
    await _show_time(runner, push.show_time)
    o = runner.plan.origin
    offset = show_to_enu(o, np.array([push.offset])) - show_to_enu(o, np.zeros((1, 3)))
    # On the loop's thread, like the truth probe: the simulator's pipe is not shared
    # between threads.
    fleet.call("push", offset[0].tolist(), push.sysid, None, push.duration)
    if runner.events is not None:
        runner.events.emit("push", system_id=push.sysid, offset_m=list(push.offset),
                           show_time=round(push.show_time, 2))


def _truth_probe(runner: ShowRunner, fleet: SimProcess | SimGroup
                 ) -> Callable[[float, float], None]:
    """Every tick: where the simulated drones really are, and their LEDs (asked on one
    tick, read on the next).

    If the simulator process is gone (killed, crashed) there is no fleet left
    to fly: the probe raises one :class:`SimulatorError` saying so, which ends
    the runner's loop and becomes the report's error (and keeps raising it, should
    it be called again).
    """
    origin = runner.plan.origin
    ids = list(fleet.sysids)
    gone: list[SimulatorError] = []

    def probe(now: float, show_time: float) -> None:
        if gone:
            raise gone[0]
        mon, seq = runner.monitor, runner.sequence
        if mon is None or seq is None:
            return
        try:
            # Asked one tick, read the next: the control loop never waits on the
            # simulator's process (on a busy machine a round trip per tick made the ground
            # station late for the simulator's scheduling, not its own work).
            ready, truth = fleet.answer()
            fleet.ask("truth")
        except SimulatorError as exc:
            err = exc
            if isinstance(exc.__cause__, (EOFError, OSError)):  # its pipe broke: it died
                err = SimulatorError(f"the simulator process died mid-flight (exit code "
                                     f"{fleet.exitcode}): the simulated fleet is gone")
            gone.append(err)
            raise err from exc
        if not ready:
            return
        positions, leds = truth
        mon.observe_truth(now, ids, enu_to_show(origin, positions))
        for sysid, (led, when) in zip(ids, leds, strict=True):
            # On the show clock, which holds and ramps: not simply "when - start".
            shown_at = None if when is None else seq.show_time_of(when)
            mon.observe_led(sysid, led, when, shown_at)

    return probe
