"""``groundctl check PLAN [--json]``: re-verify a saved plan in continuous time."""

from __future__ import annotations

import argparse
import json
import sys

from groundctl.errors import EXIT_OK, EXIT_UNSAFE


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("check", help="re-verify a saved plan file")
    p.add_argument("plan", help="plan file written by 'groundctl plan'")
    p.add_argument("--json", action="store_true", help="print the verdict as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from groundctl.plan.plan import Plan
    from groundctl.plan.verify import verify

    plan = Plan.load(args.plan)
    ver = verify(plan)
    o = ver.overall
    report = {
        "plan_file": args.plan, "show": plan.show_name, "drones": plan.drones,
        "duration_s": plan.duration, "min_separation_m": o.min_separation,
        "worst_violation_m": ver.worst_violation, "max_speed_mps": o.max_speed_h,
        "max_accel_mps2": o.max_accel, "pattern_error_m": max(ver.pattern_errors, default=0.0),
        "violations": list(ver.violations), "safe": ver.safe,
    }
    if args.json:
        json.dump(report, sys.stdout)
        sys.stdout.write("\n")
    else:
        verdict = "SAFE" if ver.safe else "UNSAFE"
        print(f"{verdict}: {args.plan}: {plan.drones} drones, {plan.duration:.1f} s, min "
              f"separation {o.min_separation:.3f} m, max speed {o.max_speed_h:.2f} m/s, max "
              f"accel {o.max_accel:.2f} m/s^2")
        for v in ver.violations:
            print(f"  violation: {v}")
    return EXIT_OK if ver.safe else EXIT_UNSAFE
