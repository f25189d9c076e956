"""Argument types shared by the commands: each turns bad text into one clear usage error."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from groundctl.sim.config import wind_from
from groundctl.vehicleid import parse_vehicle


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
            return wind_from(float(speed_text), float(from_text))
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(
            f"--wind must be EAST,NORTH[,UP] in m/s or SPEED@FROM_DEGREES, not {text!r}")
    return (parts[0], parts[1], parts[2] if len(parts) == 3 else 0.0)


def vehicle(text: str) -> int:
    """A vehicle on the command line: ``17``, or ``2:17`` for network 2's system id 17
    (:func:`~groundctl.vehicleid.parse_vehicle`)."""
    try:
        return parse_vehicle(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def push(text: str) -> tuple[int, float, tuple[float, float, float]]:
    """``--push SYSID@T:E,N,U``: (vehicle id, time s, offset m)."""
    usage = (f"--push must be SYSID@T:E,N,U (e.g. 5@20:3,0,0), not {text!r} (SYSID 2:5 is "
             "network 2's system id 5)")
    who, at, rest = text.partition("@")
    when, colon, vec = rest.partition(":")
    try:
        sysid, t = parse_vehicle(who), float(when)
        offset = tuple(float(x) for x in vec.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(usage) from None
    if not at or not colon or len(offset) != 3 or t < 0 \
            or not all(math.isfinite(x) for x in (t, *offset)):
        raise argparse.ArgumentTypeError(usage)
    return sysid, t, (offset[0], offset[1], offset[2])


#: How long a ``--gust-on`` blows when its text gives no duration, s (the step gust the
#: real ArduCopter figures of issue 32 were measured with).
GUST_DURATION_S = 4.0


def gust_on(text: str) -> tuple[int, float, float, float, float]:
    """``--gust-on SYSID@T:SPEED@FROM[,DURATION_S]``: (vehicle id, time s, speed m/s,
    the compass direction it blows from in degrees, duration s)."""
    usage = (f"--gust-on must be SYSID@T:SPEED@FROM[,DURATION_S] (e.g. 5@20:9@270,4: "
             f"9 m/s from the west for 4 s), not {text!r} (SYSID 2:5 is network 2's "
             "system id 5)")
    who, at, rest = text.partition("@")
    when, colon, spec = rest.partition(":")
    speed_text, at2, tail = spec.partition("@")
    from_text, comma, duration_text = tail.partition(",")
    try:
        sysid, t = parse_vehicle(who), float(when)
        speed, frm = float(speed_text), float(from_text)
        duration = float(duration_text) if comma else GUST_DURATION_S
    except ValueError:
        raise argparse.ArgumentTypeError(usage) from None
    numbers = (t, speed, frm, duration)
    if not (at and colon and at2) or not all(math.isfinite(x) for x in numbers) \
            or t < 0 or speed < 0 or duration <= 0:
        raise argparse.ArgumentTypeError(usage)
    return sysid, t, speed, frm % 360.0, duration


#: ``--fail`` kinds: what goes wrong with the vehicle.
FAIL_KINDS = ("motor", "battery", "link")
def fail(text: str) -> tuple[int, float, str]:
    """``--fail SYSID@T:KIND``: (vehicle id, time s, kind in FAIL_KINDS)."""
    usage = (f"--fail must be SYSID@T:KIND with KIND one of {', '.join(FAIL_KINDS)} (e.g. "
             f"5@20:motor), not {text!r} (SYSID 2:5 is network 2's system id 5)")
    who, at, rest = text.partition("@")
    when, colon, kind = rest.partition(":")
    try:
        sysid, t = parse_vehicle(who), float(when)
    except ValueError:
        raise argparse.ArgumentTypeError(usage) from None
    if not at or not colon or kind not in FAIL_KINDS or not math.isfinite(t) or t < 0:
        raise argparse.ArgumentTypeError(usage)
    return sysid, t, kind


def add_fail(p: argparse.ArgumentParser, when: str) -> None:
    """``--fail SYSID@T:KIND``; ``when`` says what T counts."""
    p.add_argument("--fail", type=fail, action="append", default=[], metavar="SYSID@T:KIND",
                   help=f"make one vehicle fail at {when} (repeatable): motor (it loses "
                        "thrust and falls), battery (its pack drops to three quarters of "
                        "the level at which a drone leaves the show, [limits] "
                        "land_battery_pct, 20 %% unless the show says: it is flown out and "
                        "lands), link (it goes "
                        "silent both ways for good and its own failsafe takes over)")


def weak(text: str) -> list[tuple[int, float]]:
    """``--weak SYSID[,SYSID...]:FACTOR``: [(vehicle id, factor in (0, 1])]."""
    usage = f"--weak must be SYSID[,SYSID...]:FACTOR with FACTOR in (0, 1], not {text!r}"
    who, colon, factor_text = text.rpartition(":")  # the ids may be 2:17
    try:
        ids = [parse_vehicle(x) for x in who.split(",")]
        factor = float(factor_text)
    except ValueError:
        raise argparse.ArgumentTypeError(usage) from None
    if not colon or not 0 < factor <= 1:
        raise argparse.ArgumentTypeError(usage)
    return [(s, factor) for s in ids]


def workers(text: str) -> int:
    """``--workers N``: 1..64 planning processes."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--workers must be a whole number, not {text!r}")\
            from None
    if not 1 <= value <= 64:
        raise argparse.ArgumentTypeError(f"--workers must be within 1..64, not {text}")
    return value


