"""The console's side of ``groundctl dry-run`` and ``groundctl fly``: its options and when
it opens.

The console opens when stdout, stdin and stderr are terminals (Textual draws on
stderr), unless ``--no-console``
or ``--json``; ``--console`` asks for it (and needs a terminal).  With the
console the show arms only on the operator's go (``--go`` skips the gate, for
scripts), and a pre-flight check that waiting cannot fix (a low battery, a
vehicle off its slot) does not end the pre-flight early: the operator decides
(exclude the vehicle, or quit) until ``--preflight-timeout``.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Callable, Coroutine
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from groundctl.errors import ConsoleUnavailable, GroundctlError

if TYPE_CHECKING:
    from groundctl.console.session import ConsoleSession
    from groundctl.flight.runner import RunnerConfig
    from groundctl.viz.live import LiveRerun

Flown = tuple[dict[str, Any], GroundctlError | None, bool]
"""What a flying command's flight gives: its report, the error that ended it, whether
anything flew."""


def add_console_options(p: argparse.ArgumentParser) -> None:
    """``--console / --no-console`` and ``--go``."""
    p.add_argument("--console", action=argparse.BooleanOptionalAction, default=None,
                   help="the operator console (default: on when stdout and stdin are "
                        "terminals and not --json)")
    p.add_argument("--go", action="store_true",
                   help="with the console: arm as soon as the pre-flight passes, without "
                        "waiting for the operator's go")


def console_wanted(args: argparse.Namespace) -> bool:
    """Whether this run opens the console (see the module docstring)."""
    if args.json:
        if args.console:
            raise ConsoleUnavailable("--console and --json cannot go together: --json "
                                     "prints one JSON object and no console")
        return False
    # Textual draws on stderr and reads stdin; the report follows on stdout.
    terminal = _isatty(sys.stdout) and _isatty(sys.stdin) and _isatty(sys.__stderr__)
    if args.console and not terminal:
        raise ConsoleUnavailable("--console needs stdin, stdout and stderr to be a terminal "
                                 "(--no-console for scripts)")
    return terminal if args.console is None else bool(args.console)


def console_config(config: RunnerConfig) -> RunnerConfig:
    """The runner's settings under the console: the operator, not a 3 s timer, decides
    about a check waiting cannot fix."""
    return replace(config, settle_s=max(config.settle_s, config.preflight_timeout_s))


def outcome(report: dict[str, Any]) -> str:
    """The console's last line: how the flight ended."""
    reasons = report.get("unsafe_reasons") or []
    if report.get("safe"):
        return "SAFE: every vehicle is down (closing the console)"
    return "NOT SAFE: " + (str(reasons[0]) if reasons else "see the report") + \
        " (closing the console)"


def _isatty(stream: Any) -> bool:
    try:
        return bool(stream is not None and stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


def run_flight(main: Coroutine[Any, Any, Flown], session: ConsoleSession | None,
               live: LiveRerun | None, notify: Callable[[str], None]) -> Flown:
    """Run a flying command's ``main`` (report, error, flown): beside the console if there
    is one, and the live Rerun stream closed (bounded, flushed) whatever happens."""
    from groundctl.commands.flying import close_live_rerun

    try:
        if session is not None:
            from groundctl.console.session import run_with_console
            return asyncio.run(run_with_console(session, main, lambda r: outcome(r[0])))
        return asyncio.run(main)
    finally:
        close_live_rerun(live, notify)
