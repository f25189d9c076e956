"""One vehicle's MAVLink codec: pymavlink encodes and decodes, sockets live elsewhere.

One ``MAVLink(None, ...)`` object per vehicle keeps that vehicle's sequence
numbers, parser state and signing state, as skybrush-server's channel does per
peer.  Every datagram is parsed on its own: UDP keeps packet boundaries, so a
truncated packet must not swallow the start of the next datagram.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

#: Signing timestamps count 10 µs units since 2015-01-01 00:00:00 UTC.
_SIGNING_EPOCH = 1420070400

#: ArduPilot accepts these unsigned even with signing on (GCS_Signing.cpp): radio
#: status from a local radio modem.
_UNSIGNED_OK = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS})


@dataclass
class CodecCounters:
    """What one vehicle's codec has seen (read through fleet snapshots)."""

    packets_in: int = 0
    """MAVLink packets decoded and accepted."""
    packets_out: int = 0
    """MAVLink packets encoded."""
    bad_packets: int = 0
    """Malformed, truncated, bad-CRC or unknown packets, counted and ignored."""
    rejected_signature: int = 0
    """Packets rejected because they were unsigned or badly signed."""


class VehicleCodec:
    """Encoder/decoder for one vehicle (system id ``sysid``, component 1)."""

    def __init__(self, sysid: int, signing_key: bytes | None = None) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.mav.robust_parsing = True
        self.counters = CodecCounters()
        if signing_key is not None:
            self.mav.signing.secret_key = signing_key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - _SIGNING_EPOCH) * 100_000)
            self.mav.signing.allow_unsigned_callback = _allow_unsigned

    def decode(self, data: bytes) -> list[mavlink.MAVLink_message]:
        """Messages in one datagram; anything unusable is counted, never raised."""
        mav = self.mav
        # A fresh parse per datagram: drop whatever a previous bad datagram left.
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = mavlink.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False
        out: list[mavlink.MAVLink_message] = []
        try:
            msg = mav.parse_char(data)
            while msg is not None:
                self._accept(msg, out)
                msg = mav.parse_char(b"")
        except mavlink.MAVError as exc:
            if "signature" in str(exc):
                self.counters.rejected_signature += 1
            else:
                self.counters.bad_packets += 1
        except Exception:  # a bad packet must never take a vehicle down
            self.counters.bad_packets += 1
        if mav.buf_len() > 0:
            self.counters.bad_packets += 1  # a truncated packet at the end of the datagram
        return out

    def _accept(self, msg: mavlink.MAVLink_message, out: list[mavlink.MAVLink_message]) -> None:
        if isinstance(msg, mavlink.MAVLink_bad_data):
            # robust_parsing turns decode errors, bad signatures included, into BAD_DATA.
            if "signature" in str(getattr(msg, "reason", "")):
                self.counters.rejected_signature += 1
            else:
                self.counters.bad_packets += 1
            return
        self.counters.packets_in += 1
        out.append(msg)

    def encode(self, msg: mavlink.MAVLink_message) -> bytes:
        """Wire bytes of ``msg`` (MAVLink 2, signed when a key is set)."""
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.counters.packets_out += 1
        return data


def _allow_unsigned(mav: mavlink.MAVLink, msgid: int) -> bool:
    return msgid in _UNSIGNED_OK
