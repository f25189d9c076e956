"""Shared builders for the executor tests: a tiny plan and hand-made vehicle states.

No tests here; the executor's test modules import these.
"""

from __future__ import annotations

import numpy as np
import pymap3d

from groundctl.link.flavours import Flavour
from groundctl.link.state import GeoPoint, GlobalPosition, VehicleState
from groundctl.plan.plan import Plan
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import GeoOrigin, Limits

ORIGIN = GeoOrigin(lat=47.397742, lon=8.545594, alt=488.0, heading_deg=0.0)
HOME = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [6.0, 0.0, 0.0]])
TAKEOFF_ALT = 3.0


def make_plan(home: np.ndarray = HOME, origin: GeoOrigin = ORIGIN,
              min_separation: float = 1.5, takeoff_altitude: float = TAKEOFF_ALT) -> Plan:
    """Every drone climbs 2 m and moves 4 m along +y by t=5 s, then comes back by t=10 s."""
    start = home + np.array([0.0, 0.0, takeoff_altitude])
    mid = start + np.array([0.0, 4.0, 2.0])
    pos = np.stack([start, mid, start], axis=1)
    vel = np.zeros_like(pos)
    n = len(home)
    colors = np.zeros((n, 2, 3))
    colors[:, 1] = [1.0, 0.5, 0.0]
    return Plan(show_name="tiny", origin=origin, limits=Limits(min_separation=min_separation),
                model="quadrotor", home=np.asarray(home, dtype=float),
                takeoff_altitude=takeoff_altitude,
                trajectories=Trajectories(np.array([0.0, 5.0, 10.0]), pos, vel),
                color_times=np.array([0.0, 10.0]), colors=colors, formations=())


def geo_offset(origin: GeoOrigin, east: float, north: float, up: float = 0.0) -> GeoPoint:
    """The geodetic point ``east``, ``north``, ``up`` metres from ``origin``."""
    lat, lon, alt = pymap3d.enu2geodetic(east, north, up, origin.lat, origin.lon, origin.alt)
    return GeoPoint(float(lat), float(lon), float(alt))


def make_vehicle(sysid: int, now: float = 100.0, flavour: Flavour = Flavour.ARDUPILOT,
                 ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 ekf_origin: GeoPoint | None = None, battery: float = 95.0, fix: int = 3,
                 rtt_s: float | None = 0.02, offset_s: float = 50.0,
                 lost_packets: int = 0) -> VehicleState:
    """A healthy vehicle on the ground, heard at ``now``, with a TIMESYNC answer."""
    v = VehicleState(system_id=sysid, flavour=flavour, mode="STABILIZE",
                     position_ned=ned, velocity_ned=(0.0, 0.0, 0.0),
                     battery_remaining_pct=battery, gps_fix_type=fix,
                     ekf_origin=ekf_origin or geo_offset(ORIGIN, 0.0, 0.0),
                     last_heard=now, last_heartbeat=now)
    v.global_position = GlobalPosition(0.0, 0.0, 0.0, -ned[2], (0.0, 0.0, 0.0), None)
    for seq in range(100):
        v.quality.update(1, seq)
    if lost_packets:
        v.quality.update(1, 99 + lost_packets + 1)
    if rtt_s is not None:
        sent = now - rtt_s
        ts1 = v.timesync.request(sent)
        tc1 = round((sent + rtt_s / 2 + offset_s) * 1e9)
        v.timesync.receive(tc1, ts1, now)
    return v


def set_altitude(v: VehicleState, alt: float) -> None:
    """Put ``v`` ``alt`` metres above home, as GLOBAL_POSITION_INT and LOCAL_POSITION_NED say."""
    n, e, _ = v.position_ned or (0.0, 0.0, 0.0)
    v.position_ned = (n, e, -alt)
    v.global_position = GlobalPosition(0.0, 0.0, 0.0, alt, (0.0, 0.0, 0.0), None)
