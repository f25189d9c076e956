"""MAVLink 2 message signing: a shared 32-byte key, set up on pymavlink codecs.

pymavlink keeps signing state on each ``MAVLink`` codec object (``mav.signing``):
the secret key, our link id, whether to sign what we send, a per-stream
replay guard for what we receive, and a callback deciding whether an unsigned
packet may pass.  This module fills that state in, and checks incoming
signatures itself (:class:`SigningGuard`): pymavlink 2.4.50's
``check_signature`` stores a packet's timestamp as the stream's newest *before*
it verifies the signature, so one packet with a wrong signature and a fresh
timestamp made every later genuine packet of that stream a "replay" (the
vehicle was marked lost for the rest of the flight).  Here nothing moves until
the signature is verified, and the replay guard is shared by every codec of a
link (MAVLink keys streams by link id, system and component, not by address: a
signed packet replayed from another port is a replay too).  A rejected packet
comes out of the parser as BAD_DATA whose reason says ``signature``.
"""

from __future__ import annotations

import hashlib
import hmac
import time
from collections.abc import Callable
from dataclasses import dataclass, field

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


#: A new stream's first timestamp may be this far behind ours (MAVLink: one minute), in
#: signing timestamp units (10 µs).
NEW_STREAM_SLACK = 60 * 100_000


@dataclass
class SigningGuard:
    """Incoming signature checks for every codec of one link (or of one vehicle).

    :meth:`verify` checks the signature first and only then the timestamp against the
    stream's newest, so a forged packet changes nothing; a replayed one (a timestamp
    not after the newest of its stream) is refused without changing anything either.
    """

    key: bytes
    """The shared secret, 32 bytes."""
    timestamp: int
    """Our newest timestamp: the wall clock at start, then the newest accepted.  A new
    stream must start within NEW_STREAM_SLACK of it."""
    streams: dict[tuple[int, int, int], int] = field(default_factory=dict)
    """(link id, system id, component id) -> newest timestamp of a verified packet."""

    def __post_init__(self) -> None:
        if len(self.key) != 32:
            raise ValueError(f"`key` must be 32 bytes, got {len(self.key)}")

    def verify(self, msgbuf: bytes | bytearray, src_system: int, src_component: int) -> None:
        """Accept signed packet ``msgbuf`` or raise pymavlink's MAVError saying why (the
        parser turns it into BAD_DATA, so it never leaves the codec)."""
        if len(msgbuf) < 13 + 12:
            raise mavlink.MAVError("bad signature: packet too short to carry one")
        link_id = msgbuf[-13]
        timestamp = int.from_bytes(msgbuf[-12:-6], "little")
        digest = hashlib.sha256(self.key + bytes(msgbuf[:-6])).digest()[:6]
        if not hmac.compare_digest(digest, bytes(msgbuf[-6:])):
            raise mavlink.MAVError("bad signature (wrong key or corrupted packet)")
        stream = (link_id, src_system, src_component)
        newest = self.streams.get(stream)
        if newest is not None and timestamp <= newest:
            raise mavlink.MAVError(f"signature replayed: timestamp {timestamp} not after "
                                   f"{newest} on link {link_id}")
        if newest is None and timestamp + NEW_STREAM_SLACK < self.timestamp:
            raise mavlink.MAVError("signature of a new stream more than a minute old")
        self.streams[stream] = timestamp
        self.timestamp = max(self.timestamp, timestamp)


def new_guard(config: SigningConfig, wall: Callable[[], float] = time.time) -> SigningGuard:
    """A guard for ``config``'s key, starting from the wall clock now."""
    return SigningGuard(bytes(config.key), signing_timestamp(wall()))
