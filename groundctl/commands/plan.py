"""``groundctl plan SHOW [-o PLAN] [--json]``: plan, verify, print the table, write the plan."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from groundctl.commands.options import add_points_dir, add_rerun_option, rerun_target, workers
from groundctl.commands.progress import ProgressBar
from groundctl.errors import EXIT_OK, EXIT_UNSAFE
from groundctl.skybrush.cli import add_import_options

if TYPE_CHECKING:
    from groundctl.plan.plan import Plan


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("plan", help="plan and verify a show, write the plan file")
    p.add_argument("show", help="show file (TOML), Skybrush .skyc, or Skybrush CSV export "
                                "(folder or zip)")
    p.add_argument("-o", "--output", metavar="PLAN",
                   help="plan file to write (default: SHOW with .plan.npz); a name ending "
                        "in .skyc writes a Skybrush compiled show instead")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.add_argument("--workers", type=workers, default=None, metavar="N",
                   help="parallel processes for transitions, 1..64 (default: one per core)")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="plan transitions on a Ray cluster: auto, ray://HOST:10001, HOST:6379, "
                        "or local to start one here (needs the ray extra)")
    add_points_dir(p)
    add_import_options(p)
    add_rerun_option(p, "the planned show (paths, slots, each transition's closest approach)",
                     "PLAN with .rrd")
    p.set_defaults(func=run)


def default_plan_path(show: str | Path) -> Path:
    show = Path(show)
    return show.with_name(show.stem + ".plan.npz")


def run(args: argparse.Namespace) -> int:
    from groundctl.plan.planner import plan_show
    from groundctl.plan.report import report_dict, report_table
    from groundctl.show.loader import load_show
    from groundctl.skybrush import cli as skybrush

    skybrush.refuse_for_plan(Path(args.show))  # a plan file, a stray zip: one clear line
    if skybrush.is_import(Path(args.show)):
        return skybrush.run_plan(args)
    out = Path(args.output) if args.output else default_plan_path(args.show)
    rerun = rerun_target(args.rerun, out.with_suffix(".rrd"))
    show = load_show(args.show, args.points_dir)
    if out.suffix.lower() == ".skyc":
        from groundctl.errors import SkybrushExportError
        from groundctl.skybrush.writer import MAX_SKYBRUSH_DRONES
        if show.drones > MAX_SKYBRUSH_DRONES:  # said before planning, not after
            raise SkybrushExportError(out, f"{show.drones} drones, more than the "
                                           f"{MAX_SKYBRUSH_DRONES} Skybrush loads in one show")
    executor = None
    if args.ray is not None:
        from groundctl.plan.distribute import RayExecutor

        executor = RayExecutor(args.ray)
    bar = ProgressBar(f"planning {show.name}")
    try:
        result = plan_show(show, workers=args.workers, progress=bar, executor=executor)
    finally:
        bar.close()
        if executor is not None:
            executor.close()
    if out.suffix.lower() == ".skyc":
        from groundctl.errors import SkybrushExportError
        from groundctl.skybrush.importing import export_skyc
        try:
            export_skyc(result.plan, out)
        except SkybrushExportError as exc:
            # Planning took its time: keep what it made.
            kept = result.plan.save(out.with_suffix(".plan.npz"))
            raise SkybrushExportError(exc.path, f"{exc.message}; the plan is saved as "
                                                f"{kept}", drone=exc.drone) from None
    else:
        result.plan.save(out)
    report = report_dict(result)
    report["plan_file"] = str(out)
    if args.json:
        json.dump(report, sys.stdout)
        sys.stdout.write("\n")
    else:
        print(report_table(report))
        print(f"plan written to {out}")
    if rerun is not None:
        _to_rerun(result.plan, rerun, args.json)
    return EXIT_OK if report["safe"] else EXIT_UNSAFE


def _to_rerun(plan: Plan, target: tuple[str, str | None], quiet: bool) -> None:
    """``--rerun``: the plan alone, the fleet flying it on ``show_time``."""
    from groundctl.viz import scene

    kind, where = target
    rec = scene.open_recording([scene.RerunTarget(kind, where)],  # type: ignore[arg-type]
                               f"plan {plan.show_name}")
    try:
        scene.log_plan(rec, plan)
        scene.log_styles(rec, [], None)
        scene.log_planned_fleet(rec, plan)
    except BaseException:
        rec.disconnect()
        raise
    scene.close_recording(rec)
    if not quiet:
        print(f"rerun: plan {kind}{f' {where}' if where else ''}", file=sys.stderr)
