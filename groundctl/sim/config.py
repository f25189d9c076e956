"""Simulator configuration: plain dataclasses, validated on construction.

:class:`Dynamics` holds one flavour's flight-dynamics tuning (speed and
acceleration limits, loop gains, takeoff and landing behaviour);
:class:`SimConfig` the whole fleet (how many vehicles, where, which autopilot,
where the ground station is, boot delays, weather, seed, signing key, faults).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from groundctl.link.flavours import Flavour
from groundctl.sim.faults import LinkFaults
from groundctl.vehicleid import vehicle_id

#: Default show origin: ArduPilot SITL's default home (Canberra Model Aircraft Club).
DEFAULT_ORIGIN = (-35.363261, 149.165230, 584.0)


@dataclass(frozen=True)
class Dynamics:
    """Flight-dynamics tuning of one autopilot flavour (SI units, z up).

    The controller cascade is described in :mod:`groundctl.sim.physics`;
    ``input_shaping`` and ``advance_target`` choose between ArduCopter's
    structure (the setpoint is a kinematic target that is advanced between
    messages and reached along a jerk-limited path) and PX4's (each message is
    flown as it is until the next one).  The field defaults are the ArduCopter
    4.7-dev calibration (``ARDUPILOT_47_DYNAMICS``).
    """

    firmware: tuple[int, int, int] = (4, 7, 0)
    """The autopilot version the calibration imitates (major, minor, patch): what the
    simulated vehicle reports (AUTOPILOT_VERSION, its boot text) and the parameter names
    it answers to (ArduCopter 4.8 renamed its speeds and heights to SI units)."""

    max_speed_xy: float = 10.0
    """Horizontal speed limit, m/s (ArduCopter WPNAV_SPEED, PX4 MPC_XY_VEL_MAX)."""
    max_speed_up: float = 2.5
    """Climb-rate limit, m/s (WPNAV_SPEED_UP / MPC_Z_VEL_MAX_UP)."""
    max_speed_down: float = 1.5
    """Descent-rate limit, m/s (WPNAV_SPEED_DN / MPC_Z_VEL_MAX_DN)."""
    max_accel_xy: float = 2.5
    """Horizontal acceleration of the path, m/s² (WPNAV_ACCEL / MPC_ACC_HOR): the input
    shaping's limit, and the braking curve of the position loop's sqrt controller."""
    max_accel_z: float = 2.5
    """Vertical acceleration of the path, m/s² (WPNAV_ACCEL_Z / MPC_ACC_UP_MAX): the input
    shaping's limit and the vertical sqrt controller's braking curve."""
    thrust_accel_z: float = 2.5
    """Vertical acceleration the thrust can add or take away around hover, m/s²: the limit
    of the whole vertical command (path, feedback, integrator)."""
    max_jerk: float = 5.0
    """Jerk limit, m/s³ (PSC_JERK_NE / MPC_JERK_AUTO): of the shaped path with
    ``input_shaping`` (its gains are ``max_jerk / max_accel``, so this sets how far
    the path lags a target without acceleration), else of the commanded acceleration."""
    max_tilt_accel: float = 5.66
    """Horizontal acceleration the airframe can produce at its lean-angle limit, m/s²
    (g tan 30°: ArduCopter's ANGLE_MAX; PX4's MPC_TILTMAX_AIR is 45°).  The whole
    command (path, feedback and integrator) is limited to this, nothing before it, so
    the controller can lean into the wind as far as the airframe can."""
    pos_p: float = 1.1
    """Position-loop gain, 1/s (PSC_NE_POS_P / MPC_XY_P)."""
    pos_p_z: float = 1.0
    """Vertical position-loop gain, 1/s (PSC_D_POS_P / MPC_Z_P)."""
    vel_p: float = 1.5
    """Velocity-loop gain, 1/s (PSC_NE_VEL_P / MPC_XY_VEL_P_ACC)."""
    vel_i: float = 0.5
    """Velocity-loop integral gain, 1/s², which rejects steady wind (PSC_NE_VEL_I /
    MPC_XY_VEL_I_ACC)."""
    vel_p_z: float = 1.5
    """Vertical velocity-loop gain, 1/s (PSC_D_VEL_P / MPC_Z_VEL_P_ACC)."""
    vel_i_z: float = 0.5
    """Vertical velocity-loop integral gain, 1/s² (ArduCopter's throttle integrator
    PSC_D_ACC_I / MPC_Z_VEL_I_ACC)."""
    vel_imax: float = 10.0
    """Limit of the horizontal velocity integrator, m/s² (PSC_NE_VEL_IMAX, 10 in 4.8;
    the lean-angle limit binds first).  Anti-windup: while the command is limited the
    integrator may only shrink along the limited direction, as AC_PID_2D does."""
    vel_imax_z: float = 2.0
    """Limit of the vertical velocity integrator, m/s²."""
    response_tau: float = 0.15
    """First-order lag of the horizontal acceleration (the attitude) behind its command, s
    (ArduCopter ATC_INPUT_TC is 0.15 s)."""
    response_tau_z: float = 0.15
    """First-order lag of the vertical acceleration (the thrust: motor speed) behind its
    command, s."""
    takeoff_spool_s: float = 2.0
    """Time between a takeoff command and lift-off (motor spool-up, takeoff checks), s."""
    takeoff_speed: float = 1.0
    """Climb-rate limit during takeoff, m/s (ArduCopter 4.8: WPNAV_SPEED_UP)."""
    land_speed: float = 0.5
    """Final descent rate when landing, m/s (LAND_SPEED / MPC_LAND_SPEED)."""
    land_detect_s: float = 3.0
    """Time on the ground with the throttle down before the land detector trips, s."""
    drag: float = 0.25
    """Linear (rotor momentum) drag: acceleration per m/s of air-relative velocity, 1/s.
    In still air it brakes every move, which the feed-forward does not know about: the
    vehicle lags its setpoints (the 4.7 calibration's ~150 ms)."""
    drag_quad: float = 0.0
    """Quadratic (body) drag: acceleration per (m/s)² of airspeed, 1/m.  Wind is a force
    on the airframe through these terms, which the controller has to lean against; this
    one is small at show speeds in still air and grows with the wind."""
    velocity_bias: float = 0.0
    """Standard deviation of the slowly wandering bias of the autopilot's horizontal
    velocity estimate, m/s (an EKF's velocity is never exact: GPS velocity noise, IMU
    bias).  The position loop holds the vehicle where its estimated velocity equals the
    loop's demand, ``bias / pos_p`` off its target, and its reported position with it: a
    centimetre or two that wanders over tens of seconds, per vehicle."""
    velocity_bias_tau: float = 40.0
    """Correlation time of that bias, s."""
    airframe_noise: float = 0.0
    """Standard deviation of a random horizontal acceleration on each flying vehicle, per
    axis, m/s²: what a real airframe adds to the commanded acceleration and a point mass
    does not (the attitude loop's errors from IMU noise and bias, the motors' response,
    the air the rotors stir), correlated over :attr:`airframe_noise_tau`.  The position and
    velocity loops reject most of it; what they leave is a real vehicle's wander about its
    target, a couple of centimetres each way, holding as much as moving, the wander itself
    decorrelating within a second or two."""
    airframe_noise_z: float = 0.0
    """The same vertically (the thrust's), m/s²: the vertical loops are stiffer, so the
    same wander takes more of it."""
    airframe_noise_tau: float = 1.0
    """Correlation time of that acceleration, s."""
    input_shaping: bool = False
    """ArduCopter AC_PosControl: the target is reached along a jerk-limited kinematic
    path (shape_pos_vel_accel: sqrt controllers of gain ``max_jerk / max_accel_xy``)
    whose acceleration feeds forward, and the position and velocity loops correct the
    vehicle onto that path.  Off (PX4): the loops act on the setpoint directly."""
    advance_target: bool = False
    """ArduCopter GUIDED posvelaccel: between setpoint messages the position target
    moves on with the velocity target and the velocity with the acceleration target
    (every loop, until the next message or GUID_TIMEOUT).  PX4 flies each trajectory
    setpoint as it is until the next one."""

    def __post_init__(self) -> None:
        positive = ("max_speed_xy", "max_speed_up", "max_speed_down", "max_accel_xy",
                    "max_accel_z", "thrust_accel_z", "max_jerk", "max_tilt_accel", "pos_p",
                    "pos_p_z", "vel_p", "vel_p_z", "response_tau", "response_tau_z",
                    "takeoff_speed", "land_speed", "velocity_bias_tau",
                    "airframe_noise_tau")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"`{name}` must be positive, got {getattr(self, name)}")
        non_negative = ("vel_i", "vel_i_z", "vel_imax", "vel_imax_z", "takeoff_spool_s",
                        "land_detect_s", "drag", "drag_quad", "velocity_bias",
                        "airframe_noise", "airframe_noise_z")
        for name in non_negative:
            if getattr(self, name) < 0:
                raise ValueError(f"`{name}` must be non-negative, got {getattr(self, name)}")


