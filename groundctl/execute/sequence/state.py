"""The state every layer of the sequence reads and changes: the vehicles' runs,
the show clock and its holds, the show's phase, and the few helpers all of them share
(sending a command, the phase a vehicle is streamed as)."""

from __future__ import annotations

from collections.abc import Collection, Mapping

import numpy as np

from groundctl.execute.paths import sample_paths
from groundctl.execute.sequence.lifecycle import Event, step
from groundctl.execute.sequence.standby import Replacement, Standby
from groundctl.execute.sequence.types import (
    _DONE,
    NO_TRACK,
    Action,
    Command,
    Land,
    SequenceConfig,
    ShowPhase,
    StreamRequest,
    VehiclePhase,
    VehicleRun,
)
from groundctl.execute.showclock import ShowClock, brake_ramp
from groundctl.link.flavours import Flavour
from groundctl.link.state import VehicleState
from groundctl.plan.plan import Plan
from groundctl.plan.trajectory import Trajectories

#: A spare in these phases is still getting ready to join (on its pad or over it).
_BEFORE_JOINING = frozenset({VehiclePhase.PREFLIGHT, VehiclePhase.ARMING,
                             VehiclePhase.TAKEOFF, VehiclePhase.READY})


class SequenceState:
    """The sequence's state and clock, shared by every layer of
    :class:`~groundctl.execute.sequence.ShowSequence`."""

    def __init__(self, plan: Plan, tracks: Mapping[int, int], flavours: Mapping[int, Flavour],
                 config: SequenceConfig | None = None,
                 grounded_tracks: Collection[int] = (), *,
                 spares: Mapping[int, int] | None = None, use_spares: bool = True) -> None:
        """``tracks`` maps system id -> plan track for every vehicle that flies;
        ``grounded_tracks`` are tracks whose (excluded) drone stays on its slot;
        ``spares`` maps system id -> spare pad for every spare ready on its pad
        (``use_spares`` False: they stay there, ``--no-spares``)."""
        spares = dict(spares or {})
        missing = sorted((set(tracks) | set(spares)) - set(flavours))
        if missing:
            raise ValueError(f"`flavours` has no autopilot for vehicle(s) {missing}")
        if len(set(tracks.values())) != len(tracks):
            raise ValueError("`tracks` gives one track to two vehicles")
        self.plan = plan
        self.config = config or SequenceConfig()
        self.vehicles: dict[int, VehicleRun] = {
            sysid: VehicleRun(sysid, track, flavours[sysid])
            for sysid, track in sorted(tracks.items())}
        self.grounded_tracks: set[int] = set(grounded_tracks)
        if spares and plan.spares is None:
            raise ValueError("`spares` given for a plan without spares")
        if set(spares) & set(tracks):
            raise ValueError("a vehicle is both a spare and a show vehicle")
        self.standby: dict[int, Standby] = {
            sysid: Standby(sysid, flavours[sysid], pad) for sysid, pad in sorted(spares.items())}
        """The spares ready on their pads (:mod:`~groundctl.execute.sequence.spares`)."""
        self.air_spares = plan.spares is not None and plan.spares.standby == "air"
        """``standby = "air"``: the spares take off with the fleet and hover at their
        points (each a run from the start, of no track until it takes one over)."""
        if self.air_spares and plan.spares is not None and use_spares:
            for sysid, pad in sorted(spares.items()):
                point = plan.spares.points[pad]
                self.vehicles[sysid] = VehicleRun(
                    sysid, NO_TRACK, flavours[sysid], pad=pad,
                    hold_point=(float(point[0]), float(point[1]), float(point[2])),
                    landing_point=(float(point[0]), float(point[1]), float(point[2])))
        self.use_spares = use_spares
        self.replacements: list[Replacement] = []
        """Every track a spare was sent into, and how it went."""
        self._join_tries: dict[tuple[int, int], int] = {}
        self._join_queue: list[tuple[int, int, tuple[float, float, float]]] = []
        self._said_no_spare: set[int] = set()
        self._spares_heard: set[int] = set()
        self._spares_low: set[int] = set()  # spares below the show's battery minimum
        self._gone_dark: set[int] = set()  # left the show mid-show: LEDs off from then on
        self.takeoffs_s: list[float] = []
        """How long each vehicle took from being told to arm to hovering ready, s: a
        spare sent into a track is given the slowest of them (and more) to get up."""
        self.aborted: str | None = None
        """Why the show was called off before it could be flown (None: it was not)."""
        self._slots = plan.landing_hover  # where each track's descent starts
        self._home_hover = plan.home + np.array([0.0, 0.0, plan.takeoff_altitude])
        self._first = plan.trajectories.evaluate(0.0)[0]  # where each track's show starts
        self._ready_since: float | None = None
        self._return_wanted = False  # a return plan is needed (land-all, blocked spots)
        self._return: tuple[Trajectories, dict[int, int]] | None = None
        self._return_clock: ShowClock | None = None
        self._started = False
        self._ended = False
        self._columns = False  # the last resort: landing straight down, column by column
        self._stopped_at: float | None = None  # show time at which land_all stopped the show
        brake = self.config.brake_accel or 0.5 * plan.limits.max_accel
        speeds = np.linalg.norm(plan.trajectories.vel, axis=-1)
        self.clock = ShowClock(brake_ramp(float(speeds.max(initial=0.0)), brake))
        """The show clock (braking holds; see :mod:`groundctl.execute.showclock`)."""
        self._pre_start_hold = False  # the operator held before the show clock started
        self._replans = 0  # returns planned again for blocked landing spots
        self._after_return = False  # a new return starts from the landing points
        self._battery = (self.config.land_battery_pct if self.config.land_battery_pct
                         is not None else plan.limits.land_battery_pct)
        # This update's show-frame positions (one vectorised conversion per update).
        self._positions: dict[int, np.ndarray | None] = {}

    # -- clock -----------------------------------------------------------------------
    @property
    def started_at(self) -> float | None:
        """Our time of show time 0, None before the show clock started."""
        return self.clock.started_at

    @property
    def paused(self) -> bool:
        """The show is held (braking or stopped) for any reason."""
        return self.clock.held or self._pre_start_hold

    @property
    def holds(self) -> set[str]:
        """Why the show is held (``operator``, ``overload``, ``stall``, ``silence``...)."""
        return set(self.clock.holds) | ({"operator"} if self._pre_start_hold else set())

    def show_time(self, now: float) -> float:
        """The show clock: 0 before the start, braking to a stop while held, capped at the
        duration (and at where land-all stopped it)."""
        t = min(max(self.clock.show_time(now), 0.0), self.plan.duration)
        return t if self._stopped_at is None else min(t, self._stopped_at)

    def show_time_of(self, when: float) -> float | None:
        """The show time at our (past) time ``when``; None before the show clock started."""
        t0 = self.clock.started_at
        if t0 is None or when < t0:
            return None
        return self.clock.show_time(when)

    @property
    def clock_state(self) -> tuple[int, ...]:
        """Each clock's (show, then return) :attr:`~ShowClock.revision`.  When it changes
        (held, released, put back after a stall, a return set off), what was predicted on
        the clocks as they were (MPC trajectories, a weak vehicle's lead) no longer
        holds: its neighbours brake, stop or set off where it was not expected."""
        return tuple(c.revision for c in self._clocks())

    def _clocks(self) -> list[ShowClock]:
        return [self.clock] + ([self._return_clock] if self._return_clock is not None else [])

    def hold_for(self, reason: str, now: float) -> bool:
        """Brake every clock (show and return) to a stop for ``reason``; True if newly held.

        Used by the driver for what the sequence cannot see itself: its own overload, a
        fleet-wide silence, a safety response.
        """
        fresh = False
        for clock in self._clocks():
            fresh |= clock.hold(now, reason)
        return fresh

    def stop_for(self, reason: str, now: float, show_time: float, rate: float = 0.0) -> None:
        """Re-synchronise the show clock to ``show_time`` and brake from ``rate`` (the
        driver stalled: its drones flew on stale setpoints, and :meth:`fit_show_time`
        found where along the plan they are)."""
        if self._ended or self.started_at is None:
            self.hold_for(reason, now)
            return
        self.clock.stop_at(now, min(max(show_time, 0.0), self.plan.duration), reason, rate)

    def fit_show_time(self, lo: float, hi: float, positions: Mapping[int, np.ndarray],
                      velocities: Mapping[int, np.ndarray]) -> tuple[float, float]:
        """The show time in [``lo``, ``hi``] at which the plan best matches where the
        drones flying the show are (least median distance), and their speed along the
        plan there as a clock rate (0 standing .. 1 at the plan's speed)."""
        rows = [(v.track, positions[s], velocities.get(s)) for s, v in self.vehicles.items()
                if v.phase is VehiclePhase.SHOW and s in positions]
        lo, hi = max(lo, 0.0), min(max(hi, lo), self.plan.duration)
        if not rows or hi <= lo:
            return lo, 0.0
        tracks = np.array([r[0] for r in rows])
        here = np.array([r[1] for r in rows])
        times = np.linspace(lo, hi, max(int((hi - lo) / 0.05) + 1, 2))
        path = self.plan.trajectories.evaluate(times, tracks)[0]  # (drones, times, 3)
        cost = np.median(np.linalg.norm(path - here[:, None, :], axis=2), axis=0)
        best = float(times[int(np.argmin(cost))])
        plan_vel = self.plan.trajectories.evaluate(best, tracks)[1]
        ratios = [float(np.dot(v, pv) / np.dot(pv, pv))
                  for (_, _, v), pv in zip(rows, plan_vel, strict=True)
                  if v is not None and float(np.dot(pv, pv)) > 0.09]
        rate = float(np.clip(np.median(ratios), 0.0, 1.0)) if ratios else 0.0
        return best, rate

    def release(self, reason: str, now: float) -> bool:
        """Drop the hold ``reason``; the clocks ramp back up once no hold is left."""
        resumed = False
        for clock in self._clocks():
            resumed |= clock.release(now, reason)
        return resumed

    def commanded_all(self, req: StreamRequest, now: float) -> dict[int, np.ndarray]:
        """Where every streamed vehicle's path puts it at ``now`` (show frame), from this
        tick's request: one vectorised evaluation for the whole fleet."""
        ids = list(req.paths)
        if not ids:
            return {}
        pos, _, _ = sample_paths([req.paths[s] for s in ids], np.full(len(ids), now),
                                 req.clocks(self.plan))
        return dict(zip(ids, pos, strict=True))

    @property
    def phase(self) -> ShowPhase:
        """LANDED only once every vehicle is down or given up; a lost vehicle may still be
        airborne, so the show is not over while one is lost."""
        # A spare on its way into a track does not set the show's phase (it arms mid-show).
        phases = {v.phase for v in self.vehicles.values()
                  if v.pad is None or v.phase not in _BEFORE_JOINING
                  or (v.standing_by and not self._started_show)}
        lost = bool(self.lost)
        if not self._started:
            return ShowPhase.PREFLIGHT
        if VehiclePhase.ARMING in phases:
            return ShowPhase.ARMING
        if phases & {VehiclePhase.TAKEOFF, VehiclePhase.READY}:
            return ShowPhase.TAKEOFF
        if phases & {VehiclePhase.SHOW, VehiclePhase.JOINING}:
            return ShowPhase.SHOW
        # ... but the flight is not over while a spare is up or getting up.
        getting_up = any(v.pad is not None and v.phase in _BEFORE_JOINING
                         and v.phase is not VehiclePhase.PREFLIGHT
                         for v in self.vehicles.values())
        if lost or getting_up or phases & {VehiclePhase.LEAVING, VehiclePhase.RETURNING,
                                           VehiclePhase.LANDING}:
            return ShowPhase.LANDING
        return ShowPhase.LANDED

    @property
    def _started_show(self) -> bool:
        return self.clock.started_at is not None

    @property
    def lost(self) -> list[int]:
        """System ids of the vehicles lost now that may be airborne (silent after their
        takeoff was sent; one lost while arming never left its slot)."""
        return [s for s, v in self.vehicles.items() if v.phase is VehiclePhase.LOST
                and v.lost_from not in (VehiclePhase.PREFLIGHT, VehiclePhase.ARMING)]

    @property
    def settled(self) -> bool:
        """Every vehicle not lost is down or given up: only lost ones keep the flight open."""
        return all(v.phase in _DONE or v.phase is VehiclePhase.LOST
                   for v in self.vehicles.values())

    @property
    def ended(self) -> bool:
        """The show is over (its end reached, or land-all)."""
        return self._ended

    # -- internals -------------------------------------------------------------------
    def _took_off(self, v: VehicleRun, now: float) -> None:
        if v.started_at is not None:
            self.takeoffs_s.append(now - v.started_at)

    def _send(self, v: VehicleRun, command: Command, now: float) -> Command:
        if command != v.pending:
            v.attempts = 0
        if not isinstance(command, Land):
            v.land_from = None  # any other command ends a descent
        elif (command != v.pending or v.land_from is None) \
                and v.phase is not VehiclePhase.LOST:  # (a lost one's position is old)
            here = self._positions.get(v.sysid)
            if here is not None:
                v.land_from = (float(here[0]), float(here[1]))
        v.pending, v.sent_at, v.retry_at = command, now, None
        v.attempts += 1
        return command

    @staticmethod
    def _to(v: VehicleRun, event: Event, previous: VehiclePhase | None = None) -> None:
        """Move ``v`` on ``event`` through the lifecycle table
        (:mod:`~groundctl.execute.sequence.lifecycle`)."""
        v.phase = step(v.phase, event, previous)

    @staticmethod
    def _lost_to(v: VehicleRun, event: Event, previous: VehiclePhase | None = None) -> None:
        """Move the phase a LOST vehicle was lost in (what it is streamed as) on
        ``event``, by the same table."""
        assert v.lost_from is not None
        v.lost_from = step(v.lost_from, event, previous)

    @staticmethod
    def streamed_as(v: VehicleRun) -> VehiclePhase:
        """Its phase, or for a lost vehicle the phase it was lost in (what it is streamed)."""
        return v.lost_from if v.phase is VehiclePhase.LOST and v.lost_from else v.phase

    def _altitude(self, state: VehicleState) -> float | None:
        if state.global_position is not None:
            return state.global_position.relative_alt_m
        return None

    # -- provided by a higher layer ------------------------------------------------------
    def _land_in_columns(self, reason: str, now: float) -> list[Action]:
        """The last resort (:mod:`~groundctl.execute.sequence.columns`), which a failed return
        (:mod:`~groundctl.execute.sequence.returns`, the layer below it) falls back on."""
        raise NotImplementedError

