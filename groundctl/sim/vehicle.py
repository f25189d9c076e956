"""One simulated vehicle's MAVLink behaviour, without I/O.

:meth:`Vehicle.handle` takes a decoded message and the simulated time and
returns the messages to send back; :meth:`Vehicle.tick` runs the timers
(heartbeat, requested streams, TIMESYNC, failsafes) and returns what is due.
The vehicle steers its row ``i`` of the shared :class:`FleetPhysics`.

What both autopilots share lives here (streams, parameters, TIMESYNC,
setpoint decoding, arming bookkeeping, landing and RTL sequencing, the
heading, STATUSTEXT chunking); the flavour subclasses
(:mod:`~groundctl.sim.ardupilot`, :mod:`~groundctl.sim.px4`) decide what is
allowed and how each mode behaves.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, TypeAlias

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import MODE_FLAG_CUSTOM, Flavour, encode_mode, mode_from_set_mode
from groundctl.link.messages import FORCE_MAGIC
from groundctl.sim import physics as P
from groundctl.sim import telemetry as T
from groundctl.sim.config import SimConfig
from groundctl.sim.fence import FENCE, FenceServer
from groundctl.sim.frames import FleetFrames
from groundctl.sim.params import ParamStore
from groundctl.sim.rtk import NOISE_M, RtkReceiver

Msg: TypeAlias = mavlink.MAVLink_message

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
DENIED = mavlink.MAV_RESULT_DENIED
FAILED = mavlink.MAV_RESULT_FAILED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
TEMP_REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED

#: SET_POSITION_TARGET type_mask groups (POSITION_TARGET_TYPEMASK).
MASK_POS = 0x007
MASK_VEL = 0x038
MASK_ACC = 0x1C0
MASK_YAW = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
MASK_YAW_RATE = mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
#: Bytes of text one STATUSTEXT carries.
STATUSTEXT_LEN = 50
#: Both autopilots send their own TIMESYNC request about every 10 s.
TIMESYNC_PERIOD = 10.0


@dataclass
class Stream:
    """A message sent periodically at the ground station's request."""

    interval: float
    """Seconds between messages."""
    due: float
    """Simulated time of the next one."""


@dataclass(frozen=True)
class Setpoint:
    """A decoded setpoint in the show frame (None: that part is ignored by type_mask)."""

    pos: np.ndarray | None
    """Position, show-frame ENU m."""
    vel: np.ndarray | None
    """Velocity (feed-forward with a position), ENU m/s."""
    acc: np.ndarray | None
    """Acceleration (feed-forward), ENU m/s²."""
    yaw: float | None = None
    """Heading, rad clockwise from north (the vehicle's NED frame)."""
    yaw_rate: float | None = None
    """Yaw rate, rad/s (clockwise seen from above)."""


