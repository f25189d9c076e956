"""Test-session settings that do not belong to any one fixture module."""

from __future__ import annotations

import signal


def pytest_configure() -> None:
    # A shell starts background jobs with SIGINT ignored (and `nohup` SIGHUP), and an
    # ignored signal stays ignored across exec: every `groundctl sim` a test starts and
    # stops with Ctrl-C would ignore it.  The suite's own process takes Ctrl-C as usual,
    # and so do the processes it starts.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
