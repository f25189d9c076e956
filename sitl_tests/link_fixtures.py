"""A small hand-written MAVLink vehicle for link tests: a plain UDP socket and a pymavlink codec.

It deliberately does not reuse groundctl's codec or state code, so the tests
check groundctl against pymavlink itself.  It records everything it receives
and answers what a test scripts: COMMAND_ACKs (with optional STATUSTEXT
reasons), TIMESYNC answers with a known clock offset, HEARTBEATs.
"""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import Clock, ScaledClock
from groundctl.link.flavours import Flavour, encode_mode, mode_from_set_mode

Address = tuple[str, int]


@dataclass
class ScriptedAck:
    """How the peer answers one COMMAND_LONG."""

    result: int | None
    """MAV_RESULT to send, or None to stay silent (a lost ACK)."""
    statustext: str = ""
    """STATUSTEXT sent just before the ACK (ArduPilot's order), if any."""
    in_progress_first: bool = False
    """Send an IN_PROGRESS ACK first."""


class VehiclePeer:
    """A fake vehicle on 127.0.0.1 with an ephemeral port."""

    def __init__(
        self,
        system_id: int,
        gcs: Address,
        flavour: Flavour = Flavour.ARDUPILOT,
        *,
        clock: Clock | None = None,
        timesync_offset_s: float = 0.0,
        signing_key: bytes | None = None,
        component_id: int = 1,
        mode: str = "STABILIZE",
    ) -> None:
        self.system_id = system_id
        self.gcs = gcs
        self.flavour = flavour
        self.clock = clock or ScaledClock()
        self.timesync_offset_s = timesync_offset_s
        self.mode = mode
        self.armed = False
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.address: Address = self.sock.getsockname()
        self.mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        if signing_key is not None:
            for codec in (self.mav, self.rx):
                codec.signing.secret_key = signing_key
                codec.signing.timestamp = int((time.time() - 1_420_070_400) * 100_000)
                codec.signing.allow_unsigned_callback = None
            self.mav.signing.sign_outgoing = True
        self.received: list[Any] = []
        self.acks: dict[int, deque[ScriptedAck]] = {}
        self.default_ack: int | None = mavlink.MAV_RESULT_ACCEPTED
        self.heartbeat_period: float | None = None
        self.muted = False
        """Drop everything the peer would send (a cut link)."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    # -- sending ---------------------------------------------------------

    def send(self, msg: Any) -> None:
        with self._lock:
            data = msg.pack(self.mav)
            self.mav.seq = (self.mav.seq + 1) % 256
        if not self.muted:
            self.sock.sendto(data, self.gcs)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.gcs)

    def heartbeat(self) -> None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        self.send(self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR, self.flavour.mav_autopilot, base,
            encode_mode(self.flavour, self.mode), mavlink.MAV_STATE_STANDBY))

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_CRITICAL) -> None:
        self.send(self.mav.statustext_encode(severity, text.encode()))

    def vehicle_time_ns(self) -> int:
        return round((self.clock.now() + self.timesync_offset_s) * 1e9)

    # -- scripting -------------------------------------------------------

    def script(self, command: int, *answers: ScriptedAck) -> None:
        """Queue answers for ``command``; once used up, :attr:`default_ack` applies."""
        self.acks.setdefault(command, deque()).extend(answers)

    def messages(self, kind: str) -> list[Any]:
        return [m for m in list(self.received) if m.get_type() == kind]

    async def wait_for(self, kind: str, pred: Callable[[Any], bool] = lambda m: True,
                       timeout: float = 2.0) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for m in self.messages(kind):
                if pred(m):
                    return m
            await asyncio.sleep(0.005)
        raise AssertionError(f"peer {self.system_id}: no {kind} within {timeout} s")

    # -- the receive loop ------------------------------------------------

    def _run(self) -> None:
        next_hb = 0.0
        while not self._stop.is_set():
            if self.heartbeat_period is not None and time.monotonic() >= next_hb:
                next_hb = time.monotonic() + self.heartbeat_period
                self.heartbeat()
            try:
                data, _ = self.sock.recvfrom(65536)
            except (TimeoutError, OSError):
                continue
            for msg in self.rx.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA":
                    continue
                self.received.append(msg)
                self._answer(msg)

    def _answer(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "TIMESYNC" and msg.tc1 == 0:
            self.send(self.mav.timesync_encode(self.vehicle_time_ns(), msg.ts1))
        elif kind == "COMMAND_LONG":
            queue = self.acks.get(msg.command)
            answer = queue.popleft() if queue else ScriptedAck(self.default_ack)
            if answer.result is None:
                return
            if msg.command == mavlink.MAV_CMD_DO_SET_MODE and answer.result == 0:
                self.mode = mode_from_set_mode(self.flavour, msg.param2, msg.param3) or self.mode
            if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and answer.result == 0:
                self.armed = msg.param1 == 1
            if answer.in_progress_first:
                self.send(self.mav.command_ack_encode(
                    msg.command, mavlink.MAV_RESULT_IN_PROGRESS, 50, 0,
                    msg.get_srcSystem(), msg.get_srcComponent()))
            if answer.statustext:
                self.statustext(answer.statustext)
            self.send(self.mav.command_ack_encode(
                msg.command, answer.result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.sock.close()

    def __enter__(self) -> VehiclePeer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


async def eventually(cond: Callable[[], Any], timeout: float = 2.0, what: str = "") -> Any:
    """Poll ``cond`` until truthy; fail the test with ``what`` after ``timeout`` wall seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        await asyncio.sleep(0.005)
    raise AssertionError(f"timed out waiting for {what or cond}")


class EventList:
    """An event sink that keeps events in memory."""

    def __init__(self) -> None:
        self.items: list[tuple[str, dict[str, Any]]] = []

    def emit(self, event: str, /, **fields: Any) -> None:
        self.items.append((event, fields))

    def named(self, event: str) -> list[dict[str, Any]]:
        return [f for e, f in self.items if e == event]


def run(coro_fn: Callable[..., Any]) -> Callable[..., Any]:
    """Run an ``async def`` test in a fresh event loop (no pytest-asyncio here)."""
    import functools

    @functools.wraps(coro_fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        return asyncio.run(asyncio.wait_for(coro_fn(*args, **kwargs), timeout=20))

    return wrapper
