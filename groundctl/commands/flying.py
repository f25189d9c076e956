"""What ``groundctl dry-run`` and ``groundctl fly`` share: options, planning, Ctrl-C, output."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import stat
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol

from groundctl.commands.options import (
    add_plan_source,
    add_points_dir,
    add_rerun_option,
    positive,
    rerun_target,
    signing_key,
    vehicle,
)
from groundctl.commands.progress import ProgressBar
from groundctl.errors import EXIT_ABORTED, EXIT_OK, EXIT_UNSAFE, GroundctlError, UnsafePlan
from groundctl.execute.preflight import Thresholds
from groundctl.rtk.options import REQUIRE_RTK, add_rtk_options
from groundctl.vehicleid import parse_vehicle

if TYPE_CHECKING:
    from groundctl.flight.runner import RunnerConfig, ShowRunner
    from groundctl.plan.plan import Plan
    from groundctl.show.model import VehicleSettings
    from groundctl.viz.live import LiveRerun

# The executor, the planner and the report are imported where they are used, not with the
# options: a command line that fails its parsing, or asks for --help, answers at once.

#: The show ``groundctl dry-run`` flies when none is given.
BUNDLED_DEMO = Path(__file__).resolve().parents[2] / "shows" / "demo.toml"


def add_runner_options(p: argparse.ArgumentParser) -> None:
    """Options of the executor itself, common to both commands."""
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.add_argument("--record", type=Path, default=None, metavar="DIR",
                   help="write flight.tlog, events.jsonl and report.json here "
                        "(default recordings/<show>-<command>-<UTC time>)")
    p.add_argument("--exclude", type=vehicle, action="append", default=[], metavar="SYSID",
                   help="keep this vehicle on the ground (repeatable; 2:17 is network 2's "
                        "system id 17); the rest must still be safe without it")
    p.add_argument("--rate", type=positive, default=10.0, metavar="HZ",
                   help="setpoint rate per vehicle (default 10)")
    p.add_argument("--link-workers", choices=("auto", "on", "off"), default="auto",
                   help="read and parse each MAVLink network's telemetry in a worker "
                        "process of its own, off the control loop (auto: for fleets of 100 "
                        "vehicles or more)")
    p.add_argument("--lead", type=lead_ms, default=None, metavar="MS|auto",
                   help="setpoints are taken this far ahead of the show clock, to cover the "
                        "link delay and the vehicle's response; 'auto' (the default) "
                        "measures each vehicle's own in flight")
    p.add_argument("--mpc", action=argparse.BooleanOptionalAction, default=None,
                   help="replan a drone pushed off its path with MPC (default: on, or as the "
                        "show's [mpc] table says)")
    p.add_argument("--no-spares", action="store_true",
                   help="fly without the plan's spares: they stay on their pads, and a "
                        "track whose drone leaves the show stays dark")
    p.add_argument("--min-battery", type=float, default=Thresholds.min_battery_pct,
                   metavar="PCT", help="pre-flight battery minimum (default %(default)s %%)")
    p.add_argument("--max-wind", type=positive, default=None, metavar="M/S",
                   help="the strongest wind the vehicles may estimate: pre-flight refuses "
                        "above it, the show holds then lands (default: the show's "
                        "[limits] max_wind, 10)")
    p.add_argument("--preflight-timeout", type=positive, default=120.0, metavar="S",
                   help="give up if the pre-flight checks have not all passed after this "
                        "(default 120)")
    p.add_argument("--signing-key", type=signing_key, default=None, metavar="HEX",
                   help="MAVLink 2 signing key, 64 hex digits")
    p.add_argument("--vehicle", dest="vehicle_file", type=Path, default=None, metavar="FILE",
                   help="take the vehicles' own safety settings from the [vehicle] table of "
                        "FILE (a TOML file: a show file or one with only that table) instead "
                        "of the show's; for a Skybrush show, which has none")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    add_rerun_option(p, "stream the flight, live,", "live.rrd in the recording directory")
    add_rtk_options(p)


def lead_ms(text: str) -> float | None:
    """``--lead``: milliseconds (non-negative), or ``auto`` (None: measured per vehicle)."""
    if text.strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--lead must be milliseconds or 'auto', not {text!r}")\
            from None
    if not 0 <= value <= 2000:
        raise argparse.ArgumentTypeError(f"--lead must be within 0..2000 ms, not {text}")
    return value


def runner_config(args: argparse.Namespace, tracks: dict[int, int] | None = None) -> RunnerConfig:
    from groundctl.flight.runner import RunnerConfig

    return RunnerConfig(rate_hz=args.rate,
                        lead_s=None if args.lead is None else args.lead / 1000.0,
                        mpc=args.mpc, use_spares=not args.no_spares,
                        preflight_timeout_s=args.preflight_timeout,
                        excluded=frozenset(args.exclude), tracks=tracks,
                        thresholds=Thresholds(
                            min_battery_pct=args.min_battery, max_wind=args.max_wind,
                            require_fix_type=REQUIRE_RTK.get(args.require_rtk or "")),
                        vehicle=vehicle_settings(args))


def vehicle_settings(args: argparse.Namespace) -> VehicleSettings | None:
    """The ``[vehicle]`` table: from ``--vehicle FILE`` if given (which must have one),
    else from the show file flown, or for a ``.npz`` plan from ``--show`` (or its sibling
    ``X.toml``); None without one."""
    from groundctl.show.loader import load_vehicle_file, load_vehicle_settings
    from groundctl.skybrush.sniff import is_skybrush
    given: Path | None = getattr(args, "vehicle_file", None)
    if given is not None:
        return load_vehicle_file(given)
    path: Path | None = args.show
    if path is not None and is_skybrush(path):
        return None  # a Skybrush show carries no [vehicle] table
    if path is not None and path.suffix == ".npz":
        path = getattr(args, "plan_show", None) or path.with_suffix(".toml")
        if getattr(args, "accept_plan_limits", False) or not path.is_file():
            return None
    return None if path is None else load_vehicle_settings(path)


def load_or_plan(path: Path, quiet: bool, *, show_file: Path | None = None,
                 accept_plan_limits: bool = False,
                 points_dirs: Sequence[Path] = ()) -> Plan:
    """A plan file checked against its show, or a show file planned now; UnsafePlan if it
    does not verify.

    A ``.npz`` plan is verified against the limits of ``show_file`` (default:
    its sibling ``X.toml``), which it must have been planned from, or with
    ``accept_plan_limits`` against its own (:mod:`groundctl.plan.provenance`).
    """
    if path.suffix == ".npz":
        from groundctl.plan.plan import Plan
        from groundctl.plan.provenance import plan_source
        from groundctl.plan.verify import verify
        plan = plan_source(Plan.load(path), path, show_file, accept_plan_limits,
                           points_dirs).plan
        ver = verify(plan)
        if not ver.safe:
            raise UnsafePlan(ver.violations)
        _say_spares(plan, quiet)
        return plan
    from groundctl.plan.planner import plan_show
    from groundctl.show.loader import load_show
    show = load_show(path, points_dirs)
    if not quiet:
        print(f"planning {show.name}: {show.drones} drones", file=sys.stderr, flush=True)
    bar = ProgressBar(f"planning {show.name}")
    try:
        result = plan_show(show, progress=bar)
    finally:
        bar.close()
    if not result.verification.safe:
        raise UnsafePlan(result.verification.violations)
    if not quiet:
        print(f"planned and verified in {result.seconds:.1f} s: {result.plan.duration:.0f} s "
              f"show", file=sys.stderr, flush=True)
    _say_spares(result.plan, quiet)
    return result.plan


def _say_spares(plan: Plan, quiet: bool) -> None:
    """Where the plan's spares wait, said once (and how this version flies them)."""
    if plan.spares is not None and not quiet:
        how = "on their pads" if plan.spares.standby == "ground" else \
            "in the air over their pads (they take off and land with the fleet)"
        print(f"spares: {plan.spares.count} waiting {how}; one takes over the track of a "
              "drone that leaves the show", file=sys.stderr, flush=True)


