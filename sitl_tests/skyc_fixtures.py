"""Hand-made Skybrush shows for the tests: ``show.json`` documents written here, not by
groundctl's exporter, so that the reader is tested against the format, not against itself."""

from __future__ import annotations

import base64
import json
import zipfile
from pathlib import Path
from typing import Any

#: A light program by hand: red for 1 s (50 units of 20 ms), fade to blue over 2 s, end.
LIGHTS = bytes([0x04, 255, 0, 0, 50, 0x08, 0, 0, 255, 100, 0x00])


def rest_to_rest(t: float, frm: list[float], to: list[float]) -> list[Any]:
    """A cubic segment ending at ``to`` at time ``t``, at rest at both ends."""
    return [t, to, [frm, to]]


def drone(name: str, home: list[float], moves: list[tuple[float, list[float]]],
          lights: bytes = LIGHTS) -> dict[str, Any]:
    """A drone that takes off at ``home`` to 5 m in 3 s, holds 2 s, then flies each
    (end time, point) of ``moves`` rest to rest with a 2 s hold after each, and lands
    straight down in 3 s."""
    x, y, z = home
    top = [x, y, z + 5.0]
    pts: list[Any] = [[0.0, home, []], rest_to_rest(3.0, home, top), [5.0, top, []]]
    here, t = top, 5.0
    for end, p in moves:
        pts.append(rest_to_rest(end, here, p))
        t = end + 2.0
        pts.append([t, p, []])
        here = p
    ground = [here[0], here[1], z]
    pts.append(rest_to_rest(t + 3.0, here, ground))
    return {"type": "generic", "settings": {
        "name": name, "home": home, "trajectory": {"version": 1, "points": pts},
        "lights": {"version": 1, "data": base64.b64encode(lights).decode()}}}


def show_doc(drones: list[dict[str, Any]], min_distance: float = 1.5) -> dict[str, Any]:
    return {"version": 1, "environment": {"type": "outdoor"}, "meta": {"title": "hand-made"},
            "settings": {"validation": {"minDistance": min_distance, "maxVelocityXY": 5.0,
                                        "maxVelocityZ": 2.5, "maxAltitude": 50.0}},
            "swarm": {"drones": drones}}


def calm_drones() -> list[dict[str, Any]]:
    """Three drones that never meet: each moves 6 m along y, 4 m apart in x."""
    return [drone(f"d{i + 1}", [4.0 * i, 0.0, 0.0], [(15.0, [4.0 * i, 6.0, 5.0])])
            for i in range(3)]


def crossing_drones() -> list[dict[str, Any]]:
    """Drones 1 and 2 swap places head on (they meet at t = 10 s); drone 3 flies apart."""
    return [drone("left", [0.0, 0.0, 0.0], [(15.0, [10.0, 0.0, 5.0])]),
            drone("right", [10.0, 0.0, 0.0], [(15.0, [0.0, 0.0, 5.0])]),
            drone("apart", [0.0, 10.0, 0.0], [(15.0, [0.0, 16.0, 5.0])])]


def write_skyc(path: Path, doc: dict[str, Any]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("show.json", json.dumps(doc))
    return path
