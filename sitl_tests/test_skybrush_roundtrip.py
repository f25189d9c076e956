"""Skybrush shows as Skybrush means them, through import and export: each drone exported
with its own segments and within the size Skybrush's server uploads, the show placed
where ``environment.location`` puts it, drone names and cues kept, and Skybrush's drone
limit.  Hand-made ``show.json`` documents (:mod:`skyc_fixtures`), read back as JSON."""

from __future__ import annotations

import base64
import json
import math
import subprocess
import sys
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
import pytest
from flight_fixtures import REPO
from skyc_fixtures import LIGHTS, calm_drones, drone, show_doc, write_skyc

from groundctl.errors import EXIT_USAGE, PlanFileError, SkybrushExportError
from groundctl.execute.frames import show_to_enu
from groundctl.plan.plan import Cue, Plan
from groundctl.show.model import GeoOrigin
from groundctl.skybrush.importing import export_skyc, import_show
from groundctl.skybrush.model import BezierTrack, SkyDrone, SkyShow, heading_of
from groundctl.skybrush.writer import (
    MAX_TRAJECTORY_BYTES,
    drone_json,
    trajectory_bytes,
)
from groundctl.skybrush.writer import (
    write_skyc as write_sky_show,
)

GROUNDCTL = [sys.executable, "-m", "groundctl"]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GROUNDCTL, *args], capture_output=True, text=True, cwd=REPO,
                          timeout=300)


def _drones_of(path: Path) -> list[dict[str, Any]]:
    drones: list[dict[str, Any]] = json.loads(
        zipfile.ZipFile(path).read("show.json"))["swarm"]["drones"]
    return drones


def _interleaved(n: int = 8, moves: int = 12) -> list[dict[str, Any]]:
    """``n`` drones 4 m apart, each making ``moves`` moves on its own clock: drone i's
    moves end 0.13 i s later than drone 0's, so no two drones share a knot."""
    out = []
    for i in range(n):
        x = 4.0 * i
        steps = [(8.0 + 4.0 * k + 0.13 * i,
                  [x + 0.4 * math.sin(k + i), 1.0 * k, 5.0 + 0.5 * ((k + i) % 3)])
                 for k in range(moves)]
        out.append(drone(f"wander_{i + 1}", [x, 0.0, 0.0], steps))
    return out


# -- each drone with its own segments, within Skybrush's upload size ------------------------


def test_an_export_keeps_each_drones_own_segments_and_round_trips(tmp_path: Path) -> None:
    source = write_skyc(tmp_path / "wander.skyc", show_doc(_interleaved()))
    r = import_show(source)
    assert r.safe, r.lines()
    own = [len(d["settings"]["trajectory"]["points"]) - 1 for d in _drones_of(source)]
    union = len(r.plan.trajectories.times) - 1
    assert union > 5 * max(own)  # every drone's knots together
    out = export_skyc(r.plan, tmp_path / "out.skyc")
    written = _drones_of(out)
    for d, n in zip(written, own, strict=True):
        # Its own segments: the show between takeoff and landing kept segment for
        # segment; the takeoff and landing re-timed (a drone that starts down while
        # another still flies keeps that stretch of its descent, then the re-timed one).
        assert len(d["settings"]["trajectory"]["points"]) - 1 <= n + 2
        assert trajectory_bytes(d["settings"]["trajectory"]["points"]) < 2000
    back = import_show(out, limits=r.plan.limits)
    assert back.safe
    ts = np.linspace(0.0, r.plan.duration, 20001)
    err = np.abs(r.plan.trajectories.evaluate(ts)[0] - back.plan.trajectories.evaluate(ts)[0])
    assert err.max() < 2e-4  # positions are written to 0.1 mm


def _long_track(segments: int) -> BezierTrack:
    """One drone wandering through ``segments`` curved 1 s segments in all three axes."""
    t = np.arange(segments + 1, dtype=float)
    p = np.column_stack([np.sin(t), np.cos(t), 5.0 + 0.5 * np.sin(0.7 * t)])
    v = np.column_stack([np.cos(t), -np.sin(t), 0.35 * np.cos(0.7 * t)])
    ctrl = np.stack([p[:-1], p[:-1] + v[:-1] / 3, p[1:] - v[1:] / 3, p[1:]], axis=1)
    return BezierTrack(t, ctrl)


