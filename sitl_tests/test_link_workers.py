"""The receive path in worker processes (issue 34, groundctl/link/worker.py): the
worker protocol (messages packed and rebuilt unchanged, batches), the worker's reads of
a real loopback socket (garbage, truncation, signatures), FleetLink with workers
against the simulator over UDP on two networks, and a worker that dies (seen at once,
the network silent meanwhile, restarted on the same socket, its vehicles heard again)."""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import pickle
import signal
import socket
import time

import pytest
from link_fixtures import EventList, eventually, run
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import ManualClock, PacedClock, ScaledClock
from groundctl.link import FleetLink
from groundctl.link.codec import new_codec
from groundctl.link.signing import SigningConfig
from groundctl.link.worker import (
    MAX_BACKLOG_BYTES,
    Conflator,
    Datagram,
    FrameReader,
    Pacer,
    Receiver,
    Superseded,
    WorkerSetup,
    decode_batch,
    encode_batch,
    encode_sends,
    pack_message,
    unpack,
    unpack_message,
    use_workers,
)
from groundctl.sim import SimConfig, SimFleet

KEY = bytes(range(32))


def _sample_messages() -> list[mavlink.MAVLink_message]:
    return [
        mavlink.MAVLink_heartbeat_message(2, 3, 81, 4, 4, 3),
        mavlink.MAVLink_local_position_ned_message(1234, 1.5, -2.25, -5.0, 0.1, 0.2, -0.3),
        mavlink.MAVLink_global_position_int_message(1000, 473977418, 85455939, 500000,
                                                    10000, 1, 2, 3, 65535),
        mavlink.MAVLink_statustext_message(4, b"PreArm: GPS not healthy", 7, 0),
        mavlink.MAVLink_param_value_message(b"FENCE_ENABLE", 1.0, 9, 1200, 17),
        mavlink.MAVLink_command_ack_message(400, 0, 0, 0, 255, 190),
        mavlink.MAVLink_attitude_quaternion_message(10, 1.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3,
                                                    [0.0, 0.0, 0.0, 0.0]),
    ]


def _wire(msgs: list[mavlink.MAVLink_message], sysid: int = 7,
          key: bytes | None = None) -> list[bytes]:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 0
        mav.signing.timestamp = int((time.time() - 1420070400) * 100000)
    return [m.pack(mav) for m in msgs]


def _parsed(wire: list[bytes]) -> list[mavlink.MAVLink_message]:
    rx = new_codec()
    return [m for data in wire for m in rx.parse_buffer(data) or []]


def test_a_message_rebuilt_from_its_packed_form_is_the_message_parsed() -> None:
    for msg in _parsed(_wire(_sample_messages())):
        back = unpack_message(pack_message(msg))
        assert type(back) is type(msg) and back.get_type() == msg.get_type()
        assert back.to_dict() == msg.to_dict()
        assert bytes(back.get_msgbuf()) == bytes(msg.get_msgbuf())
        assert (back.get_srcSystem(), back.get_srcComponent(), back.get_seq()) == \
            (msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq())
        assert back.get_header().__dict__ == msg.get_header().__dict__
    text = unpack_message(pack_message(_parsed(_wire(_sample_messages()))[3]))
    assert text.text == "PreArm: GPS not healthy"  # decoded, as a parsed one is


def test_a_batch_crosses_the_pipe_unchanged() -> None:
    packed = tuple(pack_message(m) for m in _parsed(_wire(_sample_messages())))
    batch = [Datagram(("127.0.0.1", 14551), 12.5, packed),
             Datagram(("127.0.0.2", 9), 12.75, (), ("bad CRC", "truncated packet (3 bytes)"),
                      (5,), 2)]
    errors, back = decode_batch(encode_batch(batch, 3))
    assert (errors, back) == (3, batch)
    assert all(type(d) is Datagram for d in back)  # not bare tuples that compare equal
    assert back[1].refused_signatures == (5,) and back[1].unknown == 2
    assert decode_batch(encode_batch([])) == (0, [])


def test_frames_of_sends_are_read_back_however_the_pipe_cuts_them() -> None:
    frames = [[(b"\xfd" + bytes([i]) * 40, ("127.0.0.1", 14550 + i))] * (i + 1)
              for i in range(5)]
    wire = b"".join(encode_sends(f) for f in frames)
    reader = FrameReader()
    got = []
    for k in range(0, len(wire), 7):  # a pipe read ends anywhere
        got += [pickle.loads(p) for p in reader.feed(wire[k:k + 7])]
    assert got == frames


