"""Rerun views (issue 13): replay, live stream and ``plan --rerun``, read back with Rerun's
own reader.

One real dry-run of the quick show (real UDP, the simulator in its own process,
x8) is flown once for the module with the live stream attached; its recording
directory is then replayed by ``groundctl replay`` as an operator runs it.
What the .rrd says is checked against the peers: the tlog decoded
independently (pymavlink's own tlog reader, the executor's own frame
conversion), report.json, events.jsonl.

rerun-sdk 0.41 has no ``rerun.dataframe`` (its ``ChunkStore.reader`` needs
datafusion, not installed): its chunk reader ``rerun.chunk.RrdReader`` is used.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from flight_fixtures import FAST, QUICK_SHOW, REPO, quick_plan
from pymavlink import mavutil
from rerun.chunk import RrdReader

from groundctl.errors import EXIT_OK, EXIT_USAGE
from groundctl.execute.frames import ned_to_show
from groundctl.flight.dryrun import DryRunOptions, fly_dry_run
from groundctl.link.state import GeoPoint
from groundctl.record.events import read_events
from groundctl.record.showclock import ShowClockLog, read_show_clock
from groundctl.viz.eventlog import event_level
from groundctl.viz.live import LiveRerun
from groundctl.viz.scene import RerunTarget
from groundctl.viz.tlogread import decode_tlog

GROUNDCTL = [sys.executable, "-m", "groundctl"]

pytestmark = pytest.mark.slow


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GROUNDCTL, *args], capture_output=True, text=True, cwd=REPO,
                          timeout=120, check=False)


@dataclass
class Entity:
    """One entity of an .rrd: its static components and its temporal rows."""

    static: dict[str, Any] = field(default_factory=dict)
    rows: dict[str, list[Any]] = field(default_factory=lambda: defaultdict(list))

    def column(self, name: str) -> list[Any]:
        return self.rows[name]

    def seconds(self, timeline: str = "show_time") -> np.ndarray:
        return np.array(self.rows[timeline], dtype=float)


def read_rrd(path: Path) -> dict[str, Entity]:
    """Every entity of the .rrd's recording, chunks merged (row order: chunk order)."""
    out: dict[str, Entity] = defaultdict(Entity)
    for chunk in RrdReader(path).stream().collect().stream():
        batch = chunk.to_record_batch()
        data: dict[str, list[Any]] = {}
        for name, col in zip(batch.schema.names, batch.columns, strict=True):
            if pa.types.is_duration(col.type) or pa.types.is_timestamp(col.type):
                data[name] = (col.cast(pa.int64()).to_numpy() / 1e9).tolist()  # s
            else:
                data[name] = col.to_pylist()
        ent = out[chunk.entity_path]
        n = chunk.num_rows
        if chunk.is_static:
            ent.static.update({k: v[-1] for k, v in data.items()})
            continue
        names = set(data) | set(ent.rows)
        for k in names:
            ent.rows[k].extend(data.get(k, [None] * n))
    return dict(out)


@dataclass(frozen=True)
class Flown:
    directory: Path
    report: dict[str, Any]
    live: Path
    replay: Path
    replay_run: subprocess.CompletedProcess[str]


@cache
def _flown(root: Path) -> Flown:
    directory = root / "quick"
    live_path = root / "live.rrd"
    live = LiveRerun(quick_plan(), [RerunTarget("save", str(live_path))])
    options = DryRunOptions(**FAST, record_dir=directory)
    try:
        result = asyncio.run(fly_dry_run(quick_plan(), options, on_runner=live.attach))
    finally:
        assert live.close() == []
    assert result.report["safe"], result.report["unsafe_reasons"]
    out = root / "replay.rrd"
    run = _run("replay", str(directory), "-o", str(out))
    return Flown(directory, result.report, live_path, out, run)


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> Flown:
    return _flown(tmp_path_factory.mktemp("rerun"))


@pytest.fixture(scope="module")
def replayed(flown: Flown) -> dict[str, Entity]:
    assert flown.replay_run.returncode == EXIT_OK, flown.replay_run.stderr
    return read_rrd(flown.replay)


