"""The vehicles' own safety settings: parameter protocol, fence upload, ``[vehicle]``.

The parameter client is tested as the pure state machine it is (a dropped
reply, a confirm, a vehicle that will not take a value, PX4's bytewise
integers); the fence upload and the parameter enforcement run over real UDP
against the simulator, for both autopilots; a dry-run pushes one vehicle out
of the fence and the simulator's own fence action lands it.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from flight_fixtures import QUICK_SHOW, REPO, dry_run, quick_plan, vehicle
from link_fixtures import run
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import ScaledClock
from groundctl.errors import PreflightFailed, ShowFileError
from groundctl.execute.vehset import enforce, fence_vertices, offset_polygon, targets_for
from groundctl.flight.dryrun import Push
from groundctl.flight.runner import RunnerConfig
from groundctl.link import Flavour, FleetLink
from groundctl.link.fence import FenceDownload, FenceUpload, inclusion_items, upload_fence
from groundctl.link.params import ParamClient, decode_wire, encode_wire, run_params
from groundctl.record.events import read_events
from groundctl.show.loader import load_show, load_vehicle_file
from groundctl.show.model import GeoOrigin, Limits, VehicleSettings
from groundctl.sim import SimConfig, SimFleet
from groundctl.sim.config import dynamics_profile
from groundctl.sim.fence import FenceServer

AP, PX4 = Flavour.ARDUPILOT, Flavour.PX4
INT8, INT32 = mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_INT32
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
ORIGIN = GeoOrigin(47.3977, 8.5456, 488.0, 30.0)
SQUARE = ((-8.0, -8.0), (8.0, -8.0), (8.0, 8.0), (-8.0, 8.0))
FENCE_TYPE = mavlink.MAV_MISSION_TYPE_FENCE


def _value(name: str, value: float, ptype: int, index: int = 0, count: int = 10,
           flavour: Flavour = AP) -> mavlink.MAVLink_param_value_message:
    return mavlink.MAVLink_param_value_message(name.encode(), encode_wire(flavour, value, ptype),
                                               ptype, count, index)


# -- the parameter client, pure --------------------------------------------------------------

def test_a_read_is_retried_after_a_dropped_reply_and_fails_after_the_last_try() -> None:
    c = ParamClient(3, AP, timeout_s=1.0, attempts=3)
    c.read("FENCE_ACTION")
    c.read("RTL_ALT")
    first = c.poll(0.0)
    assert [m.get_type() for m in first] == ["PARAM_REQUEST_READ"] * 2
    assert c.poll(0.5) == []  # not timed out yet
    c.receive(_value("RTL_ALT", 1500, mavlink.MAV_PARAM_TYPE_INT32), 0.6)
    again = c.poll(1.0)  # the FENCE_ACTION reply was dropped: asked again, RTL_ALT not
    assert [m.param_id for m in again] == ["FENCE_ACTION"]
    c.receive(_value("FENCE_ACTION", 2, INT8), 1.2)
    assert c.done and c.values["FENCE_ACTION"].value == 2 and c.values["RTL_ALT"].value == 1500
    lost = ParamClient(3, AP, timeout_s=1.0, attempts=2)
    lost.read("NOPE")
    sent = sum(len(lost.poll(t)) for t in (0.0, 1.0, 2.0, 3.0))
    assert sent == 2 and lost.done
    assert lost.failed["NOPE"] == "no PARAM_VALUE for NOPE after 2 tries of 1 s"


def test_a_set_counts_only_once_the_echo_carries_the_value() -> None:
    c = ParamClient(1, AP)
    c.set("FENCE_ACTION", 2, INT8)
    (msg,) = c.poll(0.0)
    assert msg.get_type() == "PARAM_SET" and msg.param_value == 2.0 and msg.param_type == INT8
    c.receive(_value("FENCE_ACTION", 1, INT8), 0.1)  # an echo of the old value: not yet
    assert not c.done and "FENCE_ACTION" not in c.confirmed
    c.receive(_value("FENCE_ACTION", 2, INT8), 0.2)
    assert c.done and c.confirmed == {"FENCE_ACTION"}


def test_a_set_the_vehicle_will_not_take_fails_naming_what_it_says() -> None:
    c = ParamClient(1, AP, timeout_s=0.5, attempts=2)
    c.set("FS_GCS_TIMEOUT", 5.0, REAL32)
    for t in (0.0, 0.5, 1.0):
        c.poll(t)
        c.receive(_value("FS_GCS_TIMEOUT", 2.0, REAL32), t + 0.1)
    assert c.done
    assert c.failed["FS_GCS_TIMEOUT"] == ("PARAM_SET FS_GCS_TIMEOUT = 5 not confirmed after 2 "
                                          "tries of 0.5 s (the vehicle says 2)")


def test_px4_integers_travel_bytewise_and_a_window_bounds_what_is_outstanding() -> None:
    wire = encode_wire(PX4, 3, INT32)
    assert wire != 3.0 and decode_wire(PX4, wire, INT32) == 3.0
    assert encode_wire(AP, 3, INT32) == 3.0 and decode_wire(PX4, 4.5, REAL32) == 4.5
    c = ParamClient(1, PX4, window=2)
    for name in ("A", "B", "C", "D"):
        c.read(name)
    assert len(c.poll(0.0)) == 2
    c.receive(_value("A", 5, INT32, flavour=PX4), 0.1)
    assert c.values["A"].value == 5.0
    assert [m.param_id for m in c.poll(0.2)] == ["C"]


def test_a_parameter_list_fills_its_gaps_by_index() -> None:
    c = ParamClient(1, AP, timeout_s=1.0)
    c.request_list()
    assert [m.get_type() for m in c.poll(0.0)] == ["PARAM_REQUEST_LIST"]
    for i in (0, 2):
        c.receive(_value(f"P{i}", i, REAL32, index=i, count=3), 0.1)
    gaps = c.poll(1.0)
    assert [(m.get_type(), m.param_index) for m in gaps] == [("PARAM_REQUEST_READ", 1)]
    c.receive(_value("P1", 1, REAL32, index=1, count=3), 1.1)
    assert c.done and sorted(c.values) == ["P0", "P1", "P2"]


# -- the mapping and the fence polygon ---------------------------------------------------------

def test_operator_keys_map_to_each_autopilots_parameters() -> None:
    s = VehicleSettings(fence=True, fence_action="land", gcs_failsafe="rtl", gcs_timeout=4.5,
                        rtl_alt=20.0, land_speed=0.6, params=(("RTL_ALT", 2500.0),),
                        params_px4=(("COM_OBL_RC_ACT", 4.0),))
    limits = Limits(max_alt=40.0, geofence=SQUARE)
    ap = {t.name: t.value for t in targets_for(s, AP, limits)}
    assert ap == {"FENCE_ENABLE": 1, "FENCE_TYPE": 5, "FENCE_ALT_MAX": 42.0, "FENCE_ACTION": 2,
                  "FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 4.5, "RTL_ALT_M": 25.0,
                  "LAND_SPD_MS": 0.6}
    # The raw RTL_ALT (cm) won over rtl_alt, and is asked under both names: on 4.8 as
    # RTL_ALT_M in m.
    raw = next(t for t in targets_for(s, AP, limits) if t.name == "RTL_ALT_M")
    assert raw.names == ("RTL_ALT_M", "RTL_ALT") and raw.under("RTL_ALT").value == 2500.0
    mixed = replace(s, params=(("RTL_ALT_M", 30.0), ("WPNAV_SPEED", 800.0)))
    wanted = {t.name: (t.value, t.names) for t in targets_for(mixed, AP, limits)}
    assert wanted["RTL_ALT_M"] == (30.0, ("RTL_ALT_M", "RTL_ALT"))
    assert wanted["WP_SPD"] == (8.0, ("WP_SPD", "WPNAV_SPEED"))
    # ArduCopter 4.8 renamed land_speed's parameter to m/s; before, LAND_SPEED in cm/s.
    land = next(t for t in targets_for(s, AP, limits) if t.name == "LAND_SPD_MS")
    assert land.names == ("LAND_SPD_MS", "LAND_SPEED") and land.under("LAND_SPEED").value == 60
    rtl = next(t for t in targets_for(VehicleSettings(rtl_alt=20.0), AP, limits))
    assert (rtl.name, rtl.value, rtl.under("RTL_ALT").value) == ("RTL_ALT_M", 20.0, 2000)
    px4 = {t.name: t.value for t in targets_for(s, PX4, limits)}
    assert px4 == {"GF_MAX_VER_DIST": 42.0, "GF_ACTION": 5, "NAV_DLL_ACT": 2,
                   "COM_DL_LOSS_T": 5, "RTL_RETURN_ALT": 20.0, "MPC_LAND_SPEED": 0.6,
                   "RTL_ALT": 2500.0, "COM_OBL_RC_ACT": 4.0}


def test_the_fence_lies_the_margin_beyond_the_geofence() -> None:
    grown = offset_polygon(np.array(SQUARE), 2.0)
    assert np.allclose(np.abs(grown), 10.0)
    clockwise = offset_polygon(np.array(SQUARE[::-1]), 2.0)
    assert np.allclose(np.abs(clockwise), 10.0)
    verts = fence_vertices(ORIGIN, SQUARE, 2.0)
    assert len(verts) == 4 and all(abs(lat - 47.3977) < 2e-4 for lat, _ in verts)


# -- the fence upload against the simulator's fence server, in memory ----------------------------

def _exchange(up: FenceUpload | FenceDownload, server: FenceServer, drop: set[int]) -> int:
    """Run ``up`` against ``server`` with a 0.25 s step; messages numbered in ``drop`` (both
    ways, counted together) are lost.  Returns the number of messages."""
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    n, t = 0, 0.0
    while not up.done and t < 60.0:
        for msg in up.poll(t):
            n += 1
            if n in drop:
                continue
            for reply in server.handle(gcs.decode(bytearray(msg.pack(gcs))), t):
                n += 1
                if n not in drop:
                    up.receive(reply, t)
        for reply in server.tick(t):
            n += 1
            if n not in drop:
                up.receive(reply, t)
        t += 0.25
    return n


def test_a_fence_upload_survives_a_lost_count_and_a_lost_ack() -> None:
    verts = fence_vertices(ORIGIN, SQUARE, 1.0)
    server = FenceServer(1)
    up = FenceUpload(1, verts, timeout_s=1.0)
    # 1 the count (lost), 2 the count again, 3 request 0 ... 9 item 3, 10 the ACK (lost).
    _exchange(up, server, drop={1, 10})
    assert up.ok, up.error
    assert np.allclose(server.vertices, verts, atol=2e-7)


def test_a_vehicle_that_keeps_asking_again_cannot_hold_the_upload_for_ever() -> None:
    # A review's case: re-requesting item 0 every 0.5 s reset the tries for ever.
    up = FenceUpload(1, fence_vertices(ORIGIN, SQUARE, 1.0), timeout_s=1.0, attempts=3)
    now = 0.0
    up.poll(now)
    while not up.done and now < 10_000.0:
        now += 0.5
        up.receive(mavlink.MAVLink_mission_request_int_message(
            255, 190, 0, mavlink.MAV_MISSION_TYPE_FENCE), now)
        up.poll(now)
    assert up.done and not up.ok
    assert up.error == f"fence upload: not finished within {up.budget_s:g} s"
    assert now <= up.budget_s + 0.5


def test_a_refused_fence_names_the_result_and_silence_fails_after_the_last_try() -> None:
    server = FenceServer(1)
    too_many = FenceUpload(1, tuple((47.0 + i * 1e-5, 8.0) for i in range(300)))
    _exchange(too_many, server, drop=set())
    assert too_many.error == "fence upload refused: MAV_MISSION_NO_SPACE"
    silent = FenceUpload(1, fence_vertices(ORIGIN, SQUARE, 1.0), timeout_s=1.0, attempts=3)
    _exchange(silent, server, drop=set(range(1, 100)))
    assert silent.error == "fence upload: no answer to MISSION_COUNT after 3 tries of 1 s"


def test_a_fence_download_reads_every_item_through_losses_and_closes_with_an_ack() -> None:
    verts = fence_vertices(ORIGIN, SQUARE, 1.0)
    server = FenceServer(1)
    assert _exchange(FenceUpload(1, verts), server, drop=set()) > 0
    down = FenceDownload(1, timeout_s=1.0)
    # 1 the list request (lost), 2 it again, 3 the count, 4 request 0, 5 item 0 (lost) ...
    _exchange(down, server, drop={1, 5})
    assert down.ok, down.error
    assert tuple(down.items or ()) == inclusion_items(verts)
    (ack,) = down.poll(60.0)  # the transfer is closed once, with an ACK
    assert ack.get_type() == "MISSION_ACK" and ack.type == mavlink.MAV_MISSION_ACCEPTED
    assert down.poll(61.0) == []
    empty = FenceDownload(1)
    _exchange(empty, FenceServer(1), drop=set())
    assert empty.ok and empty.items == []


def test_a_forged_fence_count_a_refusal_and_silence_end_the_download_with_a_reason() -> None:
    forged = FenceDownload(1)
    forged.poll(0.0)
    forged.receive(mavlink.MAVLink_mission_count_message(255, 190, 10**6, FENCE_TYPE), 0.1)
    assert forged.error == "fence download: the vehicle claims 1000000 items (at most 256)"
    refused = FenceDownload(1)
    refused.poll(0.0)
    refused.receive(mavlink.MAVLink_mission_ack_message(
        255, 190, mavlink.MAV_MISSION_DENIED, FENCE_TYPE), 0.1)
    assert refused.error == "fence download refused: MAV_MISSION_DENIED"
    silent = FenceDownload(1, timeout_s=1.0, attempts=3)
    _exchange(silent, FenceServer(1), drop=set(range(1, 100)))
    assert silent.error == "fence download: no answer to MISSION_REQUEST_LIST after 3 tries of 1 s"


# -- over UDP against the simulator ------------------------------------------------------------

async def _with_fleet(flavour: Flavour, count: int = 2, **cfg: object):  # type: ignore[no-untyped-def]
    link = FleetLink(("127.0.0.1", 0), clock=ScaledClock(), heartbeat_period=0.2, tick=0.01)
    await link.start()
    assert link.local_address is not None
    config = SimConfig(count=count, flavour=flavour, gcs=link.local_address,
                       ekf_origin_delay_s=0.5, ready_delay_s=1.0, origin=(47.3977, 8.5456, 488.0),
                       **cfg)  # type: ignore[arg-type]
    fleet = SimFleet(config, ScaledClock(2.0)).start()
    await link.wait_for_vehicles(list(range(1, count + 1)), timeout=10.0)
    return link, fleet


@pytest.mark.parametrize("flavour", [AP, PX4], ids=str)
@run
async def test_fence_upload_and_parameters_against_the_simulator(flavour: Flavour) -> None:
    link, fleet = await _with_fleet(flavour)
    try:
        verts = fence_vertices(ORIGIN, SQUARE, 2.0)
        up = FenceUpload(1, verts)
        assert await upload_fence(link, up, link.clock), up.error
        stored = fleet.vehicles[0].fence.vertices
        assert np.allclose(stored, verts, atol=2e-7) and up.requested == {0, 1, 2, 3}
        settings = VehicleSettings(fence=True, fence_action="land", gcs_failsafe="land",
                                   gcs_timeout=5.0, rtl_alt=20.0)
        limits = Limits(max_alt=40.0, geofence=SQUARE)
        out = await enforce(link, link.clock, {1: flavour, 2: flavour}, settings, ORIGIN, limits)
        assert all(not o.problems and o.fence for o in out.values()), out
        v = fleet.vehicles[1]
        if flavour is AP:
            assert (v.params["FENCE_ACTION"], v.params["FENCE_ENABLE"], v.params["RTL_ALT_M"],
                    v.params["FS_GCS_ENABLE"], v.params["FENCE_TOTAL"]) == (2, 1, 20.0, 5, 4)
            assert "FENCE_ACTION 1 -> 2" in out[2].changed
        else:
            assert (v.params["GF_ACTION"], v.params["NAV_DLL_ACT"], v.params["RTL_RETURN_ALT"],
                    v.params["GF_MAX_VER_DIST"]) == (5, 3, 20.0, 42.0)
            assert "GF_ACTION 2 -> 5" in out[2].changed
        if flavour is AP:  # PX4 reports no GEOFENCE bit in SYS_STATUS
            assert v.fence_bits(fleet.time)[0]
        # A second pass finds everything as the show needs it: nothing changed.
        again = await enforce(link, link.clock, {1: flavour}, settings, ORIGIN, limits)
        assert again[1].changed == [] and again[1].problems == []
    finally:
        fleet.stop()
        await link.close()


@pytest.mark.parametrize("profile", ["ardupilot-4.8", "ardupilot-4.7"])
@run
async def test_rtl_alt_and_land_speed_are_set_under_the_names_the_firmware_knows(
        profile: str) -> None:
    # Real ArduCopter 4.8 refused a show asking rtl_alt and land_speed: it has no RTL_ALT
    # or LAND_SPEED any more (RTL_ALT_M in m, LAND_SPD_MS in m/s); 4.5-4.7 have only those.
    new = profile.endswith("4.8")
    link, fleet = await _with_fleet(AP, count=1, dynamics=dynamics_profile(profile))
    try:
        settings = VehicleSettings(rtl_alt=20.0, land_speed=0.6)
        out = await enforce(link, link.clock, {1: AP}, settings, ORIGIN, Limits(max_alt=40.0))
        assert out[1].problems == [], out
        params = fleet.vehicles[0].params
        if new:
            assert out[1].names == {"RTL_ALT_M": "RTL_ALT_M", "LAND_SPD_MS": "LAND_SPD_MS"}
            assert (params["RTL_ALT_M"], params["LAND_SPD_MS"]) == (20.0, pytest.approx(0.6))
            assert "RTL_ALT_M 15 -> 20" in out[1].changed
        else:
            assert out[1].names == {"RTL_ALT_M": "RTL_ALT", "LAND_SPD_MS": "LAND_SPEED"}
            assert (params["RTL_ALT"], params["LAND_SPEED"]) == (2000, 60)
            assert "RTL_ALT 1500 -> 2000" in out[1].changed
        assert fleet.vehicles[0].params.si("RTL_ALT") == 20.0  # what its RTL climbs to
    finally:
        fleet.stop()
        await link.close()


@run
async def test_a_parameter_no_firmware_name_answers_is_one_line_naming_both() -> None:
    link, fleet = await _with_fleet(AP, count=1)
    try:
        client = ParamClient(1, AP, timeout_s=0.2, attempts=2)
        client.read_any(("NO_SUCH_M", "NO_SUCH"))
        client.read_any(("LAND_SPEED", "LAND_SPD_MS"))
        await run_params(link, client, link.clock, 5.0)
        assert client.failed == {"NO_SUCH_M": "no PARAM_VALUE for NO_SUCH_M or NO_SUCH after "
                                              "2 tries of 0.2 s"}
        assert "LAND_SPD_MS" in client.values and "LAND_SPEED" not in client.failed
    finally:
        fleet.stop()
        await link.close()


@pytest.mark.parametrize("flavour", [AP, PX4], ids=str)
@run
async def test_a_differing_parameter_is_refused_when_set_is_false(flavour: Flavour) -> None:
    name = "FENCE_ACTION" if flavour is AP else "GF_ACTION"
    link, fleet = await _with_fleet(flavour, count=1)
    try:
        settings = VehicleSettings(fence=True, fence_action="land", set=False)
        out = await enforce(link, link.clock, {1: flavour}, settings, ORIGIN,
                            Limits(max_alt=40.0, geofence=SQUARE))
        was, need = (1, 2) if flavour is AP else (2, 5)
        assert (f"{name} is {was}, show needs {need} (land); not allowed to change it "
                "([vehicle] set = false)") in out[1].problems
        assert fleet.vehicles[0].params[name] == was  # untouched
        # Nor is the fence written: the vehicle's own is downloaded and must be the show's.
        assert ("fence: it has no fence, show needs its 4-vertex inclusion polygon; not "
                "allowed to change it ([vehicle] set = false)") in out[1].problems
        assert fleet.vehicles[0].fence.vertices == [] and not out[1].fence
        limits = Limits(max_alt=40.0, geofence=SQUARE)
        other = FenceUpload(1, fence_vertices(ORIGIN, SQUARE, 5.0))
        assert await upload_fence(link, other, link.clock), other.error
        out = await enforce(link, link.clock, {1: flavour}, settings, ORIGIN, limits)
        assert ("fence: its own fence has 4 items at other places, show needs its 4-vertex "
                "inclusion polygon; not allowed to change it ([vehicle] set = false)"
                ) in out[1].problems
        same = FenceUpload(1, fence_vertices(ORIGIN, SQUARE, settings.fence_margin))
        assert await upload_fence(link, same, link.clock), same.error
        out = await enforce(link, link.clock, {1: flavour}, settings, ORIGIN, limits)
        assert out[1].fence and not any(p.startswith("fence") for p in out[1].problems)
    finally:
        fleet.stop()
        await link.close()


# -- the show file -----------------------------------------------------------------------------

def _show(tmp_path: Path, vehicle_table: str, geofence: bool = True) -> Path:
    text = QUICK_SHOW.read_text()
    if geofence:
        text = text.replace("max_altitude = 40.0", "max_altitude = 40.0\n"
                            "geofence = [[-12, -12], [12, -12], [12, 12], [-12, 12]]")
    path = tmp_path / "show.toml"
    path.write_text(text + "\n[vehicle]\n" + vehicle_table)
    return path


def test_the_vehicle_table_is_read_and_checked(tmp_path: Path) -> None:
    show = load_show(_show(tmp_path, 'fence = true\nfence_action = "rtl"\nset = false\n'
                                     "params = { FS_EKF_ACTION = 1, px4 = { GF_SOURCE = 0 } }\n"))
    assert show.vehicle == VehicleSettings(fence=True, fence_action="rtl", set=False,
                                           params=(("FS_EKF_ACTION", 1.0),),
                                           params_px4=(("GF_SOURCE", 0.0),))
    assert load_show(QUICK_SHOW).vehicle is None
    bad = {
        'fence_action = "explode"\n': "[vehicle]: 'fence_action' must be one of 'land', 'rtl', "
                                      "'brake', 'report', got 'explode'",
        "gcs_timeout = 0\n": "[vehicle]: 'gcs_timeout' must be at least 1, got 0",
        "fence = 1\n": "[vehicle]: 'fence' must be true or false, got integer 1",
        "params = { fence_action = 2 }\n": "[vehicle]: 'params' parameter name string "
                                           "'fence_action' must be 1-16 characters",
        "fense = true\n": "[vehicle]: unknown key 'fense'; did you mean 'fence'?",
    }
    for table, message in bad.items():
        with pytest.raises(ShowFileError) as exc:
            load_show(_show(tmp_path, table))
        assert message in str(exc.value), str(exc.value)
    with pytest.raises(ShowFileError, match="'fence' = true needs a \\[limits\\] geofence"):
        load_show(_show(tmp_path, "fence = true\n", geofence=False))


def test_a_malformed_vehicle_table_is_one_line_and_exit_2(tmp_path: Path) -> None:
    path = _show(tmp_path, "rtl_alt = \"high\"\n")
    proc = subprocess.run([sys.executable, "-m", "groundctl", "dry-run", str(path), "--json"],
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert lines[-1].endswith("[vehicle]: 'rtl_alt' must be a number, got string 'high'"), lines


# -- the dry-run -------------------------------------------------------------------------------

def _fenced_plan():  # type: ignore[no-untyped-def]
    plan = quick_plan()
    return replace(plan, limits=replace(plan.limits, geofence=((-9.0, -9.0), (9.0, -9.0),
                                                               (9.0, 9.0), (-9.0, 9.0))))


@pytest.mark.slow
@pytest.mark.parametrize("flavour", [AP, PX4], ids=str)
def test_a_vehicle_pushed_out_of_the_fence_is_landed_by_its_own_fence(
        flavour: Flavour, tmp_path: Path) -> None:
    settings = VehicleSettings(fence=True, fence_action="land", fence_margin=1.0,
                               rtl_alt=15.0)
    # Vehicle 6 is at x = 3.1 m at show time 1 s and its fence at x = 10 m. Carried 11 m
    # in 1 s, its autopilot braking against the push all the while, its telemetry shows it
    # 0.3-0.7 m past the fence still at 9-10 m/s (an 8 m push peaked 0.1-0.3 m past it
    # on an idle machine and short of it on a busy one).
    result = dry_run(tmp_path, flavour=flavour, plan=_fenced_plan(),
                     runner=RunnerConfig(vehicle=settings),
                     pushes=(Push(6, 1.0, (11.0, 0.0, 0.0)),))
    events = list(read_events(tmp_path / "events.jsonl"))
    uploaded = [e for e in events if e.get("event") == "vehicle_settings_set"]
    assert sorted(e["system_id"] for e in uploaded if e["fence"]) == list(range(1, 10))
    # rtl_alt under the name the simulated ArduCopter 4.8 knows, said once for all nine.
    names = [e["names"] for e in events if e.get("event") == "vehicle_settings_names"]
    assert names == ([{"RTL_ALT_M": list(range(1, 10))}] if flavour is AP else []), names
    text = "Fence Breached" if flavour is AP else "Geofence violated"
    breach = [e for e in events if e.get("event") == "statustext" and e.get("system_id") == 6
              and e.get("text") == text]
    assert breach, [e for e in events if e.get("system_id") == 6][-20:]
    land = "LAND" if flavour is AP else "AUTO.LAND"
    modes = [e for e in events if e.get("event") == "mode_changed" and e.get("system_id") == 6]
    assert any(e.get("new") == land for e in modes), modes
    # groundctl reports it (the vehicle left the show for the fence's mode) and lands the
    # rest: the flight stays safe, the pushed vehicle down where its fence put it.
    six = vehicle(result.report, 6)
    assert six["landed"] and six["reason"] == f"left {'GUIDED' if flavour is AP else 'OFFBOARD'} " \
        f"for {land} during show"
    assert result.report["safe"], result.report["unsafe_reasons"]
    assert [vehicle(result.report, s)["phase"] for s in range(1, 10)] == ["landed"] * 9


@pytest.mark.slow
def test_a_dry_run_with_a_differing_parameter_and_set_false_is_refused(tmp_path: Path) -> None:
    settings = VehicleSettings(gcs_failsafe="land", set=False)
    result = dry_run(tmp_path, runner=RunnerConfig(vehicle=settings))
    assert isinstance(result.error, PreflightFailed)
    assert result.error.exit_code == 1
    assert result.error.failures[1] == [
        "FS_GCS_ENABLE is 0, show needs 5 (land); not allowed to change it "
        "([vehicle] set = false)"]
    assert not result.flown  # refused before anything was armed
    assert "pre-flight checks failed: vehicle 1: FS_GCS_ENABLE is 0" in \
        result.report["unsafe_reasons"][0]


def test_a_vehicle_file_gives_the_table_and_anything_else_is_one_line(tmp_path: Path) -> None:
    """``--vehicle FILE``: the [vehicle] table alone (a Skybrush show has none); its fence
    is the flown plan's geofence, checked before arming."""
    only = tmp_path / "vehicle.toml"
    only.write_text('[vehicle]\nfence = true\nfence_action = "rtl"\nset = false\n')
    assert load_vehicle_file(only) == VehicleSettings(fence=True, fence_action="rtl", set=False)
    bad = {"none.toml": ("x = 1\n", "no [vehicle] table (--vehicle takes the vehicles' own "
                                     "settings from one)"),
           "latin.toml": (b"[vehicle]\n# caf\xe9\n", "not UTF-8 text (a [vehicle] table is "
                                                    "TOML)"),
           "typo.toml": ("[vehicle]\nfense = true\n", "unknown key 'fense'")}
    for name, (text, message) in bad.items():
        path = tmp_path / name
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        with pytest.raises(ShowFileError) as err:
            load_vehicle_file(path)
        assert message in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("flavour", [AP, PX4], ids=str)
