"""``--smooth TOL``: a Skybrush show made of straight segments (corners at every knot) is
refused as it is and planned safe with its corners rounded, within TOL of the show's path
measured here on the polyline itself; a corner that cannot be rounded is named, one line,
and the show stays refused; a bad TOL is one argparse line."""

from __future__ import annotations

import base64
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from flight_fixtures import REPO
from skyc_fixtures import LIGHTS, show_doc, write_skyc

from groundctl.errors import EXIT_OK, EXIT_UNSAFE, EXIT_USAGE
from groundctl.plan.verify import LIMIT_TOL
from groundctl.skybrush.importing import import_show

GROUNDCTL = [sys.executable, "-m", "groundctl"]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GROUNDCTL, *args], capture_output=True, text=True, cwd=REPO,
                          timeout=300, check=False)


def straight_drone(name: str, home: list[float], path: list[list[float]],
                   steps: float | list[float] = 0.5) -> dict[str, Any]:
    """A drone that climbs straight to 5 m in 3 s, holds until 5 s, flies ``path`` as
    straight segments (``steps`` s each: Skybrush's demo is 0.5 s pieces), holds 2 s
    and lands straight down in 3 s: every knot a corner."""
    x, y, z = home
    top = [x, y, z + 5.0]
    points: list[Any] = [[0.0, home, []], [3.0, top, []], [5.0, top, []]]
    t = 5.0
    durations = steps if isinstance(steps, list) else [steps] * len(path)
    for p, dt in zip(path, durations, strict=True):
        t += dt
        points.append([t, p, []])
    points.append([t + 2.0, path[-1], []])
    points.append([t + 5.0, [path[-1][0], path[-1][1], z], []])
    return {"type": "generic", "settings": {
        "name": name, "home": home, "trajectory": {"version": 1, "points": points},
        "lights": {"version": 1, "data": base64.b64encode(LIGHTS).decode()}}}


def circle(x0: float, radius: float = 1.5, pieces: int = 24) -> list[list[float]]:
    """1.5 laps of a circle through (x0, 0, 5), 16 straight 0.5 s pieces a lap (1.2 m/s,
    0.46 m/s velocity jumps, 1.2 m/s from and to rest)."""
    cx = x0 + radius
    return [[cx + radius * math.cos(math.pi + 2 * math.pi * k / 16),
             radius * math.sin(math.pi + 2 * math.pi * k / 16), 5.0]
            for k in range(1, pieces + 1)]


def circles() -> list[dict[str, Any]]:
    return [straight_drone(f"c{i + 1}", [6.0 * i, 0.0, 0.0], circle(6.0 * i))
            for i in range(3)]


def ramp() -> dict[str, Any]:
    """East at 1 m/s, then two 0.5 s steps of 1.6 m/s north each: no blend of one corner
    fits between them at 3 m/s^2 within 0.15 m, one blend across both does; then slowing."""
    x, y, path = 18.0, 0.0, []
    for vx, vy in [(1.0, 0.0)] * 4 + [(1.0, 1.6), (1.0, 3.2), (1.0, 3.2), (1.0, 3.2),
                                      (0.8, 2.4), (0.6, 1.6), (0.4, 0.8), (0.2, 0.4)]:
        x, y = x + 0.5 * vx, y + 0.5 * vy
        path.append([x, y, 5.0])
    return straight_drone("ramp", [18.0, 0.0, 0.0], path + [path[-1]] * (24 - len(path)))


def polyline(doc: dict[str, Any], times: np.ndarray) -> np.ndarray:
    """(n, T, 3) every drone's straight-segment path as written, at Skybrush ``times``."""
    out = []
    for d in doc["swarm"]["drones"]:
        pts = d["settings"]["trajectory"]["points"]
        t = np.array([p[0] for p in pts])
        xyz = np.array([p[1] for p in pts])
        out.append(np.stack([np.interp(times, t, xyz[:, k]) for k in range(3)], axis=1))
    return np.array(out)


