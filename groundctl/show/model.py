"""The show model: what an operator asked for, validated and in metres.

Coordinates are metres in the *show frame*: origin at ``Show.origin`` (a
geodetic point), +y pointing along ``origin.heading_deg`` (degrees clockwise
from true north; the audience looks along +y at vertical formations drawn in
the x-z plane), +x to its right, +z up.  ``heading_deg = 0`` makes the show
frame plain east-north-up.  Everything downstream of the loader (planner,
executor) works in this frame; the link layer converts to each vehicle's own NED frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class GeoOrigin:
    """Geodetic anchor of the show frame."""

    lat: float
    """Latitude in degrees (WGS84)."""
    lon: float
    """Longitude in degrees (WGS84)."""
    alt: float
    """Altitude of the show frame's z = 0 in metres above mean sea level."""
    heading_deg: float = 0.0
    """Direction of the show frame's +y axis, degrees clockwise from true north."""


@dataclass(frozen=True)
class Limits:
    """Flight envelope every drone must stay in, everywhere, at all times."""

    max_speed_h: float = 5.0
    """Max horizontal speed, m/s."""
    max_speed_up: float = 2.5
    """Max climb rate, m/s."""
    max_speed_down: float = 1.5
    """Max descent rate, m/s (slower than climb: descending into own wash)."""
    max_accel: float = 3.0
    """Max acceleration magnitude, m/s^2."""
    min_separation: float = 1.5
    """Min distance between any two drones' centres, m."""
    min_alt: float = 2.0
    """Min altitude above the show frame's z = 0 once the show is running, m."""
    max_alt: float = 120.0
    """Max altitude, m."""
    geofence: tuple[tuple[float, float], ...] | None = None
    """Optional horizontal polygon (x, y) in show-frame metres; None = no fence."""
    land_battery_pct: float = 20.0
    """A drone whose battery falls below this mid-show leaves the show on a way out and
    lands (below half of it, it lands where it is), percent."""
    max_flight_time: float = 900.0
    """The battery's endurance: the climb, every transition and hold, and the descent
    must fit in it, s."""
    max_wind: float = 10.0
    """Strongest wind the show is flown in, m/s horizontal, as the vehicles themselves
    estimate it (ArduPilot's WIND, PX4's WIND_COV): pre-flight refuses a vehicle that
    estimates more; in the air the fleet holds while the wind is above it, and lands
    when it stays there (:mod:`groundctl.execute.wind`)."""

    def scaled(self, speed: float, accel: float = 1.0) -> Limits:
        """These limits with the three speeds scaled by ``speed`` and the acceleration
        by ``accel`` (a weak vehicle's own envelope, the MPC's escape margin)."""
        return replace(self, max_speed_h=self.max_speed_h * speed,
                       max_speed_up=self.max_speed_up * speed,
                       max_speed_down=self.max_speed_down * speed,
                       max_accel=self.max_accel * accel)


@dataclass(frozen=True)
class QuadrotorModel:
    """3D point mass with speed and acceleration limits (show multirotors)."""

    kind: Literal["quadrotor"] = "quadrotor"


@dataclass(frozen=True)
class UnicycleModel:
    """The paper's 2D model: constant speed V, heading rate |u| <= V / r_min."""

    speed: float = 2.0
    """Constant forward speed V, m/s."""
    r_min: float = 1.5
    """Min turning radius, m (so the max turn rate is speed / r_min)."""
    max_turn_rate: float = 1.0
    """Absolute cap on |u|, rad/s (the paper's 1 rad/s); min of this and V/r_min applies."""
    kind: Literal["unicycle"] = "unicycle"

    @property
    def turn_rate_limit(self) -> float:
        return min(self.max_turn_rate, self.speed / self.r_min)


Model = QuadrotorModel | UnicycleModel


