"""The WGS-84 ellipsoid, for the conversions done by hand on hot paths (metres per
degree for every global position received, the simulator's ECEF to geodetic for every
vehicle at every step), where pymap3d's generality would cost more than the sum."""

from __future__ import annotations

#: Semi-major axis, m.
A = 6378137.0
#: Flattening.
F = 1.0 / 298.257223563
#: Semi-minor axis, m.
B = A * (1.0 - F)
#: First eccentricity squared.
E2 = 1.0 - (B / A) ** 2
#: Second eccentricity squared.
EP2 = (A / B) ** 2 - 1.0