@pytest.mark.parametrize(("mode", "vehicles", "want"), [
    ("off", 1000, False), ("on", 2, True), ("auto", 99, False), ("auto", 100, True)])
def test_link_workers_modes(mode: str, vehicles: int, want: bool) -> None:
    assert use_workers(mode, vehicles) is want


def test_an_unknown_link_workers_mode_is_one_line() -> None:
    with pytest.raises(ValueError, match="--link-workers must be one of auto, on, off"):
        use_workers("sometimes", 10)


def _bound() -> tuple[socket.socket, socket.socket]:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.bind(("127.0.0.1", 0))
    return rx, tx


def _read_all(receiver: Receiver, want: int) -> list[Datagram]:
    out: list[Datagram] = []
    deadline = time.monotonic() + 5.0
    while len(out) < want and time.monotonic() < deadline:
        out += receiver.read()
        time.sleep(0.001)
    return out


def test_the_worker_reads_parses_and_dates_what_a_real_socket_holds() -> None:
    rx, tx = _bound()
    try:
        setup = WorkerSetup(0, 255, 190, None, False, os.getpid())
        receiver = Receiver(rx, setup)
        good = _wire(_sample_messages()[:2])
        before = time.monotonic()
        for data in [good[0], b"\xfd\x09garbage-not-mavlink", good[1][:-3], good[1]]:
            tx.sendto(data, rx.getsockname())
        got = _read_all(receiver, 4)
        assert len(got) == 4
        assert all(d.address == tx.getsockname() for d in got)
        assert all(before <= d.arrived <= time.monotonic() for d in got)
        assert [len(d.messages) for d in got] == [1, 0, 0, 1]
        assert got[1].bad and not got[0].bad and not got[3].bad
        assert any("truncated" in reason for reason in got[2].bad)
        assert unpack_message(got[3].messages[0]).x == 1.5
    finally:
        rx.close()
        tx.close()


def test_the_worker_checks_signatures_with_the_network_key() -> None:
    rx, tx = _bound()
    try:
        setup = WorkerSetup(1, 255, 190, SigningConfig(KEY, 0, False), False, os.getpid())
        receiver = Receiver(rx, setup)
        for data in _wire(_sample_messages()[:1], sysid=9, key=KEY) + \
                _wire(_sample_messages()[:1], sysid=12):
            tx.sendto(data, rx.getsockname())
        got = _read_all(receiver, 2)
        assert [len(d.messages) for d in got] == [1, 0]
        assert got[1].refused_signatures == (12,)
    finally:
        rx.close()
        tx.close()


def test_a_paced_clock_dates_a_batch_as_it_dates_each() -> None:
    clock = PacedClock(4.0, participants=1)
    ages = [0.0, 0.01, 0.05, 0.2]
    now, times = clock.dated(ages)
    many = [now - t for t in times]
    each = [n - t for n, (t,) in (clock.dated([a]) for a in ages)]  # one at a time
    assert many == pytest.approx(each, abs=4.0 * 0.01)  # read a moment apart, at x4
    assert many[0] == pytest.approx(0.0, abs=0.01)
    assert many[-1] == pytest.approx(0.8, abs=0.05)
    assert clock.dated([0.2])[1] == [pytest.approx(times[-1], abs=4.0 * 0.01)]


# -- FleetLink with receive workers, against the simulator over UDP ----------------------


def _two_networks(link: FleetLink) -> SimConfig:
    return SimConfig(count=4, system_ids=[1, 2, 1, 2], networks=[1, 1, 2, 2],
                     gcs_networks=link.local_addresses, ekf_origin_delay_s=0.5,
                     ready_delay_s=1.0)


