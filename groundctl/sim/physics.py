"""Fleet physics: every vehicle a multirotor point mass, stepped together in numpy.

:meth:`FleetPhysics.step` is pure arithmetic over ``(n, 3)`` arrays (no Python
loop over vehicles).  Axes are the show's ENU frame, z up.  Each vehicle runs
the cascade ArduCopter's AC_PosControl and PX4's PositionControl share, with
ArduCopter's input stage in front of it when the flavour has one:

    [advance_target]  the target moves on between messages: p += v dt, v += a dt
    [input_shaping]   desired path (p_d, v_d, a_d) reaches the target jerk-limited
                      (shape_pos_vel_accel: sqrt controllers of gain jerk/accel)
    position error p_d - p --sqrt controller--> velocity correction (+ v_d)
    velocity error  --P + I (anti-windup)----> acceleration correction (+ a_d)
    whole command limited to the lean-angle limit --first-order thrust lag--> thrust

Without the input stage (PX4) p_d, v_d, a_d are the setpoint itself and the
command is jerk-limited instead.  The controller acts on the *estimated*
position (truth plus GPS error), so a GPS glitch moves the real vehicle.

Wind is a force: the air-relative velocity drags the airframe (linear rotor
momentum drag plus quadratic body drag), so holding station in wind takes a
lean that the velocity integrator learns, up to the tilt limit.  The wind is
the mean (optionally scaled with height, as SITL's SIM_WIND_T), fast
turbulence like SITL's SIM_WIND_TURB, slow seeded gusts (one field over the
show, :class:`GustField`) and injected gusts.

Around it: ground contact, spool-up before lift-off, a land detector timer,
GPS error, the velocity estimate's slow bias and the airframe's own random
acceleration (:class:`~groundctl.sim.config.Dynamics`: what a real vehicle's wander
about its target comes from), motor failure (thrust gone: the vehicle falls) and
battery drain.
"""

from __future__ import annotations

import numpy as np

from groundctl.sim.config import Dynamics, Wind, WindProfile

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
#: Time constant of the autopilots' wind estimate (s): the EKF's wind states follow the
#: air the airframe feels, in flight only (on the ground it keeps its last estimate).
WIND_EST_TAU = 2.0
#: The random gusts are one field over space (:class:`GustField`): Fourier modes per
#: axis, and the smallest correlation length they get (m).
GUST_MODES = 48
GUST_MIN_LENGTH = 10.0
#: Below this height the landing descent slows to the land speed (ArduCopter LAND_ALT_LOW).
LAND_SLOW_HEIGHT = 10.0
#: Full battery lasts this long hovering (s); idle on the ground draws a tenth of that.
HOVER_ENDURANCE_S = 1200.0


