"""The simulated vehicle's fence: the mission protocol's server side for
MAV_MISSION_TYPE_FENCE, and the inclusion test.

Upload, as ArduPilot (``AP_Mission`` / ``AC_PolyFence_loader``) and PX4
(``MavlinkMissionManager``) serve it: MISSION_COUNT starts a transfer (count 0
clears the fence and is ACKed at once); the vehicle asks for each item with
MISSION_REQUEST_INT, again after ``retry_s`` without an answer; an item of the
wrong sequence number is answered by asking again for the one expected; the
last item is ACKed ACCEPTED and only then does the new fence replace the old (a
repeat of the last item after that, the ground station not having heard the
ACK, is ACKed again).
An item that is not an inclusion-polygon vertex (or whose vertex count
disagrees with the first) is refused with MAV_MISSION_UNSUPPORTED /
MAV_MISSION_INVALID_PARAM1.  Download (MISSION_REQUEST_LIST, then
MISSION_REQUEST_INT per item) serves the stored fence.

One inclusion polygon is supported (what a show uses); exclusion polygons and
circles are refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeAlias

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

Msg: TypeAlias = mavlink.MAVLink_message
FENCE = mavlink.MAV_MISSION_TYPE_FENCE
INCLUSION = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
#: Most vertices one fence may hold (ArduPilot's storage holds about this many on SITL).
MAX_VERTICES = 256


def inside(polygon: np.ndarray, x: float, y: float) -> bool:
    """Whether (x, y) lies inside ``polygon`` (n, 2), by ray crossing (even-odd)."""
    px, py = polygon[:, 0], polygon[:, 1]
    qx, qy = np.roll(px, -1), np.roll(py, -1)
    crosses = (py > y) != (qy > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = px + (y - py) * (qx - px) / (qy - py)
    return bool(np.count_nonzero(crosses & (x < at)) % 2 == 1)


@dataclass
class FenceServer:
    """One vehicle's stored fence and the transfer in progress."""

    sysid: int
    """The vehicle's system id (the sender of its replies)."""
    retry_s: float = 0.5
    """A request unanswered this long is sent again."""
    vertices: list[tuple[float, float]] = field(default_factory=list)
    """The stored inclusion polygon, (lat, lon) degrees; empty: no fence."""
    version: int = 0
    """Bumped whenever :attr:`vertices` changes (the vehicle re-projects then)."""
    _incoming: list[tuple[float, float]] | None = None
    _count: int = 0
    _peer: tuple[int, int] = (255, 0)
    _asked_at: float = 0.0

    def handle(self, msg: Msg, now: float) -> list[Msg]:
        """React to one mission-protocol message of mission type FENCE."""
        if getattr(msg, "mission_type", None) != FENCE:
            return []
        kind = msg.get_type()
        if kind == "MISSION_COUNT":
            return self._on_count(msg, now)
        if kind == "MISSION_ITEM_INT":
            return self._on_item(msg, now)
        if kind == "MISSION_REQUEST_LIST":
            return [mavlink.MAVLink_mission_count_message(
                msg.get_srcSystem(), msg.get_srcComponent(), len(self.vertices), FENCE)]
        if kind == "MISSION_REQUEST_INT":
            return self._serve(msg)
        return []

    def tick(self, now: float) -> list[Msg]:
        """The vehicle's retry of an unanswered request."""
        if self._incoming is None or now - self._asked_at < self.retry_s:
            return []
        return [self._request(len(self._incoming), now)]

    # -- upload -------------------------------------------------------------------------------
    def _on_count(self, msg: Msg, now: float) -> list[Msg]:
        self._peer = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.count == 0:
            self._store([])
            return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]
        if msg.count > MAX_VERTICES:
            self._incoming = None
            return [self._ack(mavlink.MAV_MISSION_NO_SPACE)]
        self._incoming, self._count = [], int(msg.count)
        return [self._request(0, now)]

    def _on_item(self, msg: Msg, now: float) -> list[Msg]:
        if self._incoming is None:
            if self.vertices and msg.seq == len(self.vertices) - 1:
                # The last item again: our ACK was lost, so the ground station repeats it.
                return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]
            return []  # no transfer: ignored
        seq = len(self._incoming)
        if msg.seq != seq:
            return [self._request(seq, now)]
        if msg.command != INCLUSION:
            self._incoming = None
            return [self._ack(mavlink.MAV_MISSION_UNSUPPORTED)]
        if round(msg.param1) != self._count:
            self._incoming = None
            return [self._ack(mavlink.MAV_MISSION_INVALID_PARAM1)]
        lat, lon = msg.x / 1e7, msg.y / 1e7
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            self._incoming = None
            return [self._ack(mavlink.MAV_MISSION_INVALID_PARAM5_X)]
        self._incoming.append((lat, lon))
        if len(self._incoming) < self._count:
            return [self._request(len(self._incoming), now)]
        self._store(self._incoming)
        self._incoming = None
        return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]

    def _store(self, vertices: list[tuple[float, float]]) -> None:
        self.vertices = list(vertices)
        self.version += 1

    def _request(self, seq: int, now: float) -> Msg:
        self._asked_at = now
        return mavlink.MAVLink_mission_request_int_message(*self._peer, seq, FENCE)

    def _ack(self, result: int) -> Msg:
        return mavlink.MAVLink_mission_ack_message(*self._peer, result, FENCE)

    # -- download -----------------------------------------------------------------------------
    def _serve(self, msg: Msg) -> list[Msg]:
        if not 0 <= msg.seq < len(self.vertices):
            return [mavlink.MAVLink_mission_ack_message(
                msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_INVALID_SEQUENCE,
                FENCE)]
        lat, lon = self.vertices[msg.seq]
        return [mavlink.MAVLink_mission_item_int_message(
            msg.get_srcSystem(), msg.get_srcComponent(), msg.seq, mavlink.MAV_FRAME_GLOBAL,
            INCLUSION, 0, 0, float(len(self.vertices)), 0.0, 0.0, 0.0, round(lat * 1e7),
            round(lon * 1e7), 0.0, FENCE)]