def plan_for(args: argparse.Namespace) -> Plan:
    """:func:`load_or_plan` with the options :func:`add_plan_options` registered (a
    Skybrush .skyc or CSV show is imported and verified instead)."""
    from groundctl.skybrush.sniff import is_skybrush
    if is_skybrush(args.show):
        from groundctl.skybrush.cli import flight_plan
        return flight_plan(args)
    return load_or_plan(args.show, args.quiet, show_file=args.plan_show,
                        accept_plan_limits=args.accept_plan_limits, points_dirs=args.points_dir)


def add_plan_options(p: argparse.ArgumentParser) -> None:
    """Where a flying command's plan comes from: ``--show``, ``--accept-plan-limits``,
    ``--points-dir``."""
    add_plan_source(p)
    add_points_dir(p)


def say(quiet: bool) -> Callable[[str], None]:
    """The plain mode's ``notify``: a line on stderr that never makes the caller wait
    (:class:`~groundctl.console.terminal.LineWriter`)."""
    from groundctl.console.terminal import stderr_lines

    def notify(text: str) -> None:
        if not quiet:
            stderr_lines().line(text)
    return notify


#: Signals that stop a flight: Ctrl-C, a service manager's stop, a closed terminal.
STOP_SIGNALS: tuple[tuple[str, str], ...] = (
    ("SIGINT", "Ctrl-C"), ("SIGTERM", "SIGTERM"), ("SIGHUP", "SIGHUP (terminal closed)"))


