"""``groundctl plan SHOW [-o PLAN] [--json]``: plan, verify, print the table, write the plan."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from groundctl.commands.options import add_points_dir, workers
from groundctl.commands.progress import ProgressBar
from groundctl.errors import EXIT_OK, EXIT_UNSAFE


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("plan", help="plan and verify a show, write the plan file")
    p.add_argument("show", help="show file (TOML)")
    p.add_argument("-o", "--output", metavar="PLAN",
                   help="plan file to write (default: SHOW with .plan.npz)")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.add_argument("--workers", type=workers, default=None, metavar="N",
                   help="parallel processes for transitions, 1..64 (default: one per core)")
    add_points_dir(p)
    p.set_defaults(func=run)


def default_plan_path(show: str | Path) -> Path:
    show = Path(show)
    return show.with_name(show.stem + ".plan.npz")


def run(args: argparse.Namespace) -> int:
    from groundctl.plan.planner import plan_show
    from groundctl.plan.report import report_dict, report_table
    from groundctl.show.loader import load_show

    show = load_show(args.show, args.points_dir)
    bar = ProgressBar(f"planning {show.name}")
    try:
        result = plan_show(show, workers=args.workers, progress=bar)
    finally:
        bar.close()
    out = Path(args.output) if args.output else default_plan_path(args.show)
    result.plan.save(out)
    report = report_dict(result)
    report["plan_file"] = str(out)
    if args.json:
        json.dump(report, sys.stdout)
        sys.stdout.write("\n")
    else:
        print(report_table(report))
        print(f"plan written to {out}")
    return EXIT_OK if report["safe"] else EXIT_UNSAFE
