"""Test-session settings that do not belong to any one fixture module."""

from __future__ import annotations

import json
import signal
from pathlib import Path
from typing import Any

import pytest


def pytest_configure() -> None:
    # A shell starts background jobs with SIGINT ignored (and `nohup` SIGHUP), and an
    # ignored signal stays ignored across exec: every `groundctl sim` a test starts and
    # stops with Ctrl-C would ignore it.  The suite's own process takes Ctrl-C as usual,
    # and so do the processes it starts.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


# -- the longest first, list-scheduled -----------------------------------------------
# Tests are collected longest first, by the last recorded durations (DURATIONS), and
# `--dist load` hands them out with :class:`LongestFirst`: each worker is handed the
# next unit of the collection whenever it finishes a test (it holds one more than it
# runs), so the half-minute flights start at once, the longest tests not yet handed
# out go to the first workers free (list scheduling, one test ahead), and the run ends
# on short tests instead of on one worker's flight while the others idle.  (In file
# order, or with worksteal handing each worker a contiguous quarter of the collection,
# the long flights came wherever their module fell.)
#
# A unit is one test, except a module in ONE_WORKER: its module fixture is a flight, a
# Ray cluster, a pool of planning processes or a planned show, set up once on the one
# worker that runs the whole module.  (xdist's own `loadgroup` would do this from
# `xdist_group` marks, but with pytest 9.2 it no longer tags the tests, and the modules
# were spread over every worker, each flying the fixture's flight again.)
#
# The durations are a schedule, never a bound: an unknown test counts as UNKNOWN_S, and
# a stale file costs only balance.

DURATIONS = Path(__file__).with_name("durations.json")
#: The duration assumed for a test the file does not know, s.
UNKNOWN_S = 1.0
#: Modules run whole by one worker (their module-scoped fixture is expensive).
ONE_WORKER = frozenset({"sitl_tests/test_record_rerun.py", "sitl_tests/test_plan_ray.py",
                        "sitl_tests/test_flight_workers.py", "sitl_tests/test_skybrush.py"})


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


def unit_of(nodeid: str) -> str:
    """The unit of work a test belongs to: its module for a module in ONE_WORKER,
    else the test itself."""
    module = nodeid.split("::", 1)[0]
    return module if module in ONE_WORKER else nodeid


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    recorded = _recorded()
    if not recorded:
        return
    own = {item.nodeid: recorded.get(item.nodeid, UNKNOWN_S) for item in items}
    unit = {item.nodeid: unit_of(item.nodeid) for item in items}
    weight: dict[str, float] = {}
    for nodeid, u in unit.items():
        weight[u] = weight.get(u, 0.0) + own[nodeid]
    items.sort(key=lambda item: (-weight[unit[item.nodeid]], unit[item.nodeid],
                                 -own[item.nodeid]))


try:
    from xdist.scheduler import LoadScopeScheduling
except ImportError:  # without xdist the suite runs in one process, in the same order
    pass
else:
    class LongestFirst(LoadScopeScheduling):
        """xdist's scope scheduling with :func:`unit_of` as the scope and the units in
        collection order (the longest first).  A worker holds two tests: the one it runs
        and the next (it runs a test only once it knows the next, for fixture teardown);
        when it finishes one it is handed the next unit of the queue.  (xdist's scope
        scheduling tops a worker up only below three, a deeper queue behind a busy
        worker.)  A worker that crashes: the test it ran is reported and not run again,
        its other tests go back to the front of the queue."""

        def __init__(self, config: pytest.Config, log: Any = None) -> None:
            super().__init__(config, log)
            config.option.loadscopereorder = False  # the collection's order is the plan

        def _split_scope(self, nodeid: str) -> str:
            return unit_of(nodeid)

        def _reschedule(self, node: Any) -> None:
            if node.shutting_down:
                return
            # Topped up to two (a unit may be a whole module: then it holds more).
            while self.workqueue and self._pending_of(self.assigned_work[node]) < 2:
                self._assign_work_unit(node)
            if not self.workqueue:
                node.shutdown()  # it runs what it holds, then stops

        def remove_node(self, node: Any) -> str | None:
            workload = self.assigned_work.pop(node)
            left = {scope: {nodeid: False for nodeid, done in unit.items() if not done}
                    for scope, unit in workload.items()}
            left = {scope: unit for scope, unit in left.items() if unit}
            if not left:
                return None
            first = next(iter(left))
            crashed = next(iter(left[first]))
            del left[first][crashed]  # reported as the crash, not run again
            queued = list(self.workqueue.items())
            self.workqueue.clear()
            self.workqueue.update((scope, unit) for scope, unit in left.items() if unit)
            self.workqueue.update(queued)
            for other in list(self.assigned_work):
                self._reschedule(other)
            return crashed

    @pytest.hookimpl(optionalhook=True)  # `-p no:xdist` leaves the hook without a spec
    def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
        if config.getvalue("dist") != "load":
            return None  # another --dist: xdist's own
        return LongestFirst(config, log)


_measured: dict[str, float] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _measured[report.nodeid] = _measured.get(report.nodeid, 0.0) + report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    if not session.config.getoption("--store-durations") or \
            hasattr(session.config, "workerinput"):  # the controller writes, not the workers
        return
    merged = {**_recorded(), **{k: round(v, 2) for k, v in _measured.items()}}
    DURATIONS.write_text(json.dumps(dict(sorted(merged.items())), indent=0) + "\n")