def _tlog_messages(path: Path, kinds: set[str]) -> list[Any]:
    conn = mavutil.mavlink_connection(str(path))
    got = []
    while (m := conn.recv_match(type=list(kinds))) is not None:
        got.append(m)
    conn.close()
    return got


def test_the_recording_keeps_the_plan_and_the_show_clock(flown: Flown) -> None:
    names = {p.name for p in flown.directory.iterdir()}
    assert {"flight.tlog", "events.jsonl", "report.json", "plan.npz",
            "showclock.csv"} <= names
    clock = read_show_clock(flown.directory / "showclock.csv")
    started = clock.show_time_s[np.isfinite(clock.show_time_s)]
    assert started.size and started.max() == pytest.approx(quick_plan().duration)
    # The timeline counts up to the show's start and runs on after its end.
    line = clock.timeline()
    assert line[0] < 0 and line[-1] > quick_plan().duration
    assert np.all(np.diff(line) >= -1e-9)


def test_replay_has_every_view(flown: Flown, replayed: dict[str, Entity]) -> None:
    assert "written to" in flown.replay_run.stderr
    for path in ("/world/vehicles", "/world/trails", "/world/closest_pair",
                 "/world/plan/paths", "/world/plan/targets/1", "/world/plan/targets/2",
                 "/world/plan/closest/1", "/world/site/takeoff", "/series/separation/min",
                 "/series/separation/limit", "/series/tracking_error", "/series/lateness_ms",
                 "/series/battery", "/log"):
        assert path in replayed, path
    vehicles = replayed["/world/vehicles"]
    labels = {label for row in vehicles.column("Points3D:labels") for label in row}
    assert labels == {str(s) for s in range(1, 10)}
    assert set(vehicles.rows) >= {"show_time", "wall_time"}
    limit = replayed["/series/separation/limit"].column("Scalars:scalars")
    assert {x[0] for x in limit} == {quick_plan().limits.min_separation}
    # Nine lines of tracking error, named by vehicle.
    names = replayed["/series/tracking_error"].static["SeriesLines:names"]
    assert names == [f"vehicle {s}" for s in range(1, 10)]


def _row_at(ent: Entity, show_time: float) -> int:
    return int(np.argmin(np.abs(ent.seconds() - show_time)))


def test_a_vehicles_position_matches_the_tlog(flown: Flown,
                                              replayed: dict[str, Entity]) -> None:
    plan = quick_plan()
    ring = plan.formations[0]
    vehicles = replayed["/world/vehicles"]
    k = _row_at(vehicles, (ring.arrive + ring.end) / 2)  # held: the drones barely move
    wall = vehicles.seconds("wall_time")[k]
    labels = vehicles.column("Points3D:labels")[k]
    shown = np.array(vehicles.column("Points3D:positions")[k])
    msgs = _tlog_messages(flown.directory / "flight.tlog",
                          {"LOCAL_POSITION_NED", "GPS_GLOBAL_ORIGIN"})
    for sysid in (1, 5, 9):
        origin = next(m for m in msgs if m.get_type() == "GPS_GLOBAL_ORIGIN"
                      and m.get_srcSystem() == sysid)
        last = [m for m in msgs if m.get_type() == "LOCAL_POSITION_NED"
                and m.get_srcSystem() == sysid and m._timestamp <= wall][-1]
        ekf = GeoPoint(origin.latitude / 1e7, origin.longitude / 1e7, origin.altitude / 1e3)
        expected = ned_to_show(plan.origin, ekf, [last.x, last.y, last.z])
        got = shown[labels.index(str(sysid))]
        # Carried to the tick with its own velocity (< 0.1 s at hover speed).
        assert np.linalg.norm(got - expected) < 0.03, (sysid, got, expected)


