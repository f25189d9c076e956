"""``groundctl check PLAN [--show SHOW | --accept-plan-limits] [--json]``: re-verify a plan.

The plan is verified in continuous time against its show's limits, not the
copy it carries (:mod:`groundctl.plan.provenance`).  Without its show a plan
can still be found unsafe by its own limits (exit 1), but never called safe:
that is refused (exit 2) with the way to proceed.
"""

from __future__ import annotations

import argparse
import json
import sys

from groundctl.commands.options import add_plan_source, add_points_dir
from groundctl.errors import EXIT_OK, EXIT_UNSAFE, UntrustedPlan


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "check", help="re-verify a saved plan file against its show's limits",
        description="Re-verify a plan file in continuous time against the limits of the show "
                    "it was planned from (--show, or the plan's sibling X.toml). A plan not "
                    "planned from that show, or edited since, is refused unless "
                    "--accept-plan-limits trusts the limits it carries.")
    p.add_argument("plan", help="plan file written by 'groundctl plan'")
    p.add_argument("--json", action="store_true", help="print the verdict as one JSON object")
    add_plan_source(p)
    add_points_dir(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from groundctl.plan.plan import Plan
    from groundctl.plan.provenance import plan_source
    from groundctl.plan.verify import verify
    from groundctl.skybrush.cli import refuse_for_check

    refuse_for_check(args.plan)  # a show (TOML or Skybrush) is not a plan: say so
    loaded = Plan.load(args.plan)
    try:
        source = plan_source(loaded, args.plan, args.plan_show, args.accept_plan_limits,
                             args.points_dir)
    except UntrustedPlan as exc:
        # Unsafe even by the limits it carries is unsafe whatever its show says; "safe"
        # needs the show.
        ver = verify(loaded)
        if ver.safe:
            raise
        why = (f"not tied to the show given: {exc.message}" if args.plan_show
               else "no show to check it against")
        plan, limits_from = loaded, f"the plan file itself ({why})"
    else:
        plan, limits_from = source.plan, source.limits_from
        ver = verify(plan)
    o = ver.overall
    report = {
        "plan_file": args.plan, "show": plan.show_name, "drones": plan.drones,
        "duration_s": plan.duration, "min_separation_m": o.min_separation,
        "worst_violation_m": ver.worst_violation, "max_speed_mps": o.max_speed_h,
        "max_accel_mps2": o.max_accel, "pattern_error_m": max(ver.pattern_errors, default=0.0),
        "violations": list(ver.violations), "safe": ver.safe, "limits_from": limits_from,
    }
    if args.json:
        json.dump(report, sys.stdout)
        sys.stdout.write("\n")
    else:
        verdict = "SAFE" if ver.safe else "UNSAFE"
        print(f"{verdict}: {args.plan}: {plan.drones} drones, {plan.duration:.1f} s, min "
              f"separation {o.min_separation:.3f} m, max speed {o.max_speed_h:.2f} m/s, max "
              f"accel {o.max_accel:.2f} m/s^2; limits from {limits_from}")
        for v in ver.violations:
            print(f"  violation: {v}")
    return EXIT_OK if ver.safe else EXIT_UNSAFE
