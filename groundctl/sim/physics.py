"""Fleet physics: every vehicle a multirotor point mass, stepped together in numpy.

:meth:`FleetPhysics.step` is pure arithmetic over ``(n, 3)`` arrays (no Python
loop over vehicles).  Axes are the show's ENU frame, z up.  Each vehicle runs
the cascade ArduCopter's AC_PosControl and PX4's PositionControl share:

    position error --sqrt controller--> velocity demand (+ velocity feed-forward)
    velocity error --P + I-----------> acceleration demand (+ acceleration feed-forward)
    acceleration demand --jerk limit, first-order thrust lag--> acceleration

with speed, acceleration and jerk limits, so position-only setpoints lag
behind a moving target and feed-forward removes most of that lag, as on the
real autopilots.  The controller acts on the *estimated* position (truth plus
GPS error), so a GPS glitch moves the real vehicle, as it would.

Around it: ground contact, spool-up before lift-off, a land detector timer,
wind (mean + seeded Ornstein-Uhlenbeck gusts + injected gusts), GPS error,
motor failure (thrust gone: the vehicle falls) and battery drain.
"""

from __future__ import annotations

import numpy as np

from groundctl.sim.config import Dynamics

GRAVITY = 9.80665

#: Control modes (per vehicle, int8).
CTRL_OFF = 0  # motors stopped: disarmed
CTRL_IDLE = 1  # armed, motors at idle on the ground, waiting for a takeoff
CTRL_TRACK = 2  # flying: tracking the position / velocity / acceleration target
CTRL_LAND = 3  # descending at the landing speed over the target's horizontal position

#: A touchdown faster than this (m/s) is a crash.
CRASH_SPEED = 3.0
#: Gust and GPS-error correlation times (s).
GUST_TAU = 2.0
GPS_TAU = 20.0
#: Below this height the landing descent slows to the land speed (ArduCopter LAND_ALT_LOW).
LAND_SLOW_HEIGHT = 10.0
#: Full battery lasts this long hovering (s); idle on the ground draws a tenth of that.
HOVER_ENDURANCE_S = 1200.0