def test_led_colours_are_the_led_control_sent(flown: Flown,
                                              replayed: dict[str, Entity]) -> None:
    # Compared in whole microseconds, the tlog's resolution: a colour sent at the tick's own
    # instant (a paced clock stands still within a tick) is sent at or before it.
    sent: dict[int, list[tuple[int, tuple[int, int, int]]]] = defaultdict(list)
    for m in _tlog_messages(flown.directory / "flight.tlog", {"LED_CONTROL"}):
        sent[m.target_system].append((round(m._timestamp * 1e6), tuple(m.custom_bytes[:3])))
    vehicles = replayed["/world/vehicles"]
    walls = np.round(vehicles.seconds("wall_time") * 1e6).astype(np.int64)
    seen = set()
    for k in range(0, len(walls), 7):
        for label, colour in zip(vehicles.column("Points3D:labels")[k],
                                 vehicles.column("Points3D:colors")[k], strict=True):
            before = [c for t, c in sent[int(label)] if t <= walls[k]]
            if not before:
                continue
            rgba = colour.to_bytes(4, "big")  # Rerun stores 0xRRGGBBAA
            assert tuple(rgba[:3]) == before[-1], (label, k)
            seen.add(before[-1])
    assert len(seen) > 3  # the ring's blue and the square's gradient were both seen


#: How far apart (in flight time) the monitor's and the replay's datings of one telemetry
#: sample may be: half a tick; see the test below.
DATING_S = 0.05


def _pair_speeds(replayed: dict[str, Entity], at: list[float]) -> float:
    """The largest |v_a| + |v_b| of the closest pair at each show time ``at``, from the
    replayed positions one tick either side (m/s)."""
    vehicles = replayed["/world/vehicles"]
    show = vehicles.seconds()
    labels = vehicles.column("Points3D:labels")
    points = vehicles.column("Points3D:positions")
    worst = 0.0
    for t in at:
        j = int(np.argmin(np.abs(show - t)))
        lo, hi = max(j - 1, 0), min(j + 1, len(show) - 1)
        here = np.array(points[j])
        d = np.linalg.norm(here[:, None] - here[None], axis=2) + np.diag(np.full(len(here),
                                                                                 np.inf))
        pair = np.unravel_index(int(np.argmin(d)), d.shape)
        speed = 0.0
        for i in pair:
            label = labels[j][i]
            if label in labels[lo] and label in labels[hi]:
                a = np.array(points[lo][labels[lo].index(label)])
                b = np.array(points[hi][labels[hi].index(label)])
                speed += float(np.linalg.norm(b - a)) / max(show[hi] - show[lo], 1e-9)
        worst = max(worst, speed)
    return worst


def test_minimum_separation_series_matches_the_report(flown: Flown,
                                                      replayed: dict[str, Entity]) -> None:
    series = replayed["/series/separation/min"]
    values = np.array([x[0] for x in series.column("Scalars:scalars")])
    k = int(np.argmin(values))
    # Both are the closest pair at the same ticks, from the same telemetry, but each dates
    # the samples its own way before carrying them to the tick: the monitor by the
    # TIMESYNC offset (never after a sample arrived), the replay by vehicle clocks fitted
    # to the tlog's receive times.  Where the two datings differ by dt, a pair's distance
    # differs by at most (|v_a| + |v_b|) dt: with the pair moving at 1.6 m/s, 4 ms apart
    # is the 6.7 mm once seen on a busy machine (against 0.5 mm idle).  The bound allows
    # DATING_S at both minima: the series' minimum is at most the series at the report's
    # tick, and the report's at most the monitor's value at the series' tick.
    report = flown.report
    speeds = _pair_speeds(replayed, [series.seconds()[k], report["min_separation_at_s"]])
    tolerance = 0.002 + DATING_S * speeds
    assert abs(values[k] - report["min_separation_m"]) <= tolerance, (
        values[k], report["min_separation_m"], speeds)
    pair = replayed["/world/closest_pair"]
    j = _row_at(pair, series.seconds()[k])
    assert pair.column("LineStrips3D:labels")[j] == [f"{values[k]:.2f} m"]
    # Tracking error: per vehicle against its report figures.  The monitor carries each
    # sample to the tick with TIMESYNC's clock offsets, the replay with vehicle clocks
    # fitted to the tlog's receive times: on a busy machine the receive times jitter, and
    # a single sample's difference moves the largest error by centimetres (2 cm RMS
    # apart on a machine running the whole suite beside two busy processes), so the RMS
    # is held to 3 cm and the largest to 10 cm.
    errors = np.array(replayed["/series/tracking_error"].column("Scalars:scalars"),
                      dtype=float)
    for j, v in enumerate(sorted(flown.report["vehicles"], key=lambda v: v["system_id"])):
        flown_err = errors[np.isfinite(errors[:, j]), j]
        assert float(np.sqrt(np.mean(flown_err ** 2))) == pytest.approx(
            v["rms_tracking_error_m"], abs=0.03)
        assert float(flown_err.max()) == pytest.approx(v["max_tracking_error_m"], abs=0.10)


