"""pymavlink as a codec only: encoding messages to bytes and parsing datagrams.

groundctl never lets pymavlink touch a socket.  An :class:`Encoder` turns
message objects into bytes (one per vehicle, so our outgoing sequence numbers
run per link), a :class:`DatagramParser` turns one remote address's datagrams
into messages (one per address, since half-parsed packets and replay guards
belong to a peer).  Malformed input never raises out of here: it is counted.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.signing import SigningConfig, SigningGuard, apply_signing, new_guard

#: Our MAVLink system id by convention for a ground station.
GCS_SYSTEM_ID = 255
#: MAV_COMP_ID_MISSIONPLANNER: the component id ground stations use.
GCS_COMPONENT_ID = 190


class GuardedMAVLink(mavlink.MAVLink):
    """pymavlink's codec with incoming signatures checked by a :class:`SigningGuard`
    (verified before any replay state moves; see :mod:`groundctl.link.signing`)."""

    guard: SigningGuard | None = None

    def check_signature(self, msgbuf: bytearray, srcSystem: int,
                        srcComponent: int) -> bool:
        if self.guard is None:
            return bool(super().check_signature(msgbuf, srcSystem, srcComponent))
        # Raising here (not returning False) also keeps a badly signed packet from
        # pymavlink's allow-unsigned fallback: only unsigned packets may be let through.
        self.guard.verify(msgbuf, srcSystem, srcComponent)
        return True


def new_codec(
    src_system: int = GCS_SYSTEM_ID,
    src_component: int = GCS_COMPONENT_ID,
    signing: SigningConfig | None = None,
    wall: Callable[[], float] = time.time,
    guard: SigningGuard | None = None,
) -> mavlink.MAVLink:
    """A pymavlink ``MAVLink`` object with no file, robust parsing, optional signing.

    Incoming signatures are checked by ``guard`` (shared by the codecs of one link), or
    by a guard of this codec's own.
    """
    if not 1 <= src_system <= 255:
        raise ValueError(f"`src_system` must be in 1..255, got {src_system}")
    if not 0 <= src_component <= 255:
        raise ValueError(f"`src_component` must be in 0..255, got {src_component}")
    mav = GuardedMAVLink(None, srcSystem=src_system, srcComponent=src_component)
    # Robust parsing turns garbage into BAD_DATA messages instead of raising
    # MAVError in the middle of a buffer (which would lose the packets after it).
    mav.robust_parsing = True
    if signing is not None:
        apply_signing(mav, signing, wall)
        mav.guard = guard if guard is not None else new_guard(signing, wall)
    return mav


class Encoder:
    """Packs message objects into wire bytes with our system/component ids."""

    def __init__(self, mav: mavlink.MAVLink) -> None:
        self.mav = mav

    def encode(self, msg: mavlink.MAVLink_message) -> bytes:
        """Wire bytes for ``msg``; advances our sequence number.

        ``MAVLink_message.pack`` does not advance ``mav.seq`` (only
        ``MAVLink.send`` does, and that writes to a file), so we do it here.
        """
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.mav.total_packets_sent += 1
        self.mav.total_bytes_sent += len(data)
        return data


@dataclass
class ParseResult:
    """What one datagram contained."""

    messages: list[mavlink.MAVLink_message] = field(default_factory=list)
    """Well-formed, correctly signed (if signing is on) messages, in order."""
    bad: list[str] = field(default_factory=list)
    """One reason per rejected piece: bad prefix, CRC, length, signature, truncation."""
    unknown: int = 0
    """Well-formed packets of messages our dialect does not know (ignored)."""
    refused_signatures: list[int] = field(default_factory=list)
    """The system id each packet refused by signing claimed (unsigned, wrong signature,
    replayed timestamp), one entry per packet (also in :attr:`bad`)."""


class DatagramParser:
    """Parses the datagrams of one remote address."""

    def __init__(self, mav: mavlink.MAVLink) -> None:
        self.mav = mav

    def feed(self, data: bytes) -> ParseResult:
        """Messages and rejects in ``data``; never raises."""
        result = ParseResult()
        try:
            parsed = self.mav.parse_buffer(data) or []
        except Exception as exc:  # pymavlink raises assorted errors on hostile input
            result.bad.append(f"parser error: {exc}")
            parsed = []
            self._reset()
        for msg in parsed:
            if isinstance(msg, mavlink.MAVLink_bad_data):
                reason = str(msg.reason)
                result.bad.append(reason)
                if "signature" in reason.lower():
                    sysid = _claimed_system(bytes(msg.data))
                    if sysid is not None:
                        result.refused_signatures.append(sysid)
            elif isinstance(msg, mavlink.MAVLink_unknown):
                # A message our dialect lacks: well-formed, just not ours to read.
                result.unknown += 1
            else:
                result.messages.append(msg)
        if self.mav.buf_len() > 0:
            # UDP carries whole MAVLink packets per datagram: a packet cut short
            # at the end of one datagram will never be completed by the next, and
            # keeping its head would corrupt the parse of the next datagram.
            result.bad.append(f"truncated packet ({self.mav.buf_len()} bytes)")
            self._reset()
        return result

    def _reset(self) -> None:
        self.mav.buf = bytearray()
        self.mav.buf_index = 0
        self.mav.expected_length = mavlink.HEADER_LEN_V1 + 2
        self.mav.have_prefix_error = False


def _claimed_system(data: bytes) -> int | None:
    """The sender system id in a packet's header (MAVLink 2 or 1), None if too short."""
    if len(data) > 5 and data[0] == mavlink.PROTOCOL_MARKER_V2:
        return data[5]
    if len(data) > 3 and data[0] == mavlink.PROTOCOL_MARKER_V1:
        return data[3]
    return None
