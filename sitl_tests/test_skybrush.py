"""Shows from and to Skybrush: .skyc and CSV import, export and round trip, every conflict
found and repaired, a dry-run of an imported show, hostile archives refused, files that are
not what a command reads named."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from flight_fixtures import QUICK_SHOW, REPO
from skyc_fixtures import (
    LIGHTS,
    calm_drones,
    crossing_drones,
    drone,
    show_doc,
    write_skyc,
)

from groundctl.errors import EXIT_OK, EXIT_UNSAFE, EXIT_USAGE, ImportedShowError
from groundctl.plan.planner import plan_show
from groundctl.show.loader import load_show
from groundctl.skybrush import lights
from groundctl.skybrush.convert import plan_to_sky
from groundctl.skybrush.csvshow import write_csv_show
from groundctl.skybrush.importing import export_skyc, import_show
from groundctl.skybrush.sniff import Kind, sniff

GROUNDCTL = [sys.executable, "-m", "groundctl"]


def _run(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GROUNDCTL, *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout, check=False)


def _error_line(out: subprocess.CompletedProcess[str]) -> str:
    lines = [ln for ln in out.stderr.splitlines() if not ln.startswith("note: ")]
    assert len(lines) == 1, out.stderr
    assert "Traceback" not in out.stderr
    return lines[0]


@pytest.fixture(scope="module")
def quick_plan():  # type: ignore[no-untyped-def]
    return plan_show(load_show(QUICK_SHOW), workers=1).plan


def _crossing_pairs() -> list[dict[str, object]]:
    """Two pairs that swap places head on (1 and 2 at t = 10 s, 3 and 4 at t = 10 s, far
    from the first pair), and drone 5 that flies apart."""
    a, b, c = crossing_drones()
    return [a, b,
            drone("up", [0.0, 30.0, 0.0], [(15.0, [10.0, 30.0, 5.0])]),
            drone("down", [10.0, 30.0, 0.0], [(15.0, [0.0, 30.0, 5.0])]),
            c]


# -- the light program codec --------------------------------------------------------------


def test_a_hand_written_light_program_decodes_to_its_keys() -> None:
    keys = lights.decode(LIGHTS)
    assert keys[:2] == [lights.LightKey(0.0, (0, 0, 0)), lights.LightKey(0.0, (255, 0, 0))]
    assert lights.LightKey(1.0, (255, 0, 0)) in keys
    assert keys[-1] == lights.LightKey(3.0, (0, 0, 255))


def test_light_programs_round_trip_with_long_durations_and_steps() -> None:
    keys = [lights.LightKey(0.0, (10, 20, 30)), lights.LightKey(4.0, (10, 20, 30)),
            lights.LightKey(9.0, (200, 0, 7)), lights.LightKey(9.0, (0, 255, 0)),
            lights.LightKey(300.0, (1, 2, 3))]
    code = lights.encode(keys)
    back = lights.decode(code)
    assert back[-1] == lights.LightKey(300.0, (1, 2, 3))
    assert lights.LightKey(9.0, (0, 255, 0)) in back and lights.LightKey(9.0, (200, 0, 7)) \
        in back
    assert lights.encode(back[1:]) == code  # the leading black key is the drone's own


def test_loops_are_unrolled_and_radio_channels_refused() -> None:
    loop = bytes([0x0C, 3, 0x04, 255, 255, 255, 5, 0x06, 5, 0x0D, 0x00])
    keys = lights.decode(loop)
    assert keys[-1].t == pytest.approx(0.6)
    assert sum(k.rgb == (255, 255, 255) for k in keys) >= 3
    with pytest.raises(lights.LightProgramError, match="radio channels"):
        lights.decode(bytes([0x10, 0, 1, 2, 5]))
    with pytest.raises(lights.LightProgramError, match="unknown command"):
        lights.decode(bytes([0x7F]))
    with pytest.raises(lights.LightProgramError, match="ends inside a command"):
        lights.decode(bytes([0x04, 1, 2]))


# -- a hand-made .skyc ----------------------------------------------------------------------


def test_a_hand_made_skyc_is_read_as_written(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones()))
    assert sniff(path) is Kind.SKYC
    r = import_show(path)
    plan = r.plan
    assert r.safe and not r.conflicts
    assert plan.drones == 3 and plan.show_name == "hand-made"
    # Up and at rest at t = 3 s, 5 m above home; the last rest before landing at 17 s.
    assert r.imported.t0 == pytest.approx(3.0) and r.imported.t_end == pytest.approx(17.0)
    assert plan.takeoff_altitude == pytest.approx(5.0) and plan.duration == pytest.approx(14.0)
    assert plan.limits.min_separation == 1.5 and plan.limits.max_alt == 50.0
    np.testing.assert_allclose(plan.home[1], [4.0, 0.0, 0.0])
    # Skybrush time 10 s is half way along the 5 -> 15 s move (a rest-to-rest cubic).
    pos, vel, _ = plan.trajectories.evaluate(7.0)
    np.testing.assert_allclose(pos[2], [8.0, 3.0, 5.0], atol=1e-9)
    np.testing.assert_allclose(vel[2], [0.0, 1.5 * 6.0 / 10.0, 0.0], atol=1e-9)
    # The program faded to blue by 3 s: blue from the plan's start on.
    np.testing.assert_allclose(plan.colors_at(0.0)[0], [0.0, 0.0, 1.0])


def test_a_skyc_with_references_and_a_takeoff_time(tmp_path: Path) -> None:
    d = calm_drones()[0]
    traj = d["settings"]["trajectory"]  # type: ignore[index]
    traj["takeoffTime"] = 2.0
    d["settings"]["trajectory"] = {"$ref": "./drones/d1/trajectory.json#"}  # type: ignore[index]
    doc = show_doc([d])
    path = tmp_path / "ref.skyc"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("show.json", json.dumps(doc))
        zf.writestr("drones/d1/trajectory.json", json.dumps(traj))
    r = import_show(path)
    assert r.imported.t0 == pytest.approx(5.0) and r.plan.duration == pytest.approx(14.0)


def test_a_sideways_takeoff_is_refused_naming_the_drone(tmp_path: Path) -> None:
    doc = show_doc(calm_drones())
    pts = doc["swarm"]["drones"][1]["settings"]["trajectory"]["points"]
    pts[1] = [3.0, [6.0, 0.0, 5.0], []]  # climbs diagonally
    with pytest.raises(ImportedShowError, match=r"drone 2 \(d2\) is .* sideways"):
        import_show(write_skyc(tmp_path / "side.skyc", doc))


# -- export and round trip ------------------------------------------------------------------


def test_an_exported_plan_is_a_skyc_skybrush_reads(quick_plan, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path = export_skyc(quick_plan, tmp_path / "quick.skyc")
    doc = json.loads(zipfile.ZipFile(path).read("show.json"))
    assert doc["version"] == 1 and len(doc["swarm"]["drones"]) == 9
    s = doc["swarm"]["drones"][0]["settings"]
    assert s["home"] == pytest.approx(list(quick_plan.home[0]))
    assert s["trajectory"]["version"] == 1 and s["lights"]["version"] == 1
    pts = s["trajectory"]["points"]
    assert pts[0][2] == [] and all(len(p[2]) in (0, 2) for p in pts[1:])  # straight: none
    assert pts[0][1] == pytest.approx(list(quick_plan.home[0]))
    assert base64.b64decode(s["lights"]["data"])[-1] == lights.END
    assert doc["settings"]["validation"]["minDistance"] == quick_plan.limits.min_separation


def test_round_trip_keeps_trajectories_within_1_cm_and_colours_exact(  # type: ignore[no-untyped-def]
        quick_plan, tmp_path: Path) -> None:
    plan = quick_plan
    path = export_skyc(plan, tmp_path / "quick.skyc")
    r = import_show(path, plan.origin, limits=plan.limits)
    back = r.plan
    assert r.safe and back.drones == plan.drones
    assert back.duration == pytest.approx(plan.duration, abs=1e-6)
    assert back.takeoff_altitude == pytest.approx(plan.takeoff_altitude, abs=1e-3)
    ts = np.linspace(0.0, plan.duration, 4001)
    err = np.abs(plan.trajectories.evaluate(ts)[0] - back.trajectories.evaluate(ts)[0]).max()
    assert err < 0.01
    for t in plan.color_times:
        want = np.round(plan.colors_at(float(t)) * 255) / 255
        np.testing.assert_array_equal(back.colors_at(float(t)), want)
    # And again: the same light bytecode, the same curves.
    again = export_skyc(back, tmp_path / "again.skyc")
    d1 = json.loads(zipfile.ZipFile(path).read("show.json"))["swarm"]["drones"]
    d2 = json.loads(zipfile.ZipFile(again).read("show.json"))["swarm"]["drones"]
    assert [d["settings"]["lights"] for d in d1] == [d["settings"]["lights"] for d in d2]


def test_plan_writes_a_skyc_and_reads_it_back_on_the_command_line(tmp_path: Path) -> None:
    out = _run("plan", str(QUICK_SHOW), "-o", str(tmp_path / "quick.skyc"))
    assert out.returncode == EXIT_OK, out.stderr
    assert sniff(tmp_path / "quick.skyc") is Kind.SKYC
    back = _run("plan", str(tmp_path / "quick.skyc"), "--json")
    assert back.returncode == EXIT_OK, back.stderr
    report = json.loads(back.stdout)
    assert report["safe"] and report["drones"] == 9 and report["conflicts"] == []
    assert report["written"] == str(tmp_path / "quick.plan.npz")


# -- CSV -----------------------------------------------------------------------------------


def test_csv_folder_and_zip_of_an_exported_plan(quick_plan, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sky, climb = plan_to_sky(quick_plan)
    folder = write_csv_show(sky, tmp_path / "csv", fps=10)
    assert sniff(folder) is Kind.CSV_DIR
    zipped = tmp_path / "csv.zip"
    with zipfile.ZipFile(zipped, "w") as zf:
        for f in sorted(folder.iterdir()):
            zf.write(f, f"export/{f.name}")
    assert sniff(zipped) is Kind.CSV_ZIP
    ts = np.linspace(0.5, quick_plan.duration - 0.5, 2001)
    want = quick_plan.trajectories.evaluate(ts)[0]
    for source in (folder, zipped):
        r = import_show(source, quick_plan.origin, limits=quick_plan.limits)
        assert r.safe, r.lines()
        offset = r.imported.t0 - r.imported.climb_s - climb  # plan 0 on the CSV's clock
        got = r.plan.trajectories.evaluate(ts - offset)[0]
        assert np.abs(got - want).max() < 0.01


def test_a_hand_made_csv_folder(tmp_path: Path) -> None:
    folder = tmp_path / "Show"
    folder.mkdir()
    for i, x in enumerate((0.0, 3.0)):
        rows = ["Time [msec],x [m],y [m],z [m],Red,Green,Blue"]
        for ms in range(0, 16001, 250):
            t = ms / 1000.0
            z = 4.0 * min(t / 4.0, 1.0) if t <= 12.0 else 4.0 * max(0.0, (16.0 - t) / 4.0)
            y = 0.0 if t <= 4.0 else 5.0 * min((t - 4.0) / 8.0, 1.0)
            if 4.0 < t < 12.0:
                z = 4.0
            rows.append(f"{ms},{x:.3f},{y:.3f},{z:.3f},{255 * i},0,{int(t * 10)}")
        (folder / f"Drone {i + 1}.csv").write_text("\n".join(rows) + "\n")
    r = import_show(folder)
    assert r.plan.drones == 2 and [d.name for d in r.source.drones] == ["Drone 1", "Drone 2"]
    np.testing.assert_allclose(r.plan.home[1], [3.0, 0.0, 0.0])
    assert r.plan.takeoff_altitude == pytest.approx(4.0, abs=1e-3)
    # Colour rows are exact: 7.0 s into the CSV is blue 70.
    t_plan = 7.0 - r.imported.t0 + r.imported.climb_s
    assert r.plan.colors_at(t_plan)[1] * 255 == pytest.approx([255, 0, 70])


def test_a_bad_csv_names_the_file_and_line(tmp_path: Path) -> None:
    folder = tmp_path / "bad"
    folder.mkdir()
    (folder / "d1.csv").write_text("0,0,0,0,0,0,0\n100,0,0,0.1,0,0\n")
    out = _run("plan", str(folder))
    assert out.returncode == EXIT_USAGE
    assert "d1.csv: line 2: 6 columns, not 7" in _error_line(out)


# -- conflicts and repair ------------------------------------------------------------------


def test_every_conflict_is_listed_and_the_exit_is_non_zero(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "cross.skyc", show_doc(_crossing_pairs()))
    out = _run("plan", str(path))
    assert out.returncode == EXIT_UNSAFE, out.stderr
    conflicts = [ln for ln in out.stdout.splitlines() if ln.startswith("conflict: ")]
    assert len(conflicts) == 2
    assert "drones 1 (left) and 2 (right) come 0.000 m apart at t = 7.00 s" in conflicts[0]
    assert "[show time 10.00 s]" in conflicts[0]
    assert "drones 3 (up) and 4 (down)" in conflicts[1]
    assert out.stdout.splitlines()[-2].startswith("UNSAFE: ")


def test_repair_replans_only_the_conflicting_stretches(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "cross.skyc", show_doc(_crossing_pairs()))
    before = import_show(path)
    fixed_path = tmp_path / "fixed.skyc"
    out = _run("plan", str(path), "--repair", "-o", str(fixed_path))
    assert out.returncode == EXIT_OK, out.stdout + out.stderr
    assert sum(ln.startswith("repaired: ") for ln in out.stdout.splitlines()) == 2
    # Verified safe again, read back from the file written.
    after = import_show(fixed_path, limits=before.plan.limits)
    assert after.safe and not after.conflicts
    assert after.verification.overall.min_separation >= 1.5 - 1e-3
    # The rest unchanged within 1 cm: drone 5 throughout, everyone outside 5..15 s.
    ts = np.linspace(0.0, before.plan.duration, 2801)
    a = before.plan.trajectories.evaluate(ts)[0]
    b = after.plan.trajectories.evaluate(ts)[0]
    assert np.abs(a[4] - b[4]).max() < 0.01
    outside = (ts < 2.0 - 1e-6) | (ts > 12.0 + 1e-6)
    assert np.abs(a[:, outside] - b[:, outside]).max() < 0.01
    # Inside, the pairs really moved apart.
    assert np.abs(a[:2, ~outside] - b[:2, ~outside]).max() > 0.5


def test_dry_run_refuses_a_conflicting_show_without_repair(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "cross.skyc", show_doc(crossing_drones()))
    out = _run("dry-run", str(path), "--no-record", "--no-console")
    assert out.returncode == EXIT_UNSAFE
    assert "drones 1 (left) and 2 (right)" in _error_line(out)


@pytest.mark.slow
def test_dry_run_flies_an_imported_show_against_the_simulator(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones()))
    out = _run("dry-run", str(path), "--speed", "8", "--ready-delay", "2", "--json",
               "--no-record", "--no-console", "--origin", "47.3977,8.5456,488", timeout=240)
    assert out.returncode == EXIT_OK, out.stderr
    report = json.loads(out.stdout)
    assert report["safe"] and report["landed"] and len(report["vehicles"]) == 3
    assert report["min_separation_m"] > 3.5
    assert report["max_tracking_error_m"] < 0.5
    # Pre-flight's polls (origin, home) asked again until the vehicles can answer are
    # not refusals: the link counts no refusal beyond the flight's own commands (none on
    # a clean flight; one a busy machine provoked would be in both).
    assert report["commands_refused"] == sum(v["commands_refused"]
                                             for v in report["vehicles"])
    assert sorted(v["name"] for v in report["vehicles"]) == ["d1", "d2", "d3"]


@pytest.mark.slow
def test_dry_run_flies_a_repaired_show(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "cross.skyc", show_doc(crossing_drones()))
    out = _run("dry-run", str(path), "--repair", "--speed", "8", "--ready-delay", "2",
               "--json", "--no-record", "--no-console", timeout=240)
    assert out.returncode == EXIT_OK, out.stderr
    report = json.loads(out.stdout)
    assert report["safe"] and report["true_min_separation_m"] > 1.0


# -- files that are not what the command reads ----------------------------------------------


def test_check_of_a_show_file_says_it_is_a_show() -> None:
    out = _run("check", "shows/quick.toml")
    assert out.returncode == EXIT_USAGE
    line = _error_line(out)
    assert "shows/quick.toml: is a show file (TOML), not a plan file" in line
    assert "pickle" not in line


def test_check_of_a_skyc_and_plan_of_a_plan_file_say_what_they_are(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones()))
    out = _run("check", str(path))
    assert out.returncode == EXIT_USAGE
    assert "is a Skybrush compiled show (.skyc), not a plan file" in _error_line(out)
    planned = _run("plan", str(path))
    assert planned.returncode == EXIT_OK, planned.stderr
    out = _run("plan", str(tmp_path / "calm.plan.npz"))
    assert out.returncode == EXIT_USAGE
    assert "is a groundctl plan file (.npz), not a show" in _error_line(out)


def test_a_skyc_that_is_not_a_zip_is_not_called_utf8(tmp_path: Path) -> None:
    path = tmp_path / "x.skyc"
    path.write_bytes(bytes(range(256)) * 4)
    out = _run("plan", str(path))
    assert out.returncode == EXIT_USAGE
    line = _error_line(out)
    assert "not a Skybrush .skyc show: not a zip archive" in line and "UTF-8" not in line


def _huge_member(path: Path, name: str = "show.json", size: int = 80 << 20) -> Path:
    chunk = b" " * (1 << 20)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf, \
            zf.open(name, "w", force_zip64=True) as f:
        for _ in range(size >> 20):
            f.write(chunk)
    return path


@pytest.mark.parametrize("make, message", [
    (lambda p: _huge_member(p), "declares 80.0 MiB uncompressed, more than 64.0 MiB"),
    (lambda p: write_skyc(p, {"version": 1}) and _add(p, "../../etc/evil.json", b"{}"),
     "points outside the archive"),
    (lambda p: write_skyc(p, show_doc([calm_drones()[0]] * 10_001)),
     "10001 drones, more than the 10000"),
    (lambda p: write_skyc(p, {"version": 2, "swarm": {"drones": []}}),
     "'version' is 2; groundctl reads version 1"),
    (lambda p: _many_members(p, 1200), "lists 1200 members, more than the 1100"),
])
def test_a_hostile_skyc_is_refused_in_one_line(make, message: str, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "hostile.skyc"
    make(path)
    out = _run("plan", str(path), timeout=60)
    assert out.returncode == EXIT_USAGE, out.stdout + out.stderr
    assert message in _error_line(out)


def _add(path: Path, name: str, data: bytes) -> Path:
    with zipfile.ZipFile(path, "a") as zf:
        zf.writestr(name, data)
    return path


def _many_members(path: Path, count: int) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for i in range(count):
            zf.writestr(f"m{i}.json", b"")
    return path


def test_a_member_bigger_than_it_declares_is_refused(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "lie.skyc", show_doc(calm_drones()))
    raw = bytearray(path.read_bytes())
    # Shrink the declared size in both headers: the inflated data is then too long.
    size = len(zipfile.ZipFile(path).read("show.json"))
    old, new = size.to_bytes(4, "little"), (size // 2).to_bytes(4, "little")
    assert raw.count(old) >= 2
    path.write_bytes(bytes(raw).replace(old, new))
    with pytest.raises(ImportedShowError, match=r"does not hold the size|corrupt"):
        import_show(path)


def test_bad_origin_is_refused() -> None:
    out = _run("plan", "x.skyc", "--origin", "95,8,400")
    assert out.returncode == EXIT_USAGE
    assert "--origin" in out.stderr and "lat" in out.stderr


def test_the_shows_geofence_is_checked_and_written_back(tmp_path: Path) -> None:
    doc = show_doc(calm_drones())
    doc["settings"]["geofence"] = {"version": 1, "polygons": [  # type: ignore[index]
        {"isInclusion": True, "points": [[-2, -2, 0], [6, -2, 0], [6, 8, 0], [-2, 8, 0]]}]}
    path = write_skyc(tmp_path / "fenced.skyc", doc)
    out = _run("plan", str(path))
    assert out.returncode == EXIT_UNSAFE
    assert any("outside the geofence" in ln for ln in out.stdout.splitlines())
    r = import_show(path)
    assert r.plan.limits.geofence == ((-2.0, -2.0), (6.0, -2.0), (6.0, 8.0), (-2.0, 8.0))
    again = import_show(export_skyc(r.plan, tmp_path / "again.skyc"))
    assert again.plan.limits.geofence == r.plan.limits.geofence


def test_wait_until_gray_and_white_decode() -> None:
    # SET_GRAY 128 for 10 frames, WAIT_UNTIL frame 50 (1 s), FADE_TO_WHITE over 25 frames.
    keys = lights.decode(bytes([0x05, 128, 10, 0x03, 50, 0x0B, 25, 0x00]))
    assert lights.LightKey(1.0, (128, 128, 128)) in keys
    assert keys[-1] == lights.LightKey(1.5, (255, 255, 255))


def _frames_played(code: bytes, frames: int) -> list[tuple[int, int, int]]:
    """The colour at each 20 ms frame 0..frames-1, from the decoded keys (linear between
    keys, the later of two keys at one time holding from then on)."""
    keys = lights.decode(code)
    out = []
    for f in range(frames):
        t = f * lights.UNIT_S + 1e-9
        before = [k for k in keys if k.t <= t]
        after = [k for k in keys if k.t > t]
        a = before[-1]
        if not after:
            out.append(a.rgb)
            continue
        b = after[0]
        w = (t - a.t) / (b.t - a.t)
        out.append(tuple(round(x + (y - x) * w) for x, y in zip(a.rgb, b.rgb, strict=True)))
    return out


def test_wait_until_counts_frames_as_skybrush_plays_it() -> None:
    # White, WAIT_UNTIL frame 500 (10 s; varint f4 03), then red for 1 s: Skybrush's
    # player turns the drone red at frame 500 exactly, not at 0.5 s.
    code = bytes([0x07, 0, 0x03, 0xF4, 0x03, 0x04, 255, 0, 0, 50, 0x00])
    played = _frames_played(code, 560)
    assert played[:500] == [(255, 255, 255)] * 500
    assert played[500:550] == [(255, 0, 0)] * 50
    # After RESET_CLOCK the deadline counts from there: white 2 s, reset, wait until frame
    # 100 of the new clock (4 s in all), then green.
    code = bytes([0x07, 100, 0x0E, 0x03, 100, 0x04, 0, 255, 0, 10, 0x00])
    played = _frames_played(code, 210)
    assert played[199] == (255, 255, 255) and played[200] == (0, 255, 0)


def test_straight_segments_with_corners_are_reported(tmp_path: Path) -> None:
    doc = show_doc(calm_drones())
    pts = doc["swarm"]["drones"][0]["settings"]["trajectory"]["points"]
    pts[3] = [15.0, pts[3][1], []]  # the 5 -> 15 s move as a straight segment: corners
    out = _run("plan", str(write_skyc(tmp_path / "corner.skyc", doc)))
    assert out.returncode == EXIT_UNSAFE
    corners = [ln for ln in out.stdout.splitlines() if "changes velocity by" in ln]
    assert len(corners) == 2 and "drone 1 (d1) changes velocity by 0.60 m/s" in corners[0]


def test_a_takeoff_altitude_below_the_show_climbs_the_rest_in_the_plan(tmp_path: Path) -> None:
    path = write_skyc(tmp_path / "calm.skyc", show_doc(calm_drones()))
    r = import_show(path, takeoff_altitude=3.0)
    plan = r.plan
    assert plan.takeoff_altitude == 3.0 and r.imported.climb_s > 0
    np.testing.assert_allclose(plan.trajectories.pos[:, 0], plan.home + np.array([0.0, 0.0, 3.0]))
    np.testing.assert_allclose(plan.trajectories.evaluate(r.imported.climb_s)[0][:, 2], 5.0)
    assert r.safe, r.lines()