@run
async def test_a_link_with_workers_hears_and_commands_two_networks() -> None:
    events = EventList()
    link = FleetLink([("127.0.0.1", 0), ("127.0.0.1", 0)], clock=ScaledClock(),
                     events=events, heartbeat_period=0.1, timesync_period=0.1, tick=0.01,
                     link_workers=True)
    async with link:
        pids = link.worker_pids
        assert len(pids) == 2 and os.getpid() not in pids
        fleet = SimFleet(_two_networks(link), ScaledClock(4.0))
        try:
            fleet.start()
            await link.wait_for_vehicles([1, 2, 1001, 1002], timeout=5.0)
            await link.set_mode(1001, "GUIDED")  # the answer (COMMAND_ACK) via the worker
            await eventually(lambda: fleet.state(1001).mode == "GUIDED", what="2:1 GUIDED")
            assert fleet.state(1).mode != "GUIDED"
            await eventually(lambda: link.vehicles[2].rtt_s is not None, timeout=3.0,
                             what="a TIMESYNC round trip through the worker, both ways")
            rtt = link.vehicles[2].rtt_s
            assert rtt is not None and 0.0 < rtt < 1.0
            assert link.stats.packets > 0 and link.stats.bad_packets == 0
            assert sum(w.direct for w in link._workers) == 0  # every send by a worker
        finally:
            fleet.stop()
    assert link.worker_pids == []  # closed with the link


@run
async def test_a_worker_that_dies_holds_its_network_and_is_replaced() -> None:
    events = EventList()
    link = FleetLink([("127.0.0.1", 0), ("127.0.0.1", 0)], clock=ScaledClock(),
                     events=events, heartbeat_period=0.1, timesync_period=0.1, tick=0.01,
                     fleet_silence=0.5, lost_timeout=1.0, link_workers=True)
    async with link:
        fleet = SimFleet(_two_networks(link), ScaledClock(4.0))
        try:
            fleet.start()
            await link.wait_for_vehicles([1, 2, 1001, 1002], timeout=5.0)
            old = link.worker_pids[1]
            os.kill(old, signal.SIGKILL)  # as the kernel's OOM killer would
            died = await eventually(lambda: events.named("link_worker_died"), timeout=3.0,
                                    what="the death seen")
            assert died[0]["network"] == 2 and died[0]["exit_code"] == -9
            await eventually(lambda: link.fleet_silent, timeout=2.0, what="fleet silent")
            restarted = await eventually(lambda: events.named("link_worker_restarted"),
                                         timeout=3.0, what="a new worker")
            assert restarted[0]["network"] == 2 and restarted[0]["pid"] != old
            assert link.worker_pids[1] != old
            await eventually(lambda: not link.fleet_silent, timeout=3.0, what="heard again")
            assert not any(v.lost for v in link.vehicles.values())
            assert not events.named("vehicle_lost")
            assert link.stats.worker_deaths == 1
            # A command after the restart goes through the new worker.
            await link.set_mode(1002, "GUIDED")
            await eventually(lambda: fleet.state(1002).mode == "GUIDED", what="2:2 GUIDED")
        finally:
            fleet.stop()


@run
async def test_workers_on_a_clock_real_time_does_not_move() -> None:
    """A manual clock (a test's) dates every datagram at its own reading."""
    link = FleetLink(("127.0.0.1", 0), clock=ManualClock(5.0), link_workers=True)
    async with link:
        rx, tx = _bound()
        rx.close()
        try:
            assert link.local_address is not None
            for data in _wire(_sample_messages()[:2], sysid=3):
                tx.sendto(data, link.local_address)
            await eventually(lambda: 3 in link.vehicles, what="vehicle 3 heard")
            assert link.vehicles[3].last_heard == 5.0
        finally:
            tx.close()


@run
async def test_a_worker_that_takes_no_sends_never_blocks_the_loop() -> None:
    """A worker stopped (SIGSTOP: a debugger, a machine thrashing): every send returns at
    once, the pipe's backlog is bounded (the oldest dropped and counted), and once it
    runs again the rest leave."""
    link = FleetLink(("127.0.0.1", 0), clock=ScaledClock(), link_workers=True)
    async with link:
        rx, tx = _bound()
        tx.close()
        try:
            assert link.local_address is not None
            peer = rx.getsockname()
            worker = link._workers[0]
            pid = worker.pid
            assert pid is not None
            os.kill(pid, signal.SIGSTOP)
            try:
                # 100,000 sends while it is stopped: were a write to wait for it, this
                # would never end (the test's timeout says so).
                for k in range(200):
                    for i in range(500):  # each its own bytes (pickle shares repeats)
                        worker.send((k * 500 + i).to_bytes(4, "little") + bytes(57), peer)
                    worker.flush()
                assert worker.dropped > 0
                assert worker._writer is not None
                assert worker._writer.waiting <= MAX_BACKLOG_BYTES + 500 * 100
            finally:
                os.kill(pid, signal.SIGCONT)
            got = 0
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and got < 1000:
                await asyncio.sleep(0.01)
                with contextlib.suppress(BlockingIOError):
                    while True:
                        rx.recv(100)
                        got += 1
            assert got >= 1000  # the backlog left once the worker ran again
        finally:
            rx.close()


