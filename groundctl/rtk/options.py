"""The flying commands' RTK and ground-station options: ``--rtk``, ``--require-rtk``,
``--gcs-sysid`` (registered by :func:`add_rtk_options`)."""

from __future__ import annotations

import argparse

from groundctl.rtk.sources import RtkSourceError, SourceSpec, parse_source

#: ``--require-rtk`` words -> minimum GPS_RAW_INT.fix_type.
REQUIRE_RTK = {"float": 5, "fixed": 6}
#: GPS_FIX_TYPE names, as the pre-flight says them.
FIX_NAMES = {0: "none", 1: "none", 2: "2D", 3: "3D", 4: "DGPS", 5: "RTK float",
             6: "RTK fixed", 7: "static", 8: "PPP"}


def fix_name(fix: int | None) -> str:
    return "-" if fix is None else FIX_NAMES.get(fix, str(fix))


def rtk_source(text: str) -> SourceSpec:
    try:
        return parse_source(text)
    except RtkSourceError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def gcs_sysid(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 255:
        raise argparse.ArgumentTypeError(f"--gcs-sysid must be a system id within 1..255, "
                                         f"not {text!r}")
    return value


def add_rtk_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rtk", type=rtk_source, default=None, metavar="SOURCE",
                   help="forward RTCM3 corrections to every vehicle as GPS_RTCM_DATA: "
                        "serial:DEVICE:BAUD, [tcp:]HOST:PORT, "
                        "ntrip://USER:PASS@HOST:PORT/MOUNT or a file of RTCM3 (replayed "
                        "one epoch a second, looping)")
    p.add_argument("--require-rtk", choices=sorted(REQUIRE_RTK), default=None,
                   help="pre-flight: every vehicle's GPS_RAW_INT fix type must be RTK float "
                        "(5) or fixed (6)")
    p.add_argument("--gcs-sysid", type=gcs_sysid, default=255, metavar="ID",
                   help="the ground station's MAVLink system id (default 255; component "
                        "190)")
