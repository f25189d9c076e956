"""The ground station's receive path per datagram: CPU from the socket's bytes to the
vehicle's state, with the telemetry mix a flying vehicle sends.

Issue 34 asks for 0.7 ms of CPU per vehicle per second in all of the executor's
processes; a vehicle streams about 24 datagrams a second at groundctl's requested
rates (LOCAL_POSITION_NED 10 Hz, VFR_HUD 4, GLOBAL_POSITION_INT 2 and ATTITUDE,
SYS_STATUS, GPS_RAW_INT, WIND, HEARTBEAT, TIMESYNC, EXTENDED_SYS_STATE,
EKF_STATUS_REPORT 1 Hz each, the mix a dry-run's tlog shows; until session 36
GLOBAL_POSITION_INT 5 and ATTITUDE 2, 28 a second), one MAVLink packet per
datagram as ArduCopter SITL sends them.  This times what the control loop does for
each (``FleetLink``'s handler, the clock's dating, pymavlink's parse, the vehicle
state and the trust checks), with no socket, on the paced clock of a dry-run and the
scaled clock of a flight:

    .venv/bin/python benchmarks/bench_receive.py [--vehicles 9] [--seconds 20]

It prints µs per datagram and the CPU per vehicle per second the mix costs.
"""

from __future__ import annotations

import argparse
import itertools
import math
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import PacedClock, ScaledClock
from groundctl.link.codec import DatagramParser, new_codec
from groundctl.link.fleet import FleetLink
from groundctl.link.worker import Datagram, decode_batch, encode_batch, pack_message

#: Message -> Hz, as the dry-run's tlog counts them per vehicle.
MIX: dict[str, float] = {
    "LOCAL_POSITION_NED": 10.0, "GLOBAL_POSITION_INT": 2.0, "VFR_HUD": 4.0,
    "ATTITUDE": 1.0, "SYS_STATUS": 1.0, "GPS_RAW_INT": 1.0, "WIND": 1.0,
    "HEARTBEAT": 1.0, "TIMESYNC": 1.0, "EXTENDED_SYS_STATE": 1.0,
    "EKF_STATUS_REPORT": 1.0,
}


def _message(kind: str, t: float, i: int) -> mavlink.MAVLink_message:
    """Vehicle ``i``'s ``kind`` at ``t`` s: flying a slow circle 10 m up."""
    ms = int(t * 1000)
    x, y, z = 5.0 * math.cos(0.2 * t) + 3 * i, 5.0 * math.sin(0.2 * t), -10.0
    vx, vy = -1.0 * math.sin(0.2 * t), 1.0 * math.cos(0.2 * t)
    lat = int((47.3977 + x / 111_320.0) * 1e7)
    lon = int((8.5456 + y / 75_000.0) * 1e7)
    if kind == "LOCAL_POSITION_NED":
        return mavlink.MAVLink_local_position_ned_message(ms, x, y, z, vx, vy, 0.0)
    if kind == "GLOBAL_POSITION_INT":
        return mavlink.MAVLink_global_position_int_message(
            ms, lat, lon, 498_000, 10_000, int(vx * 100), int(vy * 100), 0, 9000)
    if kind == "VFR_HUD":
        return mavlink.MAVLink_vfr_hud_message(1.0, 1.0, 90, 45, 498.0, 0.0)
    if kind == "ATTITUDE":
        return mavlink.MAVLink_attitude_message(ms, 0.01, 0.02, 1.5, 0.0, 0.0, 0.0)
    if kind == "SYS_STATUS":
        return mavlink.MAVLink_sys_status_message(
            0x7FFFFFFF, 0x7FFFFFFF, 0x7FFFFFFF, 300, 15800, 1200, 80, 0, 0, 0, 0, 0, 0)
    if kind == "GPS_RAW_INT":
        return mavlink.MAVLink_gps_raw_int_message(
            ms * 1000, 6, lat, lon, 498_000, 70, 90, 100, 9000, 18)
    if kind == "WIND":
        return mavlink.MAVLink_wind_message(0.0, 0.0, 0.0)
    if kind == "HEARTBEAT":
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
            mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
            4, mavlink.MAV_STATE_ACTIVE, 3)
    if kind == "TIMESYNC":
        return mavlink.MAVLink_timesync_message(ms * 1_000_000, ms * 1_000_000)  # an answer
    if kind == "EXTENDED_SYS_STATE":
        return mavlink.MAVLink_extended_sys_state_message(0, mavlink.MAV_LANDED_STATE_IN_AIR)
    if kind == "EKF_STATUS_REPORT":
        return mavlink.MAVLink_ekf_status_report_message(0x3FF, 0.1, 0.1, 0.1, 0.1, 0.1)
    raise ValueError(kind)