def test_events_are_in_the_log_with_levels(flown: Flown, replayed: dict[str, Entity]) -> None:
    log = replayed["/log"]
    lines = list(zip(log.column("TextLog:level"), log.column("TextLog:text"), strict=True))
    events = read_events(flown.directory / "events.jsonl")
    assert len(lines) == len(events)
    texts = [t[0] for _, t in lines]
    assert any("show started" in t for t in texts)
    assert any(t.startswith("mode_changed vehicle 1:") and "GUIDED" in t for t in texts)
    # Each line at its event's level.  (A refused command was the flight's only warning,
    # and only when a request beat the EKF origin: a busy machine left none.)
    assert [lv[0] for lv, _ in lines] == [event_level(e) for e in events]
    assert event_level({"event": "command_refused"}) == "WARN"
    assert ["INFO"] in [lv for lv, t in lines if t[0].startswith("report:")]


def test_the_live_stream_shows_the_same_flight(flown: Flown) -> None:
    live = read_rrd(flown.live)
    for path in ("/world/vehicles", "/world/plan/paths", "/series/separation/min",
                 "/series/tracking_error", "/series/lateness_ms", "/log"):
        assert path in live, path
    sep = np.array([x[0] for x in live["/series/separation/min"].column("Scalars:scalars")])
    # The monitor's own positions: its minimum over the show is the report's.
    assert sep.min() == pytest.approx(flown.report["min_separation_m"], abs=0.005)
    late = np.array([x[0] for x in live["/series/lateness_ms"].column("Scalars:scalars")])
    assert late.size >= flown.report["setpoint_lateness_ms"]["ticks"] - 5
    show = live["/world/vehicles"].seconds()
    assert show.max() > quick_plan().duration


