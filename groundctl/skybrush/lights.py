"""Skybrush light programs (``ledctrl`` bytecode), decoded to colour keys and encoded back.

The bytecode (libskybrush ``src/lights``): one command byte, then its arguments;
durations are varints (7 bits a byte, least significant first, high bit "more")
counting 20 ms frames, ``WAIT_UNTIL``'s deadline too (frames from the program's
start: libskybrush's player, skybrush.js and pyledctrl's compiler agree; or from its
last ``RESET_CLOCK``, as libskybrush counts it).  ``SET_*`` sets the
colour at once and then waits its duration; ``FADE_*`` fades linearly from the
current colour to its colour over its duration.  Colours are bytes 0..255.

A decoded program is a list of :class:`LightKey`: the colour is linear between
consecutive keys, and two keys at the same time are a step (the later one holds
from that time on).  Programs from anywhere are run with a bounded number of
instructions and keys, and refused in one line on anything a show without
radio-controlled channels cannot mean (colours from RC channels, triggered jumps).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

#: One duration unit of the bytecode, s.
UNIT_S = 0.02
#: Most instructions run while decoding one program (loops and jumps unrolled).
MAX_INSTRUCTIONS = 1_000_000
#: Most colour keys one program may produce.
MAX_KEYS = 200_000

END, NOP, SLEEP, WAIT_UNTIL, SET_COLOR, SET_GRAY, SET_BLACK, SET_WHITE = range(8)
FADE_TO_COLOR, FADE_TO_GRAY, FADE_TO_BLACK, FADE_TO_WHITE = range(8, 12)
LOOP_BEGIN, LOOP_END, RESET_CLOCK = 12, 13, 14
SET_COLOR_FROM_CHANNELS, FADE_TO_COLOR_FROM_CHANNELS, JUMP, TRIGGERED_JUMP = 16, 17, 18, 19
SET_PYRO, SET_PYRO_ALL = 20, 21

RGB = tuple[int, int, int]
BLACK: RGB = (0, 0, 0)
WHITE: RGB = (255, 255, 255)


@dataclass(frozen=True)
class LightKey:
    """The colour at one instant."""

    t: float
    """Time from the start of the program, s."""
    rgb: RGB
    """Colour, bytes 0..255."""


class LightProgramError(ValueError):
    """A program that cannot be decoded; the message says where and why."""


class _Reader:
    def __init__(self, code: bytes) -> None:
        self.code = code
        self.pc = 0

    def byte(self) -> int:
        if self.pc >= len(self.code):
            raise LightProgramError(f"the program ends inside a command at byte {self.pc}")
        b = self.code[self.pc]
        self.pc += 1
        return b

    def varint(self) -> int:
        value, shift = 0, 0
        while True:
            b = self.byte()
            value |= (b & 0x7F) << shift
            if not b & 0x80:
                return value
            shift += 7
            if shift > 35:
                raise LightProgramError(f"a number longer than 5 bytes at byte {self.pc}")


def decode(code: bytes, until_s: float | None = None) -> list[LightKey]:
    """The colour keys of ``code``; ``until_s`` stops it there (a looping program).

    The colour is black until the first command sets it, as on the drone.
    """
    r = _Reader(code)
    t_ms = 0  # the program's clock, ms
    origin_ms = 0  # RESET_CLOCK moves the origin WAIT_UNTIL counts from
    color: RGB = BLACK
    keys: list[LightKey] = [LightKey(0.0, BLACK)]
    loops: list[tuple[int, int]] = []  # (address after LOOP_BEGIN, iterations left; 0 = forever)
    limit_ms = None if until_s is None else until_s * 1000.0

    def wait(ms: int) -> None:
        nonlocal t_ms
        t_ms += ms

    def set_to(rgb: RGB, ms: int) -> None:
        nonlocal color
        if rgb != color:
            keys.append(LightKey(t_ms / 1000.0, color))
            keys.append(LightKey(t_ms / 1000.0, rgb))
            color = rgb
        wait(ms)

    def fade_to(rgb: RGB, ms: int) -> None:
        nonlocal color
        if ms == 0:
            set_to(rgb, 0)
            return
        keys.append(LightKey(t_ms / 1000.0, color))
        wait(ms)
        keys.append(LightKey(t_ms / 1000.0, rgb))
        color = rgb

    for _ in range(MAX_INSTRUCTIONS):
        if r.pc >= len(code) or (limit_ms is not None and t_ms > limit_ms):
            break
        if len(keys) > MAX_KEYS:
            raise LightProgramError(f"more than {MAX_KEYS} colour changes")
        at = r.pc
        op = r.byte()
        if op == END:
            break
        if op == NOP:
            continue
        if op == SLEEP:
            wait(r.varint() * 20)
        elif op == WAIT_UNTIL:
            deadline = origin_ms + r.varint() * 20  # frames, like every duration
            t_ms = max(t_ms, deadline)
        elif op == SET_COLOR:
            rgb = (r.byte(), r.byte(), r.byte())
            set_to(rgb, r.varint() * 20)
        elif op == SET_GRAY:
            g = r.byte()
            set_to((g, g, g), r.varint() * 20)
        elif op == SET_BLACK:
            set_to(BLACK, r.varint() * 20)
        elif op == SET_WHITE:
            set_to(WHITE, r.varint() * 20)
        elif op == FADE_TO_COLOR:
            rgb = (r.byte(), r.byte(), r.byte())
            fade_to(rgb, r.varint() * 20)
        elif op == FADE_TO_GRAY:
            g = r.byte()
            fade_to((g, g, g), r.varint() * 20)
        elif op == FADE_TO_BLACK:
            fade_to(BLACK, r.varint() * 20)
        elif op == FADE_TO_WHITE:
            fade_to(WHITE, r.varint() * 20)
        elif op == LOOP_BEGIN:
            iterations = r.byte()
            loops.append((r.pc, iterations))
        elif op == LOOP_END:
            if not loops:
                raise LightProgramError(f"LOOP_END without LOOP_BEGIN at byte {at}")
            start, left = loops.pop()
            if left == 0 or left > 1:  # 0 iterations: for ever (bounded by until_s)
                loops.append((start, 0 if left == 0 else left - 1))
                r.pc = start
        elif op == RESET_CLOCK:
            origin_ms = t_ms
        elif op == JUMP:
            address = r.varint()
            if address >= len(code):
                raise LightProgramError(f"JUMP to byte {address}, beyond the program")
            r.pc = address
            loops.clear()
        elif op in (SET_PYRO, SET_PYRO_ALL):
            r.byte()  # pyro channels: nothing to do with lights
        elif op in (SET_COLOR_FROM_CHANNELS, FADE_TO_COLOR_FROM_CHANNELS, TRIGGERED_JUMP):
            raise LightProgramError(f"command {op:#04x} at byte {at} depends on radio "
                                    "channels, which a show flown from groundctl has not")
        else:
            raise LightProgramError(f"unknown command {op:#04x} at byte {at}")
    else:
        if until_s is None:
            raise LightProgramError(f"more than {MAX_INSTRUCTIONS} instructions (a loop "
                                    "without end?)")
    keys.append(LightKey(t_ms / 1000.0, color))
    return _tidy(keys)


def _tidy(keys: list[LightKey]) -> list[LightKey]:
    """Drop keys that say nothing new: repeats of the same time and colour, and middle
    keys of a constant stretch."""
    out: list[LightKey] = []
    for k in keys:
        if out and out[-1] == k:
            continue
        if (len(out) >= 2 and out[-1].rgb == k.rgb == out[-2].rgb
                and out[-2].t < out[-1].t < k.t):
            out[-1] = k
            continue
        out.append(k)
    return out


def _varint(value: int) -> bytes:
    if value < 0:
        raise ValueError("`value` must be non-negative")
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        if value:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def encode(keys: Sequence[LightKey]) -> bytes:
    """Bytecode that plays ``keys`` (times rounded to the 20 ms unit, without drift).

    The colour before the first key is the first key's colour; two keys at the
    same time (after rounding) are a step.
    """
    if not keys:
        return bytes([END])
    out = bytearray()
    units = [round(k.t / UNIT_S) for k in keys]
    first = keys[0].rgb
    out += bytes([SET_COLOR, *first]) + _varint(max(units[0], 0))
    prev_u, prev_c = max(units[0], 0), first
    for u, k in zip(units[1:], keys[1:], strict=True):
        d = max(u - prev_u, 0)
        if d == 0:
            if k.rgb != prev_c:
                out += bytes([SET_COLOR, *k.rgb]) + _varint(0)
        elif k.rgb == prev_c:
            out += bytes([SLEEP]) + _varint(d)
        else:
            out += bytes([FADE_TO_COLOR, *k.rgb]) + _varint(d)
        prev_u, prev_c = prev_u + d, k.rgb
    out.append(END)
    return bytes(out)
