"""One simulated vehicle's MAVLink codec, with the counters an autopilot keeps.

The codec itself is the link layer's (:mod:`groundctl.link.codec`): one
pymavlink ``MAVLink(None, ...)`` object per vehicle, used only to encode and
decode, each datagram parsed on its own, nothing ever raised on bad input.  A
vehicle and the ground station must frame, sign and reject packets the same
way, so they share that code rather than each having its own.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.codec import DatagramParser, Encoder, new_codec
from groundctl.link.signing import SigningConfig

#: ArduPilot accepts these unsigned even with signing on (GCS_Signing.cpp): radio
#: status from a local radio modem.
UNSIGNED_OK = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS})


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
        signing = None if signing_key is None else SigningConfig(signing_key,
                                                                 unsigned_ok=UNSIGNED_OK)
        self.mav = new_codec(sysid, 1, signing)
        self._encoder = Encoder(self.mav)
        self._parser = DatagramParser(self.mav)
        self.counters = CodecCounters()

    def decode(self, data: bytes) -> list[mavlink.MAVLink_message]:
        """Messages in one datagram; anything unusable is counted, never raised."""
        result = self._parser.feed(data)
        for reason in result.bad:
            if "signature" in reason:
                self.counters.rejected_signature += 1
            else:
                self.counters.bad_packets += 1
        # A real autopilot drops messages it has no definition for: count them as bad.
        self.counters.bad_packets += result.unknown
        self.counters.packets_in += len(result.messages)
        return result.messages

    def encode(self, msg: mavlink.MAVLink_message) -> bytes:
        """Wire bytes of ``msg`` (MAVLink 2, signed when a key is set)."""
        self.counters.packets_out += 1
        return self._encoder.encode(msg)
