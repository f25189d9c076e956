"""A writer of valid RTCM3 frames for rehearsal fixtures (seeded, not real observations).

Each epoch: a 1005 station position, then MSM7-shaped GPS (1077), GLONASS (1087)
and Galileo (1097) messages whose headers are right (number, station, epoch time,
the multiple-message flag set on all but the last) and whose bodies are seeded
random bytes, with correct CRC-24Q; sizes span one to four GPS_RTCM_DATA fragments
(one frame exactly 360 bytes long, the case that needs an empty last fragment).
"""

from __future__ import annotations

import numpy as np

from groundctl.rtk.rtcm import frame


class _Bits:
    def __init__(self) -> None:
        self.value = 0
        self.n = 0

    def put(self, width: int, x: int) -> None:
        self.value = (self.value << width) | (x & ((1 << width) - 1))
        self.n += width

    def payload(self, total_bytes: int | None = None) -> bytes:
        nbytes = (self.n + 7) // 8 if total_bytes is None else total_bytes
        return (self.value << (nbytes * 8 - self.n)).to_bytes(nbytes, "big")


def station_1005(station: int, ecef_m: tuple[float, float, float]) -> bytes:
    """A 1005 (stationary antenna reference point) payload."""
    b = _Bits()
    b.put(12, 1005)
    b.put(12, station)
    b.put(6, 0)  # ITRF realisation year
    for flag in (1, 1, 0, 0):  # GPS, GLONASS, Galileo indicators, reference-station flag
        b.put(1, flag)
    b.put(38, round(ecef_m[0] * 1e4))
    b.put(1, 0)  # single receiver oscillator
    b.put(1, 0)  # reserved
    b.put(38, round(ecef_m[1] * 1e4))
    b.put(2, 0)  # quarter cycle indicator
    b.put(38, round(ecef_m[2] * 1e4))
    return b.payload()


def msm_payload(number: int, station: int, epoch_ms: int, more: bool, size: int,
                rng: np.random.Generator) -> bytes:
    """An MSM-shaped payload of ``size`` bytes: a true header, a random body."""
    b = _Bits()
    b.put(12, number)
    b.put(12, station)
    b.put(30, epoch_ms)
    b.put(1, 1 if more else 0)
    head = b.payload(8)  # 55 header bits, the rest of the 8 bytes zero
    body = rng.integers(0, 256, size - len(head), dtype=np.uint8).tobytes()
    return head + body


#: (message number, payload bytes) of each epoch's observation messages, in order.
EPOCH_LAYOUT: tuple[tuple[int, int], ...] = ((1077, 420), (1087, 354), (1097, 150))


def epochs(count: int, seed: int = 0, station: int = 7) -> list[bytes]:
    """``count`` epochs (1 s apart) of whole frames, each epoch's frames joined."""
    rng = np.random.default_rng(seed)
    out = []
    ecef = (4_027_893.5, 307_045.6, 4_919_474.9)
    for k in range(count):
        frames = [frame(station_1005(station, ecef))]
        epoch_ms = 345_600_000 + 1000 * k
        for j, (number, size) in enumerate(EPOCH_LAYOUT):
            more = j < len(EPOCH_LAYOUT) - 1
            frames.append(frame(msm_payload(number, station, epoch_ms, more, size, rng)))
        out.append(b"".join(frames))
    return out
