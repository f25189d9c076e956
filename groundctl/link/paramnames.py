"""Autopilot parameters that firmware versions name differently, and their units.

ArduCopter 4.8 renamed its heights, speeds and accelerations to SI units: RTL_ALT
(cm) is RTL_ALT_M (m), LAND_SPEED (cm/s) is LAND_SPD_MS (m/s), WPNAV_SPEED (cm/s) is
WP_SPD (m/s) ...  A vehicle does not answer for a name it does not know, so a ground
station asks for both (:meth:`~groundctl.link.params.ParamClient.read_any`) and uses
the one answered, in its unit.  Checked against the ArduCopter V4.8.0-dev SITL build
in ``../shared/sitl`` (the names in its binary).  PX4 renamed none of the parameters
groundctl sets since v1.15.
"""

from __future__ import annotations

#: The first ArduCopter version with the SI names.
ARDUCOPTER_SI_NAMES = (4, 8, 0)

#: ArduCopter's name before 4.8 -> (its 4.8 name, the old unit's count per SI unit:
#: cm -> m, cm/s -> m/s, cm/s/s -> m/s/s).
ARDUCOPTER_48_RENAMES: dict[str, tuple[str, float]] = {
    "RTL_ALT": ("RTL_ALT_M", 100.0),
    "RTL_ALT_FINAL": ("RTL_ALT_FINAL_M", 100.0),
    "RTL_CLIMB_MIN": ("RTL_CLIMB_MIN_M", 100.0),
    "RTL_SPEED": ("RTL_SPEED_MS", 100.0),
    "WPNAV_SPEED": ("WP_SPD", 100.0),
    "WPNAV_SPEED_UP": ("WP_SPD_UP", 100.0),
    "WPNAV_SPEED_DN": ("WP_SPD_DN", 100.0),
    "WPNAV_ACCEL": ("WP_ACC", 100.0),
    "WPNAV_ACCEL_Z": ("WP_ACC_Z", 100.0),
    "WPNAV_RADIUS": ("WP_RADIUS_M", 100.0),
    "LAND_SPEED": ("LAND_SPD_MS", 100.0),
    "LAND_SPEED_HIGH": ("LAND_SPD_HIGH_MS", 100.0),
    "LAND_ALT_LOW": ("LAND_ALT_LOW_M", 100.0),
}

#: The same from the other side: ArduCopter 4.8's name -> (its name before, scale).
ARDUCOPTER_OLD_NAMES: dict[str, tuple[str, float]] = {
    new: (old, scale) for old, (new, scale) in ARDUCOPTER_48_RENAMES.items()}


def si_name(name: str) -> tuple[str, str, float] | None:
    """For an ArduCopter parameter either version names: (the 4.8 name, the name before,
    the old unit's count per SI unit); None for a parameter not renamed."""
    if name in ARDUCOPTER_48_RENAMES:
        new, scale = ARDUCOPTER_48_RENAMES[name]
        return new, name, scale
    if name in ARDUCOPTER_OLD_NAMES:
        old, scale = ARDUCOPTER_OLD_NAMES[name]
        return name, old, scale
    return None


def convert(name: str, value: float, to: str) -> float:
    """``value`` of ArduCopter parameter ``name`` in the unit of ``to``: ``name`` itself
    or its name in the other version (``convert("RTL_ALT", 2000, "RTL_ALT_M")`` is 20)."""
    if to == name:
        return value
    renamed = si_name(name)
    if renamed is None or to not in renamed[:2]:
        raise ValueError(f"{to} is not {name} under another name")
    new, _, scale = renamed
    return value / scale if to == new else value * scale