#: ArduCopter V4.8.0-dev in SITL, calibrated by sitl_tests/test_sim_calibration.py and
#: sitl_tests/test_sim_wind.py.  GUIDED's target is advanced between messages and reached
#: through AC_PosControl's input shaping, with its defaults: PSC_NE_POS_P 1, PSC_NE_VEL_P 2,
#: PSC_NE_VEL_I 1 (IMAX 10 m/s²), PSC_D_POS_P 1, PSC_D_VEL_P 5, WPNAV_ACCEL 2.5 and
#: WPNAV_ACCEL_Z 1 m/s², WPNAV_SPEED_UP 2.5 m/s, LAND_SPEED 0.5 m/s, ANGLE_MAX 30°.
#: Calibrated rather than read off parameters: the shaping's jerk, 6 m/s³ where
#: PSC_JERK_NE is 5 (at 5 the line from position + velocity setpoints lags 25 % more than
#: SITL measured: the vehicle-side dynamics SITL adds are not modelled); the airframe's
#: drag (below);
#: spool-up before lift-off and the land detector's delay, fitted to the takeoff and LAND
#: times; the velocity estimate's bias, 2 cm/s wandering over 40 s, fitted to nine SITL
#: instances flying the quick show (benchmarks/bench_sitl.py: per-vehicle RMS 0.031-0.043
#: m, across the path 0.028 m, formations held within 2 cm of their slots' offsets); the
#: airframe's own wander (session 38), a random acceleration of 0.03 m/s² horizontally and
#: 0.12 m/s² vertically per axis over 3 s, fitted to the same flights' holds, where SITL's
#: reported positions wander 0.021 / 0.022 / 0.016 m RMS (east / north / up) about their
#: slots and move a median 0.021 m in 2 s: a point mass without it held 0.013 / 0.015 /
#: 0.007 m, and the show's per-vehicle RMS was a third below SITL's.
ARDUPILOT_DYNAMICS = Dynamics(
    firmware=(4, 8, 0),
    max_accel_z=1.0,
    thrust_accel_z=5.0,
    max_jerk=6.0,
    pos_p=1.0,
    vel_p=2.0,
    vel_i=1.0,
    vel_imax=10.0,
    vel_p_z=5.0,
    vel_i_z=1.0,
    response_tau_z=0.05,
    takeoff_spool_s=2.6,
    takeoff_speed=2.5,
    land_detect_s=1.7,
    # The airframe's drag: SITL's default quad has rotor momentum drag (linear in the
    # air-relative velocity) and body drag (quadratic), together 45° of lean at 15 m/s.
    # Fitted to a hovering ArduCopter SITL's step gusts (benchmarks/bench_gust.py, 4 s
    # from the west: 9 m/s carried it 1.24 m, here 1.17 m; 15 m/s 11.3 m, past its lean,
    # here 14.5 m) and to its calm 10 m line (RMS 0.169 m, here 0.168 m).  Its line in a
    # steady 8 m/s with turbulence is flown worse here than in SITL (RMS 0.29 against
    # 0.199 m; test_sim_wind.py): on the cautious side.  Until session 29 the drag was
    # 0.02/m quadratic only, fitted to that line, and a 9 m/s gust carried the simulated
    # vehicle 0.53 m and a 15 m/s one 1.4 m: a rehearsal showed gusts as harmless.
    drag=0.03,
    drag_quad=0.043,
    velocity_bias=0.02,
    airframe_noise=0.03,
    airframe_noise_z=0.12,
    airframe_noise_tau=3.0,
    input_shaping=True,
    advance_target=True,
)