def test_a_damaged_tlog_is_replayed_up_to_the_damage(flown: Flown, tmp_path: Path) -> None:
    directory = tmp_path / "damaged"
    shutil.copytree(flown.directory, directory)
    tlog = directory / "flight.tlog"
    data = tlog.read_bytes()
    # Cut mid-record: half the file, or a byte on if half falls on a record boundary (the
    # flight's size varies with the machine; two boundaries are never a byte apart).
    half = len(data) // 2
    good = decode_tlog(data[:half])
    if good.damage is None:
        good = decode_tlog(data[:half + 1])
    assert good.damage is not None
    cut = good.damage.offset
    tlog.write_bytes(data[:cut] + b"\x00" * 40 + data[cut + 40:])  # zeros from there
    out = tmp_path / "damaged.rrd"
    run = _run("replay", str(directory), "-o", str(out))
    assert run.returncode == EXIT_USAGE
    errors = [line for line in run.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "Traceback" not in run.stderr
    assert f"at byte {cut} of {len(data)}" in errors[0]
    assert "replayed the" in errors[0] and "show time" in errors[0]
    rrd = read_rrd(out)
    vehicles = rrd["/world/vehicles"]
    stopped = float(errors[0].rsplit("show time ", 1)[1].split(" s")[0])
    shown = [len(p) for p, t in zip(vehicles.column("Points3D:positions"),
                                    vehicles.seconds(), strict=True) if t > stopped + 1.5]
    assert shown and not any(shown)  # nothing heard after the damage
    assert any(lv == ["ERROR"] and t[0].startswith("tlog:") for lv, t in
               zip(rrd["/log"].column("TextLog:level"), rrd["/log"].column("TextLog:text"),
                   strict=True))


def test_a_bare_tlog_replays_without_its_directory(flown: Flown, tmp_path: Path) -> None:
    tlog = tmp_path / "only.tlog"
    shutil.copy(flown.directory / "flight.tlog", tlog)
    run = _run("replay", str(tlog), "--plan", str(flown.directory / "plan.npz"))
    assert run.returncode == EXIT_OK, run.stderr
    assert "no show clock log" in run.stderr
    rrd = read_rrd(tmp_path / "only.rrd")
    assert {"/world/vehicles", "/world/plan/paths", "/log"} <= set(rrd)
    texts = [t[0] for t in rrd["/log"].column("TextLog:text")]
    assert any(t.startswith("heartbeat vehicle 3: GUIDED, armed") for t in texts)


def test_plan_rerun_of_a_bundled_show(tmp_path: Path) -> None:
    out = tmp_path / "quick.plan.npz"
    run = _run("plan", str(QUICK_SHOW), "-o", str(out), "--json", "--rerun")
    assert run.returncode == EXIT_OK, run.stderr
    report = json.loads(run.stdout)
    rrd = read_rrd(tmp_path / "quick.plan.rrd")
    for t in report["transitions"]:
        label = rrd[f"/world/plan/closest/{t['index']}"].static["LineStrips3D:labels"]
        assert f"{t['min_separation_m']:.2f} m (limit 1.5)" in label[0]
    fleet = rrd["/world/vehicles"]
    show = fleet.seconds()
    assert show.min() == 0.0 and show.max() == pytest.approx(report["duration_s"], abs=0.1)
    assert {len(p) for p in fleet.column("Points3D:positions")} == {9}
    assert "/world/plan/paths" in rrd and "/world/plan/targets/2" in rrd


def test_rerun_option_words_are_checked() -> None:
    run = _run("dry-run", str(QUICK_SHOW), "--rerun", "save")
    assert run.returncode == 2 and "--rerun takes nothing, 'spawn'" in run.stderr


def test_show_clock_log_drops_a_cut_last_line(tmp_path: Path) -> None:
    path = tmp_path / "showclock.csv"
    wall = iter([100.0, 100.1, 100.2])
    log = ShowClockLog(path, wall=lambda: next(wall))
    log.tick(1.0, None, 0.001)
    log.tick(1.2, 0.0, 0.002)
    log.tick(1.4, 0.2, None)
    log.close()
    path.write_text(path.read_text() + "100.3,1.6,0.")  # a crash mid-line
    clock = read_show_clock(path)
    assert clock.ticks == 3
    assert clock.timeline().tolist() == pytest.approx([-0.2, 0.0, 0.2])
    assert np.isnan(clock.lateness_ms[2]) and clock.lateness_ms[1] == pytest.approx(2.0)


def test_tlog_decoding_stops_at_the_first_bad_record(tmp_path: Path) -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from groundctl.link import messages
    from groundctl.link.codec import Encoder, new_codec
    from groundctl.record.tlog import TlogWriter

    path = tmp_path / "flight.tlog"
    gcs = Encoder(new_codec(255, 190))
    veh = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    t0 = 1_700_000_000.0
    first = [veh.gps_global_origin_encode(473977000, 85456000, 488000).pack(veh),
             veh.local_position_ned_encode(1000, 1.0, 2.0, -3.0, 0.1, 0.0, 0.0).pack(veh)]
    with TlogWriter(path, flush_interval=10.0) as tlog:
        tlog.write(first[0], t0)
        tlog.write(first[1], t0 + 0.1)
        before_led = sum(8 + len(p) for p in first)  # each record: its stamp, its packet
        tlog.write(gcs.encode(messages.led_rgb(7, 10, 20, 30)), t0 + 0.2)
    good = path.read_bytes()
    bad_crc = bytearray(good[before_led:])  # the LED_CONTROL record again, its CRC off
    bad_crc[-1] ^= 0xFF
    data = decode_tlog(good + bytes(bad_crc) + good)
    assert data.packets == 3 and data.damage is not None
    assert data.damage.offset == len(good) and "CRC" in data.damage.reason
    assert data.damage.last_unix_s == pytest.approx(t0 + 0.2)
    assert data.positions.ned.tolist() == [pytest.approx([1.0, 2.0, -3.0])]
    assert data.leds[7][1].tolist() == [[10, 20, 30]]
    assert data.origins[7] == [(t0, 47.3977, 8.5456, 488.0)]
    cut = decode_tlog(good[:-5])
    assert cut.packets == 2 and cut.damage is not None
    assert cut.damage.reason == "cut short in a packet"
    stamp = decode_tlog(good + good[:5])
    assert stamp.packets == 3 and stamp.damage is not None
    assert stamp.damage.reason == "cut short in a timestamp"
