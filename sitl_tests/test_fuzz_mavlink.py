"""A small seeded run of the MAVLink fuzz (``benchmarks/fuzz_mavlink.py`` runs the big one).

1,500 hostile datagrams (random, truncated, bit-flipped, spoofed from other ports,
forged from the vehicles' own addresses where a raw socket opens, wrongly signed,
replayed, stray ids) at the ground station of a dry-run of the quick show, all on
127.0.0.1: no crash, no traceback, a safe flight, and no vehicle believed to be in a
state the simulator never had.
"""

from __future__ import annotations

import numpy as np
import pytest
from hostile_mavlink import Hostile, Target, fly_fuzzed


def test_a_seeded_fuzz_during_a_dry_run_crashes_nothing_and_changes_no_state() -> None:
    r = fly_fuzzed(count=1500, seed=7, speed=4.0)
    why = (r.error, r.crashes, r.tracebacks[:3], r.violations, r.report.get("unsafe_reasons"))
    assert r.total == 1500, why
    assert not r.crashes and not r.tracebacks and r.error is None, why
    assert not r.unsafe and r.report["landed"], why
    assert r.violations == [], why
    assert r.report["simulator"]["down_and_disarmed"] == 9
    assert r.link["bad_packets"] > 0 and r.link["unknown_system_packets"] > 0
    if r.raw:  # forged sources arrived as the vehicles and were caught as such
        assert r.airborne > 0 and r.link["link_conflicts"] > 0
        assert all(n > 0 for n in r.conflicts.values()), r.conflicts
        # ... and each vehicle's count is in its report line.
        per = {v["system_id"]: v["link_conflicts"] for v in r.report["vehicles"]}
        assert sum(per.values()) > 0 and all(n >= 0 for n in per.values()), per


def test_the_fuzz_sends_to_loopback_only() -> None:
    target = Target(("192.0.2.1", 14550), {1: ("127.0.0.1", 5760)}, {1: (47.0, 8.0, 400.0)})
    hostile = Hostile(np.random.default_rng(0), target, None, None)
    try:
        with pytest.raises(ValueError, match="loopback"):
            for _ in range(50):
                hostile.one()
    finally:
        hostile.close()