def deviation(doc: dict[str, Any], path: Path, tol: float) -> tuple[float, Any]:
    """The largest distance between the plan and the polyline at the same instant (sampled
    every millisecond over the flown window), and the import."""
    r = import_show(path, smooth=tol)
    t = np.arange(r.imported.t0, r.imported.t_end, 1e-3)
    plan_t = t - (r.imported.t0 - r.imported.climb_s)
    got = r.plan.trajectories.evaluate(plan_t)[0]
    return float(np.linalg.norm(got - polyline(doc, t), axis=2).max()), r


def test_straight_segments_are_refused_as_they_are_and_planned_safe_smoothed(
        tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "circles.skyc", show_doc(circles()))
    out = _run("plan", str(path))
    assert out.returncode == EXIT_UNSAFE, out.stderr
    assert any("changes velocity by 0.46 m/s at once" in ln for ln in out.stdout.splitlines())

    out = _run("plan", str(path), "--smooth", "0.1", "--json")
    assert out.returncode == EXIT_OK, out.stdout + out.stderr
    report = json.loads(out.stdout)
    assert report["safe"] and report["max_accel_mps2"] <= 3.0
    smoothed = report["smoothed"]
    assert smoothed["tolerance_m"] == 0.1 and smoothed["unrounded"] == []
    # 23 corners along the circle, one from rest, one to rest: per drone.
    for i, d in enumerate(smoothed["drones"]):
        assert d["drone"] == i + 1 and d["name"] == f"c{i + 1}"
        assert d["corners"] == 25 and d["unrounded"] == 0
        assert 0.05 < d["max_deviation_m"] <= 0.1 and d["max_accel_mps2"] <= 3.0
    assert [ln for ln in report["violations"] if not ln.startswith("smoothed: ")] == []

    text = _run("plan", str(path), "--smooth", "0.1")
    assert text.returncode == EXIT_OK
    lines = text.stdout.splitlines()
    assert lines[0].startswith("smoothed: drone 1 (c1): 25 corners rounded, at most 0.07")
    assert "max accel 2.3" in lines[0] and lines[3].startswith("SAFE: ")


@pytest.mark.parametrize("tol", [0.1, 0.08])
def test_the_plan_stays_within_the_tolerance_of_the_polyline(tol: float,
                                                             tmp_path: Path) -> None:
    doc = show_doc(circles())
    path = write_skyc(tmp_path / "circles.skyc", doc)
    dev, r = deviation(doc, path, tol)
    assert r.safe, r.lines()
    assert 0.5 * tol < dev <= tol
    # The reported deviation is a bound of the measured one (and tight: straight pieces).
    reported = max(d.max_deviation for d in r.smoothing.drones)
    assert dev <= reported + 1e-9 and reported - dev < 1e-3
    # The verifier's acceleration, and every drone's figure: within the limit, and the
    # figure is the plan's own over the flown window.
    assert r.verification.overall.max_accel <= 3.0 * (1 + LIMIT_TOL)
    flown = np.linspace(r.imported.climb_s, r.imported.climb_s + r.imported.t_end
                        - r.imported.t0, 20001)
    sampled = np.linalg.norm(r.plan.trajectories.evaluate(flown)[2], axis=2).max(axis=1)
    for d, a in zip(r.smoothing.drones, sampled, strict=True):
        assert a - 1e-6 <= d.max_accel <= 3.0 and d.max_accel - a < 0.01
    # The drones corner at the same instants: they share their blends' knots.
    tracks = [d.track.times for d in r.smoothing.show.drones]
    assert all(np.array_equal(tracks[0], t) for t in tracks)
    assert len(r.plan.trajectories.times) <= 2 * len(import_show(path).plan.trajectories.times)


def test_corners_too_close_for_a_blend_each_are_rounded_by_one(tmp_path: Path) -> None:
    doc = show_doc([*circles(), ramp()])
    path = write_skyc(tmp_path / "ramp.skyc", doc)
    tight = import_show(path, smooth=0.1)
    assert not tight.safe
    assert [u.time for u in tight.smoothing.unrounded] == [7.0, 7.5]
    dev, r = deviation(doc, path, 0.15)
    assert r.safe, r.lines()
    assert dev <= 0.15
    assert r.smoothing.drones[3].corners == 8 and r.smoothing.drones[3].max_accel <= 3.0