#: ArduCopter 4.7-dev in SITL, the simulator's earlier calibration (line from position +
#: velocity setpoints RMS 0.25 / max 0.44 m, position only 1.12 / 2.19 m, takeoff to 95 %
#: of 5 m in 7.5 s, LAND to disarm 13-15 s): no input shaping, targets held between
#: messages, linear drag; its tracking lags the setpoints by about 150 ms.  Kept to
#: compare against logs of that build; sitl_tests/test_sim_calibration.py still checks it.
ARDUPILOT_47_DYNAMICS = Dynamics()

#: PX4 v1.15 multicopter defaults (MPC_*); takeoff to MIS_TAKEOFF_ALT at MPC_TKO_SPEED.
#: Trajectory setpoints are flown as they come (mc_pos_control takes each one as is, no
#: advancing between them, no shaping in OFFBOARD); the same airframe (and its drag) as
#: ArduPilot's.
PX4_DYNAMICS = Dynamics(
    firmware=(1, 15, 0),
    max_speed_xy=12.0,
    max_speed_up=3.0,
    max_speed_down=1.5,
    max_accel_xy=3.0,
    max_accel_z=4.0,
    thrust_accel_z=4.0,
    max_tilt_accel=9.81,
    max_jerk=8.0,
    pos_p=0.95,
    pos_p_z=1.0,
    vel_p=1.8,
    vel_i=0.4,
    vel_imax=9.81,
    vel_p_z=4.0,
    vel_i_z=2.0,
    response_tau=0.1,
    response_tau_z=0.05,
    takeoff_spool_s=1.0,
    takeoff_speed=1.5,
    land_speed=0.7,
    land_detect_s=2.0,
    drag=0.03,
    drag_quad=0.043,
)

