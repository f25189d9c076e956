"""The ``groundctl`` command: parses, dispatches to groundctl.commands.<verb>.

Every :class:`~groundctl.errors.GroundctlError` becomes one line on stderr and
its exit code; Ctrl-C exits with EXIT_ABORTED after the command's own cleanup
(``finally`` blocks flush logs and recordings) has run.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import sys
from collections.abc import Sequence

from groundctl import __version__
from groundctl.errors import EXIT_ABORTED, GroundctlError

#: Verb modules under groundctl.commands, in the order ``--help`` lists them.
COMMANDS = ("plan", "check", "dry_run", "fly", "sim", "replay")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="groundctl",
        description="Ground station for formation drone light shows.",
    )
    parser.add_argument("--version", action="version", version=f"groundctl {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output on stderr (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"groundctl.commands.{name}").add_parser(sub)
    return parser


#: Longest error line printed; the rest is cut (a hostile file can make a long one).
MAX_ERROR_CHARS = 2000


def one_line(text: str) -> str:
    """``text`` as one printable line: line breaks, terminal escapes and other control
    characters (which a file's names and keys may hold) shown escaped, and cut at
    :data:`MAX_ERROR_CHARS`."""
    out = "".join(ch if ch.isprintable() else ascii(ch)[1:-1] for ch in text)
    return out if len(out) <= MAX_ERROR_CHARS else out[:MAX_ERROR_CHARS - 3] + "..."


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from groundctl.console.terminal import LineHandler

    handler = LineHandler()  # never waits on the terminal (a stuck one drops lines)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(
        level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)],
        handlers=[handler],
    )
    try:
        return int(args.func(args))
    except GroundctlError as exc:
        _error_line(f"groundctl {args.command}: error: {one_line(str(exc))}")
        return exc.exit_code
    except KeyboardInterrupt:
        _error_line(f"groundctl {args.command}: interrupted")
        return EXIT_ABORTED
    finally:
        from groundctl.console.terminal import stderr_lines
        stderr_lines().wait_written()  # log lines still queued, for a moment
        _flush_or_detach()


def _error_line(text: str) -> None:
    """The one line on stderr, after the lines queued before it (for a moment: they
    are written by a thread of their own, and the error line came out above the line
    it ends); a terminal that is gone (the operator's closed, a dropped SSH connection)
    changes no exit code."""
    from groundctl.console.terminal import stderr_lines

    stderr_lines().wait_written()
    with contextlib.suppress(OSError, ValueError):
        print(text, file=sys.stderr, flush=True)


def _flush_or_detach() -> None:
    """Flush stdout and stderr; one whose terminal is gone is pointed at /dev/null, so
    that the interpreter's own flush at exit cannot fail and turn the exit code into
    120."""
    for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            with contextlib.suppress(OSError):
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, fd)
                os.close(null)


if __name__ == "__main__":
    sys.exit(main())
