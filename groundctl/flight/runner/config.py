"""How the runner flies (:class:`RunnerConfig`), what it counts per vehicle
(:class:`VehicleRecord`), how long the flight may take (:class:`FlightBudget`), and
the constants and small helpers its layers share."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from groundctl.execute.frames import ned_vel_to_show
from groundctl.execute.guard import GuardConfig
from groundctl.execute.lead import LeadConfig
from groundctl.execute.preflight import Thresholds
from groundctl.execute.sequence import HOVER_BEFORE_SHOW_S, SequenceConfig, VehiclePhase
from groundctl.link.state import VehicleState
from groundctl.plan.plan import Plan
from groundctl.show.model import VehicleSettings
from groundctl.vehicleid import spell_many

log = logging.getLogger("groundctl.flight.runner")  # the package's name, as before the split

#: Checks a vehicle cannot pass by waiting (once their value is known).
PERMANENT_CHECKS = frozenset({"battery", "slot"})
#: More notices than this of one kind in one tick are folded into one line.
FOLD_AFTER = 3
#: Phases in which a vehicle is (or may be) in the air, for the guard's closest pair.
_AIRBORNE = frozenset({VehiclePhase.READY, VehiclePhase.JOINING, VehiclePhase.SHOW,
                       VehiclePhase.LEAVING, VehiclePhase.RETURNING})
#: Phases whose wind estimate is the air's now (in the air, or coming down through it).
_WIND_PHASES = _AIRBORNE | {VehiclePhase.TAKEOFF, VehiclePhase.LANDING}

def _ids(ids: Sequence[int]) -> str:
    """Vehicles as a short list: "(1-4, 7, 9, 2:1-2:250)" (see :func:`spell_many`)."""
    return "(" + spell_many(ids) + ")"


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
    send_slot_vehicles: int = 64
    """A tick's setpoints leave in slots of at most this many vehicles, spread evenly
    over the tick's period (each vehicle in the same slot every tick, its setpoint taken
    for its own sending instant), so a large fleet's setpoints are not one burst whose
    last leaves a burst's length late."""
    connect_timeout_s: float = 30.0
    """Every expected vehicle must send a HEARTBEAT within this."""
    preflight_timeout_s: float = 120.0
    """Every vehicle must pass its pre-flight checks within this."""
    settle_s: float = 3.0
    """A check that waiting cannot fix must fail this long before the pre-flight gives up."""
    spare_settle_s: float = 10.0
    """Once the show's own vehicles pass pre-flight, spares not ready yet (their streams,
    battery or EKF origin still to come) are waited for this much longer, s; then the
    show starts without them, said."""
    excluded: frozenset[int] = frozenset()
    """System ids the operator keeps on the ground."""
    tracks: Mapping[int, int] | None = None
    """System id -> plan track from a fleet file; None maps vehicles by position."""
    spare_ids: frozenset[int] = frozenset()
    """System ids a fleet file marks as spares (``spare = true``): matched to the plan's
    spare pads only, never to a track, and not waited for when connecting."""
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
    join_lead_s: float = 8.0
    """A spare's way into a vacated track leaves no sooner than this much show time after
    it is asked for, s; its planning gets that much wall time (less half a second)."""
    use_spares: bool = True
    """Send the plan's spares into tracks their drones left (False: ``--no-spares``)."""
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
        if self.send_slot_vehicles < 1:
            raise ValueError(f"`send_slot_vehicles` must be at least 1, got "
                             f"{self.send_slot_vehicles}")
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