def test_the_trajectory_size_is_skybrushs_encoding() -> None:
    # A scale byte and the start point (9), then per segment 3 bytes and per moving axis
    # 2 (straight) or 6 (curved) bytes; an axis that stays put costs nothing.
    points = [[0.0, [0.0, 0.0, 0.0], []],
              [1.0, [0.0, 0.0, 3.0], []],                          # straight up: 3 + 2
              [2.0, [1.0, 0.0, 3.0], [[0.2, 0.5, 3.0], [0.8, 0.5, 3.0]]],  # x, y curved
              [3.0, [1.0, 0.0, 3.0], []],                          # hover: 3
              [80.0, [1.0, 0.0, 3.0], []]]                         # 77 s: two pieces
    # The 77 s hover is split in two by the server; rounding may move a piece's axis by
    # a unit, so each of its axes is counted as straight: never below the server.
    assert trajectory_bytes(points) == 9 + 5 + (3 + 12) + 3 + 2 * (3 + 6)


def test_an_export_past_skybrushs_upload_size_is_refused_naming_the_drone(
        tmp_path: Path) -> None:
    small = SkyDrone("small", np.zeros(3), _long_track(10), ())
    big = SkyDrone("big", np.array([10.0, 0.0, 0.0]), _long_track(3200), ())
    entry = drone_json(big)
    assert trajectory_bytes(entry["settings"]["trajectory"]["points"]) \
        > MAX_TRAJECTORY_BYTES
    show = SkyShow(title="too long", drones=(small, big))
    path = tmp_path / "big.skyc"
    with pytest.raises(SkybrushExportError, match=r"drone 2 \(big\)'s trajectory is "
                                                  r"[\d,]+ bytes") as info:
        write_sky_show(show, path)
    assert info.value.drone == 2
    assert not path.exists()
    write_sky_show(SkyShow(title="fits", drones=(small,)), path)  # one that fits is written
    assert path.exists()


def test_an_export_of_more_drones_than_skybrush_loads_is_refused(tmp_path: Path) -> None:
    track = BezierTrack(np.array([0.0, 1.0]), np.zeros((1, 4, 3)))
    drones = tuple(SkyDrone(f"d{i}", np.zeros(3), track, ()) for i in range(5001))
    with pytest.raises(SkybrushExportError, match="5001 drones, more than the 5000 Skybrush"):
        write_sky_show(SkyShow(title="many", drones=drones), tmp_path / "many.skyc")
    # groundctl plan says so before planning a show that large.
    toml = (REPO / "benchmarks" / "fleet10k.toml").read_text().replace(
        "drones = 10000", "drones = 5001")
    show = tmp_path / "fleet5001.toml"
    show.write_text(toml)
    out = _run("plan", str(show), "-o", str(tmp_path / "fleet5001.skyc"))
    assert out.returncode == EXIT_USAGE
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert lines[-1].endswith("5001 drones, more than the 5000 Skybrush loads in one show")
    assert not (tmp_path / "fleet5001.skyc").exists()


# -- placement ---------------------------------------------------------------------------


def _placed(orientation: Any, amsl_mm: int | None = 512_300) -> dict[str, Any]:
    doc = show_doc(calm_drones())
    origin = [round(47.3977123 * 1e7), round(8.5456789 * 1e7)]
    if amsl_mm is not None:
        origin.append(amsl_mm)
    doc["environment"] = {"type": "outdoor",
                          "location": {"origin": origin, "orientation": orientation}}
    return doc


def test_environment_location_places_the_show_as_skybrush_does(tmp_path: Path) -> None:
    # calm_drones stand at x = 0, 4, 8 m along Skybrush's X axis: not symmetric.  At
    # orientation 30, X points 30 degrees east of north and Y 90 degrees to its left
    # (NWU), so drone 3's home (8, 0, 0) is 8 cos 30 m north and 8 sin 30 m east of the
    # origin; its geodetic position is computed here by pymap3d from those offsets.
    path = write_skyc(tmp_path / "placed.skyc", _placed(30.0))
    r = import_show(path)
    plan = r.plan
    assert r.placement is not None and r.placement.source == "file"
    assert plan.origin.lat == pytest.approx(47.3977123, abs=1e-9)
    assert plan.origin.lon == pytest.approx(8.5456789, abs=1e-9)
    assert plan.origin.alt == pytest.approx(512.3)
    north, east = 8.0 * math.cos(math.radians(30.0)), 8.0 * math.sin(math.radians(30.0))
    want = pymap3d.enu2geodetic(east, north, 0.0, 47.3977123, 8.5456789, 512.3)
    enu = show_to_enu(plan.origin, plan.home[2:3])[0]
    got = pymap3d.enu2geodetic(*enu, plan.origin.lat, plan.origin.lon, plan.origin.alt)
    assert got[0] == pytest.approx(want[0], abs=1e-9)  # ~0.1 mm
    assert got[1] == pytest.approx(want[1], abs=1e-9)
    assert got[2] == pytest.approx(want[2], abs=1e-4)
    # A point on Skybrush's +Y is 90 degrees to the left of +X: at bearing 300.
    left = show_to_enu(plan.origin, np.array([[0.0, 5.0, 0.0]]))[0]
    assert math.degrees(math.atan2(left[0], left[1])) % 360.0 == pytest.approx(300.0)
    # Written back on export, and read again the same.
    out = export_skyc(plan, tmp_path / "again.skyc")
    loc = json.loads(zipfile.ZipFile(out).read("show.json"))["environment"]["location"]
    assert loc == {"origin": [473977123, 85456789, 512300], "orientation": 30.0}
    o, o2 = plan.origin, import_show(out).plan.origin
    assert (o2.lat, o2.lon, o2.alt, o2.heading_deg) == pytest.approx(
        (o.lat, o.lon, o.alt, o.heading_deg))


