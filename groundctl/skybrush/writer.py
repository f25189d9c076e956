"""Writing a Skybrush compiled show (``.skyc``): a zip with ``show.json`` (see :mod:`.reader`).

Every segment is written as a cubic Bezier (two control points), or as a straight
one (none) where it is one; positions are rounded to 0.1 um and times to 1
nanosecond, lights are ``ledctrl`` bytecode (:mod:`.lights`) in base64.

What Skybrush then does with it is checked before anything is written
(:func:`check_for_skybrush`): Skybrush loads at most :data:`MAX_SKYBRUSH_DRONES`
drones (skybrush.js's show-format ``MAX_DRONE_COUNT``), and its server uploads each
drone's trajectory as one block of its binary show format, whose length field is 16
bits (:func:`trajectory_bytes`, after skybrush-server's ``SegmentEncoder``).
"""

from __future__ import annotations

import base64
import itertools
import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from groundctl.errors import SkybrushExportError
from groundctl.skybrush import lights as ledctrl
from groundctl.skybrush.model import SkyDrone, SkyShow

#: Decimals of positions, m (0.1 um: on a segment of a few milliseconds, 0.1 mm of
#: rounding is tens of m/s^2 of acceleration; Skybrush itself keeps millimetres).
POS_DECIMALS = 7
#: Decimals of times, s (a nanosecond: on a segment of a few milliseconds a
#: microsecond would already bend its curve).
TIME_DECIMALS = 9


#: Most drones Skybrush loads (skybrush.js, packages/show-format MAX_DRONE_COUNT).
MAX_SKYBRUSH_DRONES = 5000
#: Longest block of Skybrush's binary show format, bytes: a drone's trajectory as its
#: server uploads it (skybrush-server show/formats.py: a 16-bit length).
MAX_TRAJECTORY_BYTES = 65535
#: Longest segment the binary format holds, s (longer ones are split by the server).
MAX_SEGMENT_S = 65.0
#: Shortest segment, s: the binary format counts durations in whole milliseconds.
MIN_SEGMENT_S = 0.001


def _xyz(p: np.ndarray) -> list[float]:
    return [round(float(x), POS_DECIMALS) + 0.0 for x in p]


def _straight(c: np.ndarray) -> bool:
    """A cubic Bezier (4, 3) that is the straight segment at constant speed."""
    d = c[3] - c[0]
    tol = 1e-9 * (1.0 + float(np.abs(c).max()))
    return bool(np.abs(c[1] - (c[0] + d / 3)).max() <= tol
                and np.abs(c[2] - (c[0] + 2 * d / 3)).max() <= tol)


def drone_json(d: SkyDrone) -> dict[str, Any]:
    """One drone's entry of ``swarm.drones``."""
    tr = d.track
    points: list[list[Any]] = [[round(tr.start, TIME_DECIMALS), _xyz(tr.ctrl[0, 0]), []]]
    for k in range(len(tr.times) - 1):
        c = tr.ctrl[k]
        points.append([round(float(tr.times[k + 1]), TIME_DECIMALS), _xyz(c[3]),
                       [] if _straight(c) else [_xyz(c[1]), _xyz(c[2])]])
    code = ledctrl.encode(d.lights)
    return {"type": "generic", "settings": {
        "name": d.name, "home": _xyz(d.home), "landAt": _xyz(tr.ctrl[-1, 3]),
        "trajectory": {"version": 1, "takeoffTime": 0, "points": points},
        "lights": {"version": 1, "data": base64.b64encode(code).decode("ascii")}}}


def trajectory_bytes(points: list[list[Any]]) -> int:
    """Length of one drone's trajectory block as Skybrush's server encodes it for upload
    (``points`` as :func:`drone_json` writes them, takeoff time 0): a scale byte, the
    start point (4 x int16), and per segment a format byte and a 16-bit duration in ms,
    then per axis nothing if it stays put, one int16 if straight, three if curved (the
    coordinates in units of ``scale`` mm, truncated); segments over 65 s are split (an
    axis that stays put there counted as straight: the split may round it into one, so
    the figure is never below the server's)."""
    coords = [abs(x) for p in points for q in ([p[1], *list(p[2])]) for x in q]
    scale = math.ceil((math.ceil(max(coords) * 1000.0) + 1) / 32768)
    unit = 1000.0 / scale
    size = 1 + 8
    prev = points[0][1]
    prev_t = points[0][0]
    for t, end, ctrl in points[1:]:
        pieces = 1
        dt = round(t - prev_t, 3)
        if dt > MAX_SEGMENT_S:
            pieces = math.floor(dt / MAX_SEGMENT_S) + 1
        per_axis = 0
        for axis in range(3):
            series = [int(q[axis] * unit) for q in [prev, *ctrl, end]]
            if any(x != series[0] for x in series[1:]):
                per_axis += 2 if not ctrl else 6
            elif pieces > 1:
                # The server splits it by de Casteljau: rounding may move a piece's axis
                # by a unit, which then costs a straight axis.  Counted, to stay below.
                per_axis += 2
        size += pieces * (3 + per_axis)
        prev, prev_t = end, t
    return size


