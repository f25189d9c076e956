"""GPS_RTCM_DATA fragmentation (pure), as the MAVLink spec and ArduPilot's AP_GPS read it.

``flags``: bit 0 fragmented, bits 1-2 fragment id, bits 3-7 sequence id.  A
message of at most 180 bytes goes in one unfragmented packet; a longer one in
fragments of 180 bytes (at most 4, so at most 720 bytes), all with the same
sequence id, which goes up by one per fragmented message (mod 32).  The
receiver knows it has them all when every fragment before the first one that
is not full has arrived (or all four are full): so a message that is an exact
multiple of 180 bytes (360, 540) ends with an empty fragment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

FRAGMENT_LEN = 180
MAX_FRAGMENTS = 4
MAX_MESSAGE = FRAGMENT_LEN * MAX_FRAGMENTS


@dataclass(frozen=True)
class Fragment:
    """One GPS_RTCM_DATA payload."""

    flags: int
    """The message's ``flags`` field."""
    data: bytes
    """At most 180 bytes."""


class TooLarge(ValueError):
    """A message longer than four fragments carry."""


@dataclass
class Fragmenter:
    """Cuts messages into GPS_RTCM_DATA payloads; keeps the sequence id."""

    sequence: int = 0
    """Sequence id of the next fragmented message (0..31)."""

    def split(self, message: bytes) -> list[Fragment]:
        if len(message) > MAX_MESSAGE:
            raise TooLarge(f"an RTCM message of {len(message)} bytes does not fit in "
                           f"{MAX_FRAGMENTS} GPS_RTCM_DATA fragments ({MAX_MESSAGE} bytes)")
        if len(message) <= FRAGMENT_LEN:
            return [Fragment(0, bytes(message))]
        seq = self.sequence
        self.sequence = (seq + 1) & 0x1F
        parts = [message[i:i + FRAGMENT_LEN] for i in range(0, len(message), FRAGMENT_LEN)]
        if len(message) % FRAGMENT_LEN == 0 and len(parts) < MAX_FRAGMENTS:
            parts.append(b"")
        return [Fragment(1 | (k << 1) | (seq << 3), bytes(p)) for k, p in enumerate(parts)]


@dataclass
class Reassembler:
    """The receiving side (the simulator's autopilot): fragments back into messages."""

    sequence: int | None = None
    received: dict[int, bytes] = field(default_factory=dict)
    discarded: int = 0
    """Partial messages thrown away (a fragment of another sequence came first)."""

    def add(self, flags: int, data: bytes) -> bytes | None:
        """The message completed by this packet, or None."""
        if not flags & 1:
            return bytes(data)
        frag, seq = (flags >> 1) & 0x03, (flags >> 3) & 0x1F
        if self.received and (seq != self.sequence or frag in self.received):
            self.discarded += 1
            self.received = {}
        self.sequence = seq
        self.received[frag] = bytes(data)
        count = None
        for k in range(MAX_FRAGMENTS):
            part = self.received.get(k)
            if part is None:
                break
            if len(part) < FRAGMENT_LEN:
                count = k + 1
                break
        else:
            count = MAX_FRAGMENTS
        if count is None:
            return None
        message = b"".join(self.received[k] for k in range(count))
        self.received = {}
        return message