def test_origin_on_the_command_line_overrides_the_files_placement_in_one_line(
        tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "placed.skyc", _placed("30"))  # Live keeps it as text
    out = _run("plan", str(path), "--origin", "46.5,7.25,600", "-o",
               str(tmp_path / "p.npz"))
    assert out.returncode == 0, out.stderr
    notes = [ln for ln in out.stderr.splitlines() if "overrides" in ln]
    assert len(notes) == 1 and "--origin overrides the show's own placement" in notes[0]
    plan = Plan.load(tmp_path / "p.npz")
    # The origin is the operator's; the orientation, not given, stays the file's.
    assert (plan.origin.lat, plan.origin.lon, plan.origin.alt) == (46.5, 7.25, 600.0)
    assert plan.origin.heading_deg == pytest.approx(heading_of(30.0))
    out = _run("plan", str(path), "--origin", "46.5,7.25,600,90", "-o",
               str(tmp_path / "q.npz"))
    assert Plan.load(tmp_path / "q.npz").origin.heading_deg == pytest.approx(0.0)


def test_a_location_without_altitude_says_which_altitude_it_takes(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "placed.skyc", _placed(0.0, amsl_mm=None))
    out = _run("plan", str(path), "-o", str(tmp_path / "p.npz"))
    assert out.returncode == 0, out.stderr
    assert "z = 0 at 488 m (a stand-in: the show gives no altitude above sea level)" \
        in out.stderr
    # Real vehicles do not fly a stand-in altitude: fly refuses before connecting.
    out = _run("fly", str(path), "--connect", "udp:127.0.0.1:14999", "--connect-timeout", "2",
               "--no-console")
    assert out.returncode == EXIT_USAGE
    assert "gives no altitude above sea level" in out.stderr.strip().splitlines()[-1]


def test_a_show_without_location_is_skybrushs_orientation_0_and_says_so(
        tmp_path: Path) -> None:
    # Skybrush Live places an unplaced show at orientation 0: its X axis north, Y west.
    # calm_drones' drone 3 stands 8 m along X: 8 m north of the origin.
    path = write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones()))
    plan = import_show(path).plan
    east, north, _ = show_to_enu(plan.origin, plan.home[2:3])[0]
    assert north == pytest.approx(8.0) and east == pytest.approx(0.0, abs=1e-9)
    out = _run("plan", str(path), "-o", str(tmp_path / "p.npz"))
    notes = [ln for ln in out.stderr.splitlines() if ln.startswith("note: placed at")]
    assert len(notes) == 1 and "its X axis at bearing 0 deg (not placed by the show" \
        in notes[0]


def test_a_bad_location_is_refused_in_one_line(tmp_path: Path) -> None:
    doc = _placed(30.0)
    doc["environment"]["location"]["origin"] = [95e7, 8e7]  # 95 degrees north
    out = _run("plan", str(write_skyc(tmp_path / "bad.skyc", doc)))
    assert out.returncode == EXIT_USAGE
    assert "environment.location latitude" in out.stderr.strip().splitlines()[-1]


# -- names and cues ------------------------------------------------------------------------


