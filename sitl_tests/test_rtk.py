"""RTK corrections: framer, fragmenter, sources (TCP, NTRIP against a local caster), the
simulator's reassembly and fix types, and dry-runs with and without corrections."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import subprocess
import sys
from collections.abc import AsyncIterator, Awaitable, Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from flight_fixtures import QUICK_SHOW, REPO
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pyrtcm import RTCMReader

from groundctl.clock import ScaledClock
from groundctl.errors import EXIT_UNSAFE, EXIT_USAGE
from groundctl.execute.preflight import Thresholds, check_rtk
from groundctl.link.state import VehicleState
from groundctl.rtk.fragment import FRAGMENT_LEN, Fragmenter, Reassembler, TooLarge
from groundctl.rtk.rtcm import RtcmFramer, ends_epoch, frame, message_number, split_epochs
from groundctl.rtk.sources import (
    RtkSource,
    RtkSourceError,
    gga_sentence,
    load_epochs,
    parse_source,
)
from groundctl.rtk.synth import epochs
from groundctl.sim.rtk import FIXED_AFTER_S, FLOAT_AFTER_S, TIMEOUT_S, RtkReceiver

FIXTURE = REPO / "sitl_tests" / "data" / "rtcm3_10epochs.rtcm3"
GROUNDCTL = [sys.executable, "-m", "groundctl"]


def _frames() -> list[bytes]:
    return RtcmFramer().feed(FIXTURE.read_bytes())


# -- framer -----------------------------------------------------------------------------
def test_fixture_is_valid_rtcm3_for_pyrtcm_too() -> None:
    frames = _frames()
    assert len(frames) == 40
    assert {message_number(f) for f in frames} == {1005, 1077, 1087, 1097}
    assert any(len(f) > FRAGMENT_LEN for f in frames)
    assert any(len(f) == 2 * FRAGMENT_LEN for f in frames)  # needs an empty last fragment
    assert RTCMReader.parse(frames[0]).identity == "1005"
    # The fixture is what the writer makes (regenerate with groundctl.rtk.synth.epochs).
    assert FIXTURE.read_bytes() == b"".join(epochs(10))
    assert len(split_epochs(frames)) == 10
    assert [ends_epoch(f) for f in frames[:4]] == [False, False, False, True]


def test_framer_split_reads_and_bad_crc_dropped() -> None:
    frames = _frames()[:6]
    bad = bytearray(frames[2])
    bad[10] ^= 0xFF
    stream = b"\x00junk\xd3" + frames[0] + frames[1] + bytes(bad) + b"".join(frames[3:])
    framer = RtcmFramer()
    got: list[bytes] = []
    for i in range(0, len(stream), 7):  # split reads, through headers and CRCs
        got += framer.feed(stream[i:i + 7])
    assert got == [frames[0], frames[1], *frames[3:]]
    assert framer.stats.bad_crc == 1
    assert framer.stats.frames == 5


def test_frame_rejects_oversize_payload() -> None:
    with pytest.raises(ValueError, match="at most 1023"):
        frame(bytes(1024))


# -- fragmenter -------------------------------------------------------------------------
@pytest.mark.parametrize("size", [1, 179, 180, 181, 359, 360, 361, 540, 541, 719, 720])
def test_fragment_round_trip(size: int) -> None:
    msg = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    frags = Fragmenter(sequence=5).split(msg)
    if size <= FRAGMENT_LEN:
        assert [f.flags for f in frags] == [0]
    else:
        assert all(f.flags & 1 for f in frags)
        assert [(f.flags >> 1) & 3 for f in frags] == list(range(len(frags)))
        assert {f.flags >> 3 for f in frags} == {5}
        assert len(frags) <= 4
    assert all(len(f.data) <= FRAGMENT_LEN for f in frags)
    if size in (360, 540):
        assert frags[-1].data == b""  # exact multiple: an empty last fragment ends it
    if size == 720:
        assert len(frags) == 4 and len(frags[-1].data) == 180
    r = Reassembler()
    out = [r.add(f.flags, f.data) for f in frags]
    assert out[:-1] == [None] * (len(frags) - 1)
    assert out[-1] == msg


def test_fragment_limit_and_sequence_wrap() -> None:
    fr = Fragmenter(sequence=30)
    with pytest.raises(TooLarge, match="4 GPS_RTCM_DATA fragments"):
        fr.split(bytes(721))
    seqs = [fr.split(bytes(200))[0].flags >> 3 for _ in range(4)]
    assert seqs == [30, 31, 0, 1]
    fr.split(bytes(100))  # unfragmented: the sequence id does not move
    assert fr.sequence == 2


def test_reassembler_discards_a_partial_message_of_another_sequence() -> None:
    fr = Fragmenter()
    a, b = fr.split(bytes(range(200))), fr.split(bytes(300))
    r = Reassembler()
    assert r.add(a[0].flags, a[0].data) is None  # a's last fragment is lost
    assert r.add(b[0].flags, b[0].data) is None
    assert r.add(b[1].flags, b[1].data) == bytes(300)
    assert r.discarded == 1


# -- the simulated receiver -------------------------------------------------------------
def test_sim_receiver_fix_types_and_fallback() -> None:
    rx = RtkReceiver()
    assert rx.fix_type(0.0, 3) == 3
    fr = Fragmenter()
    t = 0.0
    for ep in epochs(8):
        for f in RtcmFramer().feed(ep):
            for frag in fr.split(f):
                rx.receive(frag.flags, frag.data, t)
        if t == 0.0:
            assert rx.fix_type(t, 3) == 5
        t += 1.0
    assert rx.fix_type(t, 3) == 6 and t >= FIXED_AFTER_S
    assert rx.fix_type(t, 0) == 0  # no GPS fix at all: corrections do not make one
    # Corrections stopped: fixed holds a while, then float on what it has, then 3D.
    last = t - 1.0
    assert rx.fix_type(last + FLOAT_AFTER_S - 1, 3) == 6
    assert rx.fix_type(last + FLOAT_AFTER_S + 1, 3) == 5
    assert rx.fix_type(last + TIMEOUT_S + 1, 3) == 3
    assert rx.stats()["intact"] == 32 and rx.stats()["bad"] == 0
    corrupt = bytearray(RtcmFramer().feed(epochs(1)[0])[0])
    corrupt[5] ^= 1
    rx.receive(0, bytes(corrupt), t)
    assert rx.stats()["bad"] == 1


# -- pre-flight -------------------------------------------------------------------------
def test_require_rtk_check() -> None:
    state = VehicleState(3)
    state.gps_fix_type = 3
    fixed, floating = Thresholds(require_fix_type=6), Thresholds(require_fix_type=5)
    r = check_rtk(state, fixed)
    assert not r.ok and r.detail == "fix 3D, need RTK fixed"
    state.gps_fix_type = 5
    assert check_rtk(state, floating).ok and not check_rtk(state, fixed).ok
    state.gps_fix_type = 6
    assert check_rtk(state, fixed).ok


# -- sources ----------------------------------------------------------------------------
def test_parse_source() -> None:
    assert parse_source("serial:/dev/ttyACM0:115200").baud == 115200
    s = parse_source("ntrip://me:secret@caster.example:2102/MOUNT1")
    assert (s.kind, s.host, s.port, s.path, s.user, s.password) == \
        ("ntrip", "caster.example", 2102, "MOUNT1", "me", "secret")
    assert "secret" not in s.text
    assert parse_source("127.0.0.1:2101").kind == "tcp"
    assert parse_source(str(FIXTURE)).kind == "file"
    for bad in ("serial:/dev/ttyACM0", "ntrip://host", "no/such/file", "tcp:nope"):
        with pytest.raises(RtkSourceError):
            parse_source(bad)


def test_file_without_frames_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "junk.rtcm3"
    p.write_bytes(b"\xd3\x00\x13" + bytes(30))
    with pytest.raises(RtkSourceError, match="no valid RTCM3 frame"):
        load_epochs(p)


@contextlib.asynccontextmanager
async def _loopback_server(serve: Callable[[asyncio.StreamReader, asyncio.StreamWriter],
                                           Awaitable[None]]) -> AsyncIterator[int]:
    """A TCP server on 127.0.0.1 running ``serve`` for each connection: its port."""
    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    async with server:
        yield server.sockets[0].getsockname()[1]


async def _collect(source: RtkSource, want: int) -> bytes:
    got = b""
    async for chunk in source.chunks():
        got += chunk
        if len(got) >= want:
            break
    return got


def test_tcp_source() -> None:
    data = FIXTURE.read_bytes()

    async def main() -> bytes:
        async def serve(_r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            w.write(data)
            await w.drain()
            w.close()

        async with _loopback_server(serve) as port:
            src = RtkSource(parse_source(f"tcp:127.0.0.1:{port}"), ScaledClock(1.0))
            return await asyncio.wait_for(_collect(src, len(data)), 20)

    assert asyncio.run(main()) == FIXTURE.read_bytes()


@pytest.mark.parametrize("version", ["v1", "v2"])
def test_ntrip_client_against_a_local_caster(version: str) -> None:
    data = FIXTURE.read_bytes()
    requests: list[str] = []

    async def main() -> bytes:
        async def serve(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            head = (await r.readuntil(b"\r\n\r\n")).decode()
            requests.append(head)
            token = base64.b64encode(b"me:pw").decode()
            if not head.startswith("GET /MNT ") or f"Basic {token}" not in head:
                w.write(b"HTTP/1.1 401 Unauthorized\r\n\r\n")
            elif version == "v1":
                w.write(b"ICY 200 OK\r\n\r\n" + data)
            else:
                w.write(b"HTTP/1.1 200 OK\r\nContent-Type: gnss/data\r\n"
                        b"Transfer-Encoding: chunked\r\n\r\n")
                for i in range(0, len(data), 1000):
                    part = data[i:i + 1000]
                    w.write(f"{len(part):x}\r\n".encode() + part + b"\r\n")
                w.write(b"0\r\n\r\n")
            await w.drain()
            w.close()

        async with _loopback_server(serve) as port:
            good = RtkSource(parse_source(f"ntrip://me:pw@127.0.0.1:{port}/MNT"),
                             ScaledClock(1.0))
            got = await asyncio.wait_for(_collect(good, len(data)), 20)
            bad = RtkSource(parse_source(f"ntrip://me:wrong@127.0.0.1:{port}/MNT"),
                            ScaledClock(1.0))
            with pytest.raises(RtkSourceError, match="the caster refused"):
                await asyncio.wait_for(_collect(bad, 1), 20)
            return got

    got = asyncio.run(main())
    assert RtcmFramer().feed(got) == _frames()
    assert "Ntrip-Version: Ntrip/2.0" in requests[0]


def _nmea_ok(sentence: str) -> bool:
    body, _, checksum = sentence.strip().lstrip("$").partition("*")
    x = 0
    for byte in body.encode():
        x ^= byte
    return f"{x:02X}" == checksum


def test_a_gga_sentence_says_where_the_field_is_in_nmea() -> None:
    when = datetime(2026, 12, 2, 13, 5, 9, 470000, tzinfo=UTC)
    gga = gga_sentence(47.3977, 8.5456, 488.0, when)
    assert gga.endswith("\r\n") and _nmea_ok(gga)
    fields = gga.strip().split("*")[0].split(",")
    assert fields[:10] == ["$GPGGA", "130509.47", "4723.86200", "N", "00832.73600", "E", "1",
                           "12", "1.0", "488.0"]
    south = gga_sentence(-33.8688, -151.2093, 3.0, when).split(",")
    assert south[2:6] == ["3352.12800", "S", "15112.55800", "W"]
    assert gga_sentence(10.99999999, 0.0, 0.0, when).split(",")[2] == "1100.00000"
    with pytest.raises(ValueError):
        gga_sentence(91.0, 0.0, 0.0, when)


def test_an_ntrip_client_tells_a_network_caster_where_it_is() -> None:
    """A VRS mount point sends nothing until it hears a GGA: in the Ntrip-GGA header
    (v2) and in the stream (v1), again every GGA_PERIOD_S."""
    data = FIXTURE.read_bytes()
    heard: dict[str, str] = {}

    async def main() -> bytes:
        async def serve(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            heard["head"] = (await r.readuntil(b"\r\n\r\n")).decode()
            w.write(b"ICY 200 OK\r\n\r\n")
            await w.drain()
            # A network mount point: no corrections until the rover says where it is.
            heard["stream"] = (await r.readuntil(b"\r\n")).decode()
            w.write(data)
            await w.drain()
            w.close()

        async with _loopback_server(serve) as port:
            src = RtkSource(parse_source(f"ntrip://127.0.0.1:{port}/VRS"), ScaledClock(1.0),
                            position=(47.3977, 8.5456, 488.0),
                            utc=lambda: datetime(2026, 12, 2, 13, 5, 9, tzinfo=UTC))
            got = await asyncio.wait_for(_collect(src, len(data)), 20)
            assert src.gga_sent >= 2
            return got

    assert RtcmFramer().feed(asyncio.run(main())) == _frames()
    header = next(line for line in heard["head"].splitlines() if line.startswith("Ntrip-GGA:"))
    assert _nmea_ok(header.split(": ", 1)[1]) and "4723.86200,N,00832.73600,E" in header
    assert heard["stream"].startswith("$GPGGA,130509.00,") and _nmea_ok(heard["stream"])


# -- end to end -------------------------------------------------------------------------
def _dry_run(*extra: str, record: Path | None = None) -> subprocess.CompletedProcess[str]:
    rec = ["--no-record"] if record is None else ["--record", str(record)]
    return subprocess.run([*GROUNDCTL, "dry-run", str(QUICK_SHOW), "--speed", "8",
                           "--ready-delay", "2", "--json", "--no-console", *rec,
                           *extra], capture_output=True, text=True, cwd=REPO, timeout=300,
                          check=False)


@pytest.mark.slow
def test_dry_run_with_rtk_file_every_frame_intact_and_fixed(tmp_path: Path) -> None:
    run = _dry_run("--rtk", str(FIXTURE), "--require-rtk", "fixed", "--gcs-sysid", "200",
                   record=tmp_path / "rec")
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads(run.stdout)
    assert report["safe"]
    rtk = report["rtk"]
    assert rtk["messages_sent"] >= 40 and rtk["bytes_sent"] > 0 and rtk["rate_bps"] > 0
    assert rtk["bad_crc"] == rtk["too_large"] == rtk["rate_dropped"] == 0
    sim = report["simulator"]["rtk"]
    assert len(sim) == 9
    distinct = len(set(_frames()))  # 31: the ten 1005 station frames are the same
    for sysid, stats in sim.items():
        # Every frame of the file arrived intact (each distinct one), nothing bad.
        assert stats["distinct"] == distinct, (sysid, stats)
        assert stats["bad"] == 0 and stats["intact"] >= 40
        assert stats["intact"] <= rtk["messages_sent"]
        assert stats["fix_type"] == 6
    for v in report["vehicles"]:
        assert v["fix_type"] == 6 and v["rtk_correction_age_s"] is not None
    # The tlog holds what a log analyst expects, and the corrections, under our system id.
    from pymavlink import mavutil
    log = mavutil.mavlink_connection(str(tmp_path / "rec" / "flight.tlog"))
    seen: dict[str, set[int]] = {}
    while (msg := log.recv_match()) is not None:
        seen.setdefault(msg.get_type(), set()).add(msg.get_srcSystem())
    for kind in ("ATTITUDE", "BATTERY_STATUS", "EXTENDED_SYS_STATE", "EKF_STATUS_REPORT",
                 "PARAM_VALUE"):
        assert seen.get(kind, set()) >= set(range(1, 10)), kind
    assert seen["GPS_RTCM_DATA"] == {200}


@pytest.mark.slow
def test_require_rtk_without_corrections_fails_preflight() -> None:
    run = _dry_run("--require-rtk", "fixed", "--preflight-timeout", "10")
    assert run.returncode == EXIT_UNSAFE, run.stderr[-2000:]
    assert "rtk: fix 3D, need RTK fixed" in run.stderr


def test_bad_rtk_and_gcs_sysid_options() -> None:
    run = _dry_run("--rtk", "no/such/file.rtcm3")
    assert run.returncode == EXIT_USAGE and "--rtk no/such/file.rtcm3" in run.stderr
    run = _dry_run("--gcs-sysid", "0")
    assert run.returncode == EXIT_USAGE and "--gcs-sysid" in run.stderr
    run = _dry_run("--gcs-sysid", "3")
    assert run.returncode != 0 and "simulated vehicle's system id" in run.stderr


def test_sim_streams_the_log_messages() -> None:
    from groundctl.sim import telemetry as T
    assert mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT in T.BUILDERS
    assert mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS in T.BUILDERS


def test_forwarder_survives_a_dead_source_and_counts_drops() -> None:
    import socket

    from groundctl.link.fleet import FleetLink
    from groundctl.rtk.forwarder import RtkForwarder

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    async def main() -> dict[str, object]:
        clock = ScaledClock(1.0)
        link = FleetLink(("127.0.0.1", 0), clock=clock)
        await link.start()
        notes: list[str] = []
        fwd = RtkForwarder(RtkSource(parse_source(f"tcp:127.0.0.1:{port}"), clock,
                                     connect_timeout_s=1.0), link, clock, retry_s=0.05,
                           max_rate_Bps=1000.0, notify=notes.append)
        fwd.start()
        for _ in range(400):
            if fwd.source_errors >= 3:
                break
            await asyncio.sleep(0.01)
        fwd.forward(frame(bytes(800)))  # over four fragments
        for _ in range(5):
            fwd.forward(frame(bytes(400)))  # 2030 bytes at once against 1000 B/s
        await fwd.stop()
        await link.close()
        assert len(notes) == 1 and "corrections stopped" in notes[0]
        return fwd.report()

    report = asyncio.run(main())
    assert isinstance(report["source_errors"], int) and report["source_errors"] >= 3
    assert report["too_large"] == 1
    assert report["messages_sent"] == 2 and report["rate_dropped"] == 3
    assert report["bytes_sent"] == 812
