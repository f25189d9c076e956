"""Fence upload over the MAVLink mission protocol (MAV_MISSION_TYPE_FENCE), client side.

The exchange, as ArduPilot's ``AP_Mission``/``AC_PolyFence_loader`` and PX4's
``MavlinkMissionManager`` serve it::

    GCS  MISSION_COUNT(count, mission_type=FENCE)
    VEH  MISSION_REQUEST_INT(seq 0)          (older firmware: MISSION_REQUEST)
    GCS  MISSION_ITEM_INT(seq 0, MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                          param1 = vertices, x = lat * 1e7, y = lon * 1e7)
    ...  one request and one item per vertex
    VEH  MISSION_ACK(MAV_MISSION_ACCEPTED, mission_type=FENCE)

The vehicle drives the transfer; the client answers each request (again when
it is repeated) and, when the vehicle goes quiet for ``timeout_s``, sends its
last message once more, ``attempts`` times in all.  A MISSION_ACK with any
other result ends the upload as failed, naming the result.

A download (to check the fence a vehicle holds when the show may not change it)
is driven by the client instead::

    GCS  MISSION_REQUEST_LIST(mission_type=FENCE)
    VEH  MISSION_COUNT(count)
    GCS  MISSION_REQUEST_INT(seq 0)
    VEH  MISSION_ITEM_INT(seq 0)
    ...  one request and one item per item
    GCS  MISSION_ACK(MAV_MISSION_ACCEPTED)

:class:`FenceUpload` and :class:`FenceDownload` are the pure state machines (no
I/O, time passed in); :func:`upload_fence` and :func:`download_fence` drive them
over a :class:`~groundctl.link.fleet.FleetLink`.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeAlias

from pymavlink.dialects.v20 import ardupilotmega as mavlink

if TYPE_CHECKING:
    from groundctl.clock import Clock
    from groundctl.link.fleet import FleetLink

Msg: TypeAlias = mavlink.MAVLink_message
FENCE = mavlink.MAV_MISSION_TYPE_FENCE
INCLUSION = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
AUTOPILOT = mavlink.MAV_COMP_ID_AUTOPILOT1


def mission_result_name(result: int) -> str:
    """``MAV_MISSION_ERROR`` for 1: the enum's name for a MISSION_ACK type."""
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else f"result {result}"


def vertex_item(sysid: int, seq: int, vertices: Sequence[tuple[float, float]]) -> Msg:
    """MISSION_ITEM_INT ``seq`` of an inclusion polygon of ``vertices`` (lat, lon degrees)."""
    lat, lon = vertices[seq]
    return mavlink.MAVLink_mission_item_int_message(
        sysid, AUTOPILOT, seq, mavlink.MAV_FRAME_GLOBAL, INCLUSION, 0, 0,
        float(len(vertices)), 0.0, 0.0, 0.0, round(lat * 1e7), round(lon * 1e7), 0.0, FENCE)


def _send_or_repeat(m: FenceUpload | FenceDownload, out: list[Msg], now: float,
                    silent: str) -> list[Msg]:
    """Both transfers' retry rule: something to send restarts the tries; after
    ``timeout_s`` of silence the last message goes again, ``attempts`` times in all, then
    the transfer fails as ``silent`` ("... no answer to item 3") says."""
    if out:
        m._tries, m._deadline = 1, now + m.timeout_s
    elif now >= m._deadline:
        if m._tries >= m.attempts:
            m.error = f"{silent} after {m._tries} tries of {m.timeout_s:g} s"
            return []
        assert m._last is not None
        m._tries += 1
        m._deadline = now + m.timeout_s
        out.append(m._last)
    return out