def wrap_pi(angle: float) -> float:
    """``angle`` in [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass
class Heading:
    """A vehicle's yaw and what its yaw controller is asked to do.

    Kept here rather than in :mod:`~groundctl.sim.physics`: nothing in the
    point-mass model depends on where the nose points, only the telemetry does.
    The model is the attitude controller's outer loop: a P controller on the
    heading error plus the commanded rate, limited to the autopilot's yaw-rate
    limit (ArduCopter ATC_SLEW_YAW, PX4 MC_YAWRATE_MAX).
    """

    yaw: float = 0.0
    """Heading, rad clockwise from north, in [-pi, pi)."""
    rate: float = 0.0
    """Yaw rate the vehicle turns at now, rad/s."""
    target: float | None = None
    """Heading to turn to (None: no heading target)."""
    target_rate: float = 0.0
    """Commanded yaw rate: the rate the target heading moves at, or (no target) the rate
    to turn at, rad/s."""
    face_travel: bool = False
    """Turn to face the direction of horizontal travel (ArduCopter's auto yaw in GUIDED),
    holding the heading while slower than the autopilot's threshold."""

    def hold(self) -> None:
        """Keep the current heading (yaw ignored)."""
        self.target, self.target_rate, self.face_travel = None, 0.0, False

    def command(self, yaw: float | None, yaw_rate: float | None) -> None:
        """Turn to ``yaw`` (moving on at ``yaw_rate`` if given), or at ``yaw_rate``."""
        self.face_travel = False
        self.target = None if yaw is None else wrap_pi(yaw)
        self.target_rate = 0.0 if yaw_rate is None else yaw_rate

    def step(self, dt: float, flying: bool, max_rate: float, gain: float,
             travel: float | None = None) -> None:
        """Advance ``dt`` s; ``travel`` is the direction of travel when fast enough to face it."""
        if not flying:
            self.rate = 0.0  # on the ground the motors do not turn the airframe
            return
        if self.target is not None:
            self.target = wrap_pi(self.target + self.target_rate * dt)
        target = travel if self.face_travel else self.target
        if target is not None:
            rate = gain * wrap_pi(target - self.yaw) + (0.0 if self.face_travel
                                                          else self.target_rate)
        else:
            rate = 0.0 if self.face_travel else self.target_rate
        self.rate = max(-max_rate, min(max_rate, rate))
        self.yaw = wrap_pi(self.yaw + self.rate * dt)


class Vehicle:
    """Behaviour common to both autopilots; see the flavour subclasses."""

    flavour: ClassVar[Flavour]
    boot_mode: ClassVar[str]
    #: Modes in which the vehicle reports MAV_MODE_FLAG_GUIDED_ENABLED.
    guided_modes: ClassVar[frozenset[str]] = frozenset()
    #: Whether LED_CONTROL (an ardupilotmega message) does anything.
    supports_led: ClassVar[bool] = True
    #: MAV_RESULT for DO_SET_MODE without the custom flag or with an unknown mode.
    unknown_mode_result: ClassVar[int] = UNSUPPORTED
    arm_refused_result: ClassVar[int] = FAILED
    #: Messages of the other autopilot that this one has no stream for (its wind estimate:
    #: ArduPilot sends WIND, PX4 WIND_COV).
    foreign_messages: ClassVar[frozenset[int]] = frozenset()
    """How a failing arming check is coded (ArduPilot FAILED, PX4 TEMPORARILY_REJECTED)."""
    #: Modes MAV_CMD_NAV_LAND and MAV_CMD_NAV_RETURN_TO_LAUNCH switch to.
    land_mode: ClassVar[str]
    rtl_mode: ClassVar[str]
    #: Raw text lines the autopilot prints on its MAVLink port at boot, before MAVLink
    #: starts (ArduPilot SITL's console is its first serial port); none by default.
    boot_text: ClassVar[tuple[str, ...]] = ()

    def __init__(self, index: int, sysid: int, config: SimConfig, physics: P.FleetPhysics,
                 frames: FleetFrames, boot_time: float, unix_at_boot: float) -> None:
        self.i = index
        self.sysid = sysid
        self.config = config
        self.ph = physics
        self.frames = frames
        self.boot_time = boot_time
        self.unix_at_boot = unix_at_boot
        self.params = ParamStore(self.flavour, sysid, config.params, physics.dyn)
        self.home_enu = physics.pos[index].copy()
        self.home_lla = tuple(float(x) for x in frames.geodetic(self.home_enu))
        self.mode = self.boot_mode
        self.armed = False
        self.failsafe = False
        self.led: tuple[int, int, int] = (0, 0, 0)
        self.led_blink_hz = 0.0
        self.led_changed_at: float | None = None
        self.streams: dict[int, Stream] = {}
        self.setpoints_dropped = 0
        self.arm_refusals: list[str] = []
        """Reasons (STATUSTEXT) to refuse the next arm commands with, one each (a fault)."""
        self.lost_acks: dict[int, int] = {}
        """MAV_CMD -> how many of its next COMMAND_ACKs are lost on the way (a fault: the
        command is carried out, its answer never arrives)."""
        self.last_gcs_heartbeat: float | None = None
        self.last_setpoint: float | None = None
        self.message_age = 0.0
        """How long before the physics step acting on it the message in hand arrived, s."""
        self.setpoint_kind = "none"  # "pos", "posvel", "vel", "acc"
        self.takeoff_alt: float | None = None  # ENU z the current takeoff climbs to
        self.rtl_phase: str | None = None
        self.rtl_alt = 0.0
        self.heading = Heading()
        """Where the nose points and what the yaw controller was asked."""
        self._last_tick: float | None = None
        self._statustext_id = 0
        self._out: list[Msg] = []
        self._next_heartbeat = boot_time
        self._next_timesync = boot_time + TIMESYNC_PERIOD
        self._origin_announced = False
        self._booted = False
        self.fence = FenceServer(sysid)
        """The uploaded fence (mission protocol, MAV_MISSION_TYPE_FENCE)."""
        self._fence_enu: tuple[int, np.ndarray | None] = (-1, None)
        self.rtk = RtkReceiver()
        """GPS_RTCM_DATA reassembly, CRC checks and the RTK fix (:mod:`groundctl.sim.rtk`)."""
        self._rtk_fix: int | None = None

    # -- facts --------------------------------------------------------------------------------

    def time_since_boot(self, now: float) -> float:
        """Seconds since this vehicle booted (the clock of time_boot_ms and TIMESYNC)."""
        return max(0.0, now - self.boot_time)

    def origin_set(self, now: float) -> bool:
        """Whether the EKF origin is set (LOCAL_POSITION_NED flows from then on)."""
        return self.time_since_boot(now) >= self.config.ekf_origin_delay_s

    def ready_to_arm(self, now: float) -> bool:
        """Whether the position estimate is good enough to arm."""
        return self.time_since_boot(now) >= max(self.config.ready_delay_s,
                                                self.config.ekf_origin_delay_s)

    @property
    def flying(self) -> bool:
        """Motors producing lift (taking off, flying or landing), not resting."""
        return bool(self.ph.mode[self.i] >= P.CTRL_TRACK and not self.ph.on_ground[self.i])

    def custom_mode(self) -> int:
        """HEARTBEAT.custom_mode of the current mode."""
        return encode_mode(self.flavour, self.mode)

    def guided_flag(self) -> bool:
        """Whether HEARTBEAT sets MAV_MODE_FLAG_GUIDED_ENABLED."""
        return self.mode in self.guided_modes

    def landed_state(self) -> int:
        """MAV_LANDED_STATE for EXTENDED_SYS_STATE."""
        if self.ph.on_ground[self.i] and not self.flying:
            if self.armed and self.ph.mode[self.i] == P.CTRL_TRACK and self.ph.spool[self.i] > 0:
                return mavlink.MAV_LANDED_STATE_TAKEOFF
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.ph.mode[self.i] == P.CTRL_LAND:
            return mavlink.MAV_LANDED_STATE_LANDING
        if self.takeoff_alt is not None:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def battery_readings(self) -> tuple[int, int, int]:
        """(voltage mV, current cA, remaining %) of a 4S pack."""
        frac = float(self.ph.battery[self.i])
        current = 1800 if self.flying else (100 if self.armed else 50)
        return self.battery_mv(), current, round(frac * 100)

    def battery_mv(self) -> int:
        """The pack's voltage, mV (a 4S pack, 3.5-4.2 V a cell with its charge)."""
        return int((4 * (3.5 + 0.7 * float(self.ph.battery[self.i]))) * 1000)

    # -- I/O-free interface -------------------------------------------------------------------

    def handle(self, msg: Msg, now: float, age: float = 0.0) -> list[Msg]:
        """React to one decoded message from the ground station; returns the replies.
        ``age``: how long before ``now`` (a physics step) it arrived (:meth:`apply_setpoint`
        takes a setpoint up as of then)."""
        self.message_age = age
        try:
            handler = self._HANDLERS.get(msg.get_type())
            if handler is not None:
                handler(self, msg, now)
        except (ValueError, TypeError, OverflowError, KeyError, IndexError):
            # A message that decodes but carries nonsense (NaN where an int is needed,
            # an out-of-range index) is ignored like a bad packet, never raised.
            pass
        finally:
            self.message_age = 0.0  # this message's: a setpoint re-flown later is not it
        return self._flush()

    def tick(self, now: float) -> list[Msg]:
        """Timers: heartbeat, streams, TIMESYNC requests, flight logic, failsafes."""
        if not self._booted:
            self._booted = True
            self._boot_messages(now)
        if now >= self._next_heartbeat:
            self._out.append(T.heartbeat(self, now))
            self._next_heartbeat = max(self._next_heartbeat + 1.0, now + 0.5)
        if now >= self._next_timesync:
            self._out.append(mavlink.MAVLink_timesync_message(0, self._now_ns(now)))
            self._next_timesync = now + TIMESYNC_PERIOD
        if not self._origin_announced and self.origin_set(now):
            self._origin_announced = True
            self._on_origin_set(now)
        if self.armed and self.ph.crashed[self.i]:
            self.statustext(mavlink.MAV_SEVERITY_EMERGENCY, "Crash: Disarming")
            self.disarm(now)
        self._out.extend(self.fence.tick(now))
        self._flight_logic(now)
        dt = 0.0 if self._last_tick is None else max(0.0, now - self._last_tick)
        self._last_tick = now
        max_rate, gain = self.yaw_control()
        self.heading.step(dt, self.flying, max_rate, gain, self.travel_heading())
        if self.config.rtk_noise:
            self._rtk_noise(now)
        self._send_streams(now)
        return self._flush()

    def gps_fix(self, now: float) -> int:
        """GPS_RAW_INT.fix_type: 3D a second after boot, RTK float / fixed on corrections."""
        base = mavlink.GPS_FIX_TYPE_3D_FIX if self.time_since_boot(now) > 1.0 else \
            mavlink.GPS_FIX_TYPE_NO_FIX
        return self.rtk.fix_type(now, base)

    def _rtk_noise(self, now: float) -> None:
        fix = self.gps_fix(now)
        if fix == self._rtk_fix:
            return
        sigma = NOISE_M.get(fix, NOISE_M[3])
        base = self.ph.gps_noise_m
        if base > 0:
            old = self.ph.gps_noise_m * self.ph.gps_noise_scale[self.i]
            self.ph.gps_noise_scale[self.i] = sigma / base
            if self._rtk_fix is not None and old > 0:
                self.ph.gps_err[self.i] *= sigma / old  # the receiver's solution jumps
        self._rtk_fix = fix

    def boot_lines(self) -> list[bytes]:
        """The boot text as raw datagrams (one line each), sent before any MAVLink."""
        return [b"\n" + line.encode("ascii", "replace") + b"\n" for line in self.boot_text]

    # -- helpers for subclasses ----------------------------------------------------------------

    def _flush(self) -> list[Msg]:
        out, self._out = self._out, []
        return out

    def _now_ns(self, now: float) -> int:
        return int(self.time_since_boot(now) * 1e9)

    def statustext(self, severity: int, text: str) -> None:
        """Queue a STATUSTEXT; a text longer than one message is sent in chunks."""
        for chunk_id, seq, part in self.statustext_chunks(text.encode("utf-8", "replace")):
            self._out.append(mavlink.MAVLink_statustext_message(severity, part, chunk_id, seq))

    def statustext_chunks(self, text: bytes) -> list[tuple[int, int, bytes]]:
        """``(id, chunk_seq, text)`` of the STATUSTEXT messages carrying ``text``.

        The flavour decides (ArduPilot and PX4 chunk differently); this default
        cuts the text to one message, as MAVLink 1 autopilots did.
        """
        return [(0, 0, text[:STATUSTEXT_LEN])]

    def _next_statustext_id(self, skip_zero: bool) -> int:
        """The next chunk-group id (uint16); ``skip_zero`` when 0 means "not chunked"."""
        self._statustext_id = (self._statustext_id + 1) & 0xFFFF
        if skip_zero and self._statustext_id == 0:
            self._statustext_id = 1
        return self._statustext_id

    def ack(self, msg: Msg, result: int) -> None:
        """Queue a COMMAND_ACK for ``msg`` addressed to its sender."""
        if self.lost_acks.get(msg.command, 0) > 0:
            self.lost_acks[msg.command] -= 1
            return
        self._out.append(mavlink.MAVLink_command_ack_message(
            msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _for_me(self, target_system: int) -> bool:
        return target_system in (0, self.sysid)

    def _send_streams(self, now: float) -> None:
        for msgid, stream in self.streams.items():
            if now + 1e-9 < stream.due:
                continue
            stream.due = max(stream.due + stream.interval, now + stream.interval / 2)
            if msgid in T.NEEDS_ORIGIN and not self.origin_set(now):
                continue  # e.g. no LOCAL_POSITION_NED before the EKF origin is set
            self._out.append(T.BUILDERS[msgid](self, now))

    def set_stream(self, msgid: int, interval: float | None, now: float) -> None:
        """Stream ``msgid`` every ``interval`` s (None or <= 0 stops it)."""
        if interval is None or interval <= 0:
            self.streams.pop(msgid, None)
        else:
            self.streams[msgid] = Stream(interval, now + interval)

    # -- flight actions shared by the flavours ---------------------------------------------

    def arm(self, now: float) -> None:
        """Arm: motors idle on the ground (the autopilot's disarm-delay timer starts)."""
        self.armed = True
        self.ph.mode[self.i] = P.CTRL_IDLE
        self.ph.ground_time[self.i] = 0.0
        self.ph.hold(self.i)
        self.ph.tgt_pos[self.i] = self.ph.est_pos[self.i]

    def disarm(self, now: float, reason: str = "") -> None:
        """Stop the motors (a vehicle in the air falls)."""
        self.armed = False
        self.ph.mode[self.i] = P.CTRL_OFF
        self.takeoff_alt = None
        self.rtl_phase = None
        self.heading.hold()

    def start_takeoff(self, height: float) -> None:
        """Spool up and climb ``height`` m above the current position, at takeoff speed."""
        d = self.ph.dyn
        i = self.i
        target = self.ph.est_pos[i].copy()
        target[2] = self.home_enu[2] + height
        self.ph.set_target(i, target, None, None)
        if self.ph.on_ground[i]:
            self.ph.spool[i] = d.takeoff_spool_s
        self.ph.mode[i] = P.CTRL_TRACK
        self.ph.climb_limit[i] = d.takeoff_speed
        self.takeoff_alt = float(target[2])

    def takeoff_reached(self) -> bool:
        """Whether a takeoff in progress got within 10 cm of its altitude."""
        if self.takeoff_alt is None:
            return False
        return bool(self.ph.est_pos[self.i, 2] >= self.takeoff_alt - 0.1)

    def end_takeoff(self) -> None:
        """Restore the normal climb limit after a takeoff."""
        self.takeoff_alt = None
        self.ph.climb_limit[self.i] = self.ph.dyn.max_speed_up

    def start_land(self) -> None:
        """Descend over the current position at the landing speed."""
        self.end_takeoff()
        self.rtl_phase = None
        if self.ph.mode[self.i] >= P.CTRL_TRACK:
            self.ph.hold(self.i)
            self.ph.mode[self.i] = P.CTRL_LAND

    def hold(self) -> None:
        """Brake and hold position (if flying)."""
        self.end_takeoff()
        self.rtl_phase = None
        if self.ph.mode[self.i] >= P.CTRL_TRACK:
            self.ph.hold(self.i)

    def start_rtl(self, alt: float) -> None:
        """Return to launch: climb to ``alt`` m above home, fly home, land."""
        self.end_takeoff()
        if self.ph.mode[self.i] < P.CTRL_TRACK or self.ph.on_ground[self.i]:
            self.rtl_phase = None
            return
        self.rtl_alt = self.home_enu[2] + alt
        self.rtl_phase = "climb"
        target = self.ph.est_pos[self.i].copy()
        target[2] = max(target[2], self.rtl_alt)
        self.ph.set_target(self.i, target, None, None)
        self.ph.mode[self.i] = P.CTRL_TRACK

    def _rtl_logic(self) -> None:
        i = self.i
        est = self.ph.est_pos[i]
        if self.rtl_phase == "climb" and abs(est[2] - self.ph.tgt_pos[i, 2]) < 0.5:
            self.rtl_phase = "return"
            target = self.home_enu.copy()
            target[2] = self.ph.tgt_pos[i, 2]
            self.ph.set_target(i, target, None, None)
        elif self.rtl_phase == "return" and np.hypot(*(est[:2] - self.home_enu[:2])) < 1.0:
            self.rtl_phase = "land"
            self.ph.mode[i] = P.CTRL_LAND

    def apply_setpoint(self, sp: Setpoint, now: float) -> None:
        """Fly to a setpoint (the flavour decided it is allowed)."""
        i = self.i
        self.end_takeoff()
        self.rtl_phase = None
        if sp.pos is None and sp.vel is None and sp.acc is None:
            self.ph.hold(i)
            return
        self.ph.set_target(i, sp.pos, sp.vel, sp.acc, since=self.message_age)
        if self.ph.mode[i] == P.CTRL_LAND:
            self.ph.mode[i] = P.CTRL_TRACK

    # -- decoding -----------------------------------------------------------------------------

    def decode_local(self, msg: Msg) -> Setpoint | None:
        """SET_POSITION_TARGET_LOCAL_NED to the show frame; None if the frame is unsupported."""
        mask = msg.type_mask
        if msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED:
            base = None
        elif msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED:
            base = self.ph.est_pos[self.i]
        else:
            return None
        pos = None
        if not mask & MASK_POS:
            ned = np.array([msg.x, msg.y, msg.z], dtype=float)
            if base is None:
                pos = self.frames.ned_to_show(self.i, ned)
            else:
                pos = base + self.frames.vec_ned_to_show(self.i, ned)
        vel, acc = self._feed_forward(msg, mask)
        return _finite(Setpoint(pos, vel, acc, *_yaw_fields(msg, mask)))

    def _feed_forward(self, msg: Msg, mask: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Velocity and acceleration of a position target (NED) in the show frame."""
        vel = acc = None
        if not mask & MASK_VEL:
            vel = self.frames.vec_ned_to_show(self.i, np.array([msg.vx, msg.vy, msg.vz], float))
        if not mask & MASK_ACC:
            acc = self.frames.vec_ned_to_show(
                self.i, np.array([msg.afx, msg.afy, msg.afz], float))
        return vel, acc

    def decode_global(self, msg: Msg) -> Setpoint | None:
        """SET_POSITION_TARGET_GLOBAL_INT to the show frame; None if the frame is unsupported."""
        frame = msg.coordinate_frame
        if frame in (mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL):
            alt_base = 0.0
        elif frame in (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                       mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                       mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT):
            alt_base = self.home_lla[2]
        else:
            return None
        mask = msg.type_mask
        pos = None
        if not mask & MASK_POS:
            pos = self.frames.from_geodetic(msg.lat_int / 1e7, msg.lon_int / 1e7,
                                            alt_base + msg.alt)
        vel, acc = self._feed_forward(msg, mask)
        return _finite(Setpoint(pos, vel, acc, *_yaw_fields(msg, mask)))

    # -- message handlers ---------------------------------------------------------------------

    def _on_heartbeat(self, msg: Msg, now: float) -> None:
        if msg.type == mavlink.MAV_TYPE_GCS and self._is_my_gcs(msg.get_srcSystem()):
            self.last_gcs_heartbeat = now

    def _is_my_gcs(self, sysid: int) -> bool:
        return True

    def _on_command(self, msg: Msg, now: float) -> None:
        if not self._for_me(msg.target_system):
            return
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        if msg.get_type() == "COMMAND_INT":
            # COMMAND_INT carries params 5 and 6 as scaled integers (lat/lon * 1e7).
            p += [msg.x / 1e7, msg.y / 1e7, msg.z]
        else:
            p += [msg.param5, msg.param6, msg.param7]
        cmd = msg.command
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self._cmd_message_interval(msg, p, now)
        elif cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            self._cmd_request_message(msg, as_int(p[0]), now)
        elif cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self.ack(msg, ACCEPTED)
            self._out.append(T.autopilot_version(self, now))
        elif cmd == mavlink.MAV_CMD_GET_HOME_POSITION:
            self._cmd_request_message(msg, mavlink.MAVLINK_MSG_ID_HOME_POSITION, now)
        else:
            self.ack(msg, self.command(msg, cmd, p, now))

    def command(self, msg: Msg, cmd: int, p: list[float], now: float) -> int:
        """Mode, arming, takeoff, land and RTL commands; returns the MAV_RESULT to ACK.

        Both autopilots take the same commands; what differs (which checks pass,
        which mode LAND and RTL mean, how a refusal is coded) lives in the
        flavour's hooks and class attributes.
        """
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            if not as_int(p[0]) & MODE_FLAG_CUSTOM:
                return self.unknown_mode_result
            return self.request_mode(p[1], p[2], now)
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] == 1 and not self.armed and as_int(p[1]) != FORCE_MAGIC \
                    and self.arm_refusals and self.prearm_checks_enabled():
                # An arming-time check failing (a fault).
                self.statustext(mavlink.MAV_SEVERITY_CRITICAL, self.arm_refusals.pop(0))
                return self.arm_refused_result
            return self._arm_disarm(p, now)
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(p[6], now)
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            return self.set_mode(self.land_mode, now)
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self.set_mode(self.rtl_mode, now)
        return UNSUPPORTED

    def _cmd_message_interval(self, msg: Msg, p: list[float], now: float) -> None:
        msgid, interval_us = as_int(p[0]), p[1]
        if msgid not in T.BUILDERS or msgid in self.foreign_messages:
            self.ack(msg, FAILED)
            return
        if interval_us == -1:
            self.set_stream(msgid, None, now)
        elif interval_us == 0:
            self.set_stream(msgid, self.default_interval(msgid), now)
        elif interval_us > 0:
            self.set_stream(msgid, interval_us / 1e6, now)
        else:
            self.ack(msg, FAILED)
            return
        self.ack(msg, ACCEPTED)

    def default_interval(self, msgid: int) -> float | None:
        """The interval SET_MESSAGE_INTERVAL 0 ("default rate") restores."""
        return None

    def _cmd_request_message(self, msg: Msg, msgid: int, now: float) -> None:
        builder = T.BUILDERS.get(msgid)
        if builder is None or msgid in self.foreign_messages:
            self.ack(msg, UNSUPPORTED)
            return
        if msgid in T.NEEDS_ORIGIN and not self.origin_set(now):
            self.ack(msg, FAILED)  # no home / origin yet
            return
        self.ack(msg, ACCEPTED)
        self._out.append(builder(self, now))

    def _on_request_data_stream(self, msg: Msg, now: float) -> None:
        # REQUEST_DATA_STREAM is fire-and-forget: ArduPilot never ACKs it.
        if not self._for_me(msg.target_system):
            return
        groups = (T.DATA_STREAM_GROUPS.keys() if msg.req_stream_id == mavlink.MAV_DATA_STREAM_ALL
                  else [msg.req_stream_id])
        rate = msg.req_message_rate
        for group in groups:
            for msgid in T.DATA_STREAM_GROUPS.get(group, ()):
                self.set_stream(msgid, 1.0 / rate if msg.start_stop and rate > 0 else None, now)

    def _on_setpoint(self, msg: Msg, now: float) -> None:
        if not self._for_me(msg.target_system):
            return
        if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            sp = self.decode_local(msg)
        else:
            sp = self.decode_global(msg)
        if sp is None:
            return
        self.setpoint(sp, msg.type_mask, now)

    def setpoint(self, sp: Setpoint, type_mask: int, now: float) -> None:
        """Flavour decides whether to fly a decoded setpoint."""

    def _on_param_request_list(self, msg: Msg, now: float) -> None:
        if not self._for_me(msg.target_system):
            return
        for name in self.params.names():
            self._param_value(name)

    def _on_param_request_read(self, msg: Msg, now: float) -> None:
        if not self._for_me(msg.target_system):
            return
        names = self.params.names()
        name = _param_id(msg.param_id)
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._param_value(names[msg.param_index])
        elif name in self.params.specs:
            self._param_value(name)

    def _on_param_set(self, msg: Msg, now: float) -> None:
        if msg.target_system != self.sysid:
            return
        name = _param_id(msg.param_id)
        if name in ("SYSID_THISMAV", "MAV_SYS_ID"):
            self._param_value(name)  # changing the id needs a reboot: echo the old value
            return
        if self.params.set(name, msg.param_value, msg.param_type):
            self._param_value(name)

    def _param_value(self, name: str) -> None:
        value, ptype = self.params.wire(name)
        self._out.append(mavlink.MAVLink_param_value_message(
            name.encode(), value, ptype, len(self.params), self.params.index(name)))

    def _on_timesync(self, msg: Msg, now: float) -> None:
        if msg.tc1 == 0:
            # A request: answer with our time since boot in ns, echoing ts1 (the fleet
            # hands it over with the clock's time as it is read: SimFleet._deliver).
            self._out.append(mavlink.MAVLink_timesync_message(self._now_ns(now), msg.ts1))

    def _on_led_control(self, msg: Msg, now: float) -> None:
        # Stock ArduPilot reads custom_len 3 (RGB) or 4 (RGB + blink Hz) from custom_bytes,
        # ignores instance and pattern, and never ACKs.
        if not self.supports_led or not self._for_me(msg.target_system):
            return
        if msg.custom_len not in (3, 4):
            return
        b = list(msg.custom_bytes)
        colour = (int(b[0]), int(b[1]), int(b[2]))
        if colour != self.led:
            self.led, self.led_changed_at = colour, now
        self.led_blink_hz = float(b[3]) if msg.custom_len == 4 else 0.0

    def _on_ping(self, msg: Msg, now: float) -> None:
        # A PING request (target 0/0) is answered with the same time and sequence number.
        if msg.target_system == 0 and msg.target_component == 0:
            self._out.append(mavlink.MAVLink_ping_message(
                msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_fence_message(self, msg: Msg, now: float) -> None:
        if self._for_me(msg.target_system):
            self._out.extend(self.fence.handle(msg, now))
            self._on_fence_changed()

    def _on_fence_changed(self) -> None:
        """The flavour's bookkeeping after a fence upload (ArduPilot: FENCE_TOTAL)."""

    def fence_polygon(self) -> np.ndarray | None:
        """The uploaded inclusion polygon in the simulator's ENU frame, (n, 2); None: none."""
        version, poly = self._fence_enu
        if version != self.fence.version:
            poly = None
            if len(self.fence.vertices) >= 3:
                poly = np.array([self.frames.from_geodetic(lat, lon, self.home_lla[2])[:2]
                                 for lat, lon in self.fence.vertices])
            self._fence_enu = (self.fence.version, poly)
        return poly

    def _on_mission_request_list(self, msg: Msg, now: float) -> None:
        # Ground stations download the mission on connect; this vehicle has none.
        if not self._for_me(msg.target_system):
            return
        if msg.mission_type == FENCE:
            self._out.extend(self.fence.handle(msg, now))
            return
        self._out.append(mavlink.MAVLink_mission_count_message(
            msg.get_srcSystem(), msg.get_srcComponent(), 0, msg.mission_type))

    def _on_gps_rtcm_data(self, msg: Msg, now: float) -> None:
        n = max(0, min(int(msg.len), len(msg.data)))
        self.rtk.receive(int(msg.flags), bytes(msg.data[:n]), now)

    def _on_set_mode(self, msg: Msg, now: float) -> None:
        # Legacy SET_MODE: ArduPilot ACKs it with COMMAND_ACK.command = the message id (11).
        if msg.target_system != self.sysid:
            return
        result = FAILED
        if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            result = self.request_mode(float(msg.custom_mode), 0.0, now)
        self._out.append(mavlink.MAVLink_command_ack_message(
            mavlink.MAVLINK_MSG_ID_SET_MODE, result, 0, 0, msg.get_srcSystem(),
            msg.get_srcComponent()))

    def request_mode(self, param2: float, param3: float, now: float) -> int:
        """DO_SET_MODE with the custom-mode flag: returns the MAV_RESULT."""
        name = mode_from_set_mode(self.flavour, param2, param3)
        if name is None:
            return self.unknown_mode_result
        return self.set_mode(name, now)

    def set_mode(self, name: str, now: float) -> int:
        """Switch to mode ``name`` if the flavour's checks pass; returns the MAV_RESULT."""
        return UNSUPPORTED

    def _arm_disarm(self, p: list[float], now: float) -> int:
        """COMPONENT_ARM_DISARM (p1 = 1 arms, p2 = 21196 forces)."""
        return UNSUPPORTED

    def _takeoff(self, alt: float, now: float) -> int:
        """NAV_TAKEOFF with param7 ``alt`` (its meaning differs per flavour)."""
        return UNSUPPORTED

    _HANDLERS: ClassVar[dict[str, Callable[[Vehicle, Msg, float], None]]] = {}

    # -- flavour hooks ------------------------------------------------------------------------

    def prearm_checks_enabled(self) -> bool:
        """Whether the (non-mandatory) pre-arm checks run (ArduPilot: ARMING_CHECK != 0)."""
        return True

    def yaw_control(self) -> tuple[float, float]:
        """(yaw-rate limit rad/s, heading-error gain 1/s) of the yaw controller."""
        return math.radians(60.0), 1.0

    def travel_heading(self) -> float | None:
        """The heading to face while ``heading.face_travel`` (None: too slow, hold)."""
        return None

    def fence_bits(self, now: float) -> tuple[bool, bool, bool]:
        """SYS_STATUS MAV_SYS_STATUS_GEOFENCE (present, enabled, healthy)."""
        return False, False, False

    def _boot_messages(self, now: float) -> None:
        """STATUSTEXTs and default streams at boot."""

    def _on_origin_set(self, now: float) -> None:
        """The EKF origin has just been set."""

    def _flight_logic(self, now: float) -> None:
        """Per-tick flight logic: takeoff completion, landing, timeouts, failsafes."""


def as_int(x: float) -> int:
    """A command parameter as an integer; unused parameters arrive as NaN and count as 0."""
    return int(x) if math.isfinite(x) else 0


def _yaw_fields(msg: Msg, mask: int) -> tuple[float | None, float | None]:
    """(yaw, yaw_rate) of a SET_POSITION_TARGET message; None where ignored or not finite."""
    yaw = None if mask & MASK_YAW or not math.isfinite(msg.yaw) else float(msg.yaw)
    rate = (None if mask & MASK_YAW_RATE or not math.isfinite(msg.yaw_rate)
            else float(msg.yaw_rate))
    return yaw, rate


def _finite(sp: Setpoint) -> Setpoint | None:
    for part in (sp.pos, sp.vel, sp.acc):  # (3 floats each: math, not a numpy call)
        if part is not None and not all(map(math.isfinite, part)):
            return None  # NaN in a used field: the autopilots reject the whole message
    return sp


def _param_id(raw: bytes | str) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return raw.split("\x00", 1)[0]


Vehicle._HANDLERS = {
    "HEARTBEAT": Vehicle._on_heartbeat,
    "COMMAND_LONG": Vehicle._on_command,
    "COMMAND_INT": Vehicle._on_command,
    "REQUEST_DATA_STREAM": Vehicle._on_request_data_stream,
    "SET_POSITION_TARGET_LOCAL_NED": Vehicle._on_setpoint,
    "SET_POSITION_TARGET_GLOBAL_INT": Vehicle._on_setpoint,
    "PARAM_REQUEST_LIST": Vehicle._on_param_request_list,
    "PARAM_REQUEST_READ": Vehicle._on_param_request_read,
    "PARAM_SET": Vehicle._on_param_set,
    "TIMESYNC": Vehicle._on_timesync,
    "LED_CONTROL": Vehicle._on_led_control,
    "MISSION_REQUEST_LIST": Vehicle._on_mission_request_list,
    "MISSION_COUNT": Vehicle._on_fence_message,
    "MISSION_ITEM_INT": Vehicle._on_fence_message,
    "MISSION_REQUEST_INT": Vehicle._on_fence_message,
    "SET_MODE": Vehicle._on_set_mode,
    "PING": Vehicle._on_ping,
    "GPS_RTCM_DATA": Vehicle._on_gps_rtcm_data,
}