@dataclass(frozen=True)
class MpcSettings:
    """When the executor replans a drone with MPC (``[mpc]`` in the show file)."""

    enabled: bool = True
    """MPC replanning on (``--no-mpc`` turns it off for one flight)."""
    horizon_s: float = 3.0
    """How far ahead each MPC solve plans, s."""
    trigger_error_m: float = 0.4
    """A drone farther than this from its path is replanned, m: about 3x the calm-air
    RMS tracking error of real ArduCopter (0.109 m with a fixed 150 ms lead)."""
    release_error_m: float = 0.15
    """It is handed back to its path once within this, m ..."""
    release_after_s: float = 2.0
    """... for this long, s."""

    def __post_init__(self) -> None:
        if not 0.5 <= self.horizon_s <= 10.0:
            raise ValueError("`horizon_s` must be within 0.5..10 s")
        if not 0 < self.release_error_m < self.trigger_error_m:
            raise ValueError("`release_error_m` must be positive and below `trigger_error_m`")
        if self.release_after_s < 0:
            raise ValueError("`release_after_s` must be non-negative")


FenceAction = Literal["land", "rtl", "brake", "report"]
GcsFailsafe = Literal["off", "land", "rtl", "brake"]
OffboardLoss = Literal["land", "rtl", "hold"]


@dataclass(frozen=True)
class VehicleSettings:
    """The vehicles' own safety settings the show enforces before arming (``[vehicle]``).

    The operator-level keys are mapped to each autopilot's own parameters by
    :mod:`groundctl.execute.vehset`; None leaves that setting as the vehicle has it.
    """

    fence: bool = False
    """Upload the show's ``[limits] geofence`` (plus ``fence_margin``) and the altitude
    ceiling as the vehicles' own fence, and enable it."""
    fence_action: FenceAction = "land"
    """What a vehicle does on its own when it breaches that fence."""
    fence_margin: float = 2.0
    """How far beyond the planner's geofence and ceiling the vehicles' fence lies, m, so
    that a good show never trips it."""
    gcs_failsafe: GcsFailsafe | None = None
    """What a vehicle does when it stops hearing the ground station (None: as it is)."""
    gcs_timeout: float | None = None
    """After this long without the ground station's HEARTBEAT, s (None: as it is)."""
    offboard_loss: OffboardLoss | None = None
    """PX4: what it does when offboard setpoints stop (COM_OBL_RC_ACT; None: as it is)."""
    rtl_alt: float | None = None
    """Return-to-launch height above home, m (None: as it is)."""
    land_speed: float | None = None
    """Final landing descent rate, m/s (None: as it is)."""
    set: bool = True
    """May groundctl change a parameter that differs (False: only check, and refuse)."""
    params: tuple[tuple[str, float], ...] = ()
    """Raw parameters every vehicle must have, whatever its autopilot."""
    params_ardupilot: tuple[tuple[str, float], ...] = ()
    """Raw parameters for ArduPilot vehicles only (``params.ardupilot``)."""
    params_px4: tuple[tuple[str, float], ...] = ()
    """Raw parameters for PX4 vehicles only (``params.px4``)."""


@dataclass(frozen=True)
class PlannerSettings:
    """Knobs of the SCP planner (all optional in the show file)."""

    dt: float = 0.2
    """QP time step in seconds (the paper's 20 s / 100 steps)."""
    steps: int | None = None
    """Fixed number of steps per transition; overrides dt when set (paper: N = 100)."""
    max_iterations: int = 30
    """SCP iteration cap per transition."""
    tolerance: float = 0.02
    """Converged when no sample moved more than this (m) and constraints hold (the
    unicycle planner also stops once a feasible iterate lowers the cost by < 1 %)."""
    pattern_tolerance: float = 0.1
    """The paper's eps: allowed final position error at each formation slot, m."""
    alpha: float = 1.0
    """Weight of control effort (acceleration or turn rate) in the cost."""
    beta: float = 0.01
    """Weight of deviation from the reference (straight-line) trajectory."""
    tracking_margin: float = 0.0
    """Quadrotor: pairs are planned this much further apart than the minimum
    separation, m, where their own start and goal allow (never closer than the
    limit).  Real drones follow the plan within a few tenths of a metre and the
    limit is what the *flight* must keep, so a show meant to fly should set
    0.1-0.2 (the bundled ones do).  Off by default because it costs planning
    time: more pairs are near their rows, so QP groups grow (grid -> sphere,
    100 drones: 0.18 s -> 2.5 s at 0.1 m, 13 s at 0.2 m)."""
    budget_s: float = 40.0
    """Quadrotor: wall time one transition may spend looking for a plan that keeps every
    pair apart, s; past it the transition fails naming the drones still in conflict.
    Wall time: a show planned near its budget may plan on an idle machine and not on a
    busy one, so give it room."""

    def steps_for(self, duration: float) -> int:
        """QP steps N of a transition lasting ``duration`` s: ``steps``, or dt's worth
        (at least 4).  Both planners use this rule; the loader bounds it."""
        return self.steps or max(4, math.ceil(duration / self.dt - 1e-9))


