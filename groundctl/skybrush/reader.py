"""Reading a Skybrush compiled show (``.skyc``): a zip with ``show.json``.

The layout, from Skybrush's public specification of the format
(``@skybrush/file-formats-doc``, the ``ShowSpecification`` schema) and from
how skybrush-server reads it::

    {"version": 1,
     "settings": {"validation": {"minDistance", "maxAltitude", "maxVelocityXY",
                                 "maxVelocityZ", "maxVelocityZUp"}, "cues": ...},
     "swarm": {"drones": [{"type": "generic", "settings": {
         "name": "drone_1", "home": [x, y, z], "landAt": [x, y, z],
         "trajectory": {"version": 1, "takeoffTime": 0,
                        "points": [[t, [x, y, z], [control points]], ...]},
         "lights": {"version": 1, "data": "<base64 ledctrl bytecode>"}}}]},
     "meta": {"title": ...}, "environment": {"type": "outdoor", "location": {
         "origin": [lat * 1e7, lon * 1e7, AMSL mm (optional)], "orientation": deg}}}

Each trajectory point is ``[t, end point, control points]``: the segment from
the previous point to this one is a Bezier curve of degree 1 + the number of
control points, ``t`` relative to ``takeoffTime``; the first point has none.
A value may also be ``{"$ref": "./member.json#"}``, another member of the zip
(third-party writers do this).  ``environment.location`` places the show (its frame
is NWU, +X along the orientation): :class:`~.model.SkyLocation`; a show without it is
placed at the field by Skybrush Live, so the command line gives it.

Everything is checked before it is used: sizes and names of the zip
(:mod:`.archive`), JSON nesting, every number finite and in range, times
strictly increasing, at most 1000 drones, segments of at most cubic degree.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from groundctl.errors import ImportedShowError
from groundctl.files import FileProblem
from groundctl.plan.planfile import MAX_CUES
from groundctl.show.ranges import (
    MAX_COORD,
    MAX_DRONE_STEPS,
    MAX_DRONES,
    MAX_GEOFENCE_CORNERS,
    MAX_NAME_CHARS,
)
from groundctl.skybrush import lights as ledctrl
from groundctl.skybrush.archive import ArchiveProblem, SafeZip, open_zip
from groundctl.skybrush.model import (
    BezierTrack,
    SkyDrone,
    SkyLocation,
    SkyShow,
    cubic_from_points,
)

#: Longest show, s (a battery's endurance as a show file may give it, with room).
MAX_SHOW_SECONDS = 3600.0
#: Most trajectory segments of all drones together.
MAX_SEGMENTS = MAX_DRONE_STEPS
#: Longest light program, bytes.
MAX_LIGHT_BYTES = 4 * 1024 * 1024


class _Bad(Exception):
    """A problem found while reading, before the path is attached."""


def read_skyc(path: str | Path) -> SkyShow:
    """The show in the ``.skyc`` file at ``path``; ImportedShowError on any problem."""
    try:
        with open_zip(path) as zf:
            return _read(zf, Path(path).stem)
    except FileProblem as exc:
        raise ImportedShowError(path, str(exc) if exc.missing else
                                f"not a Skybrush .skyc show: {exc}") from None
    except ArchiveProblem as exc:
        raise ImportedShowError(path, f"not a Skybrush .skyc show: {exc}") from None
    except _Bad as exc:
        raise ImportedShowError(path, f"Skybrush show: {exc}") from None


def _json_member(zf: SafeZip, name: str) -> Any:
    if name not in zf.members:
        raise _Bad(f"no {name!r} in the archive")
    raw = zf.read(name)
    try:
        return json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise _Bad(f"{name!r} is not UTF-8 text") from None
    except ValueError:
        raise _Bad(f"{name!r} is not JSON") from None
    except RecursionError:
        raise _Bad(f"{name!r} is JSON nested too deeply") from None


def _resolve(zf: SafeZip, value: Any, where: str, depth: int = 0) -> Any:
    """``{"$ref": "./x.json#"}`` replaced by that member's JSON (one level of references)."""
    if isinstance(value, dict) and set(value) == {"$ref"}:
        ref = value["$ref"]
        if depth or not isinstance(ref, str):
            raise _Bad(f"{where}: a reference must be a member name")
        name = ref.split("#", 1)[0].removeprefix("./")
        return _resolve(zf, _json_member(zf, name), where, depth + 1)
    return value