#: Named dynamics profiles (``dynamics_profile(name)``); the first of each flavour's is
#: its default.
DYNAMICS_PROFILES: dict[str, Dynamics] = {
    "ardupilot-4.8": ARDUPILOT_DYNAMICS,
    "ardupilot-4.7": ARDUPILOT_47_DYNAMICS,
    "px4-1.15": PX4_DYNAMICS,
}
#: Names accepted by :func:`dynamics_profile`.
PROFILE_NAMES: tuple[str, ...] = tuple(DYNAMICS_PROFILES)


def dynamics_profile(name: str) -> Dynamics:
    """The dynamics profile called ``name`` (one of :data:`PROFILE_NAMES`)."""
    try:
        return DYNAMICS_PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown dynamics profile {name!r}: expected one of "
                         f"{', '.join(PROFILE_NAMES)}") from None


def profile_for(flavour: Flavour, name: str | None) -> Dynamics:
    """The dynamics ``name`` (None: the flavour's calibrated default), which must be one
    of ``flavour``'s profiles (their names start with the flavour's)."""
    if name is None:
        return default_dynamics(flavour)
    dynamics = dynamics_profile(name)
    if not name.startswith(flavour.value):
        mine = [p for p in PROFILE_NAMES if p.startswith(flavour.value)]
        raise ValueError(f"dynamics profile {name!r} is not a {flavour.value} profile: "
                         f"expected one of {', '.join(mine)}")
    return dynamics


def default_dynamics(flavour: Flavour) -> Dynamics:
    """The calibrated dynamics of ``flavour``."""
    return ARDUPILOT_DYNAMICS if flavour is Flavour.ARDUPILOT else PX4_DYNAMICS


class WindProfile(enum.Enum):
    """How the mean wind varies with height (ArduPilot SITL's SIM_WIND_T)."""

    SQRT = 0
    """SIM_WIND_T 0, SITL's default: ``speed * sqrt(height / ref_height)`` below
    ``ref_height`` (SIM_WIND_T_ALT, 60 m), full speed above: calm on the ground."""
    CONSTANT = 1
    """SIM_WIND_T 1 (NO_LIMIT): the same wind at every height."""
    LINEAR = 2
    """SIM_WIND_T 2 (COEF): ``speed + (height - ref_height) * coef``, never negative."""


def wind_from(speed: float, from_deg: float) -> tuple[float, float, float]:
    """The wind (east, north, up m/s) of ``speed`` blowing from compass ``from_deg``
    (270: from the west, towards the east)."""
    frm = math.radians(from_deg)
    return (-speed * math.sin(frm), -speed * math.cos(frm), 0.0)


