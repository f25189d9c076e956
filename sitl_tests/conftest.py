"""Test-session settings that do not belong to any one fixture module."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest


def pytest_configure() -> None:
    # A shell starts background jobs with SIGINT ignored (and `nohup` SIGHUP), and an
    # ignored signal stays ignored across exec: every `groundctl sim` a test starts and
    # stops with Ctrl-C would ignore it.  The suite's own process takes Ctrl-C as usual,
    # and so do the processes it starts.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


# -- the longest first ------------------------------------------------------------------
# xdist's worksteal hands each worker a contiguous third of the collection and lets a
# worker that runs dry take the second half of the longest queue.  In file order the
# half-minute flights (fly against `groundctl sim`, the console) came wherever their
# module fell, sometimes last, and the run ended with one worker flying them while the
# other two idled.  Ordered by the last recorded durations (whole modules, longest
# first, so that a module's fixtures are still set up once per worker; within a module,
# its longest test first), the long flights start at once and the run ends on short
# tests.  The durations are a schedule, never a bound: an unknown test counts as
# UNKNOWN_S, and a stale file costs only balance.

DURATIONS = Path(__file__).with_name("durations.json")
#: The duration assumed for a test the file does not know, s.
UNKNOWN_S = 1.0


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--store-durations", action="store_true",
                     help=f"write each test's duration into {DURATIONS.name} (the order "
                          "of the next runs: the longest first)")


def _recorded() -> dict[str, float]:
    try:
        data = json.loads(DURATIONS.read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): float(v) for k, v in data.items()} if isinstance(data, dict) else {}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    recorded = _recorded()
    if not recorded:
        return
    own = {item.nodeid: recorded.get(item.nodeid, UNKNOWN_S) for item in items}
    module: dict[str, float] = {}
    for item in items:
        module[item.location[0]] = module.get(item.location[0], 0.0) + own[item.nodeid]
    items.sort(key=lambda item: (-module[item.location[0]], -own[item.nodeid]))


_measured: dict[str, float] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _measured[report.nodeid] = _measured.get(report.nodeid, 0.0) + report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    if not session.config.getoption("--store-durations") or \
            hasattr(session.config, "workerinput"):  # the controller writes, not the workers
        return
    merged = {**_recorded(), **{k: round(v, 2) for k, v in _measured.items()}}
    DURATIONS.write_text(json.dumps(dict(sorted(merged.items())), indent=0) + "\n")