class Interrupts:
    """Stop signals during a flight: the first lands every vehicle, the second abandons it.

    Ctrl-C, SIGTERM (``kill``, a service manager stopping groundctl) and SIGHUP
    (the operator's terminal closed) all mean "stop": killing the ground station
    outright would leave the fleet airborne with its setpoints frozen, so the
    first one lands everyone and the command exits once they are down (exit 5).
    Abandoning only stops the ground station: the vehicles' own failsafes (GCS
    or offboard loss) take over, which is why it takes a second signal.
    """

    def __init__(self, notify: Callable[[str], None]) -> None:
        self.notify = notify
        self.runner: ShowRunner | None = None
        self.presses = 0
        self.aborted = False
        self._task: asyncio.Task[Any] | None = None
        self._installed: list[signal.Signals] = []
        self._hung_up = False

    def attach(self, runner: ShowRunner) -> None:
        self.runner = runner

    def install(self) -> None:
        self._task = asyncio.current_task()
        loop = asyncio.get_running_loop()
        for name, label in STOP_SIGNALS:
            sig = getattr(signal, name, None)
            if sig is None:
                continue  # SIGHUP does not exist on Windows
            # Not the main thread, or a platform without loop signals: it then simply stops.
            handler = self.hangup if name == "SIGHUP" else self._on_signal
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.add_signal_handler(sig, handler, label)
                self._installed.append(sig)

    def uninstall(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in self._installed:
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.remove_signal_handler(sig)
        self._installed.clear()

    def stop(self, label: str) -> None:
        """The operator asked to stop (the console's quit): exactly as a signal."""
        self._on_signal(label)

    def hangup(self, label: str) -> None:
        """The operator's terminal is gone: SIGHUP, or the console found it gone (a
        failed write or read).  Both come for one closed terminal: it counts once, and
        only ever as the first stop -- after a Ctrl-C (the fleet already landing) a
        dropped connection must not abandon the flight."""
        if self._hung_up:
            return
        self._hung_up = True
        if self.presses:
            if self.runner is not None and self.runner.events is not None:
                self.runner.events.emit("signal", signal=label, count=self.presses,
                                        ignored="a stop is already under way")
            return
        self._on_signal(label)

    def _on_signal(self, label: str) -> None:
        self.presses += 1
        self.aborted = True
        if self.runner is not None and self.runner.events is not None:
            self.runner.events.emit("signal", signal=label, count=self.presses)
        if self.presses == 1 and self.runner is not None and self.runner.sequence is not None:
            self._say(f"{label}: landing every vehicle (again to abandon the flight)")
            self.runner.land_all()
            return
        if self.runner is not None and self.runner.sequence is None:
            self._say(f"{label}: no go; stopping before any vehicle was armed")
        else:
            self._say(f"{label}: abandoning the flight; vehicles' failsafes are in charge")
        if self._task is not None:
            self._task.cancel()

    @staticmethod
    def _say(text: str) -> None:
        # After SIGHUP the terminal may be gone, or stuck: never waited for.
        from groundctl.console.terminal import stderr_lines
        stderr_lines().line(f"\n{text}")


OPERATOR_HELP = ("commands: hold | resume | land (all) | land SYSID (to its landing spot) | "
                 "land-here SYSID | replace SYSID (a spare takes its track) | "
                 "kill SYSID confirm | status | help (SYSID 2:17: network 2's system id 17)")


class OperatorTarget(Protocol):
    """What operator commands act on: a :class:`ShowRunner`."""

    def hold(self) -> None: ...
    def resume(self) -> None: ...
    def land_all(self) -> None: ...
    def land_one(self, sysid: int) -> None: ...
    def land_here(self, sysid: int) -> None: ...
    def replace(self, sysid: int) -> None: ...
    def kill(self, sysid: int, confirm: bool = False) -> None: ...
    def status_line(self) -> str: ...


#: Each verb's usage, for the message when its arguments are wrong.
_USAGE = {
    "hold": "hold", "resume": "resume", "land": "land | land SYSID",
    "land-here": "land-here SYSID", "replace": "replace SYSID",
    "kill": "kill SYSID confirm", "status": "status",
    "help": "help",
}


class _BadArguments(Exception):
    """An operator command's arguments are wrong (said to the operator, never raised out)."""


def _sysid(verb: str, word: str) -> int:
    try:
        return parse_vehicle(word)
    except ValueError:
        raise _BadArguments(f"{verb}: {word!r} is not a system id (1-255): "
                            f"{_USAGE[verb]}") from None


def _at_most(verb: str, rest: list[str], n: int) -> None:
    if len(rest) > n:
        extra = " ".join(rest[n:])
        what = "no arguments" if n == 0 else f"at most {n} argument{'s' if n > 1 else ''}"
        raise _BadArguments(f"{verb} takes {what}, got {extra!r}: {_USAGE[verb]}")


def _needs_sysid(verb: str, rest: list[str]) -> int:
    if not rest:
        raise _BadArguments(f"{verb} needs a system id: {_USAGE[verb]}")
    return _sysid(verb, rest[0])


def operator_line(runner: OperatorTarget, line: str, notify: Callable[[str], None]) -> None:
    """Carry out one operator command typed on stdin (until the console exists).

    Bad input is said through ``notify`` (an unknown verb with the list of
    commands, wrong arguments with the verb's usage); nothing is raised.
    """
    words = line.split()
    if not words:
        return
    verb, rest = words[0].lower(), words[1:]
    if verb not in _USAGE:
        notify(f"unknown command {words[0]!r}; {OPERATOR_HELP}")
        return
    try:
        if verb == "hold":
            _at_most(verb, rest, 0)
            runner.hold()
        elif verb == "resume":
            _at_most(verb, rest, 0)
            runner.resume()
        elif verb == "land":
            _at_most(verb, rest, 1)
            if rest:
                runner.land_one(_sysid(verb, rest[0]))
            else:
                runner.land_all()
        elif verb == "land-here":
            sysid = _needs_sysid(verb, rest)
            _at_most(verb, rest, 1)
            runner.land_here(sysid)
        elif verb == "replace":
            sysid = _needs_sysid(verb, rest)
            _at_most(verb, rest, 1)
            runner.replace(sysid)
        elif verb == "kill":
            sysid = _needs_sysid(verb, rest)
            _at_most(verb, rest, 2)
            if rest[1:] not in ([], ["confirm"]):
                raise _BadArguments(f"kill: expected the word 'confirm' after the system id, "
                                    f"got {rest[1]!r}: {_USAGE[verb]}")
            # Without "confirm" the runner says why nothing was sent.
            runner.kill(sysid, confirm=rest[1:] == ["confirm"])
        elif verb == "status":
            _at_most(verb, rest, 0)
            notify(runner.status_line())
        else:
            notify(OPERATOR_HELP)
    except _BadArguments as exc:
        notify(str(exc))
    except GroundctlError as exc:  # the runner refused: say so, keep reading commands
        notify(f"{verb}: {exc}")


def stdin_is_interactive(stream: IO[str] | None) -> bool:
    """Whether ``stream`` can be watched for operator lines: a terminal, a pipe or a socket.

    ``/dev/null`` (a character device that is not a terminal), a regular file or a
    closed stream cannot: the event loop's epoll refuses them (``PermissionError``
    raised inside a callback, printed as a traceback), so they mean "no operator".
    """
    if stream is None:
        return False
    try:
        fd = stream.fileno()
        if os.isatty(fd):
            return True
        mode = os.fstat(fd).st_mode
    except (OSError, ValueError):
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode)


