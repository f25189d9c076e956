"""Frames: the show's ENU frame and every vehicle's own EKF-origin NED frame.

Both are affine functions of ECEF, so the map from one vehicle's local NED to
the show's ENU is exactly ``enu = M_i @ ned + b_i`` with a per-vehicle rotation
and offset computed once (pymap3d gives the ECEF points, the rotations are the
textbook tangent-plane ones).  Altitudes are treated as heights above the
WGS-84 ellipsoid and reported as AMSL, i.e. the geoid is ignored on both sides.

This is deliberately not :mod:`groundctl.execute.frames`: the simulator is the
executor's test oracle, and a conversion bug shared by both would cancel out in
every dry-run.  The two are written differently on purpose (an exact affine map
through ECEF here, pymap3d's geodetic round trip there).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pymap3d

from groundctl import wgs84


def _ecef_to_enu_rotation(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """Rotations ``(n, 3, 3)`` taking ECEF vectors to local East-North-Up."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, sp, cp = np.sin(lon), np.cos(lon), np.sin(lat), np.cos(lat)
    zero = np.zeros_like(lat)
    return np.stack([
        np.stack([-sl, cl, zero], axis=-1),
        np.stack([-sp * cl, -sp * sl, cp], axis=-1),
        np.stack([cp * cl, cp * sl, sp], axis=-1),
    ], axis=-2)