@run
async def test_a_worker_with_nothing_to_read_stays() -> None:
    """Its parent is the fork server, not the ground station: silence before the vehicles
    talk is no reason to leave (the first dry-run of 1,000 drones saw its workers go)."""
    from groundctl.link.worker import PARENT_CHECK_S

    events = EventList()
    link = FleetLink(("127.0.0.1", 0), clock=ScaledClock(), events=events, link_workers=True)
    async with link:
        pids = link.worker_pids
        await asyncio.sleep(3 * PARENT_CHECK_S)
        assert link.worker_pids == pids
        assert not events.named("link_worker_died")


@run
async def test_telemetry_waits_in_the_worker_while_the_control_loop_is_stalled() -> None:
    """The control loop stalls (blocked for 2 s) while 30,000 datagrams arrive: three
    times what the socket's buffer holds (about 10,000 small datagrams: the kernel
    counts 830 bytes each), so only a worker that keeps reading, and keeps what it read,
    loses none of them; afterwards they are all decided on."""
    import threading

    link = FleetLink(("127.0.0.1", 0), clock=ScaledClock(), link_workers=True)
    async with link:
        assert link.local_address is not None
        target = link.local_address
        wire = _wire(_sample_messages()[1:2], sysid=6)[0]
        count = 30_000

        def flood() -> None:
            # About 20,000 a second (800 vehicles' telemetry), in bursts of 2,000 that
            # each wait for the worker to have read most of the last out of the socket:
            # on a busy machine a worker kept from the CPU falls behind a fixed rate and
            # the kernel drops what overflows, which says nothing about what the worker
            # keeps.  A worker that stopped reading would never drain it: the test fails.
            tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                for k in range(count):
                    tx.sendto(wire, target)
                    if k % 20 == 19:
                        time.sleep(0.001)
                    if k % 2000 == 1999:
                        give_up = time.monotonic() + 60.0
                        while _rx_queued(target[1]) > 1000 * 830 \
                                and time.monotonic() < give_up:
                            time.sleep(0.01)
            finally:
                tx.close()

        sender = threading.Thread(target=flood)
        before = link.stats.datagrams
        sender.start()
        sender.join()  # the control loop stalled all along: nobody read the worker's pipe
        await eventually(lambda: link.stats.datagrams - before >= count * 0.9, timeout=60.0,
                         what="the stalled telemetry handed on")
        await asyncio.sleep(0.5)
        assert link.stats.datagrams - before > count * 0.9  # the kernel alone keeps ~1/3


def _rx_queued(port: int) -> int:
    """Bytes waiting in the receive queue of the UDP socket bound to ``port`` on this
    machine (Linux's /proc/net/udp; 0 if it is not there)."""
    with open("/proc/net/udp") as f:
        next(f)
        for line in f:
            fields = line.split()
            if int(fields[1].split(":")[1], 16) == port:
                return int(fields[4].split(":")[1], 16)
    return 0


# -- a control loop that falls behind: conflation, and the paced clock --------------------

ADDR = ("127.0.0.1", 14551)


def _position(x: float, t_ms: int) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_local_position_ned_message(t_ms, x, 0.0, -5.0, 1.0, 0.0, 0.0)


def _datagrams(msgs: list[mavlink.MAVLink_message], sysid: int = 7,
               first_seq: int = 0) -> list[Datagram]:
    """One datagram per message, numbered on from ``first_seq``, as a worker reads them."""
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    out = []
    for k, msg in enumerate(msgs):
        mav.seq = (first_seq + k) % 256  # (send() numbers on; pack() alone does not)
        parsed = _parsed([msg.pack(mav)])
        out.append(Datagram(ADDR, 100.0 + 0.01 * k, tuple(pack_message(m) for m in parsed)))
    return out


