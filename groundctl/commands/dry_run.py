"""``groundctl dry-run [SHOW]``: rehearse a show against the built-in simulator, over UDP."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from groundctl.commands.console_mode import (
    add_console_options,
    console_config,
    console_wanted,
    run_flight,
)
from groundctl.commands.flying import (
    BUNDLED_DEMO,
    Interrupts,
    add_plan_options,
    add_runner_options,
    finish,
    plan_for,
    runner_config,
    say,
    start_live_rerun,
    then,
)
from groundctl.commands.options import (
    add_fail,
    add_gust_on,
    non_negative,
    positive,
    probability,
    push,
    weak,
    wind,
)
from groundctl.errors import GroundctlError
from groundctl.link.flavours import Flavour
from groundctl.sim.config import PROFILE_NAMES
from groundctl.skybrush.cli import add_import_options


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "dry-run", help="rehearse a show against the built-in simulator",
        description="Plan the show, start a simulated fleet on loopback standing on its "
                    "takeoff slots, fly the whole show through the real executor over UDP "
                    "and report what was flown. Exit 0 only if the flight was safe.")
    p.add_argument("show", nargs="?", type=Path, default=BUNDLED_DEMO,
                   help="show file (TOML), plan file (.npz), Skybrush .skyc or CSV export; "
                        "default: the bundled demo")
    p.add_argument("--autopilot", choices=[f.value for f in Flavour], default="ardupilot",
                   help="autopilot the simulated vehicles imitate (default ardupilot)")
    p.add_argument("--speed", type=positive, default=1.0, metavar="K",
                   help="simulated seconds per real second (default 1)")
    p.add_argument("--wind", type=wind, default=(0.0, 0.0, 0.0), metavar="SPEC",
                   help="mean wind EAST,NORTH[,UP] m/s or SPEED@FROM_DEGREES")
    p.add_argument("--gust", type=non_negative, default=0.0, metavar="STD",
                   help="random gusts, m/s standard deviation per axis")
    p.add_argument("--loss", type=probability, default=0.0, metavar="P",
                   help="packet loss probability each way, e.g. 0.1")
    p.add_argument("--latency", type=non_negative, default=0.0, metavar="MS",
                   help="one-way link latency in ms")
    p.add_argument("--jitter", type=non_negative, default=0.0, metavar="MS",
                   help="latency standard deviation in ms")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="seed of every random process (default 0)")
    p.add_argument("--ready-delay", type=non_negative, default=40.0, metavar="S",
                   help="simulated seconds until vehicles may arm (SITL: 40); the EKF "
                        "origin comes at half of it")
    p.add_argument("--push", type=push, action="append", default=[], metavar="SYSID@T:E,N,U",
                   help="displace a vehicle by E,N,U metres (show frame) over one second at "
                        "show time T (repeatable), whatever its autopilot does: kinematic, "
                        "a GPS jump or a bird strike (a gust is --gust-on)")
    add_gust_on(p, "show time T")
    add_fail(p, "show time T")
    p.add_argument("--weak", type=weak, action="append", default=[],
                   metavar="SYSID[,SYSID...]:FACTOR",
                   help="scale those vehicles' maximum speed and acceleration by FACTOR "
                        "(repeatable): a weak motor or battery")
    p.add_argument("--profile", choices=PROFILE_NAMES, default=None,
                   help="the simulated vehicles' flight-dynamics calibration (default: "
                        "ardupilot-4.8 or px4-1.15)")
    p.add_argument("--no-pace", dest="paced", action="store_false",
                   help="let the simulated clock run at --speed whatever this machine keeps "
                        "up with (by default it waits for a late simulator or ground-station "
                        "loop, so a busy machine slows the rehearsal instead of flying it on "
                        "stale setpoints): rehearses the ground station's own load")
    p.add_argument("--networks", type=int, default=0, metavar="K",
                   help="spread the simulated fleet over K MAVLink networks (one UDP port "
                        "of the ground station each, 254 vehicles at most per network; "
                        "default: as many as the show needs); their vehicles are named "
                        "2:17 (network 2, system id 17), network 1's plainly 17")
    p.add_argument("--sim-processes", type=int, default=0, metavar="N",
                   help="simulate the fleet in N processes (default: one, or one per "
                        "network for fleets of more than 300 vehicles: one process carries "
                        "about 600 at real time)")
    p.add_argument("--no-record", action="store_true", help="record nothing")
    add_plan_options(p)
    add_import_options(p)
    add_runner_options(p)
    add_console_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from groundctl.flight.dryrun import DryRunOptions, Failure, Gust, Push, fly_dry_run
    from groundctl.record.recording import default_directory

    console = console_wanted(args)
    plan = plan_for(args)
    record = None if args.no_record \
        else (args.record or default_directory(plan.show_name, "dry-run"))
    options = DryRunOptions(
        flavour=Flavour(args.autopilot), speed=args.speed, wind=args.wind, gust_std=args.gust,
        loss=args.loss, latency_ms=args.latency, jitter_ms=args.jitter, seed=args.seed,
        signing_key=args.signing_key, ekf_origin_delay_s=args.ready_delay / 2,
        ready_delay_s=args.ready_delay, runner=runner_config(args), record_dir=record,
        pushes=tuple(Push(s, t, v) for s, t, v in args.push),
        gusts=tuple(Gust(*g) for g in args.gust_on),
        failures=tuple(Failure(*f) for f in args.fail),
        weak=tuple(w for group in args.weak for w in group), profile=args.profile,
        rtk=args.rtk, gcs_sysid=args.gcs_sysid, paced=args.paced, networks=args.networks,
        link_workers=args.link_workers, sim_processes=args.sim_processes)
    notify = say(args.quiet)
    interrupts = Interrupts(notify)
    live = start_live_rerun(args, plan, record)

    # -- the console (issue 12): the same flight, its lines and hooks to the console --
    session = None
    if console:
        from groundctl.console.session import ConsoleSession
        options = replace(options, runner=console_config(options.runner))
        session = ConsoleSession(interrupts.stop, hangup=interrupts.hangup, show=plan.show_name,
                                 duration_s=plan.duration,
                                 separation_limit_m=plan.limits.min_separation,
                                 go_gate=not args.go)
        notify = session.notify
    # ----------------------------------------------------------------------------------
    on_runner = then(interrupts.attach, session.attach if session is not None else None,
                     live.attach if live is not None else None)

    async def main() -> tuple[dict[str, object], GroundctlError | None, bool]:
        interrupts.install()
        try:
            result = await fly_dry_run(plan, options, notify=notify, on_runner=on_runner)
        finally:
            interrupts.uninstall()
        return result.report, result.error, result.flown

    spares = f" and {plan.spares.count} spare(s) on their pads" if plan.spares is not None \
        else ""
    say(args.quiet)(f"dry-run of {plan.show_name}: {plan.drones} simulated {args.autopilot} "
                    f"vehicles{spares} on 127.0.0.1, speed x{args.speed:g}")
    report, error, flown = run_flight(main(), session, live, say(args.quiet))
    if error is not None and not flown:
        raise error  # nothing flew: one line and the error's exit code
    return finish(report, args, interrupts.aborted)
