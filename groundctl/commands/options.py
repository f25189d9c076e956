"""Argument types shared by the commands: each turns bad text into one clear usage error."""

from __future__ import annotations

import argparse
import math


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, not {text!r}") from None


def positive(text: str) -> float:
    """A number > 0."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, not {text!r}")
    return value


def non_negative(text: str) -> float:
    """A number >= 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, not {text!r}")
    return value


def probability(text: str) -> float:
    """A packet-loss probability in [0, 1)."""
    p = _number(text)
    if not 0.0 <= p < 1.0:
        raise argparse.ArgumentTypeError(f"--loss must be in [0, 1), not {text!r}")
    return p


def signing_key(text: str) -> bytes:
    """A MAVLink 2 signing key: 64 hex digits."""
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise argparse.ArgumentTypeError("--signing-key must be 64 hex digits") from None
    if len(key) != 32:
        raise argparse.ArgumentTypeError("--signing-key must be 64 hex digits (32 bytes)")
    return key


def wind(text: str) -> tuple[float, float, float]:
    """``E,N[,U]`` m/s, or ``SPEED@FROM`` (m/s, the compass direction it blows from)."""
    try:
        if "@" in text:
            speed_text, _, from_text = text.partition("@")
            speed, frm = float(speed_text), math.radians(float(from_text))
            return (-speed * math.sin(frm), -speed * math.cos(frm), 0.0)
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(
            f"--wind must be EAST,NORTH[,UP] in m/s or SPEED@FROM_DEGREES, not {text!r}")
    return (parts[0], parts[1], parts[2] if len(parts) == 3 else 0.0)


def push(text: str) -> tuple[int, float, tuple[float, float, float]]:
    """``--push SYSID@T:E,N,U``: (system id, time s, offset m)."""
    usage = f"--push must be SYSID@T:E,N,U (e.g. 5@20:3,0,0), not {text!r}"
    who, at, rest = text.partition("@")
    when, colon, vec = rest.partition(":")
    try:
        sysid, t = int(who), float(when)
        offset = tuple(float(x) for x in vec.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(usage) from None
    if not at or not colon or len(offset) != 3 or not 1 <= sysid <= 255 or t < 0 \
            or not all(math.isfinite(x) for x in (t, *offset)):
        raise argparse.ArgumentTypeError(usage)
    return sysid, t, (offset[0], offset[1], offset[2])


def weak(text: str) -> list[tuple[int, float]]:
    """``--weak SYSID[,SYSID...]:FACTOR``: [(system id, factor in (0, 1])]."""
    usage = f"--weak must be SYSID[,SYSID...]:FACTOR with FACTOR in (0, 1], not {text!r}"
    who, colon, factor_text = text.partition(":")
    try:
        ids = [int(x) for x in who.split(",")]
        factor = float(factor_text)
    except ValueError:
        raise argparse.ArgumentTypeError(usage) from None
    if not colon or not 0 < factor <= 1 or not all(1 <= s <= 255 for s in ids):
        raise argparse.ArgumentTypeError(usage)
    return [(s, factor) for s in ids]