def _norm(v: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of ``v`` (..., k), keeping the last axis (..., 1): what
    ``np.linalg.norm(v, axis=-1, keepdims=True)`` gives, bit for bit, without its Python
    wrapper (a physics step at 50 Hz calls it a dozen times on a few rows)."""
    return np.sqrt(np.add.reduce(v * v, axis=-1, keepdims=True))


def _clip(x: np.ndarray, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
    """``np.clip(x, lo, hi)`` (its definition: the minimum of the maximum), without its
    Python wrapper."""
    return np.minimum(np.maximum(x, lo), hi)


def _limit_norm(v: np.ndarray, limit: np.ndarray | float) -> np.ndarray:
    """Scale the rows of ``v`` (..., k) down to norm ``limit`` where they exceed it."""
    norm = _norm(v)
    lim = np.asarray(limit, dtype=float)
    if lim.ndim:
        lim = lim[..., None]
    scale = np.minimum(1.0, lim / np.maximum(norm, 1e-12))
    return v * scale


def _sqrt_controller_hv(err: np.ndarray, p: np.ndarray, accel: np.ndarray,
                        limit_h: np.ndarray | float = np.inf) -> np.ndarray:
    """ArduPilot's ``sqrt_controller`` on ``(n, 3)`` errors: horizontally on the xy norm,
    along the error's direction, its output limited to norm ``limit_h``; vertically on
    its own.  ``p`` and ``accel`` are ``(2,)``: (horizontal, vertical).

    Output for an error of size d: ``p * d`` (linear) inside ``accel / p²``, the
    constant-deceleration braking curve ``sqrt(2 accel (d - accel / 2p²))`` outside, so
    that a far target is approached at a speed from which the vehicle can still stop.

    Both magnitudes go through the controller as one array, and the horizontal limit
    applies to the output's magnitude, which the controller computes anyway (a fleet's
    physics step at 50 Hz makes three of these calls on a few rows; numpy's per-call
    cost, not the arithmetic, is what they cost).
    """
    mag = np.empty((err.shape[0], 2))
    mag[:, 0] = np.sqrt(err[:, 0] * err[:, 0] + err[:, 1] * err[:, 1])
    mag[:, 1] = np.abs(err[:, 2])
    linear = accel / (p * p)
    out = np.where(mag <= linear, p * mag,
                   np.sqrt(np.maximum(2.0 * accel * (mag - linear / 2.0), 0.0)))
    res = np.empty_like(err)
    res[:, :2] = err[:, :2] * (np.minimum(out[:, 0], limit_h)
                               / np.maximum(mag[:, 0], 1e-12))[:, None]
    res[:, 2] = np.sign(err[:, 2]) * out[:, 1]
    return res


class GustField:
    """Slow random gusts as one wind field over the show, not one per vehicle.

    A gust is a lump of air tens of metres across: drones 1.5-3 m apart in a
    formation meet nearly the same one, and what pushes them towards each other
    is the difference, not the gust.  (Independent gusts per vehicle, as separate
    SITL instances have, move neighbours apart and together by the full gust:
    measured on the demo in 6 m/s gusting about 4 m/s, independent gusts took
    pairs planned 1.7 m apart down to 1.21 m.)

    The field is a sum of ``modes`` random Fourier modes per axis (kinematic
    simulation): wavevectors drawn from a Gaussian of standard deviation
    1/``length`` per component, frequencies from one of 1/``tau``, random
    phases.  Each axis is then a stationary Gaussian field of standard deviation
    ``std`` with correlation exp(-r^2 / 2 length^2) in space and
    exp(-t^2 / 2 tau^2) in time at a fixed point.  ``length`` follows Taylor's
    frozen-turbulence argument -- a gust that lasts ``tau`` at a point is the
    mean wind times ``tau`` long -- and is never below ``GUST_MIN_LENGTH``
    (well below the 100-150 m integral scale of MIL-F-8785C's low-altitude
    model at show heights: the conservative side).
    """

    def __init__(self, std: float, length: float, tau: float, rng: np.random.Generator,
                 modes: int = GUST_MODES) -> None:
        if not (std >= 0 and length > 0 and tau > 0 and modes >= 1):
            raise ValueError("`std` must be non-negative, `length`, `tau` and `modes` positive")
        self.std, self.length, self.tau = float(std), float(length), float(tau)
        self.wavevectors = rng.standard_normal((3, modes, 3)) / self.length
        """(axis, mode, xyz) 1/m."""
        self.frequencies = rng.standard_normal((3, modes)) / self.tau
        """(axis, mode) rad/s."""
        self.phases = rng.uniform(0.0, 2.0 * np.pi, (3, modes))
        self._amp = self.std * np.sqrt(2.0 / modes)

    def at(self, positions: np.ndarray, t: float) -> np.ndarray:
        """(n, 3) gust at ``positions`` (n, 3) m and time ``t`` s."""
        phase = np.einsum("nd,amd->nam", positions, self.wavevectors) \
            + (self.frequencies * t + self.phases)[None]
        return np.asarray(self._amp * np.cos(phase).sum(axis=2))


def _ou_step(x: np.ndarray, sigma: float | np.ndarray, tau: float, dt: float,
             rng: np.random.Generator) -> np.ndarray:
    """``x`` one step ``dt`` on of a stationary Ornstein-Uhlenbeck process of standard
    deviation ``sigma`` and correlation time ``tau`` (the GPS error, the velocity
    estimate's bias, the airframe's wander)."""
    k = dt / tau
    return x + (-x * k + sigma * np.sqrt(2 * k) * rng.standard_normal(x.shape))


class FleetPhysics:
    """State and dynamics of ``n`` vehicles; mutate the targets, then :meth:`step`."""

    def __init__(self, homes_enu: np.ndarray, dynamics: Dynamics, rng: np.random.Generator,
                 wind: tuple[float, float, float] | Wind = (0.0, 0.0, 0.0),
                 gust_std: float = 0.0, gps_noise_m: float = 0.0,
                 bias_rng: np.random.Generator | None = None) -> None:
        n = homes_enu.shape[0]
        self.n = n
        self.dyn = dynamics
        d = dynamics
        j = d.max_jerk
        a_h, a_v = d.max_accel_xy, d.max_accel_z
        # Gains and accelerations of the three sqrt controllers, (horizontal, vertical).
        self._shape_pos = (np.array([0.5 * j / a_h, 0.5 * j / a_v]),
                           np.array([0.5 * a_h, 0.5 * a_v]))
        self._shape_vel = (np.array([j / a_h, j / a_v]), np.array([j, j]))
        self._pos_loop = (np.array([d.pos_p, d.pos_p_z]), np.array([a_h, a_v]))
        self._vel_p = np.array([d.vel_p, d.vel_p, d.vel_p_z])
        self._vel_i = np.array([d.vel_i, d.vel_i, d.vel_i_z])
        self._lag = np.array([d.response_tau, d.response_tau, d.response_tau_z])
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
        self.des_pos = self.pos.copy()
        """Desired path the loops follow (the shaped target with ``input_shaping``), ENU m."""
        self.des_vel = np.zeros((n, 3))
        """Velocity of the desired path, ENU m/s."""
        self.des_acc = np.zeros((n, 3))
        """Acceleration of the desired path (fed forward), ENU m/s²."""
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
        self.carry = np.zeros((n, 3))
        """Velocity at which an outside push carries each vehicle, ENU m/s (a fault): it
        moves the vehicle whatever its autopilot does, and its GPS sees it."""
        self.authority = np.ones(n)
        """Fraction of its speed and acceleration authority each vehicle has (a weak motor
        or battery fault: it cannot keep up), in (0, 1]."""
        weather = wind if isinstance(wind, Wind) else Wind(
            mean=(float(wind[0]), float(wind[1]), float(wind[2])))
        self.weather = weather
        """Wind model: mean, height profile, turbulence."""
        self.wind_mean = np.asarray(weather.mean, dtype=float)
        """Mean wind, ENU (m/s), at the profile's reference height."""
        self.turbulence = np.zeros((n, 3))
        """Turbulence acting on each vehicle over the last step (m/s)."""
        self._turb_state = np.zeros((n, 3))
        self.gust_std = float(gust_std)
        """Random gust standard deviation (m/s)."""
        self.gust = np.zeros((n, 3))
        """Current random gust at each vehicle (m/s)."""
        self.gust_field = None if self.gust_std <= 0 else GustField(
            self.gust_std, max(float(np.linalg.norm(weather.mean)) * GUST_TAU, GUST_MIN_LENGTH),
            GUST_TAU, rng)
        """The gusts' wind field (None without gusts)."""
        self.gust_extra = np.zeros((n, 3))
        """Injected gusts (fault), m/s."""
        self.wind_est = np.zeros((n, 3))
        """Each autopilot's own wind estimate, ENU m/s (:data:`WIND_EST_TAU`)."""
        self.gps_noise_m = float(gps_noise_m)
        """Standard deviation of the slowly varying estimate error (m)."""
        self.gps_err = np.zeros((n, 3))
        """Slowly varying estimate error (m)."""
        self.gps_noise_scale = np.ones(n)
        """Per-vehicle factor on ``gps_noise_m`` (its GPS fix type: RTK)."""
        self.glitch = np.zeros((n, 3))
        """Injected GPS glitch offset (m)."""
        self.vel_bias = np.zeros((n, 3))
        """Bias of each autopilot's velocity estimate (horizontal, m/s): its position loop
        holds it ``bias / pos_p`` off its target (:attr:`Dynamics.velocity_bias`)."""
        self._bias_rng = bias_rng if bias_rng is not None else np.random.default_rng(0)
        if self.dyn.velocity_bias > 0:  # from the stationary distribution: no settling
            self.vel_bias[:, :2] = self.dyn.velocity_bias * self._bias_rng.standard_normal(
                (n, 2))
        self.airframe_acc = np.zeros((n, 3))
        """The airframe's random acceleration, ENU m/s² (:attr:`Dynamics.airframe_noise`)."""
        # A stream of its own, spawned from the bias's generator (which leaves that
        # generator's own draws as they were without it).
        self._airframe_sigma = np.array([d.airframe_noise, d.airframe_noise,
                                         d.airframe_noise_z])
        self._airframe_rng = self._bias_rng.spawn(1)[0] if self._airframe_sigma.any() \
            else None
        if self._airframe_rng is not None:  # stationary from the start, as the bias
            self.airframe_acc = self._airframe_sigma * self._airframe_rng.standard_normal(
                (n, 3))

    # -- derived ----------------------------------------------------------------------------

    @property
    def ground_vel(self) -> np.ndarray:
        """Velocity over the ground (what GPS measures): its own plus any push carrying it."""
        return self.vel + self.carry

    @property
    def est_pos(self) -> np.ndarray:
        """Position the autopilots believe (truth + GPS error + glitch)."""
        return self.pos + self.gps_err + self.glitch

    @property
    def height(self) -> np.ndarray:
        """Height above the ground under each vehicle (m)."""
        return self.pos[:, 2] - self.ground_z

    def wind_at(self) -> np.ndarray:
        """Mean wind at each vehicle's height, ``(n, 3)`` ENU m/s (before turbulence, gusts)."""
        w = self.weather
        speed = float(_norm(self.wind_mean)[0])
        if w.profile is WindProfile.CONSTANT or speed == 0.0:
            out = np.empty((self.n, 3))
            out[:] = self.wind_mean
            return out
        h = np.maximum(self.height, 0.0)
        if w.profile is WindProfile.SQRT:
            scale = np.sqrt(np.minimum(h / w.ref_height, 1.0))
        else:
            scale = np.maximum(speed + (h - w.ref_height) * w.coef, 0.0) / speed
        return scale[:, None] * self.wind_mean

    # -- dynamics ---------------------------------------------------------------------------

    def _inputs(self, landing: np.ndarray, descent: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What each axis tracks: target position, velocity, acceleration, position used."""
        p_in = self.tgt_pos.copy()
        v_in = np.where(self.use_vel[:, None], self.tgt_vel, 0.0)
        a_in = np.where(self.use_acc[:, None], self.tgt_acc, 0.0)
        pos_on = np.repeat(self.use_pos[:, None], 3, axis=1)
        # Landing: a descent rate, no height target (horizontally the target holds).
        pos_on[:, 2] &= ~landing
        v_in[:, 2] = np.where(landing, -descent, v_in[:, 2])
        a_in[:, 2] = np.where(landing, 0.0, a_in[:, 2])
        return p_in, v_in, a_in, pos_on

    def _shape(self, p_in: np.ndarray, v_in: np.ndarray, a_in: np.ndarray,
               pos_on: np.ndarray, dt: float) -> None:
        """Move the desired path towards the target along a jerk-limited kinematic path.

        AC_PosControl's input shaping: position error -> velocity (sqrt controller
        of gain jerk / (2 accel) braking at half the acceleration limit), velocity
        error -> acceleration (gain jerk / accel), the target's acceleration added,
        and the path's acceleration slewed at the jerk limit.  Horizontal on the
        xy norm, vertical on its own.
        """
        d = self.dyn
        jerk = d.max_jerk
        # The path first moves on with what it had (update_pos_vel_accel).
        self.des_pos += self.des_vel * dt + 0.5 * self.des_acc * dt * dt
        self.des_vel += self.des_acc * dt

        e = np.where(pos_on, p_in - self.des_pos, 0.0)
        v_t = _sqrt_controller_hv(e, *self._shape_pos, d.max_speed_xy)
        v_t[:, 2] = _clip(v_t[:, 2], -d.max_speed_down, self.climb_limit)
        v_t += v_in
        v_t[:, 2] = _clip(v_t[:, 2], -d.max_speed_down, self.climb_limit)
        a_t = _sqrt_controller_hv(v_t - self.des_vel, *self._shape_vel, d.max_accel_xy)
        a_z = d.max_accel_z
        a_t[:, 2] = _clip(a_t[:, 2], -a_z, a_z)
        a_t += a_in
        self.des_acc[:, :2] += _limit_norm(a_t[:, :2] - self.des_acc[:, :2], jerk * dt)
        self.des_acc[:, 2] += _clip(a_t[:, 2] - self.des_acc[:, 2], -jerk * dt, jerk * dt)

    def _advance_targets(self, dt: float, rows: slice | list[int] = slice(None)) -> None:
        """GUIDED between messages: the position target moves with the velocity target,
        the velocity target with the acceleration target (``rows``: the whole fleet, or
        the vehicles listed)."""
        use_vel = self.use_vel[rows]
        vel = use_vel[:, None]
        acc = (use_vel & self.use_acc[rows])[:, None]
        move = (self.use_pos[rows] & use_vel)[:, None]
        a = np.where(acc, self.tgt_acc[rows], 0.0)
        self.tgt_pos[rows] += np.where(move, self.tgt_vel[rows] * dt + 0.5 * a * dt * dt, 0.0)
        self.tgt_vel[rows] += np.where(vel, a * dt, 0.0)

    def step(self, dt: float) -> None:
        """Advance the whole fleet by ``dt`` seconds."""
        if not dt > 0:
            raise ValueError("`dt` must be positive")
        d = self.dyn
        n = self.n
        flying_mode = (self.mode >= CTRL_TRACK) & ~self.motor_failed
        self.spool = np.where(flying_mode, np.maximum(self.spool - dt, 0.0), self.spool)
        powered = flying_mode & (self.spool <= 0.0)
        landing = self.mode == CTRL_LAND
        descent = np.where(self.height > LAND_SLOW_HEIGHT, d.max_speed_down, d.land_speed)

        # Desired path: the shaped target (ArduCopter) or the setpoint itself (PX4).
        p_in, v_in, a_in, pos_on = self._inputs(landing, descent)
        if d.input_shaping:
            self._shape(p_in, v_in, a_in, pos_on, dt)
            # AC_PosControl keeps correcting onto the path even under a velocity
            # target (GUIDED's default position stabilisation); a landing has no
            # height to hold.
            fb = np.ones((n, 3), dtype=bool)
            fb[:, 2] = ~landing
        else:
            self.des_pos[:] = p_in
            self.des_vel[:] = v_in
            self.des_acc[:] = a_in
            fb = pos_on
        if d.advance_target:
            self._advance_targets(dt)

        # Position loop (horizontal on the xy norm, vertical on its own, as both autopilots do).
        err = np.where(fb, self.des_pos - self.est_pos, 0.0)
        v_dem = _sqrt_controller_hv(err, *self._pos_loop)
        v_dem += self.des_vel
        auth = self.authority
        v_dem[:, :2] = _limit_norm(v_dem[:, :2], d.max_speed_xy * auth)
        v_dem[:, 2] = _clip(v_dem[:, 2], -d.max_speed_down * auth, self.climb_limit * auth)

        # Velocity loop: P + I, the path's acceleration fed forward, the whole command
        # limited once, at the lean-angle limit (nothing is clipped before the sum, so
        # the integrator can carry a steady wind up to the airframe's authority).
        v_err = v_dem - (self.vel + self.vel_bias)
        a_dem = self.des_acc + self._vel_p * v_err + self._vint
        a_lim = a_dem.copy()
        a_lim[:, :2] = _limit_norm(a_dem[:, :2], d.max_tilt_accel * auth)
        a_lim[:, 2] = _clip(a_dem[:, 2], -d.thrust_accel_z * auth, d.thrust_accel_z * auth)
        self._integrate(v_err, a_dem, a_lim, dt)
        if d.input_shaping:
            self._acc_dem = a_lim  # the path is already jerk-limited
        else:
            self._acc_dem = self._acc_dem + _limit_norm(a_lim - self._acc_dem, d.max_jerk * dt)
        lag = np.minimum(1.0, dt / self._lag)
        acc = self.acc + (self._acc_dem - self.acc) * lag
        # Unpowered: no thrust at all, the vehicle falls (or rests on the ground).
        acc = np.where(powered[:, None], acc, np.array([0.0, 0.0, -GRAVITY]))
        self.acc = acc

        # Wind: mean (height profile) + turbulence + slow gusts + injected gusts; a force
        # through drag on the air-relative velocity.
        airborne = ~self.on_ground | (acc[:, 2] > 0)
        self._update_turbulence(dt, airborne)
        if self.gust_field is not None:
            self.gust = self.gust_field.at(self.pos, self.t)
        wind = self.wind_at() + self.turbulence + self.gust + self.gust_extra
        air = wind - self.vel
        follow = np.where(airborne & ~self.on_ground, min(dt / WIND_EST_TAU, 1.0), 0.0)
        self.wind_est += follow[:, None] * (wind - self.wind_est)
        drag = (d.drag + d.drag_quad * _norm(air)) * air
        total = acc + np.where(airborne[:, None], drag, 0.0)
        if self._airframe_rng is not None:
            self.airframe_acc = _ou_step(self.airframe_acc, self._airframe_sigma,
                                         d.airframe_noise_tau, dt, self._airframe_rng)
            total += np.where((powered & ~self.on_ground)[:, None], self.airframe_acc, 0.0)
        self.vel = self.vel + total * dt
        self.pos = self.pos + (self.vel + self.carry) * dt

        # Ground contact: clamp, stop, detect crashes.
        below = self.pos[:, 2] <= self.ground_z
        self.on_ground = below
        resting = below
        if below.any():  # (in flight nobody is: the rest of this block is a no-op then)
            self.crashed |= below & (self.vel[:, 2] < -CRASH_SPEED)
            self.pos[:, 2] = np.where(below, self.ground_z, self.pos[:, 2])
            self.vel = np.where(below[:, None], 0.0, self.vel)
            resting = below & ~(powered & (v_dem[:, 2] > 0))
        self.ground_time = np.where(resting, self.ground_time + dt, 0.0)
        if resting.any():
            # On the ground the controllers start afresh (AC_PosControl's init_controller):
            # no integrator wind-up before lift-off, the path starts where the vehicle is.
            rest = resting[:, None]
            self._vint = np.where(rest, 0.0, self._vint)
            self._acc_dem = np.where(rest, 0.0, self._acc_dem)
            self.acc = np.where(rest, 0.0, self.acc)
            self.des_pos = np.where(rest, self.est_pos, self.des_pos)
            self.des_vel = np.where(rest, 0.0, self.des_vel)
            self.des_acc = np.where(rest, 0.0, self.des_acc)

        # Estimate error: slow OU process, as an EKF fed by a GPS wanders.
        if self.gps_noise_m > 0:
            self.gps_err = _ou_step(self.gps_err, (self.gps_noise_m * self.gps_noise_scale)[
                :, None], GPS_TAU, dt, self.rng)

        if d.velocity_bias > 0:
            self.vel_bias[:, :2] = _ou_step(self.vel_bias[:, :2], d.velocity_bias,
                                            d.velocity_bias_tau, dt, self._bias_rng)

        # Battery: hover draw when flying, a tenth of it idling armed.
        draw = np.where(powered & ~self.on_ground, 1.0, np.where(self.mode > CTRL_OFF, 0.1, 0.0))
        self.battery = np.maximum(self.battery - draw * dt / HOVER_ENDURANCE_S, 0.0)
        self.t += dt

    def _integrate(self, v_err: np.ndarray, a_dem: np.ndarray, a_lim: np.ndarray,
                   dt: float) -> None:
        """Velocity integrator with AC_PID_2D's anti-windup.

        While the command is limited, the part of the integrator's growth along the
        unlimited command (the direction it is limited in) is dropped: the
        integrator can still shrink, or grow sideways, but never wind up against
        the limit.  It integrates at any velocity error otherwise; a steady wind is
        learnt even while the vehicle is being blown away.
        """
        d = self.dyn
        grow = self._vel_i * v_err * dt
        lim_xy = a_dem[:, :2] - a_lim[:, :2]
        limited = _norm(lim_xy) > 1e-9
        if limited.any():
            u = a_dem[:, :2] / np.maximum(_norm(a_dem[:, :2]), 1e-12)
            along = np.sum(grow[:, :2] * u, axis=1, keepdims=True)
            drop = limited & (along > 0)
            grow[:, :2] -= np.where(drop, along * u, 0.0)
        lim_z = a_dem[:, 2] != a_lim[:, 2]
        grow[:, 2] = np.where(lim_z & (grow[:, 2] * a_dem[:, 2] > 0), 0.0, grow[:, 2])
        self._vint = self._vint + grow
        self._vint[:, :2] = _limit_norm(self._vint[:, :2], d.vel_imax)
        self._vint[:, 2] = _clip(self._vint[:, 2], -d.vel_imax_z, d.vel_imax_z)

    def _update_turbulence(self, dt: float, airborne: np.ndarray) -> None:
        """SITL-like turbulence: Ornstein-Uhlenbeck winds, none on the ground.

        SITL low-passes a random speed of std SIM_WIND_TURB (0.98 IIR per 1200 Hz
        step: 42 ms) and points it horizontally at a fresh random azimuth every step,
        so its horizontal turbulence decorrelates within a step (nearly white: it
        hardly moves a vehicle) while the vertical keeps the 42 ms; both are
        reproduced here, std split 1/sqrt(2) over the horizontal axes.

        What acts on the vehicle during a step is the process's *average* over the
        step, drawn jointly with its end value (both Gaussian given the start): a
        correlation time shorter than the physics step then still delivers the
        right impulse, and the result does not depend on the physics rate.
        """
        w = self.weather
        if w.turbulence <= 0:
            return
        tau = np.array([w.turbulence_tau_xy, w.turbulence_tau_xy, w.turbulence_tau])
        r = dt / tau
        a = np.exp(-r)
        # Per unit variance: end value, step average, their covariance (Cholesky).
        var_end = 1.0 - a * a
        var_avg = (2.0 * r - 3.0 + 4.0 * a - a * a) / (r * r)
        cov = (1.0 - a) ** 2 / r
        l11 = np.sqrt(var_end)
        l21 = cov / l11
        l22 = np.sqrt(np.maximum(var_avg - l21 * l21, 0.0))
        std = w.turbulence * np.array([np.sqrt(0.5), np.sqrt(0.5), 1.0])
        z = self.rng.standard_normal((2, self.n, 3)) * std
        x0 = self._turb_state
        ground = ~airborne[:, None]
        self.turbulence = np.where(ground, 0.0, x0 * (1.0 - a) / r + l21 * z[0] + l22 * z[1])
        self._turb_state = np.where(ground, 0.0, a * x0 + l11 * z[0])

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
                   acc: np.ndarray | None, since: float = 0.0) -> None:
        """Track ``pos`` / ``vel`` / ``acc`` (None: not used), in the show frame, given
        ``since`` seconds ago (it arrived between two steps).  An autopilot that advances
        its target between messages (:attr:`Dynamics.advance_target`: ArduCopter's GUIDED,
        on its 400 Hz loop) has advanced it that long already when the next step runs: the
        physics' 50 Hz step does not add up to a step's lag to its response."""
        if pos is not None:
            self.tgt_pos[i] = pos
        self.use_pos[i] = pos is not None
        self.tgt_vel[i] = vel if vel is not None else 0.0
        self.use_vel[i] = vel is not None
        self.tgt_acc[i] = acc if acc is not None else 0.0
        self.use_acc[i] = acc is not None
        if since > 0 and self.dyn.advance_target:
            self._advance_targets(since, [i])