@dataclass
class FenceUpload:
    """One vehicle's fence upload; see the module docstring."""

    sysid: int
    """The vehicle's system id."""
    vertices: tuple[tuple[float, float], ...]
    """The inclusion polygon, (lat, lon) degrees, in order (3 or more)."""
    timeout_s: float = 1.0
    """How long the vehicle may stay quiet before the last message goes again."""
    attempts: int = 5
    """Sends of one message before the upload fails."""
    result: int | None = None
    """The MISSION_ACK type received (None: not yet)."""
    error: str | None = None
    """Why the upload failed (None: not failed)."""
    requested: set[int] = field(default_factory=set)
    """Item sequence numbers the vehicle asked for."""
    _last: Msg | None = None
    _deadline: float = -math.inf
    _tries: int = 0
    _pending: list[Msg] = field(default_factory=list)
    _give_up: float = math.inf
    """The whole upload's deadline: every step may take all its tries, no more (a vehicle
    that keeps asking for items again cannot hold pre-flight for ever)."""

    def __post_init__(self) -> None:
        if len(self.vertices) < 3:
            raise ValueError(f"`vertices` must be at least 3, got {len(self.vertices)}")
        if self.timeout_s <= 0:
            raise ValueError(f"`timeout_s` must be positive, got {self.timeout_s}")

    @property
    def budget_s(self) -> float:
        """The whole upload's time: every step (count, items, ACK) all its tries."""
        return self.attempts * self.timeout_s * (len(self.vertices) + 2)

    @property
    def done(self) -> bool:
        """Finished, accepted or failed."""
        return self.result is not None or self.error is not None

    @property
    def ok(self) -> bool:
        """The vehicle accepted the whole fence."""
        return self.result == mavlink.MAV_MISSION_ACCEPTED and self.error is None

    def poll(self, now: float) -> list[Msg]:
        """What to send now: the count at first, answers to requests, and a repeat of the
        last message when the vehicle has been quiet for ``timeout_s``."""
        if self.done:
            return []
        if self._last is None:
            self._give_up = now + self.budget_s
        elif now >= self._give_up:
            self.error = f"fence upload: not finished within {self.budget_s:g} s"
            return []
        out, self._pending = self._pending, []
        if self._last is None:
            self._last = mavlink.MAVLink_mission_count_message(
                self.sysid, AUTOPILOT, len(self.vertices), FENCE)
            out.append(self._last)
        step = f"item {max(self.requested)}" if self.requested else "MISSION_COUNT"
        return _send_or_repeat(self, out, now, f"fence upload: no answer to {step}")

    def receive(self, msg: Msg, now: float) -> None:
        """Take one message from the vehicle (mission requests and the ACK)."""
        kind = msg.get_type()
        if self.done or getattr(msg, "mission_type", None) != FENCE:
            return
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            seq = int(msg.seq)
            if not 0 <= seq < len(self.vertices):
                self.error = (f"fence upload: the vehicle asked for item {seq} of "
                              f"{len(self.vertices)}")
                return
            self.requested.add(seq)
            self._last = vertex_item(self.sysid, seq, self.vertices)
            self._pending.append(self._last)
        elif kind == "MISSION_ACK":
            self.result = int(msg.type)
            if self.result != mavlink.MAV_MISSION_ACCEPTED:
                self.error = f"fence upload refused: {mission_result_name(self.result)}"
            elif len(self.requested) < len(self.vertices):
                self.error = (f"fence upload: accepted after {len(self.requested)} of "
                              f"{len(self.vertices)} items")


@dataclass(frozen=True)
class FenceItem:
    """One fence item as a vehicle holds it (the integers it was sent with)."""

    command: int
    """MAV_CMD_NAV_FENCE_* of the item."""
    count: int
    """param1: the vertices of its polygon (the radius, for a circle)."""
    x: int
    """Latitude, degrees x 1e7."""
    y: int
    """Longitude, degrees x 1e7."""


def inclusion_items(vertices: Sequence[tuple[float, float]]) -> tuple[FenceItem, ...]:
    """The items :func:`vertex_item` uploads for ``vertices``, as a download returns them."""
    return tuple(FenceItem(INCLUSION, len(vertices), round(lat * 1e7), round(lon * 1e7))
                 for lat, lon in vertices)


