"""Simulator configuration: plain dataclasses, validated on construction.

:class:`Dynamics` holds one flavour's flight-dynamics tuning (speed and
acceleration limits, loop gains, takeoff and landing behaviour);
:class:`SimConfig` the whole fleet (how many vehicles, where, which autopilot,
where the ground station is, boot delays, weather, seed, signing key, faults).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from groundctl.link.flavours import Flavour
from groundctl.sim.faults import LinkFaults

#: Default show origin: ArduPilot SITL's default home (Canberra Model Aircraft Club).
DEFAULT_ORIGIN = (-35.363261, 149.165230, 584.0)


@dataclass(frozen=True)
class Dynamics:
    """Flight-dynamics tuning of one autopilot flavour (SI units, z up)."""

    max_speed_xy: float = 10.0
    """Horizontal speed limit, m/s (ArduCopter WPNAV_SPEED, PX4 MPC_XY_VEL_MAX)."""
    max_speed_up: float = 2.5
    """Climb-rate limit, m/s (WPNAV_SPEED_UP / MPC_Z_VEL_MAX_UP)."""
    max_speed_down: float = 1.5
    """Descent-rate limit, m/s (WPNAV_SPEED_DN / MPC_Z_VEL_MAX_DN)."""
    max_accel_xy: float = 2.5
    """Horizontal acceleration limit, m/s² (WPNAV_ACCEL / MPC_ACC_HOR)."""
    max_accel_z: float = 2.5
    """Vertical acceleration limit, m/s² (PSC_ACCZ / MPC_ACC_UP_MAX)."""
    max_jerk: float = 5.0
    """Jerk limit on the commanded acceleration, m/s³ (PSC_JERK_XY / MPC_JERK_AUTO)."""
    max_tilt_accel: float = 5.66
    """Horizontal acceleration the airframe can produce at its lean-angle limit, m/s²
    (g tan 30°: ArduCopter's ANGLE_MAX; PX4's MPC_TILTMAX_AIR is 45°).  Path shaping
    keeps to ``max_accel_xy``; rejecting wind may use up to this."""
    pos_p: float = 1.1
    """Position-loop gain, 1/s (PSC_POSXY_P / MPC_XY_P)."""
    pos_p_z: float = 1.0
    """Vertical position-loop gain, 1/s (PSC_POSZ_P / MPC_Z_P)."""
    vel_p: float = 1.5
    """Velocity-loop gain, 1/s (PSC_VELXY_P / MPC_XY_VEL_P_ACC)."""
    vel_i: float = 0.5
    """Velocity-loop integral gain, 1/s², which rejects steady wind."""
    response_tau: float = 0.15
    """First-order lag of the attitude/thrust response to a commanded acceleration, s."""
    takeoff_spool_s: float = 2.0
    """Time between a takeoff command and lift-off (motor spool-up, takeoff checks), s."""
    takeoff_speed: float = 1.0
    """Climb-rate limit during takeoff, m/s."""
    land_speed: float = 0.5
    """Final descent rate when landing, m/s (LAND_SPEED / MPC_LAND_SPEED)."""
    land_detect_s: float = 3.0
    """Time on the ground with the throttle down before the land detector trips, s."""
    drag: float = 0.25
    """Air-relative velocity coupling of wind into acceleration, 1/s."""


#: ArduCopter 4.7 in SITL, calibrated by sitl_tests/test_sim_calibration.py.
ARDUPILOT_DYNAMICS = Dynamics()

#: PX4 v1.15 multicopter defaults (MPC_*); takeoff to MIS_TAKEOFF_ALT at MPC_TKO_SPEED.
PX4_DYNAMICS = Dynamics(
    max_speed_xy=12.0,
    max_speed_up=3.0,
    max_speed_down=1.5,
    max_accel_xy=3.0,
    max_accel_z=4.0,
    max_tilt_accel=9.81,
    max_jerk=8.0,
    pos_p=0.95,
    pos_p_z=1.0,
    vel_p=1.8,
    vel_i=0.4,
    response_tau=0.1,
    takeoff_spool_s=1.0,
    takeoff_speed=1.5,
    land_speed=0.7,
    land_detect_s=2.0,
)


def default_dynamics(flavour: Flavour) -> Dynamics:
    """The calibrated dynamics of ``flavour``."""
    return ARDUPILOT_DYNAMICS if flavour is Flavour.ARDUPILOT else PX4_DYNAMICS


def grid_layout(count: int, spacing: float) -> np.ndarray:
    """Homes on a square grid, row by row going east then north: ``(count, 3)`` ENU metres."""
    if count <= 0:
        raise ValueError("`count` must be positive")
    if not spacing > 0:
        raise ValueError("`spacing` must be positive")
    cols = int(np.ceil(np.sqrt(count)))
    idx = np.arange(count)
    return np.stack(
        [(idx % cols) * spacing, (idx // cols) * spacing, np.zeros(count)], axis=1
    ).astype(float)


@dataclass
class SimConfig:
    """Everything a :class:`~groundctl.sim.fleet.SimFleet` needs to know.

    Homes are ENU metres from the show ``origin``; each vehicle's EKF origin is
    its own home unless ``ekf_origins`` overrides it (a real ArduCopter sets its
    EKF origin where it first gets a GPS fix, so no two share a local frame).
    """

    count: int = 1
    """Number of vehicles."""
    flavour: Flavour = Flavour.ARDUPILOT
    """Autopilot imitated by every vehicle of the fleet."""
    origin: tuple[float, float, float] = DEFAULT_ORIGIN
    """Show origin: latitude, longitude (degrees), altitude AMSL (m)."""
    positions: Sequence[Sequence[float]] | np.ndarray | None = None
    """Homes as ``(count, 3)`` ENU metres from ``origin``; None: ``grid_layout(count, spacing)``."""
    spacing: float = 3.0
    """Grid spacing in metres when ``positions`` is None."""
    ekf_origins: Sequence[tuple[float, float, float] | None] | None = None
    """Per-vehicle EKF origin (lat, lon, alt) overrides; None entries: the vehicle's home."""
    system_ids: Sequence[int] | None = None
    """MAVLink system ids; None: 1..count."""
    gcs: tuple[str, int] = ("127.0.0.1", 14550)
    """Where vehicles send until they hear from a ground station (then they reply to it)."""
    bind_host: str = "127.0.0.1"
    """Address the vehicles' sockets bind to."""
    base_port: int = 0
    """First vehicle port (the others follow); 0 binds ephemeral ports."""
    physics_rate_hz: float = 50.0
    """Physics (and vehicle scheduler) rate in simulated time."""
    ekf_origin_delay_s: float = 20.0
    """Time from boot until the EKF origin is set and LOCAL_POSITION_NED starts (SITL: ~20 s)."""
    ready_delay_s: float = 40.0
    """Time from boot until arming is allowed (SITL: ~40 s; "Arm: Need Position Estimate")."""
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Mean wind, ENU m/s (the direction the air moves to)."""
    gust_std: float = 0.0
    """Standard deviation of the seeded random gusts, m/s per axis."""
    gps_noise_m: float = 0.01
    """Standard deviation of the slowly varying position-estimate error, m."""
    seed: int = 0
    """Seed of every random process (gusts, GPS noise, link faults)."""
    signing_key: bytes | None = None
    """MAVLink 2 signing key (32 bytes): when set, unsigned or badly signed packets are rejected."""
    link_faults: LinkFaults = field(default_factory=LinkFaults)
    """Link faults of every vehicle (override one with ``SimFleet.set_link_faults``)."""
    dynamics: Dynamics | None = None
    """Flight dynamics; None: the flavour's calibrated default."""
    params: dict[str, float] = field(default_factory=dict)
    """Autopilot parameter overrides applied at boot (e.g. ``{"FS_GCS_ENABLE": 1}``)."""

    def __post_init__(self) -> None:
        self.flavour = Flavour(self.flavour)
        if self.count <= 0:
            raise ValueError("`count` must be positive")
        if not self.physics_rate_hz > 0:
            raise ValueError("`physics_rate_hz` must be positive")
        if self.ekf_origin_delay_s < 0 or self.ready_delay_s < 0:
            raise ValueError("`ekf_origin_delay_s` and `ready_delay_s` must be non-negative")
        if self.gust_std < 0 or self.gps_noise_m < 0:
            raise ValueError("`gust_std` and `gps_noise_m` must be non-negative")
        if self.system_ids is not None:
            ids = list(self.system_ids)
            if len(ids) != self.count:
                raise ValueError(f"`system_ids` has {len(ids)} entries for {self.count} vehicles")
            # Duplicates are allowed (each vehicle has its own socket, so a ground
            # station can still tell them apart by address): fleets above 255 need them.
            if not all(1 <= s <= 255 for s in ids):
                raise ValueError("`system_ids` must be integers in 1..255")
        elif self.count > 255:
            raise ValueError(
                "`count` above 255 needs explicit `system_ids` (MAVLink ids are 8 bit)")
        if self.signing_key is not None and len(self.signing_key) != 32:
            raise ValueError("`signing_key` must be 32 bytes")

    def homes_enu(self) -> np.ndarray:
        """Homes as a ``(count, 3)`` float array of ENU metres from the origin."""
        if self.positions is None:
            return grid_layout(self.count, self.spacing)
        homes = np.asarray(self.positions, dtype=float)
        if homes.ndim != 2 or homes.shape[1] not in (2, 3) or homes.shape[0] != self.count:
            raise ValueError(
                f"`positions` must have shape ({self.count}, 3), not {homes.shape}"
            )
        if homes.shape[1] == 2:
            homes = np.hstack([homes, np.zeros((self.count, 1))])
        return homes

    def sysids(self) -> list[int]:
        """System ids of the vehicles in order."""
        return list(self.system_ids) if self.system_ids is not None else list(
            range(1, self.count + 1))

    def resolved_dynamics(self) -> Dynamics:
        """``dynamics`` or the flavour's default."""
        return self.dynamics if self.dynamics is not None else default_dynamics(self.flavour)
