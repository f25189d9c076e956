"""A flight's tlog decoded into arrays: pure, pymavlink parses every packet.

The tlog format is pymavlink's (see :mod:`groundctl.record.tlog`): an 8-byte
big-endian Unix time in microseconds, then exactly one MAVLink packet.
pymavlink's own parser frames each packet (``bytes_needed``) and checks it
(CRC, length, message id); the first record that fails, or is cut short,
ends the decoding there: everything before it is kept and
:class:`TlogDamage` says where it stopped and why.

Only what the views need is kept: each vehicle's LOCAL_POSITION_NED (with its
``time_boot_ms``), GPS_GLOBAL_ORIGIN, battery, autopilot HEARTBEATs (mode and
arming) and STATUSTEXT, and the LED_CONTROL the ground station sent.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour, decode_mode

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_STAMP = struct.Struct(">Q")
#: A stamp further than this from the one before is damage, not a pause, s.
MAX_STAMP_JUMP_S = 86400.0
#: LED_CONTROL of the Skybrush firmware (instance and pattern 42: R, G, B, ...).
_SKYBRUSH = 42


@dataclass(frozen=True)
class TlogDamage:
    """Where a tlog stopped being readable."""

    offset: int
    """Byte offset of the first record not read."""
    size: int
    """Size of the tlog, bytes."""
    reason: str
    """What was wrong there ("cut short in a packet", "bad CRC", ...)."""
    last_unix_s: float | None
    """Stamp of the last record read (None: none was)."""


@dataclass(frozen=True)
class Positions:
    """LOCAL_POSITION_NED samples of every vehicle, in tlog order."""

    sysid: IntArray
    """Sender's system id per sample."""
    unix_s: FloatArray
    """When it was recorded (received), Unix s."""
    boot_s: FloatArray
    """The vehicle's ``time_boot_ms`` / 1000."""
    ned: FloatArray
    """(n, 3) x, y, z in the vehicle's local NED frame, m."""
    vel_ned: FloatArray
    """(n, 3) vx, vy, vz, m/s."""


@dataclass(frozen=True)
class TlogData:
    """What a tlog holds for the views (see the module docstring)."""

    packets: int
    """Packets decoded."""
    size: int
    """Bytes in the file."""
    first_unix_s: float | None
    """First record's stamp."""
    last_unix_s: float | None
    """Last good record's stamp."""
    positions: Positions
    """Every LOCAL_POSITION_NED."""
    origins: dict[int, list[tuple[float, float, float, float]]]
    """Per vehicle: (unix s, lat deg, lon deg, alt m) of each GPS_GLOBAL_ORIGIN."""
    battery: dict[int, tuple[FloatArray, FloatArray]]
    """Per vehicle: (unix s, remaining %) from SYS_STATUS / BATTERY_STATUS."""
    leds: dict[int, tuple[FloatArray, NDArray[np.uint8]]]
    """Per target system id (0: every vehicle): (unix s, (n, 3) RGB) of each LED_CONTROL
    the ground station sent."""
    modes: list[tuple[float, int, str, bool]]
    """(unix s, system id, mode, armed) whenever a vehicle's HEARTBEAT changed either."""
    texts: list[tuple[float, int, int, str]]
    """(unix s, system id, severity, text) of each STATUSTEXT."""
    damage: TlogDamage | None = None
    """Where decoding stopped early, or None: the whole file was read."""
    senders: set[int] = field(default_factory=set)
    """System ids of the vehicles heard (autopilot HEARTBEATs or positions)."""