@dataclass(frozen=True)
class Wind:
    """Weather of the simulated fleet: mean wind, its height profile, turbulence.

    ``SimConfig.wind`` takes either a plain ENU vector (constant wind, no
    turbulence) or this.  Heights are above the ground under each vehicle.
    """

    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Mean wind, ENU m/s (the direction the air moves to), at ``ref_height`` and above
    for ``SQRT``, everywhere for ``CONSTANT``."""
    turbulence: float = 0.0
    """Turbulence like SITL's SIM_WIND_TURB, m/s: Ornstein-Uhlenbeck winds of this
    standard deviation (split over the two horizontal axes, full vertically); only on
    vehicles in the air."""
    turbulence_tau: float = 0.042
    """Correlation time of the vertical turbulence, s: SITL filters white noise with a
    0.98 IIR at its 1200 Hz physics rate, 50 steps."""
    turbulence_tau_xy: float = 1.0 / 2400.0
    """Correlation time of the horizontal turbulence, s: SITL points the filtered speed
    at a new random azimuth every physics step, so horizontally it lasts half a step."""
    profile: WindProfile = WindProfile.CONSTANT
    """Height profile of the mean wind."""
    ref_height: float = 60.0
    """Reference height of the profile, m (SIM_WIND_T_ALT)."""
    coef: float = 0.01
    """Speed gained per metre above ``ref_height`` with ``LINEAR``, 1/s (SIM_WIND_T_COEF)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", tuple(float(c) for c in self.mean))
        object.__setattr__(self, "profile", WindProfile(self.profile))
        if len(self.mean) != 3:
            raise ValueError(f"`mean` must be an ENU vector of 3, got {len(self.mean)} values")
        if self.turbulence < 0:
            raise ValueError(f"`turbulence` must be non-negative, got {self.turbulence}")
        if not (self.turbulence_tau > 0 and self.turbulence_tau_xy > 0):
            raise ValueError("`turbulence_tau` and `turbulence_tau_xy` must be positive")
        if not self.ref_height > 0:
            raise ValueError(f"`ref_height` must be positive, got {self.ref_height}")

    @classmethod
    def sitl(cls, speed: float, from_deg: float = 180.0, turbulence: float = 0.0,
             wind_type: int = 0, ref_height: float = 60.0) -> Wind:
        """The wind of SITL's parameters: SIM_WIND_SPD, SIM_WIND_DIR (where it blows from,
        degrees from north; SITL's default 180 blows north), SIM_WIND_TURB, SIM_WIND_T,
        SIM_WIND_T_ALT."""
        to = np.radians(from_deg + 180.0)
        return cls(mean=(speed * float(np.sin(to)), speed * float(np.cos(to)), 0.0),
                   turbulence=turbulence, profile=WindProfile(wind_type),
                   ref_height=ref_height)


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
    networks: Sequence[int] | None = None
    """Each vehicle's MAVLink network, from 1 (None: all on network 1): a vehicle of
    network n sends to ``gcs_networks[n - 1]`` and is named by its vehicle id
    (:mod:`groundctl.vehicleid`: ``2:17`` is 1017) in every call of the fleet."""
    gcs_networks: Sequence[tuple[str, int]] | None = None
    """Each network's ground-station address, in network order (None: ``gcs`` alone)."""
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
    wind: tuple[float, float, float] | Wind = (0.0, 0.0, 0.0)
    """Mean wind, ENU m/s (the direction the air moves to), constant at every height; or a
    :class:`Wind` (height profile, SITL-like turbulence)."""
    gust_std: float = 0.0
    """Standard deviation of the seeded random gusts, m/s per axis (slow: 2 s correlation;
    SITL's faster turbulence is ``Wind.turbulence``)."""
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
    rtk_noise: bool = False
    """Each GPS fix type has its own estimate noise (3D ~1 m, RTK float ~0.3 m, fixed
    ~0.02 m: :mod:`groundctl.sim.rtk`) instead of ``gps_noise_m``; the dry-run's ``--rtk``."""
    boot_text: bool = False
    """Vehicles send their autopilot's boot text as raw datagrams before MAVLink (as
    ArduPilot SITL does on its MAVLink port): a ground station counts them as bad packets."""

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
        if self.networks is not None:
            nets = list(self.networks)
            gcs = self.gcs_networks if self.gcs_networks is not None else [self.gcs]
            if len(nets) != self.count or not all(1 <= n <= len(gcs) for n in nets):
                raise ValueError(f"`networks` must give each of the {self.count} vehicles a "
                                 f"network in 1..{len(gcs)}")
            local = self.local_ids()
            ids = self.sysids()
            if len(set(ids)) != len(ids) or max(local) > 254:
                raise ValueError("every vehicle needs its own system id (1..254) on its "
                                 "network")
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

    def local_ids(self) -> list[int]:
        """MAVLink system ids of the vehicles in order (on their own networks)."""
        return list(self.system_ids) if self.system_ids is not None else list(
            range(1, self.count + 1))

    def sysids(self) -> list[int]:
        """Vehicle ids in order: the system ids on network 1, ``vehicle_id(n, sysid)``
        on the others (what the ground station names them by)."""
        local = self.local_ids()
        if self.networks is None:
            return local
        return [int(vehicle_id(n, s)) for n, s in zip(self.networks, local, strict=True)]

    def gcs_of(self, index: int) -> tuple[str, int]:
        """Where vehicle ``index`` (in order) sends before it hears a ground station."""
        if self.networks is None or self.gcs_networks is None:
            return self.gcs
        return tuple(self.gcs_networks[self.networks[index] - 1])  # type: ignore[return-value]

    def resolved_dynamics(self) -> Dynamics:
        """``dynamics`` or the flavour's default."""
        return self.dynamics if self.dynamics is not None else default_dynamics(self.flavour)