def test_a_conflator_keeps_the_newest_state_and_every_number() -> None:
    ack = mavlink.MAVLink_command_ack_message(400, 0, 0, 0, 255, 190)
    beat = mavlink.MAVLink_heartbeat_message(2, 3, 81, 4, 4, 3)
    conflator = Conflator()
    mine = _datagrams([_position(1.0, 100), ack, beat, _position(2.0, 200), beat,
                       _position(3.0, 300)])
    other = _datagrams([_position(9.0, 100)], sysid=8)
    conflator.add(mine[:3])
    conflator.add(other + mine[3:])
    assert len(conflator) == 7 and conflator.oldest == mine[0].arrived
    got = conflator.take()
    assert len(conflator) == 0 and conflator.oldest is None
    kept = [unpack(d.messages[0]) for d in got]
    # The first two positions of vehicle 7 stand as their headers (numbers 0 and 3),
    # in their places; the answer, both HEARTBEATs and vehicle 8's position go whole.
    assert [type(m).__name__ for m in kept] == [
        "Superseded", "MAVLink_command_ack_message", "MAVLink_heartbeat_message",
        "MAVLink_local_position_ned_message", "Superseded", "MAVLink_heartbeat_message",
        "MAVLink_local_position_ned_message"]
    first, second = kept[0], kept[4]
    assert isinstance(first, Superseded) and isinstance(second, Superseded)
    assert (first.seq, second.seq, first.system, first.kind) == (0, 3, 7,
                                                                 "LOCAL_POSITION_NED")
    assert first.crc != second.crc
    assert kept[3].get_srcSystem() == 8 and kept[6].x == 3.0
    assert conflator.superseded == 2
    back = decode_batch(encode_batch(got))[1]  # and it crosses the pipe as it is
    assert isinstance(unpack(back[0].messages[0]), Superseded)


def test_a_conflator_past_its_limit_sheds_the_oldest() -> None:
    conflator = Conflator(limit=10)
    beat = mavlink.MAVLink_heartbeat_message(2, 3, 81, 4, 4, 3)
    conflator.add(_datagrams([beat] * 12))
    assert conflator.dropped == 6 and len(conflator) == 6


def test_superseded_packets_are_heard_and_numbered_not_acted_on() -> None:
    """Nineteen positions replaced by a twentieth while the loop was behind: no loss, no
    second sender, the vehicle's position the newest; then a packet under a number the
    vehicle already used, with other bytes, is a second sender's, superseded or not."""
    events = EventList()
    link = FleetLink(("127.0.0.1", 0), clock=ManualClock(100.0), events=events)
    conflator = Conflator()
    beat = mavlink.MAVLink_heartbeat_message(2, 3, 81, 4, 4, 3)
    conflator.add(_datagrams([beat] + [_position(0.1 * k, 100 * k) for k in range(1, 21)]))
    batch = conflator.take()
    assert sum(isinstance(unpack(d.messages[0]), Superseded) for d in batch) == 19
    link._on_batch(0, batch)
    state = link.vehicles[7]
    assert state.packets == 21 and state.quality.lost == 0
    assert state.link_conflicts == 0 and link.stats.superseded == 19
    # Only the newest position was offered to the motion check (the first track waits
    # there for its confirmation, as any vehicle's first position does).
    offered = [x for chain in state.trust.local.chains for x in chain]
    assert [x.t for x in offered] == [2.0] and offered[0].pos[0] == pytest.approx(2.0)
    forged = Conflator()
    forged.add(_datagrams([_position(5.0, 2050), _position(5.0, 2100)], first_seq=20))
    link._on_batch(0, forged.take())  # number 20 was the last position's
    assert state.link_conflicts >= 1
    assert any("numbered 20" in e["reason"] for e in events.named("link_conflict"))


def test_a_worker_behind_holds_a_paced_clock_where_its_telemetry_arrived() -> None:
    clock = PacedClock(1.0, participants=2, slack=0.01)
    ground, worker = clock.participant(0), clock.participant(1)
    ground.idle_until(math.inf)
    pacer = Pacer(worker)
    arrived = time.monotonic()
    at = clock.at_wall(arrived)
    pacer.done_up_to(arrived)  # behind: what came after this has not reached the loop
    time.sleep(0.1)
    assert clock.now() <= at + 0.01 + 1e-6  # stood where the telemetry waits
    pacer.done_up_to(None)  # caught up
    time.sleep(0.05)
    assert clock.now() >= at + 0.04
    assert clock.held_s()[1] > 0.05
