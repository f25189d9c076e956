"""The MAVLink parameter protocol, client side: a pure state machine and a thin driver.

:class:`ParamClient` holds one vehicle's exchange: reads by name
(PARAM_REQUEST_READ), a whole list (PARAM_REQUEST_LIST, gaps filled by index),
and writes (PARAM_SET) that count only once the vehicle's PARAM_VALUE echoes
the value.  No I/O and no clock inside: :meth:`ParamClient.poll` takes the
time and returns the messages to send (first tries and retries, at most
``window`` requests outstanding, so a fleet of vehicles is never flooded);
:meth:`ParamClient.receive` takes what came back.  :func:`run_params` drives
one client over a :class:`~groundctl.link.fleet.FleetLink`; many vehicles run
concurrently with ``asyncio.gather``.

Encoding (MAV_PARAM_TYPE): ArduPilot sends and reads an integer parameter's
*value* in the float field (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST``);
PX4 copies an integer's *bytes* into it (``..._PARAM_ENCODE_BYTEWISE``), so a
PX4 INT32 of 3 travels as the float 4.2e-45.  :func:`decode_wire` and
:func:`encode_wire` are the two directions.
"""

from __future__ import annotations

import asyncio
import math
import struct
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeAlias

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour

if TYPE_CHECKING:
    from groundctl.clock import Clock
    from groundctl.link.fleet import FleetLink

Msg: TypeAlias = mavlink.MAVLink_message
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
#: Integer MAV_PARAM_TYPEs (PX4 sends these bytewise).
INT_TYPES = frozenset({mavlink.MAV_PARAM_TYPE_UINT8, mavlink.MAV_PARAM_TYPE_INT8,
                       mavlink.MAV_PARAM_TYPE_UINT16, mavlink.MAV_PARAM_TYPE_INT16,
                       mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT32})
#: MAVLink component id of the autopilot.
AUTOPILOT = mavlink.MAV_COMP_ID_AUTOPILOT1


def decode_wire(flavour: Flavour, wire: float, ptype: int) -> float:
    """The value a PARAM_VALUE (or PARAM_SET) carries, read as ``flavour`` encodes it."""
    if flavour is Flavour.PX4 and ptype in INT_TYPES:
        return float(struct.unpack("<i", struct.pack("<f", wire))[0])
    if ptype in INT_TYPES:
        return float(round(wire))
    return float(wire)


def encode_wire(flavour: Flavour, value: float, ptype: int) -> float:
    """The float field of a PARAM_SET carrying ``value`` of type ``ptype`` to ``flavour``."""
    if flavour is Flavour.PX4 and ptype in INT_TYPES:
        return float(struct.unpack("<f", struct.pack("<i", round(value)))[0])
    if ptype in INT_TYPES:
        return float(round(value))
    return float(value)


def same_value(a: float, b: float, ptype: int) -> bool:
    """Whether two decoded values are the same parameter value: integers exactly, floats
    within float32 precision (ArduPilot stores float32: 0.1 comes back 0.100000001)."""
    if ptype in INT_TYPES:
        return round(a) == round(b)
    return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-6)


def _param_id(raw: bytes | str) -> str:
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\0", 1)[0]


@dataclass(frozen=True)
class ParamValue:
    """One parameter as the vehicle reported it."""

    name: str
    """Parameter id."""
    value: float
    """Decoded value (integers as whole floats)."""
    type: int
    """MAV_PARAM_TYPE."""
    index: int
    """Its index on the vehicle (-1 if unknown)."""


@dataclass
class _Request:
    kind: str  # "read", "set", "list"
    name: str = ""
    value: float = 0.0
    ptype: int = REAL32
    attempts: int = 0
    deadline: float = -math.inf
    """When the outstanding try times out (-inf: not sent yet)."""
    others: tuple[str, ...] = ()
    """A read's other names: any of them answering answers it (firmware renames)."""


