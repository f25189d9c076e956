"""Writing a Skybrush compiled show (``.skyc``): a zip with ``show.json`` (see :mod:`.reader`).

Every segment is written as a cubic Bezier (two control points); positions
are rounded to 0.1 mm and times to 1 microsecond, lights are ``ledctrl``
bytecode (:mod:`.lights`) in base64.
"""

from __future__ import annotations

import base64
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from groundctl.skybrush import lights as ledctrl
from groundctl.skybrush.model import SkyDrone, SkyShow

#: Decimals of positions, m (0.1 mm).
POS_DECIMALS = 4
#: Decimals of times, s.
TIME_DECIMALS = 6


def _xyz(p: np.ndarray) -> list[float]:
    return [round(float(x), POS_DECIMALS) + 0.0 for x in p]


def drone_json(d: SkyDrone) -> dict[str, Any]:
    """One drone's entry of ``swarm.drones``."""
    tr = d.track
    points: list[list[Any]] = [[round(tr.start, TIME_DECIMALS), _xyz(tr.ctrl[0, 0]), []]]
    for k in range(len(tr.times) - 1):
        c = tr.ctrl[k]
        points.append([round(float(tr.times[k + 1]), TIME_DECIMALS), _xyz(c[3]),
                       [_xyz(c[1]), _xyz(c[2])]])
    code = ledctrl.encode(d.lights)
    return {"type": "generic", "settings": {
        "name": d.name, "home": _xyz(d.home), "landAt": _xyz(tr.ctrl[-1, 3]),
        "trajectory": {"version": 1, "takeoffTime": 0, "points": points},
        "lights": {"version": 1, "data": base64.b64encode(code).decode("ascii")}}}


def show_json(show: SkyShow) -> dict[str, Any]:
    """The whole ``show.json`` document."""
    validation = {k: v for k, v in (("minDistance", show.min_distance),
                                    ("maxAltitude", show.max_altitude),
                                    ("maxVelocityXY", show.max_velocity_xy),
                                    ("maxVelocityZ", show.max_velocity_z),
                                    ("maxVelocityZUp", show.max_velocity_z_up)) if v is not None}
    settings: dict[str, Any] = {"cues": {"version": 1, "items": []}, "validation": validation}
    if show.geofence is not None:
        settings["geofence"] = {"version": 1, "polygons": [
            {"isInclusion": True, "points": [[x, y, 0.0] for x, y in show.geofence]}]}
    return {"version": 1,
            "environment": {"type": "outdoor"},
            "meta": {"title": show.title, "sources": ["groundctl"]},
            "settings": settings,
            "swarm": {"drones": [drone_json(d) for d in show.drones]}}


def write_skyc(show: SkyShow, path: str | Path) -> Path:
    """Write ``show`` to ``path`` as a ``.skyc`` (written beside, then renamed into place)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    text = json.dumps(show_json(show), separators=(",", ":"))
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("show.json", text)
    os.replace(tmp, path)
    return path
