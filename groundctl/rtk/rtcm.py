"""RTCM3 framing (pure): preamble 0xD3, 6 reserved bits + 10-bit length, payload, CRC-24Q.

:class:`RtcmFramer` takes bytes in any split and yields whole frames; a frame
whose CRC does not match is dropped and counted, and the framer resynchronises
on the next preamble.  The CRC is pyrtcm's (``calc_crc24q``).
"""

from __future__ import annotations

from dataclasses import dataclass

from pyrtcm import calc_crc24q

PREAMBLE = 0xD3
#: Largest payload the 10-bit length allows.
MAX_PAYLOAD = 1023


def frame(payload: bytes) -> bytes:
    """A complete RTCM3 frame around ``payload`` (header and CRC-24Q)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"`payload` must be at most {MAX_PAYLOAD} bytes, got {len(payload)}")
    head = bytes([PREAMBLE, (len(payload) >> 8) & 0x03, len(payload) & 0xFF]) + payload
    return head + calc_crc24q(head).to_bytes(3, "big")


def crc_ok(data: bytes) -> bool:
    """Whether a whole frame's CRC-24Q matches."""
    return len(data) >= 6 and calc_crc24q(data[:-3]) == int.from_bytes(data[-3:], "big")


def message_number(data: bytes) -> int:
    """The 12-bit message number of a whole frame (0 if it has no payload)."""
    return (data[3] << 4 | data[4] >> 4) if len(data) >= 8 else 0


def ends_epoch(data: bytes) -> bool:
    """Whether a frame is the last observation message of its epoch.

    MSM (1071..1137) and GPS legacy observations (1001..1004) carry, after the
    12-bit number, 12-bit station id and 30-bit epoch time, a flag that says
    more observation messages of the same epoch follow (0: this is the last).
    """
    num = message_number(data)
    is_msm = 1071 <= num <= 1137 and num % 10 in range(1, 8)
    if not (is_msm or 1001 <= num <= 1004) or len(data) < 3 + 8 + 3:
        return False
    bits = int.from_bytes(data[3:11], "big")  # payload bits 0..63
    return not (bits >> (63 - 54)) & 1


@dataclass
class FramerStats:
    """What the framer saw."""

    frames: int = 0
    """Whole frames with a good CRC."""
    bad_crc: int = 0
    """Frames dropped for a CRC mismatch."""
    skipped_bytes: int = 0
    """Bytes that were not part of a frame (noise before a preamble)."""


class RtcmFramer:
    """Incremental RTCM3 framer: :meth:`feed` bytes, get whole good frames."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.stats = FramerStats()

    def feed(self, data: bytes) -> list[bytes]:
        """The whole frames completed by ``data`` (bad-CRC ones dropped and counted)."""
        self._buf += data
        out: list[bytes] = []
        buf = self._buf
        while True:
            start = buf.find(bytes([PREAMBLE]))
            if start < 0:
                self.stats.skipped_bytes += len(buf)
                buf.clear()
                break
            if start:
                self.stats.skipped_bytes += start
                del buf[:start]
            if len(buf) < 3:
                break
            if buf[1] & 0xFC:  # reserved bits set: not a frame start
                self.stats.skipped_bytes += 1
                del buf[:1]
                continue
            total = 3 + ((buf[1] & 0x03) << 8 | buf[2]) + 3
            if len(buf) < total:
                break
            candidate = bytes(buf[:total])
            if crc_ok(candidate):
                self.stats.frames += 1
                out.append(candidate)
                del buf[:total]
            else:
                self.stats.bad_crc += 1
                del buf[:1]  # resynchronise on the next preamble
        return out


def split_epochs(frames: list[bytes]) -> list[list[bytes]]:
    """Frames grouped into epochs (each ends with its last observation message); a file
    without observation messages is one frame per epoch."""
    epochs: list[list[bytes]] = []
    current: list[bytes] = []
    for f in frames:
        current.append(f)
        if ends_epoch(f):
            epochs.append(current)
            current = []
    if current:
        if epochs:
            epochs.append(current)
        else:
            epochs = [[f] for f in current]
    return epochs