def check_for_skybrush(show: SkyShow, drones: list[dict[str, Any]]
                       ) -> tuple[int | None, str] | None:
    """Why Skybrush could not load or upload ``show`` (its drones' entries as written):
    the drone's 1-based number (None: the show as a whole) and one line naming it; None
    when it can."""
    if len(show.drones) > MAX_SKYBRUSH_DRONES:
        return None, (f"{len(show.drones)} drones, more than the {MAX_SKYBRUSH_DRONES} "
                      "Skybrush loads in one show")
    for i, entry in enumerate(drones):
        points = entry["settings"]["trajectory"]["points"]
        who = f"drone {i + 1} ({show.drones[i].name})"
        reach = max(abs(x) for p in points for q in ([p[1], *list(p[2])]) for x in q)
        if math.ceil((math.ceil(reach * 1000.0) + 1) / 32768) >= 128:
            return i + 1, (f"{who} flies {reach:.0f} m from the show's origin, more than the "
                           "4,161 m Skybrush's binary show format holds")
        for a, b in itertools.pairwise(points):
            if round(b[0] - a[0], 3) <= 0.0:
                return i + 1, (f"{who} has a trajectory segment of {1e3 * (b[0] - a[0]):.3f} ms at "
                        f"t = {a[0]:.3f} s, shorter than the millisecond Skybrush counts "
                        "durations in")
        light = len(base64.b64decode(entry["settings"]["lights"]["data"]))
        if light > MAX_TRAJECTORY_BYTES:
            return i + 1, (f"{who}'s light program is {light:,} bytes, more than the "
                           f"{MAX_TRAJECTORY_BYTES:,} Skybrush's server sends to a drone: "
                           "fewer colour changes")
        size = trajectory_bytes(points)
        if size > MAX_TRAJECTORY_BYTES:
            return i + 1, (f"{who}'s trajectory is {size:,} bytes in Skybrush's upload format "
                    f"({len(points) - 1:,} segments), more than the {MAX_TRAJECTORY_BYTES:,} "
                    "its server sends to a drone: shorten the show or split it")
    return None


def show_json(show: SkyShow) -> dict[str, Any]:
    """The whole ``show.json`` document."""
    validation = {k: v for k, v in (("minDistance", show.min_distance),
                                    ("maxAltitude", show.max_altitude),
                                    ("maxVelocityXY", show.max_velocity_xy),
                                    ("maxVelocityZ", show.max_velocity_z),
                                    ("maxVelocityZUp", show.max_velocity_z_up)) if v is not None}
    cues = [{"time": round(t, TIME_DECIMALS), "name": name} for t, name in show.cues]
    settings: dict[str, Any] = {"cues": {"version": 1, "items": cues}, "validation": validation}
    if show.geofence is not None:
        settings["geofence"] = {"version": 1, "polygons": [
            {"isInclusion": True, "points": [[x, y, 0.0] for x, y in show.geofence]}]}
    environment: dict[str, Any] = {"type": "outdoor"}
    loc = show.location
    if loc is not None:
        origin = [round(loc.lat * 1e7), round(loc.lon * 1e7)]
        if loc.amsl is not None:
            origin.append(round(loc.amsl * 1e3))
        environment["location"] = {"origin": origin,
                                   "orientation": round(loc.orientation_deg, 6)}
    return {"version": 1,
            "environment": environment,
            "meta": {"title": show.title, "sources": ["groundctl"]},
            "settings": settings,
            "swarm": {"drones": [drone_json(d) for d in show.drones]}}


def write_skyc(show: SkyShow, path: str | Path) -> Path:
    """Write ``show`` to ``path`` as a ``.skyc`` (written beside, then renamed into place);
    SkybrushExportError, and nothing written, if Skybrush could not load or upload it."""
    path = Path(path)
    # The drone count before building 5,000 drones' JSON, then every drone's trajectory.
    problem = check_for_skybrush(show, [])
    doc = show_json(show) if problem is None else {}
    if problem is None:
        problem = check_for_skybrush(show, doc["swarm"]["drones"])
    if problem is not None:
        raise SkybrushExportError(path, problem[1], drone=problem[0])
    tmp = path.with_name(f".{path.name}.tmp")
    text = json.dumps(doc, separators=(",", ":"))
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("show.json", text)
    os.replace(tmp, path)
    return path