def datagrams(vehicles: int, seconds: float) -> list[tuple[float, bytes, tuple[str, int]]]:
    """Every vehicle's datagrams over ``seconds``, in time order."""
    codecs = [mavlink.MAVLink(None, srcSystem=i + 1, srcComponent=1) for i in range(vehicles)]
    out = []
    for kind, hz in MIX.items():
        for k in range(int(seconds * hz)):
            t = k / hz + 0.001
            for i, mav in enumerate(codecs):
                out.append((t + i * 1e-4, kind, i, mav))
    out.sort(key=lambda e: e[0])
    result = []
    for t, kind, i, mav in out:
        result.append((t, _message(kind, t, i).pack(mav), ("127.0.0.1", 40000 + i)))
        mav.seq = (mav.seq + 1) % 256  # pack() does not number: the sender does
    return result


def run(clock_kind: str, vehicles: int, seconds: float, batch: int) -> tuple[float, int]:
    """CPU seconds to handle every datagram, ``batch`` a drain, and how many there were."""
    stream = datagrams(vehicles, seconds)
    clock = ScaledClock(1.0) if clock_kind == "scaled" else \
        PacedClock(1.0, participants=1).participant(0)
    link = FleetLink(("127.0.0.1", 0), clock=clock,
                     expected_ids=range(1, vehicles + 1))
    reads = [(data, addr) for _, data, addr in stream]
    start = time.process_time()
    for k in range(0, len(reads), batch):
        arrived = time.monotonic() - 1e-4  # as the transport hands them on: when they came
        link._on_datagrams([(d, a, arrived) for d, a in reads[k:k + batch]])
    return time.process_time() - start, len(stream)


def run_worker_path(clock_kind: str, vehicles: int, seconds: float,
                    batch: int) -> tuple[float, int]:
    """CPU seconds the control loop spends on every datagram when a link worker parsed
    them (``batch`` to a pipe read): the batch's bytes unpickled, each message rebuilt and
    handled.  The worker's own parse is not counted (it runs in its own process)."""
    stream = datagrams(vehicles, seconds)
    clock = ScaledClock(1.0) if clock_kind == "scaled" else \
        PacedClock(1.0, participants=1).participant(0)
    link = FleetLink(("127.0.0.1", 0), clock=clock,
                     expected_ids=range(1, vehicles + 1))
    parsers: dict[tuple[str, int], DatagramParser] = {}
    parsed = []
    for _, data, addr in stream:
        if addr not in parsers:
            parsers[addr] = DatagramParser(new_codec(255, 190))
        result = parsers[addr].feed(data)
        # Arrived "at infinity": dated as just now (an age of zero), as a fresh batch is.
        parsed.append(Datagram(addr, math.inf,
                               tuple(pack_message(m) for m in result.messages)))
    frames = [encode_batch(parsed[k:k + batch]) for k in range(0, len(parsed), batch)]
    start = time.process_time()
    for frame in frames:
        link._on_batch(0, decode_batch(frame)[1])
    return time.process_time() - start, len(stream)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=9)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 8],
                    help="datagrams a drain reads at once (1: an idle loop woken by each)")
    ap.add_argument("--paths", nargs="+", choices=["loop", "worker"],
                    default=["loop", "worker"],
                    help="loop: the control loop parses the socket's bytes itself (small "
                         "fleets); worker: a link worker parsed them, the loop takes its "
                         "batches (from 100 vehicles; --batches then counts a pipe read)")
    args = ap.parse_args()
    per_s = sum(MIX.values())
    print(f"{args.vehicles} vehicles, {args.seconds:g} s of telemetry, "
          f"{per_s:g} datagrams per vehicle per second")
    for path, kind in itertools.product(args.paths, ("paced", "scaled")):
        for batch in args.batches:
            best = math.inf
            n = 0
            for _ in range(args.repeat):
                cpu, n = (run if path == "loop" else run_worker_path)(
                    kind, args.vehicles, args.seconds, batch)
                best = min(best, cpu)
            us = best / n * 1e6
            print(f"{path:>6} path, {kind:>6} clock, {batch:3d} a drain: {us:5.1f} µs per "
                  f"datagram (best of {args.repeat}, {n} datagrams), "
                  f"{us * per_s / 1000:.2f} ms of CPU per vehicle per second")


if __name__ == "__main__":
    main()
