"""The .tlog writer: readable by pymavlink's own tlog reader, flushed on close."""

from __future__ import annotations

import time
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link import messages
from groundctl.link.codec import Encoder, new_codec
from groundctl.record.tlog import TlogWriter


def test_roundtrip_through_mavutil(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    gcs = Encoder(new_codec(255, 190))
    veh = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    t0 = 1_700_000_000.0
    with TlogWriter(path, flush_interval=10.0) as tlog:
        tlog.write(gcs.encode(messages.gcs_heartbeat()), t0)
        tlog.write(veh.heartbeat_encode(2, 3, 0, 0, 3).pack(veh), t0 + 0.5)
        tlog.write(gcs.encode(messages.position_target_local_ned(7, 0, (1, 2, -3))), t0 + 1.0)
        tlog.write(gcs.encode(messages.led_rgb(7, 1, 2, 3)), t0 + 1.5)
    conn = mavutil.mavlink_connection(str(path))
    got = []
    while (m := conn.recv_match()) is not None:
        got.append((m.get_type(), m.get_srcSystem(), round(m._timestamp - t0, 3)))
    conn.close()
    assert got == [("HEARTBEAT", 255, 0.0), ("HEARTBEAT", 7, 0.5),
                   ("SET_POSITION_TARGET_LOCAL_NED", 255, 1.0), ("LED_CONTROL", 255, 1.5)]


def test_periodic_flush_and_close_is_idempotent(tmp_path: Path) -> None:
    path = tmp_path / "f.tlog"
    t = [100.0]
    tlog = TlogWriter(path, wall=lambda: t[0], flush_interval=1.0)
    pkt = Encoder(new_codec()).encode(messages.gcs_heartbeat())
    tlog.write(pkt)
    t[0] = 101.5
    tlog.write(pkt)  # a second past the last flush: a flush is asked for
    deadline = time.monotonic() + 10.0  # by the writer thread, off the caller's loop
    while path.stat().st_size < 2 * (8 + len(pkt)) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert path.stat().st_size == 2 * (8 + len(pkt))
    tlog.close()
    tlog.close()
    tlog.write(pkt)  # after close: dropped, no error
    assert tlog.closed and path.stat().st_size == 2 * (8 + len(pkt))
