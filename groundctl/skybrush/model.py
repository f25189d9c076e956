"""A Skybrush show as read from a ``.skyc`` or a CSV export, before it is a groundctl plan.

Every trajectory is kept as piecewise *cubic* Bezier segments on its own knot
times: the ``.skyc`` format's straight and quadratic segments are elevated to
cubic exactly; CSV samples become the cubic Hermite curve through them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from groundctl.skybrush.lights import LightKey

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class BezierTrack:
    """One drone's trajectory: cubic Bezier segments between its own knots."""

    times: FloatArray
    """(K+1,) strictly increasing knot times, show seconds (takeoff time added)."""
    ctrl: FloatArray
    """(K, 4, 3) the four control points of each segment, show-frame metres."""

    def __post_init__(self) -> None:
        if self.times.ndim != 1 or len(self.times) < 2 or np.any(np.diff(self.times) <= 0):
            raise ValueError("`times` must hold at least two strictly increasing knots")
        if self.ctrl.shape != (len(self.times) - 1, 4, 3):
            raise ValueError("`ctrl` must be (K, 4, 3) for K + 1 knots")

    @property
    def start(self) -> float:
        return float(self.times[0])

    @property
    def end(self) -> float:
        return float(self.times[-1])

    def evaluate(self, t: FloatArray, side: str = "right") -> tuple[FloatArray, FloatArray]:
        """Position and velocity (T, 3) at times ``t`` (clamped to the knots).

        At a knot the segment that starts there is used (``side="right"``) or the
        one that ends there (``"left"``): they differ where the velocity jumps.
        """
        tt = np.clip(np.asarray(t, dtype=float), self.times[0], self.times[-1])
        if side == "right":
            seg = np.searchsorted(self.times, tt, side="right") - 1
        else:
            seg = np.searchsorted(self.times, tt, side="left") - 1
        seg = np.clip(seg, 0, len(self.times) - 2)
        h = self.times[seg + 1] - self.times[seg]
        s = ((tt - self.times[seg]) / h)[:, None]
        c = self.ctrl[seg]
        u = 1.0 - s
        pos = u**3 * c[:, 0] + 3 * u * u * s * c[:, 1] + 3 * u * s * s * c[:, 2] + s**3 * c[:, 3]
        vel = 3 * (u * u * (c[:, 1] - c[:, 0]) + 2 * u * s * (c[:, 2] - c[:, 1])
                   + s * s * (c[:, 3] - c[:, 2])) / h[:, None]
        return pos, vel


def cubic_from_points(points: list[FloatArray]) -> FloatArray:
    """The (4, 3) cubic Bezier equal to the Bezier of ``points`` (2, 3 or 4 points)."""
    if len(points) == 2:
        p0, p1 = points
        return np.stack([p0, p0 + (p1 - p0) / 3, p0 + 2 * (p1 - p0) / 3, p1])
    if len(points) == 3:
        p0, q, p1 = points
        return np.stack([p0, p0 + 2 * (q - p0) / 3, p1 + 2 * (q - p1) / 3, p1])
    if len(points) == 4:
        return np.stack(points)
    raise ValueError("a segment has 2 to 4 points")


def hermite_to_bezier(p0: FloatArray, v0: FloatArray, p1: FloatArray, v1: FloatArray,
                      h: FloatArray) -> FloatArray:
    """(..., 4, 3) cubic Bezier control points of the Hermite segments (p0, v0) -> (p1, v1)
    lasting ``h`` seconds (..., broadcast)."""
    hh = np.asarray(h, dtype=float)[..., None]
    return np.stack([p0, p0 + v0 * hh / 3, p1 - v1 * hh / 3, p1], axis=-2)


@dataclass(frozen=True)
class SkyDrone:
    """One drone of a Skybrush show."""

    name: str
    """Its name in the show (``drone_1``) or its CSV file's stem."""
    home: FloatArray
    """(3,) where it stands before takeoff, show-frame metres."""
    track: BezierTrack
    """Its trajectory."""
    lights: tuple[LightKey, ...]
    """Its colour keys, show seconds (linear in between; equal times are a step)."""


@dataclass(frozen=True)
class SkyLocation:
    """``environment.location``: where a Skybrush show stands on the Earth.

    Skybrush's show frame is NWU: +X points along ``orientation_deg`` (clockwise from
    true north), +Y 90 degrees to its left, +Z up (flockwave-gps's flat-earth
    transformation, type ``nwu``, which Skybrush's MAVLink driver requires).
    """

    lat: float
    """Latitude of the show frame's origin, degrees (the file holds it times 1e7)."""
    lon: float
    """Longitude, degrees (times 1e7 in the file)."""
    amsl: float | None
    """Altitude of z = 0 above mean sea level, m (millimetres in the file; None: not
    given, as Skybrush Studio writes it)."""
    orientation_deg: float
    """Bearing of the show frame's +X axis, degrees clockwise from true north."""

    @property
    def heading_deg(self) -> float:
        """groundctl's heading of the same frame, every coordinate kept (:func:`heading_of`)."""
        return heading_of(self.orientation_deg)


def heading_of(orientation_deg: float) -> float:
    """groundctl's show heading of a Skybrush show frame whose +X points at
    ``orientation_deg``, every coordinate kept as it is.

    groundctl's heading is the bearing of its +y axis, with +x to the right of it.
    Skybrush's +Y is 90 degrees to the left of +X, at ``orientation_deg - 90``; taking
    that bearing as groundctl's +y puts groundctl's +x (its right) on Skybrush's +X.  So
    (x, y, z) mean the same point in both frames."""
    return (orientation_deg - 90.0) % 360.0


def orientation_of(heading_deg: float) -> float:
    """Skybrush's orientation (the bearing of +X) of groundctl's heading: the inverse of
    :func:`heading_of`."""
    return (heading_deg + 90.0) % 360.0


@dataclass(frozen=True)
class SkyShow:
    """A whole Skybrush show."""

    title: str
    """The show's title (meta.title), or the file's stem."""
    drones: tuple[SkyDrone, ...]
    """Every drone, in file order."""
    min_distance: float | None = None
    """settings.validation.minDistance, m (None: not given)."""
    max_altitude: float | None = None
    """settings.validation.maxAltitude, m."""
    max_velocity_xy: float | None = None
    """settings.validation.maxVelocityXY, m/s."""
    max_velocity_z: float | None = None
    """settings.validation.maxVelocityZ, m/s (up and down unless ``max_velocity_z_up``)."""
    max_velocity_z_up: float | None = None
    """settings.validation.maxVelocityZUp, m/s."""
    geofence: tuple[tuple[float, float], ...] | None = None
    """settings.geofence's inclusion polygon (x, y), m (None: not given)."""
    cues: tuple[tuple[float, str], ...] = ()
    """settings.cues' items: (Skybrush show time, s; name), in time order."""
    location: SkyLocation | None = None
    """environment.location (None: the file does not place the show)."""