@functools.cache
def _show_ecef(origin: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The show origin in ECEF and the rotation ``(3, 3)`` taking ENU rows to ECEF
    rows (``ecef = origin + enu @ rot``)."""
    lat0, lon0, h0 = origin
    x0 = np.array(pymap3d.geodetic2ecef(lat0, lon0, h0), dtype=float)
    return x0, _ecef_to_enu_rotation(np.array([lat0]), np.array([lon0]))[0]


def _ecef_to_geodetic(ecef: np.ndarray) -> np.ndarray:
    """ECEF points ``(..., 3)`` to (lat deg, lon deg, height above WGS-84 m): Heikkinen
    (1982), exact in closed form away from the Earth's centre."""
    x, y, z = ecef[..., 0], ecef[..., 1], ecef[..., 2]
    a, b, e2 = wgs84.A, wgs84.B, wgs84.E2
    p2 = x * x + y * y
    p = np.sqrt(p2)
    z2 = z * z
    f = 54.0 * b * b * z2
    g = p2 + (1.0 - e2) * z2 - e2 * (a * a - b * b)
    c = e2 * e2 * f * p2 / (g * g * g)
    s = np.cbrt(1.0 + c + np.sqrt(c * c + 2.0 * c))
    k = s + 1.0 / s + 1.0
    pp = f / (3.0 * k * k * g * g)
    q = np.sqrt(1.0 + 2.0 * e2 * e2 * pp)
    r0 = (-(pp * e2 * p) / (1.0 + q)
          + np.sqrt(0.5 * a * a * (1.0 + 1.0 / q) - pp * (1.0 - e2) * z2 / (q * (1.0 + q))
                    - 0.5 * pp * p2))
    d = p - e2 * r0
    u = np.sqrt(d * d + z2)
    v = np.sqrt(d * d + (1.0 - e2) * z2)
    z0 = b * b * z / (a * v)
    out = np.empty(np.shape(ecef), dtype=float)
    out[..., 0] = np.degrees(np.arctan2(z + wgs84.EP2 * z0, p))
    out[..., 1] = np.degrees(np.arctan2(y, x))
    out[..., 2] = u * (1.0 - b * b / (a * v))
    return out


#: ENU -> NED axis swap.
_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass
class FleetFrames:
    """Per-vehicle conversions between the show frame, local NED and geodetic."""

    origin: tuple[float, float, float]
    """Show origin: lat, lon (deg), alt (m)."""
    ekf_origins: np.ndarray
    """``(n, 3)`` geodetic EKF origins of the vehicles."""
    ned_to_enu: np.ndarray
    """``(n, 3, 3)``: show ENU = ned_to_enu @ local NED + ekf_origin_enu."""
    ekf_origin_enu: np.ndarray
    """``(n, 3)``: each EKF origin in the show's ENU frame."""
    geodetic_cache: tuple[float, np.ndarray] | None = None
    """(physics time, geodetic of every vehicle's estimate) for telemetry."""

    @classmethod
    def build(cls, origin: tuple[float, float, float], homes_enu: np.ndarray,
              overrides: list[tuple[float, float, float] | None] | None = None) -> FleetFrames:
        """Frames for vehicles booted at ``homes_enu``, EKF origins at home unless overridden."""
        lat0, lon0, h0 = origin
        n = homes_enu.shape[0]
        lat, lon, alt = pymap3d.enu2geodetic(homes_enu[:, 0], homes_enu[:, 1], homes_enu[:, 2],
                                             lat0, lon0, h0)
        ekf = np.stack([np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(alt)], axis=1)
        if overrides is not None:
            if len(overrides) != n:
                raise ValueError(f"`ekf_origins` has {len(overrides)} entries for {n} vehicles")
            for i, o in enumerate(overrides):
                if o is not None:
                    ekf[i] = o
        show_rot = _ecef_to_enu_rotation(np.array([lat0]), np.array([lon0]))[0]
        veh_rot = _ecef_to_enu_rotation(ekf[:, 0], ekf[:, 1])
        # NED_i -> ENU_i -> ECEF -> show ENU.
        ned_to_enu = show_rot @ np.transpose(veh_rot, (0, 2, 1)) @ _ENU_TO_NED
        e, nn, u = pymap3d.geodetic2enu(ekf[:, 0], ekf[:, 1], ekf[:, 2], lat0, lon0, h0)
        ekf_enu = np.stack([np.atleast_1d(e), np.atleast_1d(nn), np.atleast_1d(u)], axis=1)
        return cls(origin, ekf, ned_to_enu, ekf_enu)

    def enu_to_ned(self, index: int | np.ndarray | slice, enu: np.ndarray) -> np.ndarray:
        """Show-frame ENU point(s) to vehicle ``index``'s local NED."""
        return self._rotate(index, enu - self.ekf_origin_enu[index], transposed=True)

    def ned_to_show(self, index: int | np.ndarray | slice, ned: np.ndarray) -> np.ndarray:
        """Vehicle ``index``'s local NED point(s) to show-frame ENU."""
        return self._rotate(index, ned, transposed=False) + self.ekf_origin_enu[index]

    def vec_enu_to_ned(self, index: int | np.ndarray | slice, vec: np.ndarray) -> np.ndarray:
        """Rotate a show-frame vector (velocity) into the vehicle's NED axes."""
        return self._rotate(index, vec, transposed=True)

    def vec_ned_to_show(self, index: int | np.ndarray | slice, vec: np.ndarray) -> np.ndarray:
        """Rotate a vehicle NED vector (velocity) into show-frame ENU axes."""
        return self._rotate(index, vec, transposed=False)

    def _rotate(self, index: int | np.ndarray | slice, vec: np.ndarray,
                transposed: bool) -> np.ndarray:
        """``ned_to_enu[index]`` (``transposed``: its transpose) times ``vec``.  One
        vehicle's one vector, the simulator's usual question (each vehicle's heading every
        physics tick, each setpoint it decodes), in floats: an einsum call for three
        numbers was 6 % of a simulator process (1.9 µs a call; this, 1.0 µs)."""
        if type(index) is int and type(vec) is np.ndarray and vec.shape == (3,):
            (a, b, c), (d, e, f), (g, h, k) = self.ned_to_enu[index].tolist()
            x, y, z = vec.tolist()
            if transposed:
                return np.array([a * x + d * y + g * z, b * x + e * y + h * z,
                                 c * x + f * y + k * z])
            return np.array([a * x + b * y + c * z, d * x + e * y + f * z,
                             g * x + h * y + k * z])
        spec = "...ji,...j->...i" if transposed else "...ij,...j->...i"
        return np.einsum(spec, self.ned_to_enu[index], vec)

    def geodetic(self, enu: np.ndarray) -> np.ndarray:
        """Show-frame ENU points ``(..., 3)`` to geodetic ``(..., 3)`` (lat, lon, alt).

        Through ECEF by the tangent-plane rotation, then Heikkinen's closed form (exact,
        no iteration): a handful of array operations for the whole fleet, where
        pymap3d's round trip cost about 120 µs a call, most of the telemetry's cost when
        several vehicles' GLOBAL_POSITION_INT fall due on different physics ticks.
        """
        x0, rot = _show_ecef(self.origin)
        ecef = x0 + np.asarray(enu, dtype=float) @ rot
        return _ecef_to_geodetic(ecef)

    def from_geodetic(self, lat: float, lon: float, alt: float) -> np.ndarray:
        """A geodetic point to show-frame ENU."""
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt, *self.origin)
        return np.array([float(e), float(n), float(u)])