def _kind(value: object) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int | float):
        text = repr(value)
        return text if len(text) <= 30 else "a very large number"
    if isinstance(value, str):
        return repr(value) if len(value) <= 40 and value.isprintable() else "a string"
    return {"list": "a list", "dict": "an object", "NoneType": "null"}.get(
        type(value).__name__, "a value")


def _number(value: object, where: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _Bad(f"{where} must be a number, got {_kind(value)}")
    try:
        x = float(value)
    except OverflowError:
        raise _Bad(f"{where} must be within {low:g}..{high:g}, got a very large number") \
            from None
    if not math.isfinite(x) or not low <= x <= high:
        raise _Bad(f"{where} must be within {low:g}..{high:g}, got {_kind(value)}")
    return x


def _point(value: object, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3:
        raise _Bad(f"{where} must be [x, y, z], got {_kind(value)}")
    return np.array([_number(v, where, -MAX_COORD, MAX_COORD) for v in value])


def _object(value: object, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _Bad(f"{where} must be an object, got {_kind(value)}")
    return value


def _read(zf: SafeZip, stem: str) -> SkyShow:
    doc = _object(_json_member(zf, "show.json"), "show.json")
    version = doc.get("version")
    if isinstance(version, bool) or version != 1:
        raise _Bad(f"show.json 'version' is {_kind(version)}; groundctl reads version 1")
    swarm = _object(_resolve(zf, doc.get("swarm"), "swarm"), "'swarm'")
    drones_raw = _resolve(zf, swarm.get("drones"), "swarm.drones")
    if not isinstance(drones_raw, list) or not drones_raw:
        raise _Bad("'swarm.drones' must be a list of at least one drone")
    if len(drones_raw) > MAX_DRONES:
        raise _Bad(f"{len(drones_raw)} drones, more than the {MAX_DRONES} groundctl flies")
    budget = [MAX_SEGMENTS]
    drones = tuple(_drone(zf, d, i, budget) for i, d in enumerate(drones_raw))
    settings = _object(_resolve(zf, doc.get("settings", {}), "settings"), "'settings'")
    validation = _object(settings.get("validation", {}), "'settings.validation'")

    def opt(key: str, high: float) -> float | None:
        if validation.get(key) is None:
            return None
        x = _number(validation[key], f"settings.validation.{key}", 0.0, high)
        return x if x > 0 else None

    meta = doc.get("meta", {})
    title = meta.get("title") if isinstance(meta, dict) else None
    if not isinstance(title, str) or not title.strip() or len(title) > MAX_NAME_CHARS \
            or not title.isprintable():
        title = stem[:MAX_NAME_CHARS] or "skyc"
    return SkyShow(title=title, drones=drones, min_distance=opt("minDistance", 100.0),
                   max_altitude=opt("maxAltitude", MAX_COORD),
                   max_velocity_xy=opt("maxVelocityXY", 50.0),
                   max_velocity_z=opt("maxVelocityZ", 50.0),
                   max_velocity_z_up=opt("maxVelocityZUp", 50.0),
                   geofence=_geofence(settings.get("geofence")),
                   cues=_cues(settings.get("cues")),
                   location=_location(_environment(zf, doc.get("environment"))))


def _environment(zf: SafeZip, raw: object) -> object:
    """``environment`` with its ``location`` resolved too (either may be a ``$ref``)."""
    env = _resolve(zf, raw, "environment")
    if isinstance(env, dict) and env.get("location") is not None:
        env = {**env, "location": _resolve(zf, env["location"], "environment.location")}
    return env


def _location(raw: object) -> SkyLocation | None:
    """``environment.location``: ``{"origin": [lat * 1e7, lon * 1e7(, AMSL in mm)],
    "orientation": degrees}`` (Skybrush Studio's exporter, the show format's ``Location``
    type); None when the show is not placed (no location, or an indoor show)."""
    if raw is None:
        return None
    env = _object(raw, "'environment'")
    if env.get("type", "outdoor") == "indoor" or env.get("location") is None:
        return None
    loc = _object(env["location"], "'environment.location'")
    origin = loc.get("origin")
    if not isinstance(origin, list) or len(origin) not in (2, 3):
        raise _Bad("'environment.location.origin' must be [latitude x 1e7, longitude x 1e7"
                   f"(, altitude above mean sea level in mm)], got {_kind(origin)}")
    lat = _number(origin[0], "environment.location latitude (x 1e7)", -90e7, 90e7) / 1e7
    lon = _number(origin[1], "environment.location longitude (x 1e7)", -180e7, 180e7) / 1e7
    amsl = None if len(origin) < 3 or origin[2] is None else _number(
        origin[2], "environment.location altitude (mm)", -500e3, MAX_COORD * 1e3) / 1e3
    raw_orientation = loc.get("orientation", 0.0)
    if isinstance(raw_orientation, str):  # Skybrush Live keeps it as text
        try:
            raw_orientation = float(raw_orientation)
        except ValueError:
            raise _Bad("'environment.location.orientation' must be degrees, got "
                       f"{_kind(raw_orientation)}") from None
    orientation = _number(raw_orientation, "environment.location orientation", -360.0, 360.0)
    return SkyLocation(lat=lat, lon=lon, amsl=amsl, orientation_deg=orientation % 360.0)


def _cues(raw: object) -> tuple[tuple[float, str], ...]:
    """``settings.cues``: ``{"version": 1, "items": [{"time": s, "name": text}, ...]}``,
    in time order.  A cue only names a moment, so a bad one never refuses the show: one
    without a usable time is left out, a time before the show's start (Skybrush Studio
    shifts markers by the exported frame range) is taken as 0, a name that is not
    printable text becomes ``cue N``, and past :data:`MAX_CUES` the rest are left out."""
    if not isinstance(raw, dict):
        return ()
    items = raw.get("items", [])
    if not isinstance(items, list):
        return ()
    out = []
    for k, item in enumerate(items[:MAX_CUES]):
        if not isinstance(item, dict):
            continue
        t = item.get("time")
        if isinstance(t, bool) or not isinstance(t, int | float):
            continue
        try:
            t = float(t)
        except OverflowError:
            continue
        if not math.isfinite(t) or t > MAX_SHOW_SECONDS:
            continue
        name = item.get("name")
        if not isinstance(name, str) or not name.strip() or len(name) > MAX_NAME_CHARS \
                or not name.isprintable():
            name = f"cue {k + 1}"
        out.append((max(t, 0.0), name))
    return tuple(sorted(out, key=lambda c: c[0]))


def _geofence(raw: object) -> tuple[tuple[float, float], ...] | None:
    """The inclusion polygon of ``settings.geofence`` (exclusion polygons are refused:
    groundctl's fence is one polygon to stay inside)."""
    if raw is None:
        return None
    fence = _object(raw, "'settings.geofence'")
    polygons = fence.get("polygons", [])
    if not isinstance(polygons, list):
        raise _Bad("'settings.geofence.polygons' must be a list")
    inside = []
    for k, poly in enumerate(polygons[:MAX_GEOFENCE_CORNERS]):
        where = f"settings.geofence polygon {k + 1}"
        poly = _object(poly, where)
        if poly.get("isInclusion", True) is not True:
            raise _Bad(f"{where} is an exclusion polygon; groundctl keeps drones inside one "
                       "inclusion polygon only")
        points = poly.get("points")
        if not isinstance(points, list) or not 3 <= len(points) <= MAX_GEOFENCE_CORNERS:
            raise _Bad(f"{where} must have 3 to {MAX_GEOFENCE_CORNERS} points")
        inside.append(tuple((float(p[0]), float(p[1])) for p in
                            (_point(q, f"{where} point") for q in points)))
    if len(inside) > 1:
        raise _Bad("settings.geofence has more than one polygon; groundctl keeps drones "
                   "inside one")
    return inside[0] if inside else None


def _drone(zf: SafeZip, raw: object, index: int, budget: list[int]) -> SkyDrone:
    where = f"drone {index + 1}"
    d = _object(_resolve(zf, raw, where), where)
    s = _object(_resolve(zf, d.get("settings"), where), f"{where} 'settings'")
    name = s.get("name")
    if not isinstance(name, str) or len(name) > MAX_NAME_CHARS or not name.isprintable():
        name = f"drone_{index + 1}"
    where = f"drone {index + 1} ({name})"
    traj = _object(_resolve(zf, s.get("trajectory"), where), f"{where} 'trajectory'")
    tv = traj.get("version")
    if isinstance(tv, bool) or tv != 1:
        raise _Bad(f"{where}: trajectory 'version' is {_kind(tv)}; groundctl reads version 1")
    takeoff = _number(traj.get("takeoffTime", 0.0), f"{where} 'takeoffTime'", 0.0,
                      MAX_SHOW_SECONDS)
    track = _track(traj.get("points"), where, takeoff, budget)
    home = _point(s["home"], f"{where} 'home'") if s.get("home") is not None \
        else track.ctrl[0, 0].copy()
    keys: tuple[ledctrl.LightKey, ...] = ()
    light = _resolve(zf, s.get("lights"), where)
    if light is not None:
        light = _object(light, f"{where} 'lights'")
        lv = light.get("version")
        if isinstance(lv, bool) or lv != 1:
            raise _Bad(f"{where}: lights 'version' is {_kind(lv)}; groundctl reads version 1")
        data = light.get("data", "")
        if not isinstance(data, str) or len(data) > MAX_LIGHT_BYTES * 4 // 3 + 4:
            raise _Bad(f"{where}: lights 'data' must be base64 text of at most "
                       f"{MAX_LIGHT_BYTES} bytes")
        try:
            code = base64.b64decode(data, validate=True)
        except (binascii.Error, ValueError):
            raise _Bad(f"{where}: lights 'data' is not base64") from None
        try:
            keys = tuple(ledctrl.decode(code, until_s=track.end + 1.0))
        except ledctrl.LightProgramError as exc:
            raise _Bad(f"{where}: light program: {exc}") from None
    return SkyDrone(name=name, home=home, track=track, lights=keys)


def _track(points: object, where: str, takeoff: float, budget: list[int]) -> BezierTrack:
    if not isinstance(points, list) or len(points) < 2:
        raise _Bad(f"{where}: trajectory 'points' must be a list of at least two points")
    budget[0] -= len(points) - 1
    if budget[0] < 0:
        raise _Bad(f"more than {MAX_SEGMENTS} trajectory segments in all")
    times = np.empty(len(points))
    ctrl = np.empty((len(points) - 1, 4, 3))
    prev: np.ndarray | None = None
    for k, raw in enumerate(points):
        at = f"{where} trajectory point {k + 1}"
        if not isinstance(raw, list) or len(raw) not in (2, 3):
            raise _Bad(f"{at} must be [t, [x, y, z], [control points]], got {_kind(raw)}")
        t = takeoff + _number(raw[0], f"{at} time", 0.0, MAX_SHOW_SECONDS)
        end = _point(raw[1], f"{at} position")
        cps = raw[2] if len(raw) == 3 and raw[2] is not None else []
        if not isinstance(cps, list):
            raise _Bad(f"{at} control points must be a list, got {_kind(cps)}")
        if prev is None:
            if cps:
                raise _Bad(f"{at}: the first point has no control points")
        else:
            if len(cps) > 2:
                raise _Bad(f"{at}: {len(cps)} control points (a Bezier of degree "
                           f"{len(cps) + 1}); groundctl reads segments up to cubic")
            if t <= times[k - 1]:
                raise _Bad(f"{at}: time {t - takeoff:g} s is not after the previous "
                           f"point's {times[k - 1] - takeoff:g} s")
            ctrl[k - 1] = cubic_from_points([prev, *(_point(c, f"{at} control point")
                                                     for c in cps), end])
        times[k] = t
        prev = end
    if times[-1] > MAX_SHOW_SECONDS:
        raise _Bad(f"{where}: the trajectory lasts past {MAX_SHOW_SECONDS:g} s")
    return BezierTrack(times, ctrl)
