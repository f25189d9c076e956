"""The simulated autopilot's side of RTK: GPS_RTCM_DATA in, fix type and noise out (pure).

Fragments are reassembled per sequence id (:class:`~groundctl.rtk.fragment.Reassembler`,
ArduPilot's rules), every RTCM3 frame's CRC-24Q is checked (intact and bad frames
counted, and the distinct intact frames remembered by digest so a test can tell
every frame of a file arrived).  Once valid corrections flow the fix goes
3 (3D) -> 5 (RTK float) -> 6 (RTK fixed) after ``FIXED_AFTER_S``.  Without
corrections a receiver keeps its RTK solution for a while on the ones it has: it
drops to float once the newest is ``FLOAT_AFTER_S`` old and to a plain 3D fix at
``TIMEOUT_S`` (a u-blox F9P's DGNSS timeout, CFG-NAVSPG-CONSTR_DGNSSTO, is 60 s by
default).  With the noise model on (``SimConfig.rtk_noise``, the dry-run's ``--rtk``)
each fix type has its own position-estimate wander.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

from groundctl.rtk.fragment import Reassembler
from groundctl.rtk.rtcm import RtcmFramer

FIX_3D, FIX_FLOAT, FIX_FIXED = 3, 5, 6
#: Seconds of continuous corrections from float to fixed.
FIXED_AFTER_S = 5.0
#: The newest valid correction this old: RTK fixed is lost (float on what it has).
FLOAT_AFTER_S = 10.0
#: No valid correction for this long: back to a plain 3D fix.  (It was 8 s: a ground
#: station starved for 2 wall seconds at --speed 4 dropped every vehicle to 3D at once,
#: each estimate jumped by its single-point error, and two drones came 1.09 m apart.)
TIMEOUT_S = 60.0
#: Standard deviation of the slowly varying estimate error per fix type, m (noise model on).
NOISE_M = {FIX_3D: 1.0, FIX_FLOAT: 0.3, FIX_FIXED: 0.02}
#: Distinct frames remembered at most.
MAX_DIGESTS = 4096


@dataclass
class RtkReceiver:
    """One vehicle's GPS receiver as far as corrections go."""

    reassembler: Reassembler = field(default_factory=Reassembler)
    framer: RtcmFramer = field(default_factory=RtcmFramer)
    digests: set[bytes] = field(default_factory=set)
    last_valid_at: float | None = None
    valid_since: float | None = None

    @property
    def intact(self) -> int:
        return self.framer.stats.frames

    @property
    def bad(self) -> int:
        return self.framer.stats.bad_crc

    def receive(self, flags: int, data: bytes, now: float) -> None:
        message = self.reassembler.add(flags, data)
        if message is None:
            return
        frames = self.framer.feed(message)
        if not frames:
            return
        for f in frames:
            if len(self.digests) < MAX_DIGESTS:
                self.digests.add(hashlib.blake2b(f, digest_size=8).digest())
        if self.last_valid_at is None or now - self.last_valid_at > TIMEOUT_S:
            self.valid_since = now
        self.last_valid_at = now

    def fix_type(self, now: float, base: int) -> int:
        """GPS_RAW_INT.fix_type given the receiver's own (``base``, without corrections)."""
        if base < FIX_3D or self.last_valid_at is None or self.valid_since is None \
                or now - self.last_valid_at > TIMEOUT_S:
            return base
        if now - self.last_valid_at > FLOAT_AFTER_S:
            return FIX_FLOAT
        return FIX_FIXED if now - self.valid_since >= FIXED_AFTER_S else FIX_FLOAT

    def stats(self) -> dict[str, int]:
        return {"intact": self.intact, "bad": self.bad, "distinct": len(self.digests),
                "discarded_partial": self.reassembler.discarded}