def add_gust_on(p: argparse.ArgumentParser, when: str) -> None:
    """``--gust-on SYSID@T:SPEED@FROM[,DURATION_S]``; ``when`` says what T counts (show
    time, or simulated seconds after boot)."""
    p.add_argument("--gust-on", type=gust_on, action="append", default=[],
                   metavar="SYSID@T:SPEED@FROM[,DURATION_S]",
                   help=f"blow on one vehicle from {when}: SPEED m/s from compass "
                        "direction FROM degrees for DURATION_S s (default "
                        f"{GUST_DURATION_S:g}), a force through the simulated airframe's "
                        "drag that its autopilot fights, up to its lean angle (repeatable)")


def add_points_dir(p: argparse.ArgumentParser) -> None:
    """``--points-dir DIR``: where else a show's point files may be read from."""
    p.add_argument("--points-dir", type=Path, action="append", default=[], metavar="DIR",
                   help="also read formation point files ('file = ...') from DIR "
                        "(repeatable); by default only files under the show file's own "
                        "directory are read")


def add_plan_source(p: argparse.ArgumentParser) -> None:
    """``--show SHOW | --accept-plan-limits``: what a saved plan is checked against."""
    group = p.add_mutually_exclusive_group()
    group.add_argument("--show", dest="plan_show", type=Path, default=None, metavar="SHOW",
                       help="for a .npz plan: the show file it was planned from, whose "
                            "limits it is checked against (default: the plan's sibling, "
                            "X.plan.npz -> X.toml); a plan not planned from it, or edited "
                            "since, is refused")
    group.add_argument("--accept-plan-limits", action="store_true",
                       help="for a .npz plan: trust the limits the plan file carries instead "
                            "of its show's (a plan saved before plans recorded their show, "
                            "or one from elsewhere without its show)")


# -- Rerun (issue 13) ----------------------------------------------------------------
RERUN_USAGE = "--rerun takes nothing, 'spawn', 'connect [URL]' or 'save PATH'"


class _RerunAction(argparse.Action):
    """Stores ``--rerun``'s words as (kind, where) (see :func:`rerun_words`)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        try:
            setattr(namespace, self.dest, rerun_words(list(values or [])))
        except ValueError as exc:
            parser.error(str(exc))


def add_rerun_option(p: argparse.ArgumentParser, what: str, alone: str) -> None:
    """``--rerun [spawn | connect [URL] | save PATH]``: ``what`` to Rerun; ``alone`` says
    where ``--rerun`` without words saves."""
    p.add_argument("--rerun", nargs="*", action=_RerunAction, default=None,
                   metavar="spawn|connect URL|save PATH",
                   help=f"{what} to Rerun: open a viewer (spawn), send to a running one "
                        "(connect [URL], default rerun+http://127.0.0.1:9876/proxy) or write "
                        f"an .rrd file (save PATH; --rerun alone saves {alone})")


def rerun_words(words: list[str]) -> tuple[str, str | None]:
    """(kind, where) of ``--rerun``'s words; ("save", None) means the command's default
    file."""
    if not words:
        return ("save", None)
    kind, rest = words[0], words[1:]
    if kind == "spawn" and not rest:
        return ("spawn", None)
    if kind == "connect" and len(rest) <= 1:
        return ("connect", rest[0] if rest else None)
    if kind == "save" and len(rest) == 1:
        return ("save", rest[0])
    hint = "" if kind in ("spawn", "connect", "save") else \
        " (it takes every word up to the next option: give the show before --rerun)"
    raise ValueError(f"{RERUN_USAGE}, not {' '.join(words)!r}{hint}")


def rerun_target(value: tuple[str, str | None] | None, default: Path
                 ) -> tuple[str, str | None] | None:
    """``--rerun``'s value with the default file filled in (None: not given)."""
    if value is None:
        return None
    kind, where = value
    return (kind, str(default)) if kind == "save" and where is None else (kind, where)