def test_a_corner_that_cannot_be_rounded_is_named_and_the_show_refused(tmp_path: Path) -> None:
    # Drone 3 flies 4 m out at 1 m/s and straight back: a 2 m/s reversal at show time 9 s
    # takes 0.67 s at 3 m/s^2 and strays 2 x 0.67 / 4 = 0.167 m from the corner.
    back = straight_drone("back", [12.0, 0.0, 0.0],
                          [[16.0, 0.0, 5.0], [12.0, 0.0, 5.0], [12.0, 0.0, 5.0]],
                          [4.0, 4.0, 4.0])
    path = write_skyc(tmp_path / "back.skyc", show_doc([*circles()[:2], back]))
    out = _run("plan", str(path), "--smooth", "0.1")
    assert out.returncode == EXIT_UNSAFE, out.stdout + out.stderr
    about = [ln for ln in out.stdout.splitlines() if "(back) changes velocity" in ln]
    assert about == [
        "violation: drone 3 (back) changes velocity by 2.00 m/s at once at show time 9.00 s, "
        "a corner not rounded within 0.1 m at 3 m/s^2: turning it at 3 m/s^2 takes 0.67 s "
        "and strays 0.167 m from the show's path; nor does one blend across up to 4 knots "
        "around it"]
    assert "smoothed: drone 3 (back): 2 corners rounded, at most 0.062 m from the show's " \
           "path, max accel 2.00 m/s^2; 1 not rounded (velocity jumps)" in out.stdout
    assert out.stdout.splitlines()[-2].startswith("UNSAFE: ")
    report = json.loads(_run("plan", str(path), "--smooth", "0.1", "--json").stdout)
    assert not report["safe"]
    (u,) = report["smoothed"]["unrounded"]
    assert (u["drone"], u["name"], u["show_time_s"]) == (3, "back", 9.0)
    assert u["jump_mps"] == pytest.approx(2.0)
    # With room enough it is rounded, and the show is safe.
    assert _run("plan", str(path), "--smooth", "0.2").returncode == EXIT_OK


@pytest.mark.parametrize("value, message", [
    ("-0.1", "'--smooth' must be greater than 0, got -0.1"),
    ("0", "'--smooth' must be greater than 0, got 0"),
    ("nan", "'--smooth' must be finite, got nan"),
    ("ten", "--smooth must be a tolerance in metres, not 'ten'"),
    ("50", "'--smooth' must be at most 10, got 50"),
])
def test_a_bad_smooth_value_is_one_argparse_line(value: str, message: str) -> None:
    out = _run("plan", "x.skyc", "--smooth", value)
    assert out.returncode == EXIT_USAGE
    errors = [ln for ln in out.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and "Traceback" not in out.stderr
    assert errors[0] == f"groundctl plan: error: argument --smooth: {message}"


def test_a_smoothed_show_exported_reads_back_safe(tmp_path: Path) -> None:
    # Blends put knots a few milliseconds (or less) apart: the export joins the slivers
    # and writes enough decimals that reading it back is the same curve, within the
    # same acceleration limit.
    from groundctl.skybrush.importing import export_skyc
    doc = show_doc([*circles(), ramp()])
    r = import_show(write_skyc(tmp_path / "show.skyc", doc), smooth=0.15)
    assert r.safe, r.lines()
    out = export_skyc(r.plan, tmp_path / "out.skyc")
    back = import_show(out, limits=r.plan.limits)
    assert back.safe, back.lines()
    ts = np.linspace(0.0, r.plan.duration, 40001)
    err = np.abs(r.plan.trajectories.evaluate(ts)[0] - back.plan.trajectories.evaluate(ts)[0])
    assert err.max() < 1e-3
