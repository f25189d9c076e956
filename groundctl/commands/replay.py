"""``groundctl replay RECORDING [--plan PLAN] [-o OUT.rrd] [--spawn | --connect URL]``."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from groundctl.errors import EXIT_OK


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "replay", help="write a recorded flight as a Rerun recording",
        description="Read a recording directory (flight.tlog, events.jsonl, showclock.csv, "
                    "plan.npz, report.json) or a bare .tlog and write a Rerun recording: "
                    "the fleet in 3D in its LED colours, the plan, tracking error, minimum "
                    "separation, setpoint lateness, battery and the events. A damaged tlog is "
                    "replayed up to the damage and the command says where it stopped (exit 2).")
    p.add_argument("recording", type=Path, help="recording directory or .tlog file")
    p.add_argument("--plan", type=Path, default=None, metavar="PLAN",
                   help="plan file (.npz) flown (default: the recording's plan.npz)")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="OUT.rrd",
                   help="Rerun file to write (default DIR/replay.rrd, or X.rrd beside X.tlog; "
                        "none with --spawn or --connect unless given)")
    view = p.add_mutually_exclusive_group()
    view.add_argument("--spawn", action="store_true", help="also open a Rerun viewer")
    view.add_argument("--connect", metavar="URL", default=None,
                      help="also send to a running Rerun viewer at URL "
                           "(e.g. rerun+http://127.0.0.1:9876/proxy)")
    p.add_argument("-q", "--quiet", action="store_true", help="no summary line on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from groundctl.viz.replay import default_output, find_source, replay
    from groundctl.viz.scene import RerunTarget

    source = find_source(args.recording, args.plan)
    targets: list[RerunTarget] = []
    out = args.output
    if out is None and not (args.spawn or args.connect):
        out = default_output(args.recording)
    if out is not None:
        targets.append(RerunTarget("save", str(out)))
    if args.spawn:
        targets.append(RerunTarget("spawn"))
    if args.connect:
        targets.append(RerunTarget("connect", args.connect))

    def say(text: str) -> None:
        if not args.quiet:
            print(f"replay: {text}", file=sys.stderr, flush=True)

    started = time.perf_counter()
    summary = replay(source, targets, say)
    where = f" to {out}" if out is not None else ""
    say(f"{summary.vehicles} vehicles, {summary.ticks} ticks, {summary.lines} log lines, "
        f"{summary.show_seconds:.1f} s of show written{where} in "
        f"{time.perf_counter() - started:.1f} s")
    if summary.damage is not None:
        raise summary.damage  # one line: where the tlog stopped (what came before is written)
    return EXIT_OK
