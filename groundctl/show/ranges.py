"""The range of every number a show or plan file may hold, checked before any work.

A show file is operator input and a plan file may come from anywhere: a
number out of these ranges is refused by the loader with one line naming the
file, the place, the rule and the value (``ShowFileError``), before a shape
is generated, a matrix allocated or a planner started.  The manual's
"Ranges" (docs/show-files.md) lists them; the loader and the plan-file reader both read
them from here.

Why these bounds:

* ``MAX_DRONES`` 10,000: the largest fleet the planner is measured at
  (10,000 drones grid -> sphere planned and verified in 37 s).  One MAVLink network
  addresses 254 vehicles and a ground station flies up to 10 networks, so the dry-run
  and a flight take at most 2,540 (:data:`groundctl.vehicleid.MAX_NETWORKS`); larger
  shows are planned (and split over ground stations) only.
* ``MAX_SLOTS`` 10,000 points per formation, and ``MAX_ASSIGN_CELLS`` 5,000,000: a
  formation with more slots than drones is assigned exactly on a dense drones x slots
  cost matrix (at most 40 MB); one with as many is assigned multiscale above 3000
  drones, without it.
* ``MAX_STEPS`` 2000 QP steps per transition and ``MAX_DRONE_STEPS`` 10^6
  drone-steps per show: the verifier samples every knot 12 times for every
  drone (position, velocity, acceleration), about 0.9 GB at the limit.
* ``MAX_COORD`` 10 km: the show frame is a flat tangent plane at the origin.
* Flight time: every transition and hold, plus the climb and the descent, must
  fit in ``[limits] max_flight_time`` (default 900 s), the battery's endurance.
* ``MIN_SEPARATION`` 0.5 m: the least ``min_separation`` physical drones can keep.
  Show quadcopters are 0.25-0.3 m across (two half-spans: 0.3 m), and they fly
  0.1 m off their paths each even in calm air (0.085 m the largest error measured
  on nine ArduCopter SITL vehicles): below 0.5 m a plan "keeps the
  separation" while the propellers touch.  A show planned at 1e-6 m was planned
  SAFE and flown 0.002 m apart before this floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from groundctl.files import MiB

MIN_SEPARATION = 0.5
MAX_DRONES = 10_000
MAX_SLOTS = 10_000
#: Spare drones a show may ask for (``[spares] count``).
MAX_SPARES = 1000
MAX_ASSIGN_CELLS = 5_000_000
MAX_FORMATIONS = 100
MAX_STEPS = 2000
MAX_DRONE_STEPS = 1_000_000
MAX_COORD = 10_000.0
MAX_TEXT_CHARS = 200
MAX_GEOFENCE_CORNERS = 1000
MAX_GRADIENT_STOPS = 100
MAX_NAME_CHARS = 100
MAX_SEED = 2**64 - 1
MAX_SHOW_FILE_BYTES = 1 * MiB
MAX_POINTS_FILE_BYTES = 1 * MiB
DEFAULT_MAX_FLIGHT_TIME = 900.0


@dataclass(frozen=True)
class Range:
    """An allowed interval of one number."""

    low: float
    """Smallest value (excluded if ``low_open``)."""
    high: float
    """Largest value (excluded if ``high_open``)."""
    low_open: bool = False
    """``low`` itself is not allowed (e.g. a speed must be greater than 0)."""
    high_open: bool = False
    """``high`` itself is not allowed."""

    def problem(self, key: str, value: object) -> str | None:
        """Why ``value`` is not a number in this range (None if it is)."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            return f"'{key}' must be a number, got {type(value).__name__}"
        try:
            x = float(value)
        except OverflowError:
            return f"'{key}' must be at most {self.high:g}, got an integer of " \
                   f"{len(str(value))} digits"
        if not math.isfinite(x):
            return f"'{key}' must be finite, got {x}"
        if x < self.low or (self.low_open and x <= self.low):
            rule = "greater than" if self.low_open else "at least"
            return f"'{key}' must be {rule} {self.low:g}, got {x:g}"
        if x > self.high or (self.high_open and x >= self.high):
            rule = "below" if self.high_open else "at most"
            return f"'{key}' must be {rule} {self.high:g}, got {x:g}"
        return None


def above_zero(high: float) -> Range:
    """0 < x <= high."""
    return Range(0.0, high, low_open=True)


#: Limits field -> its range.
LIMIT_RANGES: dict[str, Range] = {
    "max_speed_h": above_zero(50.0),
    "max_speed_up": above_zero(50.0),
    "max_speed_down": above_zero(50.0),
    "max_accel": above_zero(50.0),
    "min_separation": Range(MIN_SEPARATION, 100.0),
    "min_alt": Range(0.0, MAX_COORD),
    "max_alt": above_zero(MAX_COORD),
    "land_battery_pct": Range(0.0, 100.0, low_open=True, high_open=True),
    "max_flight_time": above_zero(3600.0),
    "max_wind": above_zero(50.0),
}
#: GeoOrigin field -> its range.
ORIGIN_RANGES: dict[str, Range] = {
    "lat": Range(-90.0, 90.0),
    "lon": Range(-180.0, 180.0),
    "alt": Range(-500.0, MAX_COORD),
    "heading_deg": Range(-360.0, 360.0),
}
#: MpcSettings field -> its range.
MPC_RANGES: dict[str, Range] = {
    "horizon_s": Range(0.5, 10.0),
    "trigger_error_m": above_zero(10.0),
    "release_error_m": above_zero(10.0),
    "release_after_s": Range(0.0, 600.0),
}
TAKEOFF_ALTITUDE = above_zero(MAX_COORD)
COORDINATE = Range(-MAX_COORD, MAX_COORD)
ANGLE_DEG = Range(-360.0, 360.0)
SIZE = above_zero(MAX_COORD)
SPACING = above_zero(1000.0)
DT = Range(0.01, 5.0)
#: VehicleSettings number -> its range.
VEHICLE_RANGES: dict[str, Range] = {
    "fence_margin": Range(0.0, 100.0),
    "gcs_timeout": Range(1.0, 120.0),
    "rtl_alt": Range(2.0, 300.0),
    "land_speed": Range(0.1, 5.0),
}
#: A raw parameter's value (ArduPilot and PX4 parameters are 32-bit).
PARAM_VALUE = Range(-1e9, 1e9)
MAX_RAW_PARAMS = 200
