"""Fuzz the ground station with hostile MAVLink while it flies a dry-run.

Flies the quick show against the simulator over loopback UDP (the real
``groundctl dry-run`` path) and sends hostile datagrams at the ground station
throughout: random bytes, truncated and bit-flipped packets, valid packets
spoofed from other ports, the same from the vehicles' own addresses (a raw
socket; skipped where it cannot be opened), packets signed with wrong keys,
sniffed genuine packets replayed, stray system ids.  Everything goes to
127.0.0.0/8 only.  The kinds are in ``sitl_tests/hostile_mavlink.py``; a small
seeded run is ``sitl_tests/test_fuzz_mavlink.py``.

Reported per flight: datagrams sent (by kind, and while airborne), crashes,
unsafe flights, tracebacks, and every vehicle whose believed state (mode,
armed, battery, EKF origin, position) was at some moment never true in the
simulator: a state changed by a spoofed packet.  Exit 0 only if all are zero.

    .venv/bin/python benchmarks/fuzz_mavlink.py [--count 12000] [--speed 2] [--seed 1]
                                               [--runs unsigned signed] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "sitl_tests"))

from hostile_mavlink import KINDS, FuzzResult, fly_fuzzed

from groundctl.link.flavours import Flavour


def _summary(name: str, r: FuzzResult) -> dict[str, Any]:
    link = r.link
    return {
        "run": name, "datagrams": r.total, "airborne": r.airborne, "raw_socket": r.raw,
        "by_kind": {k: r.sent.get(k, 0) for k in KINDS},
        "crashes": len(r.crashes), "unsafe": int(r.unsafe), "tracebacks": len(r.tracebacks),
        "state_changed_by_spoofing": len(r.violations), "error": r.error,
        "stale_s": r.stale_s,
        "landed": r.report.get("landed"), "down_and_disarmed":
            r.report.get("simulator", {}).get("down_and_disarmed"),
        "true_min_separation_m": r.report.get("true_min_separation_m"),
        "vehicles_lost": sum(1 for v in r.report.get("vehicles", [])
                             if v.get("phase") == "lost"),
        "link_conflicts": link.get("link_conflicts"), "bad_signatures":
            link.get("bad_signatures"), "bad_packets": link.get("bad_packets"),
        "address_conflicts": link.get("address_conflicts"),
        "unknown_system_packets": link.get("unknown_system_packets"),
        "conflicts_per_vehicle": r.conflicts, "wall_s": round(r.wall_s, 1),
        "details": {"crashes": r.crashes, "tracebacks": r.tracebacks[:5],
                    "violations": r.violations, "unsafe_reasons":
                        r.report.get("unsafe_reasons")},
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", type=int, default=12000, help="hostile datagrams per flight")
    p.add_argument("--speed", type=float, default=2.0, help="dry-run speed (sim s per s)")
    p.add_argument("--seed", type=int, default=1, help="seed of the traffic and the simulator")
    p.add_argument("--runs", nargs="+", default=["unsigned", "signed"],
                   choices=["unsigned", "signed"], help="flights: without / with signing")
    p.add_argument("--autopilot", choices=["ardupilot", "px4"], default="ardupilot")
    p.add_argument("--no-raw", action="store_true", help="no forged sources, no sniffing")
    p.add_argument("--json", action="store_true", help="one JSON object per flight")
    p.add_argument("--record", type=Path, default=None, metavar="DIR",
                   help="record each flight (tlog, events, report) under DIR/RUN")
    args = p.parse_args()
    flavour = Flavour.PX4 if args.autopilot == "px4" else Flavour.ARDUPILOT
    ok = True
    for i, name in enumerate(args.runs):
        r = fly_fuzzed(count=args.count, seed=args.seed + i, speed=args.speed,
                       signed=name == "signed", flavour=flavour, use_raw=not args.no_raw,
                       record_dir=None if args.record is None else args.record / name)
        s = _summary(name, r)
        ok &= not (r.crashes or r.unsafe or r.tracebacks or r.violations or r.error)
        if args.json:
            print(json.dumps(s), flush=True)
            continue
        print(f"== {name} ({args.autopilot}, x{args.speed:g}, seed {args.seed + i}): "
              f"{s['datagrams']} hostile datagrams, {s['airborne']} while airborne, raw "
              f"socket {'yes' if r.raw else 'no (forged sources and replays skipped)'}")
        print("   by kind: " + ", ".join(f"{k} {v}" for k, v in s["by_kind"].items()))
        print(f"   crashes {s['crashes']}, unsafe {s['unsafe']}, tracebacks "
              f"{s['tracebacks']}, state changed by a spoofed packet: "
              f"{s['state_changed_by_spoofing']}, error: {s['error']}")
        print(f"   longest a belief lagged the truth (s): {s['stale_s']}")
        print(f"   landed {s['landed']} (simulator: {s['down_and_disarmed']} down and "
              f"disarmed), true min separation {s['true_min_separation_m']} m, "
              f"vehicles lost {s['vehicles_lost']}, wall {s['wall_s']} s")
        print(f"   link: {s['link_conflicts']} link conflicts, {s['bad_signatures']} bad "
              f"signatures, {s['bad_packets']} bad packets, {s['address_conflicts']} "
              f"address conflicts, {s['unknown_system_packets']} from unknown ids")
        print(f"   conflicts per vehicle: {s['conflicts_per_vehicle']}")
        for what, items in s["details"].items():
            for item in (items or [])[:5]:
                print(f"   {what}: {str(item)[:300]}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
