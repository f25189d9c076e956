"""Shared pieces of the end-to-end flight tests: the quick show's plan and a dry-run call.

No tests here.  Every dry-run goes over real loopback UDP to the built-in
simulator in its own process, sped up eight times (:data:`FAST`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

import pytest

from groundctl.flight.dryrun import DryRunOptions, DryRunResult, During, fly_dry_run
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.link.flavours import Flavour
from groundctl.plan.plan import Plan
from groundctl.sim import SimConfig

REPO = Path(__file__).resolve().parents[1]
QUICK_SHOW = REPO / "shows" / "quick.toml"

#: Eight times real time, vehicles ready to arm 2 simulated seconds after boot.  The
#: dry-run's clock is paced (groundctl/clock.py): on a machine too busy for x8 it waits
#: for whichever side is late, so a busy machine makes a flight slower, not different.
FAST: dict[str, Any] = {"speed": 8.0, "ekf_origin_delay_s": 1.0, "ready_delay_s": 2.0}


def flavours(suite: Flavour) -> list[Any]:
    """Both autopilot flavours for ``parametrize``, the one other than ``suite`` marked
    ``extended``: a behaviour of the executor's own is flown once in every run, and
    with the other flavour only by ``./scripts/test -m extended`` (the flavours' own
    ways -- modes, failsafes, fences -- are flown with both in every run)."""
    return [pytest.param(f, id=str(f), marks=() if f is suite else pytest.mark.extended)
            for f in (Flavour.ARDUPILOT, Flavour.PX4)]


@cache
def quick_plan() -> Plan:
    """The bundled 9-drone quick show, planned once per test process."""
    from groundctl.plan.planner import plan_show
    from groundctl.show.loader import load_show

    result = plan_show(load_show(QUICK_SHOW), workers=1)
    assert result.verification.safe
    return result.plan


def dry_run(record_dir: Path | None = None, *, during: During | None = None,
            customise: Callable[[SimConfig], SimConfig] | None = None,
            runner: RunnerConfig | None = None, plan: Plan | None = None,
            **options: Any) -> DryRunResult:
    """Fly the quick show (or ``plan``) through the dry-run with :data:`FAST` settings."""
    opts = DryRunOptions(**{**FAST, **options, "record_dir": record_dir,
                            "runner": runner or RunnerConfig()})
    return asyncio.run(fly_dry_run(plan or quick_plan(), opts, customise=customise,
                                   during=during))


async def until(runner: ShowRunner, condition: Callable[[], bool],
                timeout_s: float = 120.0) -> None:
    """Wait (in simulated seconds) until ``condition()`` holds."""
    deadline = runner.clock.now() + timeout_s
    while not condition():
        if runner.clock.now() > deadline:
            raise AssertionError("condition not reached in time")
        await asyncio.sleep(0.01)


def show_time(runner: ShowRunner) -> float:
    """The show clock (-1 until the show starts, so that ``> 0.0`` waits for it)."""
    seq = runner.sequence
    if seq is None or seq.started_at is None:
        return -1.0
    return seq.show_time(runner.clock.now())


def vehicle(report: dict[str, Any], sysid: int) -> dict[str, Any]:
    """The report's entry for vehicle ``sysid``."""
    return next(v for v in report["vehicles"] if v["system_id"] == sysid)