def test_names_and_cues_survive_import_plan_file_and_export(tmp_path: Path) -> None:
    doc = show_doc([drone(name, [4.0 * i, 0.0, 0.0], [(15.0, [4.0 * i, 6.0, 5.0])], LIGHTS)
                    for i, name in enumerate(["Alpha", "Bravo", "Charlie"])])
    doc["settings"]["cues"] = {"version": 1, "items": [{"time": 12.5, "name": "Chorus"},
                                                       {"time": 4.0, "name": "Intro"}]}
    r = import_show(write_skyc(tmp_path / "named.skyc", doc))
    plan = r.plan
    assert plan.names == ("Alpha", "Bravo", "Charlie")
    shift = r.imported.t0 - r.imported.climb_s  # Skybrush time of plan time 0
    assert [(c.name, round(c.time + shift, 6)) for c in plan.cues] == [("Intro", 4.0),
                                                                       ("Chorus", 12.5)]
    saved = Plan.load(plan.save(tmp_path / "named.plan.npz"))
    assert saved.names == plan.names and saved.cues == plan.cues
    last, nxt = saved.cue_at(12.5 - shift)
    assert last is not None and last.name == "Chorus" and nxt is None
    out = export_skyc(saved, tmp_path / "again.skyc")
    written = json.loads(zipfile.ZipFile(out).read("show.json"))
    assert [d["settings"]["name"] for d in written["swarm"]["drones"]] == \
        ["Alpha", "Bravo", "Charlie"]
    again = import_show(out).plan
    # On the plan's clock the cues are where they were (the export's climb is the time
    # its Skybrush clock runs ahead of the plan's, and the import takes it off again).
    assert [(c.name, round(c.time, 5)) for c in again.cues] == \
        [(c.name, round(c.time, 5)) for c in plan.cues]
    assert again.names == plan.names


def test_bad_cues_never_refuse_a_show(tmp_path: Path) -> None:
    doc = show_doc(calm_drones())
    doc["settings"]["cues"] = {"version": 1, "items": [
        {"time": -0.04, "name": "Before"},      # Studio's marker before the frame range
        {"time": "soon", "name": "Text"}, {"time": float("nan"), "name": "NaN"},
        {"time": 9000.0, "name": "Late"}, {"time": 7.0, "name": 12}, "not a cue"]}
    r = import_show(write_skyc(tmp_path / "cues.skyc", doc))
    shift = r.imported.t0 - r.imported.climb_s
    assert [(c.name, round(c.time + shift, 6)) for c in r.plan.cues] == [("Before", 0.0),
                                                                         ("cue 5", 7.0)]
    doc["settings"]["cues"] = "nonsense"
    assert import_show(write_skyc(tmp_path / "none.skyc", doc)).plan.cues == ()


def test_a_plan_file_with_bad_names_or_cues_is_refused(tmp_path: Path) -> None:
    r = import_show(write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones())))
    bad = replace(r.plan, names=("a", "b"))  # three drones
    with pytest.raises(PlanFileError, match="names 2 drones, the plan has 3"):
        Plan.load(bad.save(tmp_path / "bad.plan.npz"))
    late = replace(r.plan, cues=(Cue(5.0, "B"), Cue(1.0, "A")))  # not in time order
    with pytest.raises(PlanFileError, match="cues' are not in time order"):
        Plan.load(late.save(tmp_path / "late.plan.npz"))


def test_an_origin_given_in_code_is_used_as_it_is(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "placed.skyc", _placed(30.0))
    here = GeoOrigin(46.0, 7.0, 400.0, 12.0)
    r = import_show(path, here)
    assert r.plan.origin == here and r.placement is not None and r.placement.source == "code"


def test_the_console_shows_the_cues_on_the_show_clock(tmp_path: Path) -> None:
    from groundctl.console.model import cue_text
    r = import_show(write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones())))
    assert cue_text(r.plan, 3.0) == ""  # a show without cues says nothing
    plan = replace(r.plan, cues=(Cue(2.0, "Intro"), Cue(14.0, "Chorus")))
    assert cue_text(plan, None) == "next Intro at 2.0 s"  # before the show starts
    assert cue_text(plan, 1.0) == "next Intro in 1.0 s"
    assert cue_text(plan, 2.0) == "cue Intro · next Chorus in 12.0 s"
    assert cue_text(plan, 20.0) == "cue Chorus"


# -- the operator's limits ------------------------------------------------------------------


def test_limits_from_a_file_win_over_the_shows_validation(tmp_path: Path) -> None:
    # Drone 1 flies 30 m in 8 s rest to rest: 5.6 m/s at most, 2.8 m/s^2; the show's own
    # settings.validation allows 5 m/s.
    doc = show_doc([drone("fast", [0.0, 0.0, 0.0], [(13.0, [0.0, 30.0, 5.0])]),
                    drone("slow", [6.0, 0.0, 0.0], [(13.0, [6.0, 2.0, 5.0])])])
    path = write_skyc(tmp_path / "fast.skyc", doc)
    out = _run("plan", str(path), "-o", str(tmp_path / "a.npz"))
    assert out.returncode == 1 and "limit 5.0 m/s" in out.stdout
    faster = tmp_path / "faster.toml"
    faster.write_text("[limits]\nmax_speed_h = 6.0\n")
    out = _run("plan", str(path), "--limits", str(faster), "-o", str(tmp_path / "b.npz"))
    assert out.returncode == 0, out.stdout + out.stderr
    limits = Plan.load(tmp_path / "b.npz").limits
    assert limits.max_speed_h == 6.0 and limits.max_speed_up == 2.5  # the show's, kept
    slower = tmp_path / "slower.toml"
    slower.write_text("[limits]\nmax_speed_h = 4.0\n")  # the operator's vehicles: slower
    out = _run("plan", str(path), "--limits", str(slower), "-o", str(tmp_path / "c.npz"))
    assert out.returncode == 1 and "limit 4.0 m/s" in out.stdout


