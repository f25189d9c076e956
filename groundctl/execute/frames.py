"""Show frame <-> geodetic <-> each vehicle's local NED frame.

The show frame is anchored at a :class:`~groundctl.show.model.GeoOrigin`: +y
points along ``heading_deg`` (clockwise from true north), +x to its right, +z
up, so heading 0 is plain ENU.  Each vehicle flies in its own local NED frame
whose origin is its EKF origin (GPS_GLOBAL_ORIGIN), and two vehicles rarely
share one: a show point therefore goes show -> ENU at the show origin ->
geodetic -> NED at that vehicle's EKF origin, exactly, through WGS84 ECEF, so
vehicles with different origins fly the same show.  Between the show frame and
a local NED frame that is one rigid motion (both are tangent frames of ECEF),
computed once per EKF origin with pymap3d and applied as a matrix: the
geodetic round trip in between is the identity, and iterating it for every
telemetry sample cost the control loop a millisecond a tick.

Altitudes are used as given on both sides (the show origin's and the EKF
origin's are both AMSL as reported); only their difference matters here.

Every function is vectorised: ``xyz`` may be (3,) or (n, 3), and origins may
be one point or per-row arrays, so the whole fleet converts in one call.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray

from groundctl.link.state import GeoPoint, VehicleState
from groundctl.show.model import GeoOrigin

FloatArray = NDArray[np.float64]


def _rows(xyz: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(xyz, dtype=float)
    if arr.shape[-1:] != (3,) or arr.ndim > 2:
        raise ValueError(f"`{name}` must have shape (3,) or (n, 3), got {arr.shape}")
    return arr


def _rotation(heading_deg: float) -> FloatArray:
    """3x3 matrix taking show-frame vectors to ENU (rows are E, N, U)."""
    h = np.radians(heading_deg)
    c, s = np.cos(h), np.sin(h)
    # +y is the unit vector at bearing h: (E, N) = (sin h, cos h); +x is the
    # bearing h + 90 deg: (cos h, -sin h).
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def show_to_enu(origin: GeoOrigin, xyz: ArrayLike) -> FloatArray:
    """Show-frame vectors (positions relative to the origin, or velocities) as ENU."""
    return _rows(xyz, "xyz") @ _rotation(origin.heading_deg).T


def enu_to_show(origin: GeoOrigin, enu: ArrayLike) -> FloatArray:
    """Inverse of :func:`show_to_enu`."""
    return _rows(enu, "enu") @ _rotation(origin.heading_deg)


def _enu_to_ned(enu: FloatArray) -> FloatArray:
    return enu[..., [1, 0, 2]] * np.array([1.0, 1.0, -1.0])


def show_to_geodetic(origin: GeoOrigin, xyz: ArrayLike) -> tuple[FloatArray, FloatArray,
                                                                 FloatArray]:
    """(lat_deg, lon_deg, alt_m) of show-frame points ``xyz``."""
    enu = show_to_enu(origin, xyz)
    lat, lon, alt = pymap3d.enu2geodetic(enu[..., 0], enu[..., 1], enu[..., 2],
                                         origin.lat, origin.lon, origin.alt)
    return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float), np.asarray(alt, dtype=float)


def geodetic_to_show(origin: GeoOrigin, lat: ArrayLike, lon: ArrayLike,
                     alt: ArrayLike) -> FloatArray:
    """Show-frame points of geodetic ``lat``, ``lon`` (degrees), ``alt`` (m)."""
    e, n, u = pymap3d.geodetic2enu(lat, lon, alt, origin.lat, origin.lon, origin.alt)
    return enu_to_show(origin, np.stack([np.asarray(e), np.asarray(n), np.asarray(u)], axis=-1))


def _ecef_to_enu(lat_deg: float, lon_deg: float) -> FloatArray:
    """3x3 matrix taking ECEF vectors to ENU at geodetic ``lat_deg``, ``lon_deg``."""
    phi, lam = np.radians(lat_deg), np.radians(lon_deg)
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    return np.array([[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]])


@functools.lru_cache(maxsize=4096)
def _ned_affine(origin: GeoOrigin, ekf: GeoPoint) -> tuple[FloatArray, FloatArray]:
    """(A, b) with ``show = A @ ned + b`` for NED about ``ekf``: exact, because NED -> ECEF
    and ECEF -> ENU are both rigid motions (the geodetic round trip between them, which
    pymap3d iterates, is the identity).  A is orthonormal."""
    ecef0 = np.array(pymap3d.geodetic2ecef(ekf.lat_deg, ekf.lon_deg, ekf.alt_m), dtype=float)
    ecef_s = np.array(pymap3d.geodetic2ecef(origin.lat, origin.lon, origin.alt), dtype=float)
    ned_to_ecef = _enu_to_ned(_ecef_to_enu(ekf.lat_deg, ekf.lon_deg).T)  # columns N, E, D
    ecef_to_show = _rotation(origin.heading_deg).T @ _ecef_to_enu(origin.lat, origin.lon)
    a = ecef_to_show @ ned_to_ecef
    b = ecef_to_show @ (ecef0 - ecef_s)
    a.setflags(write=False)
    b.setflags(write=False)
    return a, b


def _affines(origin: GeoOrigin, ekf_origin: GeoPoint | Sequence[GeoPoint], pts: FloatArray,
             what: str) -> tuple[FloatArray, FloatArray]:
    """(A, b) for one EKF origin ((3, 3), (3,)) or one per row ((n, 3, 3), (n, 3))."""
    if isinstance(ekf_origin, GeoPoint):
        return _ned_affine(origin, ekf_origin)
    if pts.ndim != 2 or len(pts) != len(ekf_origin):
        raise ValueError(f"`ekf_origin` has {len(ekf_origin)} origins but `{what}` has shape "
                         f"{pts.shape}")
    key = (id(origin), *map(id, ekf_origin))
    hit = _STACKED.pop(key, None)
    if hit is not None:
        _STACKED[key] = hit  # the most recently used goes last: evicted last
        return hit[1], hit[2]
    pairs = [_ned_affine(origin, p) for p in ekf_origin]
    a = np.array([a for a, _ in pairs]).reshape(-1, 3, 3)
    b = np.array([b for _, b in pairs]).reshape(-1, 3)
    a.setflags(write=False)
    b.setflags(write=False)
    if len(_STACKED) >= _STACKED_MAX:
        _STACKED.pop(next(iter(_STACKED)), None)  # the least recently used
    # The objects are kept with their stack: while they live no other can take their ids.
    _STACKED[key] = ((origin, tuple(ekf_origin)), a, b)
    return a, b


#: The last fleets' stacked affines (:func:`_affines`), by the identity of their origin
#: objects (immutable): every tick converts the same fleet's setpoints and telemetry,
#: and stacking 1,000 matrices was a millisecond each time.  For the control loop's own
#: thread (nothing else converts frames).
_STACKED: dict[tuple[int, ...], tuple[object, FloatArray, FloatArray]] = {}
_STACKED_MAX = 8


def show_to_ned(origin: GeoOrigin, ekf_origin: GeoPoint | Sequence[GeoPoint],
                xyz: ArrayLike) -> FloatArray:
    """Show-frame points as NED in each vehicle's local frame.

    ``ekf_origin`` is one origin for every row of ``xyz``, or one per row.
    """
    pts = _rows(xyz, "xyz")
    a, b = _affines(origin, ekf_origin, pts, "xyz")
    if a.ndim == 2:
        return (pts - b) @ a  # A is orthonormal: its inverse is its transpose
    return np.einsum("nji,nj->ni", a, pts - b)


def ned_to_show(origin: GeoOrigin, ekf_origin: GeoPoint | Sequence[GeoPoint],
                ned: ArrayLike) -> FloatArray:
    """Local NED positions (telemetry) of vehicles as show-frame points."""
    pts = _rows(ned, "ned")
    a, b = _affines(origin, ekf_origin, pts, "ned")
    if a.ndim == 2:
        return pts @ a.T + b
    return np.einsum("nij,nj->ni", a, pts) + b


def show_vel_to_ned(origin: GeoOrigin, vel: ArrayLike) -> FloatArray:
    """Show-frame vectors (velocity, acceleration) as NED vectors.

    A pure rotation by the heading: the tangent planes at the show origin and
    at an EKF origin a few hundred metres away differ by about 1e-5 rad, far
    below what a velocity feed-forward can express.
    """
    return _enu_to_ned(show_to_enu(origin, _rows(vel, "vel")))


def ned_vel_to_show(origin: GeoOrigin, vel_ned: ArrayLike) -> FloatArray:
    """Inverse of :func:`show_vel_to_ned`."""
    return enu_to_show(origin, _enu_to_ned(_rows(vel_ned, "vel_ned")))


def show_positions(origin: GeoOrigin,
                   states: Mapping[int, VehicleState]) -> dict[int, FloatArray | None]:
    """Each vehicle's current show-frame position (None without EKF origin or local position).

    One vectorised conversion for the whole fleet; feeds the slot assignment
    and the console.
    """
    ready = [s for s in states.values()
             if s.ekf_origin is not None and s.position_ned is not None]
    out: dict[int, FloatArray | None] = dict.fromkeys(states)
    if ready:
        pts = ned_to_show(origin, [s.ekf_origin for s in ready],  # type: ignore[misc]
                          np.array([s.position_ned for s in ready], dtype=float))
        for s, p in zip(ready, pts, strict=True):
            out[s.system_id] = p
    return out
