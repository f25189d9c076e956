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

:class:`FenceUpload` is the pure state machine (no I/O, time passed in);
:func:`upload_fence` drives it over a :class:`~groundctl.link.fleet.FleetLink`.
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
            self._tries, self._deadline = 1, now + self.timeout_s
        elif out:
            self._tries, self._deadline = 1, now + self.timeout_s
        elif now >= self._deadline:
            if self._tries >= self.attempts:
                step = (f"item {max(self.requested)}" if self.requested else "MISSION_COUNT")
                self.error = (f"fence upload: no answer to {step} after {self._tries} tries "
                              f"of {self.timeout_s:g} s")
                return []
            self._tries += 1
            self._deadline = now + self.timeout_s
            out.append(self._last)
        return out

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


async def upload_fence(link: FleetLink, upload: FenceUpload, clock: Clock) -> bool:
    """Run ``upload`` over ``link``; True if the vehicle accepted the fence."""
    stop = link.subscribe(upload.sysid, upload.receive)
    try:
        while not upload.done:
            for msg in upload.poll(clock.now()):
                link.send_message(upload.sysid, msg)
            await asyncio.sleep(max(clock.wall_interval(0.02), 0.001))
    finally:
        stop()
    return upload.ok
