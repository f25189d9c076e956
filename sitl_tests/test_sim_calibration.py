"""The ArduPilot flavour's dynamics against figures measured on real ArduCopter SITL (4.7-dev).

Flown over real UDP on loopback, on a ManualClock (so it takes about a second
of wall time): a 10 m min-jerk line in 10 s from 10 Hz SET_POSITION_TARGET_LOCAL_NED,
tracking error read back from LOCAL_POSITION_NED at 10 Hz.  Each figure must be
within 25 % of SITL's.
"""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sim_fixtures import GcsPeer, manual_fleet

from groundctl.link.flavours import Flavour
from groundctl.sim import SimFleet

AP = Flavour.ARDUPILOT
LPN = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
ALT = 5.0
LENGTH, DURATION = 10.0, 10.0

#: SITL figures (RMS m, max m).
SITL_POS_ONLY = (1.12, 2.19)
SITL_POS_VEL = (0.25, 0.44)
SITL_TAKEOFF_95 = 7.5
SITL_LAND_TO_DISARM = (13.0, 15.0)
SITL_HOVER_DRIFT_4S = 0.01


def minjerk(t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity along the 10 m, 10 s minimum-jerk line."""
    s = np.clip(np.asarray(t, dtype=float) / DURATION, 0.0, 1.0)
    pos = LENGTH * (10 * s**3 - 15 * s**4 + 6 * s**5)
    vel = LENGTH / DURATION * (30 * s**2 - 60 * s**3 + 30 * s**4)
    return pos, vel


def _within(value: float, reference: float, tol: float = 0.25) -> bool:
    return abs(value - reference) <= tol * reference


def _takeoff(fleet: SimFleet, peer: GcsPeer) -> float:
    """GUIDED, arm, NAV_TAKEOFF 5 m; returns the time to 95 % of the altitude (from LPN)."""
    fleet.run_until(1.1)
    assert peer.set_interval(1, LPN, 10).result == 0
    assert peer.set_mode(1, AP, "GUIDED").result == 0
    assert peer.arm(1).result == 0
    ack = peer.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, ALT)
    assert ack.result == 0
    t0 = fleet.time
    peer.clear()
    m = peer.wait("LOCAL_POSITION_NED", 1, lambda m: -m.z >= 0.95 * ALT, steps=2000)
    t95 = m.time_boot_ms / 1000.0 - t0
    fleet.step(8.0)  # settle in hover
    return t95


def _fly_line(fleet: SimFleet, peer: GcsPeer, with_velocity: bool) -> tuple[float, float]:
    """Fly the line from 10 Hz setpoints; RMS and max error from LOCAL_POSITION_NED."""
    mask = 0x0DC0 if with_velocity else 0x0DF8
    start = peer.wait("LOCAL_POSITION_NED", 1, steps=10)
    x0, y0 = start.x, start.y
    peer.clear()
    t0 = fleet.time
    for k in range(int(DURATION * 10) + 1):
        p, v = minjerk(k * 0.1)
        peer.setpoint_local(1, mask, (x0 + float(p), y0, -ALT), (float(v), 0.0, 0.0))
        fleet.step(0.1)
    peer.poll()
    errors = []
    for m in peer.all("LOCAL_POSITION_NED", 1):
        t = m.time_boot_ms / 1000.0 - t0
        if 0.0 <= t <= DURATION:
            ref, _ = minjerk(t)
            errors.append(np.hypot(m.x - (x0 + float(ref)), m.y - y0))
    assert len(errors) >= 95
    e = np.array(errors)
    return float(np.sqrt(np.mean(e**2))), float(e.max())


@pytest.mark.parametrize(("with_velocity", "sitl"), [(False, SITL_POS_ONLY),
                                                      (True, SITL_POS_VEL)])
def test_min_jerk_line_tracking_matches_sitl(with_velocity: bool,
                                             sitl: tuple[float, float]) -> None:
    with manual_fleet(1) as (fleet, peer):
        _takeoff(fleet, peer)
        rms, worst = _fly_line(fleet, peer, with_velocity)
        assert _within(rms, sitl[0]), f"RMS {rms:.3f} m vs SITL {sitl[0]} m"
        assert _within(worst, sitl[1]), f"max {worst:.3f} m vs SITL {sitl[1]} m"


def test_takeoff_land_and_hover_drift_match_sitl() -> None:
    with manual_fleet(1) as (fleet, peer):
        t95 = _takeoff(fleet, peer)
        assert _within(t95, SITL_TAKEOFF_95), f"takeoff to 95 % took {t95:.2f} s"
        _fly_line(fleet, peer, with_velocity=True)
        fleet.step(5.0)  # setpoints stopped: GUIDED holds
        peer.clear()
        fleet.step(4.0)
        peer.poll()
        lp = peer.all("LOCAL_POSITION_NED", 1)
        drift = float(np.linalg.norm([lp[-1].x - lp[0].x, lp[-1].y - lp[0].y, lp[-1].z - lp[0].z]))
        assert drift <= SITL_HOVER_DRIFT_4S * 1.25, f"hover drift {drift:.4f} m over 4 s"
        assert peer.set_mode(1, AP, "LAND").result == 0
        t0 = fleet.time
        peer.clear()
        armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        hb = peer.wait("HEARTBEAT", 1, lambda m: not m.base_mode & armed, steps=3000)
        assert hb is not None
        land = fleet.time - t0
        lo, hi = SITL_LAND_TO_DISARM
        assert lo * 0.75 <= land <= hi * 1.25, f"LAND to disarm took {land:.1f} s"