@dataclass
class FenceDownload:
    """One vehicle's fence download; see the module docstring."""

    sysid: int
    """The vehicle's system id."""
    timeout_s: float = 1.0
    """How long the vehicle may stay quiet before the last request goes again."""
    attempts: int = 5
    """Sends of one request before the download fails."""
    max_items: int = 256
    """A count above this is refused (a vehicle, or a forger, claiming millions)."""
    items: list[FenceItem] | None = None
    """What the vehicle holds, in order (None: until the count is known)."""
    error: str | None = None
    """Why the download failed (None: not failed)."""
    _count: int | None = None
    _last: Msg | None = None
    _deadline: float = -math.inf
    _tries: int = 0
    _pending: list[Msg] = field(default_factory=list)
    _finished: bool = False

    def __post_init__(self) -> None:
        if self.timeout_s <= 0:
            raise ValueError(f"`timeout_s` must be positive, got {self.timeout_s}")

    @property
    def done(self) -> bool:
        """Finished: every item received, or failed."""
        return self._finished or self.error is not None

    @property
    def ok(self) -> bool:
        """Every item was received."""
        return self._finished and self.error is None

    def poll(self, now: float) -> list[Msg]:
        """What to send now: the list request at first, the next request once an answer
        came, the last one again when the vehicle has been quiet for ``timeout_s``
        (and, once every item came, the closing ACK)."""
        out, self._pending = self._pending, []
        if self.done:
            return out if self.error is None else []
        if self._last is None:
            self._last = mavlink.MAVLink_mission_request_list_message(self.sysid, AUTOPILOT,
                                                                      FENCE)
            out.append(self._last)
        step = "MISSION_REQUEST_LIST" if self.items is None else f"item {len(self.items)}"
        return _send_or_repeat(self, out, now, f"fence download: no answer to {step}")

    def receive(self, msg: Msg, now: float) -> None:
        """Take one message from the vehicle (the count, items, a refusal)."""
        kind = msg.get_type()
        if self.done or getattr(msg, "mission_type", None) != FENCE:
            return
        if kind == "MISSION_COUNT" and self.items is None:
            count = int(msg.count)
            if count > self.max_items:
                self.error = (f"fence download: the vehicle claims {count} items (at most "
                              f"{self.max_items})")
                return
            self._count, self.items = count, []
            self._next()
        elif kind == "MISSION_ITEM_INT" and self.items is not None \
                and int(msg.seq) == len(self.items):
            self.items.append(FenceItem(int(msg.command), round(float(msg.param1)),
                                        int(msg.x), int(msg.y)))
            self._next()
        elif kind == "MISSION_ACK" and int(msg.type) != mavlink.MAV_MISSION_ACCEPTED:
            self.error = f"fence download refused: {mission_result_name(int(msg.type))}"

    def _next(self) -> None:
        assert self.items is not None and self._count is not None
        if len(self.items) < self._count:
            self._last = mavlink.MAVLink_mission_request_int_message(
                self.sysid, AUTOPILOT, len(self.items), FENCE)
        else:
            self._last = mavlink.MAVLink_mission_ack_message(
                self.sysid, AUTOPILOT, mavlink.MAV_MISSION_ACCEPTED, FENCE)
            self._finished = True
        self._pending.append(self._last)


async def _drive(link: FleetLink, sysid: int, machine: FenceUpload | FenceDownload,
                 clock: Clock) -> None:
    stop = link.subscribe(sysid, machine.receive)
    try:
        while True:
            for msg in machine.poll(clock.now()):
                link.send_message(sysid, msg)
            if machine.done:
                return
            await asyncio.sleep(max(clock.wall_interval(0.02), 0.001))
    finally:
        stop()


async def upload_fence(link: FleetLink, upload: FenceUpload, clock: Clock) -> bool:
    """Run ``upload`` over ``link``; True if the vehicle accepted the fence."""
    await _drive(link, upload.sysid, upload, clock)
    return upload.ok


async def download_fence(link: FleetLink, download: FenceDownload, clock: Clock) -> bool:
    """Run ``download`` over ``link``; True if every item came."""
    await _drive(link, download.sysid, download, clock)
    return download.ok
