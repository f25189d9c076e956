"""``groundctl fly SHOW --connect ENDPOINT``: fly a show with real vehicles.

Or with a ``groundctl sim`` in another terminal: the same executor either way.
"""

from __future__ import annotations

import argparse
import asyncio
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from groundctl.commands.console_mode import (
    add_console_options,
    console_config,
    console_wanted,
    run_flight,
)
from groundctl.commands.flying import (
    Interrupts,
    add_plan_options,
    add_runner_options,
    finish,
    plan_for,
    read_operator_commands,
    runner_config,
    say,
    start_live_rerun,
)
from groundctl.errors import GroundctlError, UsageError
from groundctl.link.fleetfile import FleetFile, FleetFileError, load_fleet_file, parse_address
from groundctl.skybrush.cli import add_import_options
from groundctl.vehicleid import MAX_NETWORKS

if TYPE_CHECKING:
    from groundctl.flight.runner import ShowRunner


def endpoint(text: str) -> tuple[str, int]:
    """``[udp:|udpin:]HOST:PORT``: the local address to listen on."""
    for prefix in ("udpin:", "udp:"):
        if text.startswith(prefix):
            text = text[len(prefix):]
            break
    else:
        if text.startswith(("tcp:", "udpout:", "serial:")):
            raise argparse.ArgumentTypeError(
                f"--connect {text!r}: only UDP listening is supported (udp:HOST:PORT)")
    try:
        return parse_address(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--connect: {exc}") from None


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "fly", help="fly a show with real vehicles",
        description="Plan (or load) the show, wait for the vehicles on the MAVLink endpoint, "
                    "run the pre-flight checks and fly the show. Type hold, resume, land, "
                    "land SYSID, land-here SYSID, kill SYSID confirm on stdin. Ctrl-C (or "
                    "SIGTERM, SIGHUP) once lands every vehicle; twice abandons the flight "
                    "to the vehicles' failsafes.")
    p.add_argument("show", type=Path, help="show file (TOML), plan file (.npz), Skybrush "
                                            ".skyc or CSV export")
    p.add_argument("--connect", type=endpoint, action="append", default=None,
                   metavar="ENDPOINT",
                   help="UDP address to listen on, udp:HOST:PORT (default udp:0.0.0.0:14550); "
                        "repeat it for several MAVLink networks, one per --connect in order, "
                        "each with its own system ids 1..254 (network 2's system id 17 is "
                        "named 2:17)")
    p.add_argument("--fleet", type=Path, default=None, metavar="FILE",
                   help="fleet file: system ids, addresses, tracks")
    p.add_argument("--connect-timeout", type=float, default=30.0, metavar="S",
                   help="wait this long for every vehicle's HEARTBEAT (default 30)")
    add_plan_options(p)
    add_import_options(p)
    add_runner_options(p)
    add_console_options(p)
    # Real vehicles: a Skybrush show must say (or be told) its altitude above sea level.
    p.set_defaults(func=run, real_vehicles=True)