async def read_operator_commands(runner: ShowRunner, notify: Callable[[str], None]) -> None:
    """Operator commands from stdin, one per line, until end of input."""
    if not stdin_is_interactive(sys.stdin):
        return  # /dev/null, a regular file, closed (a service manager): no operator input
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    try:
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    except (ValueError, OSError):
        return  # stdin is a regular file or closed: no commands
    while line := await reader.readline():
        operator_line(runner, line.decode(errors="replace"), notify)


def finish(report: dict[str, Any], args: argparse.Namespace, aborted: bool) -> int:
    """Print the report; the exit code says whether the flight was safe.

    The flight is over: the lines still queued for the terminal are given a moment,
    and a terminal that is gone (the report is in the recording) changes no exit code.
    """
    from groundctl.console.terminal import stderr_lines

    stderr_lines().wait_written()
    with contextlib.suppress(OSError, ValueError):
        if args.json:
            json.dump(report, sys.stdout)
            sys.stdout.write("\n")
        else:
            from groundctl.flight.report import render_report
            print(render_report(report))
        if report.get("record_dir") and not args.quiet:
            print(f"recordings in {report['record_dir']}", file=sys.stderr)
        sys.stdout.flush()
    if aborted:  # the operator stopped the show (Ctrl-C): not the show that was planned
        return EXIT_ABORTED
    return EXIT_OK if report.get("safe") else EXIT_UNSAFE