@run
async def test_a_fence_asked_for_without_a_geofence_refuses_the_vehicle(flavour: Flavour) -> None:
    link, fleet = await _with_fleet(flavour, count=1)
    try:
        out = await enforce(link, link.clock, {1: flavour}, VehicleSettings(fence=True), ORIGIN,
                            Limits(max_alt=40.0))
        assert out[1].problems[0] == ("[vehicle] fence = true, but the plan has no geofence "
                                      "to fence the vehicle in")
        assert fleet.vehicles[0].fence.vertices == []
    finally:
        fleet.stop()
        await link.close()


def test_the_cli_takes_the_vehicle_table_from_a_file_of_its_own(tmp_path: Path) -> None:
    """The show file has no [vehicle]; ``--vehicle`` gives one, and a vehicle that differs
    refuses the flight with its reason before anything is armed."""
    path = tmp_path / "vehicle.toml"
    path.write_text('[vehicle]\ngcs_failsafe = "land"\nset = false\n')
    proc = subprocess.run([sys.executable, "-m", "groundctl", "dry-run", str(QUICK_SHOW),
                           "--vehicle", str(path), "--speed", "4", "--ready-delay", "2",
                           "--record", str(tmp_path / "rec"), "-q"],
                          capture_output=True, text=True, timeout=180, cwd=REPO)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert ("vehicle 4: FS_GCS_ENABLE is 0, show needs 5 (land); not allowed to change it "
            "([vehicle] set = false)") in proc.stderr
    missing = subprocess.run([sys.executable, "-m", "groundctl", "dry-run", str(QUICK_SHOW),
                              "--vehicle", str(tmp_path / "nope.toml"), "-q"],
                             capture_output=True, text=True, timeout=180, cwd=REPO)
    assert missing.returncode == 2
    assert missing.stderr.strip().splitlines()[-1].endswith("nope.toml: no such file")


@pytest.mark.slow
def test_the_cli_refuses_a_show_whose_vehicles_differ_with_their_reason(tmp_path: Path) -> None:
    path = tmp_path / "show.toml"
    path.write_text(QUICK_SHOW.read_text() + '\n[vehicle]\ngcs_failsafe = "land"\nset = false\n')
    proc = subprocess.run([sys.executable, "-m", "groundctl", "dry-run", str(path), "--speed",
                           "4", "--ready-delay", "2", "--record", str(tmp_path / "rec")],
                          capture_output=True, text=True, timeout=180, cwd=REPO)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert ("vehicle 4: FS_GCS_ENABLE is 0, show needs 5 (land); not allowed to change it "
            "([vehicle] set = false)") in proc.stderr