def decode_tlog(data: bytes, offset: int = 0) -> TlogData:
    """Decode a tlog's bytes (see the module docstring).  ``offset`` is added to every
    system id (a vehicle's, and an LED_CONTROL's target but 0): network n's tlog read
    with ``(n - 1) * NETWORK_STRIDE`` names its vehicles by their vehicle ids."""
    mav = mavlink.MAVLink(None)
    size = len(data)
    pos_rows: list[tuple[int, float, float, float, float, float, float, float, float]] = []
    origins: dict[int, list[tuple[float, float, float, float]]] = {}
    battery: dict[int, list[tuple[float, float]]] = {}
    leds: dict[int, list[tuple[float, int, int, int]]] = {}
    modes: list[tuple[float, int, str, bool]] = []
    texts: list[tuple[float, int, int, str]] = []
    last_mode: dict[int, tuple[str, bool]] = {}
    senders: set[int] = set()
    damage: TlogDamage | None = None
    first: float | None = None
    last: float | None = None
    packets = 0
    i = 0
    while i < size:
        start = i
        if size - i < _STAMP.size:
            damage = TlogDamage(start, size, "cut short in a timestamp", last)
            break
        t = _STAMP.unpack_from(data, i)[0] / 1e6
        i += _STAMP.size
        if last is not None and abs(t - last) > MAX_STAMP_JUMP_S:
            damage = TlogDamage(start, size, f"implausible timestamp {t:.0f} s after "
                                             f"{last:.0f} s", last)
            break
        msg = None
        reason = ""
        try:
            while msg is None:
                need = mav.bytes_needed()
                if size - i < need:
                    reason = "cut short in a packet"
                    break
                msg = mav.parse_char(data[i:i + need])
                i += need
                if msg is None and mav.buf_len() == 0:
                    # pymavlink skipped a byte that starts no packet.
                    reason = "not a MAVLink packet"
                    break
        except mavlink.MAVError as exc:
            reason = f"bad packet ({exc})"
        if msg is None or msg.get_type() == "BAD_DATA":
            damage = TlogDamage(start, size, reason or "bad packet", last)
            break
        packets += 1
        if first is None:
            first = t
        last = t
        kind = msg.get_type()
        src = msg.get_srcSystem() + offset
        if kind == "LOCAL_POSITION_NED":
            senders.add(src)
            pos_rows.append((src, t, msg.time_boot_ms / 1000.0, msg.x, msg.y, msg.z,
                             msg.vx, msg.vy, msg.vz))
        elif kind == "LED_CONTROL":
            rgb = _led_rgb(msg)
            if rgb is not None:
                target = msg.target_system + offset if msg.target_system else 0
                leds.setdefault(target, []).append((t, *rgb))
        elif kind == "GPS_GLOBAL_ORIGIN":
            origins.setdefault(src, []).append(
                (t, msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0))
        elif kind == "SYS_STATUS" or kind == "BATTERY_STATUS":
            if msg.battery_remaining >= 0:
                battery.setdefault(src, []).append((t, float(msg.battery_remaining)))
        elif kind == "HEARTBEAT":
            if msg.type == mavlink.MAV_TYPE_GCS or msg.get_srcComponent() != 1:
                continue
            senders.add(src)
            flavour = Flavour.from_heartbeat(msg.autopilot)
            state = (decode_mode(flavour, msg.base_mode, msg.custom_mode),
                     bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
            if last_mode.get(src) != state:
                last_mode[src] = state
                modes.append((t, src, state[0], state[1]))
        elif kind == "STATUSTEXT":
            texts.append((t, src, int(msg.severity), str(msg.text)))
    rows = np.array([r for r in pos_rows], dtype=float).reshape(-1, 9)
    positions = Positions(rows[:, 0].astype(np.int64), rows[:, 1], rows[:, 2],
                          rows[:, 3:6], rows[:, 6:9])
    return TlogData(
        packets=packets, size=size, first_unix_s=first, last_unix_s=last,
        positions=positions, origins=origins,
        battery={s: (np.array([r[0] for r in v]), np.array([r[1] for r in v]))
                 for s, v in battery.items()},
        leds={s: (np.array([r[0] for r in v]),
                  np.array([r[1:] for r in v], dtype=np.uint8).reshape(-1, 3))
              for s, v in leds.items()},
        modes=modes, texts=texts, damage=damage, senders=senders)


def merge_tlogs(parts: Sequence[TlogData]) -> TlogData:
    """Several networks' tlogs (decoded with their offsets) as one: positions in time
    order, the rest side by side (their vehicle ids differ)."""
    if len(parts) == 1:
        return parts[0]
    pos = [p.positions for p in parts]
    unix = np.concatenate([p.unix_s for p in pos])
    order = np.argsort(unix, kind="stable")
    positions = Positions(np.concatenate([p.sysid for p in pos])[order], unix[order],
                          np.concatenate([p.boot_s for p in pos])[order],
                          np.concatenate([p.ned for p in pos])[order],
                          np.concatenate([p.vel_ned for p in pos])[order])
    firsts = [p.first_unix_s for p in parts if p.first_unix_s is not None]
    lasts = [p.last_unix_s for p in parts if p.last_unix_s is not None]
    leds: dict[int, tuple[FloatArray, NDArray[np.uint8]]] = {}
    for p in parts:
        for target, (t, rgb) in p.leds.items():
            if target in leds:  # 0 (every vehicle) from two networks
                t0, rgb0 = leds[target]
                t, rgb = np.concatenate([t0, t]), np.concatenate([rgb0, rgb])
                keep = np.argsort(t, kind="stable")
                t, rgb = t[keep], rgb[keep]
            leds[target] = (t, rgb)
    return TlogData(
        packets=sum(p.packets for p in parts), size=sum(p.size for p in parts),
        first_unix_s=min(firsts) if firsts else None,
        last_unix_s=max(lasts) if lasts else None, positions=positions,
        origins={k: v for p in parts for k, v in p.origins.items()},
        battery={k: v for p in parts for k, v in p.battery.items()}, leds=leds,
        modes=sorted((m for p in parts for m in p.modes), key=lambda m: m[0]),
        texts=sorted((x for p in parts for x in p.texts), key=lambda x: x[0]),
        damage=next((p.damage for p in parts if p.damage is not None), None),
        senders={s for p in parts for s in p.senders})


def _led_rgb(msg: mavlink.MAVLink_led_control_message) -> tuple[int, int, int] | None:
    """The colour an LED_CONTROL sets: stock ArduPilot's custom_len 3 or 4 (R, G, B[, Hz])
    or the Skybrush firmware's instance/pattern 42 (R, G, B, ...)."""
    raw = bytes(msg.custom_bytes)
    if msg.custom_len in (3, 4) or (msg.instance == _SKYBRUSH and msg.pattern == _SKYBRUSH
                                    and msg.custom_len >= 3):
        return raw[0], raw[1], raw[2]
    return None