# -- Rerun, live (issue 13) ------------------------------------------------------------
def start_live_rerun(args: argparse.Namespace, plan: Plan, record: Path | None
                     ) -> LiveRerun | None:
    """``--rerun``: a live stream of the flight (None without the option); ``--rerun``
    alone saves ``live.rrd`` in the recording directory."""
    from groundctl.record.recording import safe_name

    default = record / "live.rrd" if record is not None \
        else Path(f"{safe_name(plan.show_name)}-live.rrd")
    target = rerun_target(args.rerun, default)
    if target is None:
        return None
    from groundctl.viz.live import LiveRerun
    from groundctl.viz.scene import RerunTarget

    kind, where = target
    return LiveRerun(plan, [RerunTarget(kind, where)])  # type: ignore[arg-type]


def close_live_rerun(live: LiveRerun | None, notify: Callable[[str], None]) -> None:
    """Send the stream's last batch; say its trouble, if any, on one line each."""
    if live is None:
        return
    for error in live.close():
        notify(f"rerun: {error}")


def then(*calls: Callable[[ShowRunner], None] | None) -> Callable[[ShowRunner], None]:
    """One ``on_runner`` callback that makes each of ``calls`` in turn."""
    def each(runner: ShowRunner) -> None:
        for call in calls:
            if call is not None:
                call(runner)
    return each