@pytest.mark.parametrize(("text", "message"), [
    ("[vehicle]\nfence = false\n", "no [limits] table"),
    ("[limits]\nmax_speed_h = -3\n", "max_speed_h"),
    ("[limits\n", "TOML syntax error"),
])
def test_a_bad_limits_file_is_one_line(text: str, message: str, tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones()))
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    out = _run("plan", str(path), "--limits", str(bad))
    assert out.returncode == EXIT_USAGE
    lines = [ln for ln in out.stderr.splitlines() if ln.strip() and not ln.startswith("note:")]
    assert len(lines) == 1 and message in lines[0]


def test_a_sliver_of_a_segment_is_joined_to_its_neighbour_on_export() -> None:
    from groundctl.skybrush.convert import own_segments
    # A curve sampled at knots 0, 1, 1.0004 and 2 s: three different cubics, the middle
    # one 0.4 ms long, which Skybrush's millisecond durations cannot hold.
    times = np.array([0.0, 1.0, 1.0004, 2.0])
    pos = np.column_stack([np.sin(times), times**2, np.zeros(4)])
    vel = np.column_stack([np.cos(times), 2 * times, np.zeros(4)])
    knots = own_segments(times, pos, vel)
    assert len(knots) == 3 and knots[0] == 0 and knots[-1] == 3
    assert np.diff(times[knots]).min() >= 0.001


def test_a_drones_own_segments_are_found_among_knots_a_millisecond_apart() -> None:
    from groundctl.plan.trajectory import Trajectories
    from groundctl.skybrush.convert import own_segments
    # One drone's own 40 curved pieces, 2 s each, on a grid that also holds 200 other
    # drones' knots a millisecond or a few beside its own (a big show's union of knots):
    # rounding makes a 1 ms piece's jerk differ by 1e-4 m/s^3 from its neighbours'.
    rng = np.random.default_rng(7)
    own_t = np.arange(41) * 2.0
    own = Trajectories(own_t, rng.uniform(-30, 30, (1, 41, 3)), rng.uniform(-3, 3, (1, 41, 3)))
    others = (own_t[rng.integers(1, 40, 200)] + rng.choice([-1, 1], 200)
              * rng.uniform(0.001, 0.004, 200))
    grid = np.unique(np.concatenate([own_t, others]))
    pos, vel, _ = own.evaluate(grid)
    knots = own_segments(grid, pos[0], vel[0])
    np.testing.assert_allclose(grid[knots], own_t)


def test_each_drone_is_exported_with_its_own_light_program(tmp_path: Path) -> None:
    # Six drones, each switching between two colours on its own beat (every 0.5 + 0.06 i
    # s): the plan's colour keys are every drone's together, the export each drone's own.
    def beat(i: int) -> bytes:
        frames = 25 + 3 * i
        code = bytearray()
        for k in range(60):
            code += bytes([0x04, 255 * (k % 2), 40 * i, 255 * (1 - k % 2), frames])
        return bytes(code + b"\x00")
    drones = [drone(f"b{i}", [4.0 * i, 0.0, 0.0], [(15.0, [4.0 * i, 6.0, 5.0])], beat(i))
              for i in range(6)]
    r = import_show(write_skyc(tmp_path / "beats.skyc", show_doc(drones)))
    assert len(r.plan.color_times) > 150  # every drone's keys together
    out = export_skyc(r.plan, tmp_path / "out.skyc")
    src = [d["settings"]["lights"]["data"] for d in drones]
    for d, data in zip(_drones_of(out), src, strict=True):
        mine = len(base64.b64decode(d["settings"]["lights"]["data"]))
        assert mine <= 2 * len(base64.b64decode(data))
    back = import_show(out, limits=r.plan.limits).plan
    for t in r.plan.color_times:  # and every colour as it was
        np.testing.assert_array_equal(np.round(back.colors_at(float(t)) * 255),
                                      np.round(r.plan.colors_at(float(t)) * 255))
