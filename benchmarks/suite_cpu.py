"""CPU per test of the suite: which tests to make cheaper when the test command is slow.

    PYTHONPATH=benchmarks .venv/bin/python -m pytest -q -n 4 -p suite_cpu sitl_tests
    .venv/bin/python benchmarks/suite_cpu.py [--top 40]

A flight's wall time is paced (it waits for its clock), so the durations pytest reports
say little about what a test costs a busy machine.  As a pytest plugin this records, per
test, the CPU seconds of the test's process and of every process it started (the
simulator, planning and MPC workers, a ``groundctl`` subprocess), sampled every 0.2 s
from /proc so that helpers which end with the test are counted, and writes one JSON file
per test process to ``$SUITE_CPU_DIR`` (default /tmp/suite-cpu).  Run as a script it
prints the tests that cost most, and the total.  Linux only.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import threading
import time
from pathlib import Path
from typing import Any

OUT = Path(os.environ.get("SUITE_CPU_DIR", "/tmp/suite-cpu"))
TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
POLL_S = 0.2


def _descendants_cpu(root: int) -> dict[int, float]:
    """CPU seconds of every live process below ``root``."""
    parent: dict[int, int] = {}
    cpu: dict[int, float] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue
        pid = int(name)
        parent[pid] = int(fields[1])
        cpu[pid] = (int(fields[11]) + int(fields[12])) / TICK
    below: set[int] = set()
    frontier = {root}
    while frontier:
        frontier = {p for p, pp in parent.items() if pp in frontier and p not in below}
        below |= frontier
    return {p: cpu[p] for p in below}


class _Watch:
    """The largest CPU figure seen for each helper process while a test runs."""

    def __init__(self) -> None:
        self.seen: dict[int, float] = {}
        self.base: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="suite-cpu")

    def start(self) -> None:
        self.base = _descendants_cpu(os.getpid())  # long-lived helpers (the fork server)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(POLL_S):
            self._sample()

    def _sample(self) -> None:
        for pid, c in _descendants_cpu(os.getpid()).items():
            self.seen[pid] = max(self.seen.get(pid, 0.0), c)

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        self._sample()
        return sum(c - self.base.get(pid, 0.0) for pid, c in self.seen.items())


_records: list[dict[str, Any]] = []
_current: dict[str, Any] = {}


def _self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def pytest_runtest_setup(item: Any) -> None:
    watch = _Watch()
    watch.start()
    _current.update(nodeid=item.nodeid, wall=time.monotonic(), cpu=_self_cpu(), watch=watch)


def pytest_runtest_teardown(item: Any, nextitem: Any) -> None:
    if _current.get("nodeid") != item.nodeid:
        return
    helpers = _current["watch"].stop()
    _records.append({"test": item.nodeid, "wall_s": round(time.monotonic() - _current["wall"], 2),
                     "cpu_s": round(_self_cpu() - _current["cpu"], 2),
                     "helpers_cpu_s": round(helpers, 2)})
    _current.clear()


def pytest_sessionfinish(session: Any, exitstatus: int) -> None:
    if not _records:
        return
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / f"cpu-{os.getpid()}.json").write_text(json.dumps(_records))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--top", type=int, default=40)
    args = ap.parse_args()
    rows = [r for f in sorted(OUT.glob("cpu-*.json")) for r in json.loads(f.read_text())]
    if not rows:
        print(f"no records in {OUT}: run the suite with -p suite_cpu first")
        return 1
    for r in rows:
        r["total"] = r["cpu_s"] + r["helpers_cpu_s"]
    rows.sort(key=lambda r: -r["total"])
    total = sum(r["total"] for r in rows)
    print(f"{len(rows)} tests, {total:.0f} s of CPU ({sum(r['cpu_s'] for r in rows):.0f} in the "
          f"test processes, {sum(r['helpers_cpu_s'] for r in rows):.0f} in their helpers)")
    print(f"{'CPU s':>7} {'own':>6} {'helpers':>8} {'wall s':>7}  test")
    for r in rows[:args.top]:
        print(f"{r['total']:>7.1f} {r['cpu_s']:>6.1f} {r['helpers_cpu_s']:>8.1f} "
              f"{r['wall_s']:>7.1f}  {r['test']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
