"""Simulator cost: CPU per vehicle, and the largest fleet that keeps real time.

Runs a fleet at speed 1 (physics 50 Hz) with a ground station in a child
process that asks every vehicle for LOCAL_POSITION_NED and GLOBAL_POSITION_INT
at 10 Hz each, and measures the simulator process's CPU time.  Loopback only.

    .venv/bin/python benchmarks/bench_sim.py                 # 200 vehicles, 20 s, then 400, 800
    .venv/bin/python benchmarks/bench_sim.py --sizes 200 --seconds 20
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import socket
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import ScaledClock
from groundctl.sim import SimConfig, SimFleet

STREAMS = (mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)


def _gcs(sock: socket.socket, targets: list[tuple[int, int]], seconds: float,
         conn: Connection) -> None:
    """Child process: request the streams from every vehicle, count what arrives."""
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    for sysid, port in targets:
        for msgid in STREAMS:
            data = mavlink.MAVLink_command_long_message(
                sysid, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msgid, 100_000,
                0, 0, 0, 0, 0).pack(mav)
            mav.seq = (mav.seq + 1) % 256
            sock.sendto(data, ("127.0.0.1", port))
    sock.settimeout(0.2)
    counts = {m: 0 for m in STREAMS}
    warmup_end = time.monotonic() + 2.0
    end = warmup_end + seconds
    started = False
    while time.monotonic() < end:
        try:
            data = sock.recv(65535)
        except TimeoutError:
            continue
        if not started and time.monotonic() >= warmup_end:
            started = True
            conn.send("go")
        if started and len(data) > 9:
            msgid = data[7] | data[8] << 8 | data[9] << 16
            if msgid in counts:
                counts[msgid] += 1
    conn.send(counts)


@dataclass
class Result:
    count: int
    cpu_s: float
    wall_s: float
    received_per_s: float
    overruns: int
    max_lag: float

    @property
    def cpu_fraction(self) -> float:
        return self.cpu_s / self.wall_s

    @property
    def real_time(self) -> bool:
        expected = self.count * 20.0
        return self.overruns == 0 and self.max_lag < 0.1 and self.received_per_s > 0.95 * expected


def run(count: int, seconds: float) -> Result:
    gcs_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs_sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    gcs_sock.bind(("127.0.0.1", 0))
    ids = [(i % 255) + 1 for i in range(count)]
    cfg = SimConfig(count=count, system_ids=ids, gcs=gcs_sock.getsockname(),
                    ekf_origin_delay_s=0.0, ready_delay_s=0.0, spacing=2.0)
    fleet = SimFleet(cfg, ScaledClock(1.0))
    parent, child = mp.Pipe()
    proc = mp.get_context("fork").Process(
        target=_gcs, args=(gcs_sock, list(zip(ids, fleet.ports, strict=True)), seconds, child))
    fleet.start()
    proc.start()
    parent.recv()  # warm-up over: streams flowing
    fleet.max_lag = 0.0
    overruns0 = fleet.overruns
    cpu0, wall0 = time.process_time(), time.monotonic()
    counts = parent.recv()
    cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
    lag, overruns = fleet.max_lag, fleet.overruns - overruns0
    proc.join()
    fleet.stop()
    gcs_sock.close()
    return Result(count, cpu, wall, sum(counts.values()) / wall, overruns, lag)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[200, 400, 800])
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args()
    print(f"{'vehicles':>8} {'cpu/wall':>9} {'cpu/vehicle':>12} {'msgs/s':>9} {'expected':>9} "
          f"{'max lag':>8} {'overruns':>8}  real time")
    largest = 0
    for n in args.sizes:
        r = run(n, args.seconds)
        print(f"{n:8d} {r.cpu_fraction:8.1%} {r.cpu_fraction / n * 1000:9.2f} ms/s "
              f"{r.received_per_s:9.0f} {n * 20:9d} {r.max_lag:7.3f}s {r.overruns:8d}  "
              f"{'yes' if r.real_time else 'NO'}", flush=True)
        if r.real_time:
            largest = max(largest, n)
    print(f"largest fleet that kept real time: {largest or 'none'} of {args.sizes}")


if __name__ == "__main__":
    main()