def run(args: argparse.Namespace) -> int:
    from groundctl.clock import ScaledClock
    from groundctl.flight.report import flight_report
    from groundctl.flight.runner import ShowRunner
    from groundctl.link.fleet import FleetLink
    from groundctl.link.worker import use_workers
    from groundctl.record.recording import Recording, default_directory

    console = console_wanted(args)
    fleet: FleetFile | None = load_fleet_file(args.fleet) if args.fleet is not None else None
    connects: list[tuple[str, int]] = args.connect or [("0.0.0.0", 14550)]
    keys: list[bytes | None] | None = None
    if fleet is not None and fleet.networks:
        if args.connect:
            raise UsageError(f"--connect conflicts with the [[network]] tables of {args.fleet}: "
                             "say the connections in one place")
        connects = [n.listen for n in fleet.networks]
        keys = [n.signing_key or args.signing_key for n in fleet.networks]
    if len(connects) > MAX_NETWORKS:
        raise UsageError(f"--connect: at most {MAX_NETWORKS} networks, got {len(connects)}")
    if len(set(connects)) != len(connects):
        raise UsageError("--connect: the same endpoint twice")

    plan = plan_for(args)
    if fleet is not None and fleet.tracks:
        bad = sorted(t for t in fleet.tracks.values() if t >= plan.drones)
        if bad:
            raise FleetFileError(args.fleet, "track", f"track(s) {bad} do not exist: the plan "
                                                      f"has tracks 0..{plan.drones - 1}")
    record = args.record or default_directory(plan.show_name, "fly")
    live = start_live_rerun(args, plan, record)  # before the recording: may fail to connect
    clock = ScaledClock(1.0)
    recording = Recording(record, clock.now, plan)
    notify = say(args.quiet)
    interrupts = Interrupts(notify)
    config = runner_config(args, fleet.tracks if fleet is not None and fleet.tracks else None)
    config = replace(config, connect_timeout_s=args.connect_timeout,
                     spare_ids=fleet.spares if fleet is not None else frozenset())
    ids = list(fleet.system_ids) if fleet is not None else None

    # -- the console (issue 12): the runner's lines, events and go gate to the console --
    session = None
    if console:
        from groundctl.console.session import ConsoleSession
        config = console_config(config)
        session = ConsoleSession(interrupts.stop, hangup=interrupts.hangup, show=plan.show_name,
                                 duration_s=plan.duration,
                                 separation_limit_m=plan.limits.min_separation,
                                 go_gate=not args.go)
        notify = session.notify
    # ----------------------------------------------------------------------------------

    async def main() -> tuple[dict[str, Any], GroundctlError | None, bool]:
        events = recording.events
        link = FleetLink(connects, clock=clock,
                         endpoints=fleet.endpoints if fleet is not None else (),
                         expected_ids=ids, signing_key=args.signing_key, signing_keys=keys,
                         tlog=recording.network_tlogs(len(connects)), events=events,
                         system_id=args.gcs_sysid,
                         link_workers=use_workers(args.link_workers,
                                                     len(ids) if ids else plan.drones))
        runner = ShowRunner(plan, link, clock, config, events=events, notify=notify,
                            expected_ids=ids)
        recording.follow(runner)  # the show clock, for a replay
        rtk = None
        if args.rtk is not None:
            from groundctl.rtk.forwarder import RtkForwarder
            from groundctl.rtk.sources import RtkSource
            field = (plan.origin.lat, plan.origin.lon, plan.origin.alt)  # for a caster's GGA
            rtk = runner.rtk = RtkForwarder(RtkSource(args.rtk, clock, position=field), link,
                                            clock, events=events, notify=notify)
        if live is not None:
            live.attach(runner)
        interrupts.attach(runner)
        interrupts.install()
        error: GroundctlError | None = None
        if session is not None:
            session.attach(runner)  # the console owns the terminal: no status lines, no stdin
        status = asyncio.create_task(_status(runner, args.quiet or session is not None))
        commands = asyncio.create_task(read_operator_commands(runner, say(False))
                                       if session is None else asyncio.sleep(0))
        try:
            await link.start()
            if rtk is not None:
                rtk.start()
            where = ", ".join(f"{h}:{p}" + (f" (network {k + 1})" if len(connects) > 1 else "")
                              for k, (h, p) in enumerate(connects))
            notify(f"listening on {where} for {len(ids) if ids else plan.drones} vehicle(s)")
            await runner.run()
        except GroundctlError as exc:
            error = exc
            events.emit("error", kind=type(exc).__name__, text=str(exc))
        finally:
            interrupts.uninstall()
            status.cancel()
            commands.cancel()
            if rtk is not None:
                await rtk.stop()
            await link.close()
            report = flight_report(runner, None if error is None else str(error))
            report["record_dir"] = str(record)
            recording.finish(report)
        return report, error, runner.sequence is not None

    report, error, flown = run_flight(main(), session, live, say(args.quiet))
    if error is not None and not flown:
        raise error  # nothing flew: one line and the error's exit code
    return finish(report, args, interrupts.aborted)


async def _status(runner: ShowRunner, quiet: bool) -> None:
    """A plain status line on stderr every second (until the console exists); never
    waited for (a terminal that stops reading drops lines, not ticks)."""
    from groundctl.console.terminal import stderr_lines

    while not quiet:
        await asyncio.sleep(1.0)
        stderr_lines().line(f"{time.strftime('%H:%M:%S')} {runner.status_line()}")