@dataclass
class ParamClient:
    """The parameter exchange with one vehicle; see the module docstring."""

    sysid: int
    """The vehicle's system id."""
    flavour: Flavour
    """How it encodes integer parameters."""
    timeout_s: float = 1.0
    """How long one try waits for its PARAM_VALUE."""
    attempts: int = 3
    """Tries per request before it fails."""
    window: int = 4
    """Requests outstanding at once."""
    values: dict[str, ParamValue] = field(default_factory=dict)
    """Every parameter value received, by name."""
    failed: dict[str, str] = field(default_factory=dict)
    """Request name ("*" for the list) -> why it failed."""
    confirmed: set[str] = field(default_factory=set)
    """Names whose PARAM_SET the vehicle confirmed."""
    count: int | None = None
    """``param_count`` the vehicle reported (None: no PARAM_VALUE yet)."""
    _queue: deque[_Request] = field(default_factory=deque)
    _active: list[_Request] = field(default_factory=list)
    _by_index: dict[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.timeout_s <= 0:
            raise ValueError(f"`timeout_s` must be positive, got {self.timeout_s}")
        if self.attempts < 1:
            raise ValueError(f"`attempts` must be at least 1, got {self.attempts}")
        if self.window < 1:
            raise ValueError(f"`window` must be at least 1, got {self.window}")

    # -- requests ---------------------------------------------------------------------
    def read(self, name: str) -> None:
        """Ask for ``name`` (PARAM_REQUEST_READ by id); its answer lands in :attr:`values`."""
        _check_name(name)
        self._queue.append(_Request("read", name))

    def read_any(self, names: tuple[str, ...]) -> None:
        """Ask for a parameter that firmware versions name differently (ArduCopter 4.8's
        RTL_ALT_M was RTL_ALT): every name is asked for on each try, and the request is
        answered by whichever the vehicle has (an autopilot does not answer for a name it
        does not know).  Its answer lands in :attr:`values` under that name; a failure in
        :attr:`failed` under the first."""
        if not names:
            raise ValueError("`names` must not be empty")
        for name in names:
            _check_name(name)
        self._queue.append(_Request("read", names[0], others=tuple(names[1:])))

    def set(self, name: str, value: float, ptype: int) -> None:
        """Set ``name`` (of MAV_PARAM_TYPE ``ptype``, as read) to ``value``; done when the
        vehicle's PARAM_VALUE echoes it (:attr:`confirmed`)."""
        _check_name(name)
        if not math.isfinite(value):
            raise ValueError(f"`value` of {name} must be finite, got {value}")
        self._queue.append(_Request("set", name, float(value), int(ptype)))

    def request_list(self) -> None:
        """Ask for every parameter (PARAM_REQUEST_LIST); the missing indices are then read
        one by one until :attr:`count` values are in."""
        self._queue.append(_Request("list"))

    @property
    def done(self) -> bool:
        """Nothing queued or outstanding."""
        return not self._queue and not self._active

    # -- the state machine ------------------------------------------------------------
    def poll(self, now: float) -> list[Msg]:
        """The messages to send now: retries of timed-out requests (or their failure after
        the last try) and new ones while the window has room."""
        out: list[Msg] = []
        for req in list(self._active):
            if now < req.deadline:
                continue
            if req.attempts >= self.attempts:
                self._active.remove(req)
                self._fail(req)
                continue
            out.extend(self._send(req, now))
        while self._queue and len(self._active) < self.window:
            req = self._queue.popleft()
            self._active.append(req)
            out.extend(self._send(req, now))
        return out

    def receive(self, msg: Msg, now: float) -> None:
        """Take one message from the vehicle (only PARAM_VALUE matters)."""
        if msg.get_type() != "PARAM_VALUE":
            return
        name = _param_id(msg.param_id)
        if not name or not math.isfinite(float(msg.param_value)):
            return
        ptype = int(msg.param_type)
        value = ParamValue(name, decode_wire(self.flavour, float(msg.param_value), ptype),
                           ptype, int(msg.param_index))
        self.values[name] = value
        if 0 <= value.index < 65535:
            self._by_index[value.index] = name
        if msg.param_count > 0:
            self.count = int(msg.param_count)
        for req in list(self._active):
            if req.kind == "read" and (req.name == name or name in req.others):
                self._active.remove(req)
            elif req.kind == "set" and req.name == name and same_value(
                    value.value, req.value, ptype):
                self._active.remove(req)
                self.confirmed.add(name)
            elif req.kind == "list" and self.count is not None and self._missing() == []:
                self._active.remove(req)

    def give_up(self) -> None:
        """Fail every request still queued or outstanding (the caller's deadline)."""
        for req in [*self._active, *self._queue]:
            self._fail(req)
        self._active.clear()
        self._queue.clear()

    # -- helpers ----------------------------------------------------------------------
    def _missing(self) -> list[int]:
        if self.count is None:
            return []
        return [i for i in range(self.count) if i not in self._by_index]

    def _send(self, req: _Request, now: float) -> list[Msg]:
        first = req.attempts == 0
        req.attempts += 1
        req.deadline = now + self.timeout_s
        if req.kind == "read":
            return [mavlink.MAVLink_param_request_read_message(
                self.sysid, AUTOPILOT, name.encode("ascii"), -1)
                for name in (req.name, *req.others)]
        if req.kind == "set":
            return [mavlink.MAVLink_param_set_message(
                self.sysid, AUTOPILOT, req.name.encode("ascii"),
                encode_wire(self.flavour, req.value, req.ptype), req.ptype)]
        if first or self.count is None:
            return [mavlink.MAVLink_param_request_list_message(self.sysid, AUTOPILOT)]
        # A list in progress: the gaps by index, a window's worth per try.
        return [mavlink.MAVLink_param_request_read_message(self.sysid, AUTOPILOT, b"", i)
                for i in self._missing()[:max(self.window * 4, 1)]]

    def _fail(self, req: _Request) -> None:
        tries = f"{req.attempts} tr{'y' if req.attempts == 1 else 'ies'}"
        wait = f"{self.timeout_s:g} s"
        if req.kind == "read":
            asked = " or ".join((req.name, *req.others))
            self.failed[req.name] = f"no PARAM_VALUE for {asked} after {tries} of {wait}"
        elif req.kind == "set":
            got = self.values.get(req.name)
            now_is = "" if got is None else f" (the vehicle says {got.value:g})"
            self.failed[req.name] = (f"PARAM_SET {req.name} = {req.value:g} not confirmed "
                                     f"after {tries} of {wait}{now_is}")
        else:
            have = len(self._by_index)
            self.failed["*"] = (f"parameter list incomplete after {tries}: {have} of "
                                f"{self.count if self.count is not None else '?'}")


def _check_name(name: str) -> None:
    if not 0 < len(name) <= 16 or not name.isascii():
        raise ValueError(f"parameter `name` must be 1-16 ASCII characters, got {name!r}")


async def run_params(link: FleetLink, client: ParamClient, clock: Clock,
                     deadline_s: float = 30.0) -> None:
    """Run ``client``'s requests over ``link`` until done or ``deadline_s`` seconds of
    ``clock`` have passed (what is outstanding then fails)."""
    stop = link.subscribe(client.sysid, client.receive)
    end = clock.now() + deadline_s
    try:
        while not client.done:
            now = clock.now()
            if now >= end:
                client.give_up()
                break
            for msg in client.poll(now):
                link.send_message(client.sysid, msg)
            await asyncio.sleep(max(clock.wall_interval(0.02), 0.001))
    finally:
        stop()