SpareStandby = Literal["ground", "air"]


@dataclass(frozen=True)
class SpareSettings:
    """Spare drones (``[spares]``): vehicles beyond the show's tracks that wait, clear of
    every show drone, to take over a failed drone's part.

    Where they wait is planned with the show (:mod:`groundctl.plan.spares`): on pads
    beside the takeoff grid (``"ground"``) or hovering above them (``"air"``), laid out
    by the planner unless given."""

    count: int
    """How many spares the show asks for."""
    standby: SpareStandby = "ground"
    """Where they wait: on the ground on their pads, or in the air above them."""
    pads: FloatArray | None = None
    """(count, 2) given ground pads (x, y), show frame, m; None: laid out beside the
    takeoff grid.  ``"ground"`` only."""
    points: FloatArray | None = None
    """(count, 3) given standby points, show frame, m (each spare's pad straight below);
    None: above laid-out pads.  ``"air"`` only."""
    altitude: float | None = None
    """Height of laid-out standby points above the ground, m (None: the show's takeoff
    altitude).  ``"air"`` only."""


@dataclass(frozen=True)
class Formation:
    """One formation of the show and the transition that leads into it."""

    name: str
    """Operator's name for it (or the shape name), used in messages."""
    shape: str
    """Shape kind: grid, line, circle, square, star, spiral, sphere, text, points."""
    points: FloatArray
    """(M, 3) slot positions in show-frame metres, M >= drones."""
    colors: FloatArray
    """(M, 3) RGB in [0, 1] for each slot."""
    transition_s: float
    """Time to fly from the previous formation into this one, s."""
    hold_s: float = 0.0
    """Time to hold this formation once reached, s."""
    index: int = 0
    """1-based position in the show file's list of formations (for messages)."""


@dataclass(frozen=True)
class Show:
    """A whole show, as loaded and validated from a show file."""

    name: str
    """Show name."""
    drones: int
    """Number of drones."""
    origin: GeoOrigin
    """Geodetic anchor and heading of the show frame."""
    limits: Limits
    """Flight envelope."""
    model: Model
    """Dynamics model used to plan."""
    home: FloatArray
    """(drones, 3) takeoff (and landing) positions on the ground, show-frame metres."""
    takeoff_altitude: float
    """Height above home each drone climbs to before the show clock starts, m."""
    formations: tuple[Formation, ...]
    """Formations in show order; a landing formation over ``home`` is the last one."""
    planner: PlannerSettings = field(default_factory=PlannerSettings)
    """SCP settings."""
    start_headings: FloatArray | None = None
    """(drones,) initial headings in radians for the unicycle model (None: face +y)."""
    mpc: MpcSettings = field(default_factory=MpcSettings)
    """MPC replanning in flight."""
    vehicle: VehicleSettings | None = None
    """The vehicles' own safety settings (``[vehicle]``); None: not checked."""
    spares: SpareSettings | None = None
    """Spare drones (``[spares]``); None: the show has none."""
    source: str = ""
    """Path of the show file it came from ("" if built in code)."""
    digest: str = ""
    """SHA-256 (hex) of the show file and the point files it reads ("" if built in code);
    a plan records it, so that a plan is only flown with the show it was planned from."""

    @property
    def start_positions(self) -> FloatArray:
        """Where the planned show begins: each home raised to the takeoff altitude."""
        start = np.array(self.home, dtype=float, copy=True)
        start[:, 2] += self.takeoff_altitude
        return start
