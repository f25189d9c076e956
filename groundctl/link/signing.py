"""MAVLink 2 message signing: a shared 32-byte key, set up on pymavlink codecs.

pymavlink keeps signing state on each ``MAVLink`` codec object (``mav.signing``):
the secret key, our link id, whether to sign what we send, a per-stream
replay guard for what we receive, and a callback deciding whether an unsigned
packet may pass.  This module only fills that state in; the codec enforces it
(an unsigned or badly signed packet comes out of the parser as BAD_DATA).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

#: Signing timestamps count 10 µs units since 2015-01-01T00:00:00Z (MAVLink spec).
SIGNING_EPOCH_UNIX_S = 1_420_070_400


@dataclass(frozen=True)
class SigningConfig:
    """How a link signs what it sends and checks what it receives."""

    key: bytes
    """The shared secret: exactly 32 bytes."""
    link_id: int = 0
    """Our link id (0-255), written into every signature we produce."""
    allow_unsigned: bool = False
    """Accept unsigned incoming packets too (migration aid); signed ones are still checked."""
    unsigned_ok: frozenset[int] = frozenset()
    """Message ids accepted unsigned even when ``allow_unsigned`` is off (ArduPilot lets
    RADIO_STATUS from a local radio modem through, GCS_Signing.cpp)."""

    def __post_init__(self) -> None:
        if len(self.key) != 32:
            raise ValueError(f"`key` must be 32 bytes, got {len(self.key)}")
        if not 0 <= self.link_id <= 255:
            raise ValueError(f"`link_id` must be in 0..255, got {self.link_id}")


def signing_timestamp(unix_s: float) -> int:
    """Signing timestamp (10 µs units since 2015-01-01) for a Unix time in seconds."""
    return int(max(unix_s - SIGNING_EPOCH_UNIX_S, 0.0) * 100_000)


def apply_signing(
    mav: mavlink.MAVLink, config: SigningConfig, wall: Callable[[], float] = time.time
) -> None:
    """Configure codec ``mav`` to sign outgoing packets and check incoming ones.

    The outgoing timestamp must start near real (wall-clock) time: receivers
    reject a new stream whose timestamp is more than a minute behind theirs, so
    this is one place where wall time, not the show clock, is the right input.
    """
    mav.signing.secret_key = bytes(config.key)
    mav.signing.link_id = config.link_id
    mav.signing.sign_outgoing = True
    mav.signing.timestamp = signing_timestamp(wall())
    allow, always = config.allow_unsigned, config.unsigned_ok
    mav.signing.allow_unsigned_callback = lambda _mav, msgid: allow or msgid in always