def _limit_norm(v: np.ndarray, limit: np.ndarray | float) -> np.ndarray:
    """Scale the rows of ``v`` (..., k) down to norm ``limit`` where they exceed it."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    lim = np.asarray(limit, dtype=float)
    if lim.ndim:
        lim = lim[..., None]
    scale = np.minimum(1.0, lim / np.maximum(norm, 1e-12))
    return v * scale


def _sqrt_controller(err: np.ndarray, p: float, accel: float) -> np.ndarray:
    """Velocity demand for a position error: linear near zero, sqrt(2 a d) far away.

    The same shape as ArduPilot's ``sqrt_controller``: P gain inside
    ``accel / p²``, constant-deceleration braking curve outside, so that a far
    target is approached at a speed from which the vehicle can still stop.
    """
    dist = np.abs(err)
    linear = accel / (p * p)
    far = np.sqrt(np.maximum(2.0 * accel * (dist - linear / 2.0), 0.0))
    return np.sign(err) * np.where(dist <= linear, p * dist, far)


#: The velocity integrator runs only while the velocity error is below this, m/s.
INTEGRATE_BELOW_MPS = 3.0


class FleetPhysics:
    """State and dynamics of ``n`` vehicles; mutate the targets, then :meth:`step`."""

    def __init__(self, homes_enu: np.ndarray, dynamics: Dynamics, rng: np.random.Generator,
                 wind: tuple[float, float, float] = (0.0, 0.0, 0.0), gust_std: float = 0.0,
                 gps_noise_m: float = 0.0) -> None:
        n = homes_enu.shape[0]
        self.n = n
        self.dyn = dynamics
        self.rng = rng
        self.t = 0.0
        self.pos = homes_enu.astype(float).copy()
        """True positions, show ENU (m)."""
        self.vel = np.zeros((n, 3))
        """True velocities, ENU (m/s)."""
        self.acc = np.zeros((n, 3))
        """Net acceleration produced by thrust (gravity compensated), ENU (m/s²)."""
        self._acc_dem = np.zeros((n, 3))
        self._vint = np.zeros((n, 3))
        self.ground_z = homes_enu[:, 2].astype(float).copy()
        """Height of the ground under each vehicle (its home's)."""
        self.mode = np.full(n, CTRL_OFF, dtype=np.int8)
        """Control mode, one of the CTRL_* constants."""
        self.tgt_pos = self.pos.copy()
        """Position target, ENU (m)."""
        self.tgt_vel = np.zeros((n, 3))
        """Velocity feed-forward / target, ENU (m/s)."""
        self.tgt_acc = np.zeros((n, 3))
        """Acceleration feed-forward, ENU (m/s²)."""
        self.use_pos = np.ones(n, dtype=bool)
        """Track ``tgt_pos`` (else velocity control only)."""
        self.use_vel = np.zeros(n, dtype=bool)
        """Add ``tgt_vel``."""
        self.use_acc = np.zeros(n, dtype=bool)
        """Add ``tgt_acc``."""
        self.climb_limit = np.full(n, dynamics.max_speed_up)
        """Per-vehicle climb-rate limit (m/s): lower during takeoff."""
        self.spool = np.zeros(n)
        """Seconds of motor spool-up left before the vehicle can lift off."""
        self.on_ground = np.ones(n, dtype=bool)
        """Resting on the ground."""
        self.ground_time = np.zeros(n)
        """Seconds on the ground without a climb demand (the land detector's input)."""
        self.crashed = np.zeros(n, dtype=bool)
        """Hit the ground faster than CRASH_SPEED."""
        self.motor_failed = np.zeros(n, dtype=bool)
        """Thrust lost (fault)."""
        self.battery = np.ones(n)
        """Remaining battery fraction."""
        self.wind_mean = np.asarray(wind, dtype=float)
        """Mean wind, ENU (m/s)."""
        self.gust_std = float(gust_std)
        """Random gust standard deviation (m/s)."""
        self.gust = np.zeros((n, 3))
        """Current random gust per vehicle (m/s)."""
        self.gust_extra = np.zeros((n, 3))
        """Injected gusts (fault), m/s."""
        self.gps_noise_m = float(gps_noise_m)
        """Standard deviation of the slowly varying estimate error (m)."""
        self.gps_err = np.zeros((n, 3))
        """Slowly varying estimate error (m)."""
        self.glitch = np.zeros((n, 3))
        """Injected GPS glitch offset (m)."""

    # -- derived ----------------------------------------------------------------------------

    @property
    def est_pos(self) -> np.ndarray:
        """Position the autopilots believe (truth + GPS error + glitch)."""
        return self.pos + self.gps_err + self.glitch

    @property
    def height(self) -> np.ndarray:
        """Height above the ground under each vehicle (m)."""
        return self.pos[:, 2] - self.ground_z

    # -- dynamics ---------------------------------------------------------------------------

    def step(self, dt: float) -> None:
        """Advance the whole fleet by ``dt`` seconds."""
        if not dt > 0:
            raise ValueError("`dt` must be positive")
        d = self.dyn
        n = self.n
        flying_mode = (self.mode >= CTRL_TRACK) & ~self.motor_failed
        self.spool = np.where(flying_mode, np.maximum(self.spool - dt, 0.0), self.spool)
        powered = flying_mode & (self.spool <= 0.0)

        # Position loop (horizontal on the xy norm, vertical on its own, as both autopilots do).
        err = np.where(self.use_pos[:, None], self.tgt_pos - self.est_pos, 0.0)
        exy = err[:, :2]
        dxy = np.linalg.norm(exy, axis=1, keepdims=True)
        vxy = exy / np.maximum(dxy, 1e-12) * _sqrt_controller(dxy, d.pos_p, d.max_accel_xy)
        vz = _sqrt_controller(err[:, 2], d.pos_p_z, d.max_accel_z)
        v_dem = np.concatenate([vxy, vz[:, None]], axis=1)
        v_dem += np.where(self.use_vel[:, None], self.tgt_vel, 0.0)
        landing = self.mode == CTRL_LAND
        descent = np.where(self.height > LAND_SLOW_HEIGHT, d.max_speed_down, d.land_speed)
        v_dem[:, 2] = np.where(landing, -descent, v_dem[:, 2])
        v_dem[:, :2] = _limit_norm(v_dem[:, :2], d.max_speed_xy)
        v_dem[:, 2] = np.clip(v_dem[:, 2], -d.max_speed_down, self.climb_limit)

        # Velocity loop with integrator (rejects steady wind) and acceleration feed-forward.
        # The path demand (P term and feed-forward) keeps to the acceleration limit; the
        # integrator, which carries the steady wind, may add up to the tilt authority.
        # Conditional integration (anti-windup): only near the demanded velocity, so a
        # long move does not wind it up and overshoot.
        v_err = v_dem - self.vel
        near = np.linalg.norm(v_err[:, :2], axis=1, keepdims=True) < INTEGRATE_BELOW_MPS
        self._vint = self._vint + np.where(near, d.vel_i * v_err * dt, 0.0)
        self._vint[:, :2] = _limit_norm(self._vint[:, :2], d.max_tilt_accel)
        self._vint[:, 2] = np.clip(self._vint[:, 2], -2.0, 2.0)
        a_dem = d.vel_p * v_err
        a_dem += np.where(self.use_acc[:, None], self.tgt_acc, 0.0)
        a_dem[:, :2] = _limit_norm(a_dem[:, :2], d.max_accel_xy)
        a_dem += self._vint
        a_dem[:, :2] = _limit_norm(a_dem[:, :2], d.max_tilt_accel)
        a_dem[:, 2] = np.clip(a_dem[:, 2], -d.max_accel_z, d.max_accel_z)
        self._acc_dem += _limit_norm(a_dem - self._acc_dem, d.max_jerk * dt)
        acc = self.acc + (self._acc_dem - self.acc) * min(1.0, dt / d.response_tau)
        # Unpowered: no thrust at all, the vehicle falls (or rests on the ground).
        acc = np.where(powered[:, None], acc, np.array([0.0, 0.0, -GRAVITY]))
        self.acc = acc

        # Wind: mean + seeded OU gusts + injected gusts, coupled through drag.
        if self.gust_std > 0:
            k = dt / GUST_TAU
            self.gust += -self.gust * k + self.gust_std * np.sqrt(2 * k) * self.rng.standard_normal(
                (n, 3))
        wind = self.wind_mean + self.gust + self.gust_extra
        airborne = ~self.on_ground | (acc[:, 2] > 0)
        total = acc + np.where(airborne[:, None], d.drag * (wind - self.vel), 0.0)
        self.vel = self.vel + total * dt
        self.pos = self.pos + self.vel * dt

        # Ground contact: clamp, stop, detect crashes.
        below = self.pos[:, 2] <= self.ground_z
        impact = below & (self.vel[:, 2] < -CRASH_SPEED)
        self.crashed |= impact
        self.pos[:, 2] = np.where(below, self.ground_z, self.pos[:, 2])
        self.vel = np.where(below[:, None], 0.0, self.vel)
        self.on_ground = below
        resting = below & ~(powered & (v_dem[:, 2] > 0))
        self.ground_time = np.where(resting, self.ground_time + dt, 0.0)
        # Integrators and demands reset on the ground: no wind-up before lift-off.
        self._vint = np.where(resting[:, None], 0.0, self._vint)
        self._acc_dem = np.where(resting[:, None], 0.0, self._acc_dem)
        self.acc = np.where(resting[:, None], 0.0, self.acc)

        # Estimate error: slow OU process, as an EKF fed by a GPS wanders.
        if self.gps_noise_m > 0:
            k = dt / GPS_TAU
            self.gps_err += -self.gps_err * k + self.gps_noise_m * np.sqrt(
                2 * k) * self.rng.standard_normal((n, 3))

        # Battery: hover draw when flying, a tenth of it idling armed.
        draw = np.where(powered & ~self.on_ground, 1.0, np.where(self.mode > CTRL_OFF, 0.1, 0.0))
        self.battery = np.maximum(self.battery - draw * dt / HOVER_ENDURANCE_S, 0.0)
        self.t += dt

    # -- commands from the autopilot logic -------------------------------------------------

    def hold(self, i: int) -> None:
        """Brake vehicle ``i`` and hold where it stops (the autopilots' "stopping point")."""
        v = self.vel[i]
        vxy = float(np.hypot(v[0], v[1]))
        stop = self.est_pos[i].copy()
        if vxy > 0:
            stop[:2] += v[:2] * vxy / (2.0 * self.dyn.max_accel_xy)
        stop[2] += v[2] * abs(v[2]) / (2.0 * self.dyn.max_accel_z)
        self.tgt_pos[i] = stop
        self.tgt_vel[i] = 0.0
        self.tgt_acc[i] = 0.0
        self.use_pos[i], self.use_vel[i], self.use_acc[i] = True, False, False
        if self.mode[i] == CTRL_LAND:
            self.mode[i] = CTRL_TRACK

    def set_target(self, i: int, pos: np.ndarray | None, vel: np.ndarray | None,
                   acc: np.ndarray | None) -> None:
        """Track ``pos`` / ``vel`` / ``acc`` (None: not used), in the show frame."""
        if pos is not None:
            self.tgt_pos[i] = pos
        self.use_pos[i] = pos is not None
        self.tgt_vel[i] = vel if vel is not None else 0.0
        self.use_vel[i] = vel is not None
        self.tgt_acc[i] = acc if acc is not None else 0.0
        self.use_acc[i] = acc is not None
