"""The flight report of a real dry-run cut short: formations never flown, and the
command counts matching the event log one for one.

One dry-run of the quick show (about 15 s of wall time), landed by the operator
3 s into the show, before its first formation.
"""

from __future__ import annotations

from pathlib import Path

from flight_fixtures import dry_run, quick_plan, show_time, until

from groundctl.flight.report import render_report
from groundctl.flight.runner import ShowRunner
from groundctl.record.events import read_events
from groundctl.sim.process import SimProcess


def test_formations_never_flown_and_every_refusal_counted(tmp_path: Path) -> None:
    async def land_early(runner: ShowRunner, sim: SimProcess) -> None:
        await until(runner, lambda: show_time(runner) > 3.0)
        runner.land_all()

    result = dry_run(tmp_path, during=land_early)
    report = result.report
    assert result.error is None, report["unsafe_reasons"]
    assert report["landed"]

    plan = quick_plan()
    unflown = [w.index for w in plan.formations if w.arrive > 3.0]
    assert unflown == [1, 2, 3]  # land-all at 3 s: the show reached none of them
    for f in report["pattern_error_m"]:
        if f["index"] in unflown:
            assert f["flown"] is False, f
            assert f["max_m"] is None and f["mean_m"] is None, f
        else:
            assert f["flown"] is True and f["max_m"] is not None, f
    text = render_report(report)
    assert "formation 1 ring: not flown" in text
    assert "pattern error max 0.0" not in text

    events = read_events(tmp_path / "events.jsonl")
    refused = sum(e["event"] == "command_refused" for e in events)
    timed_out = sum(e["event"] == "command_timeout" for e in events)
    assert report["commands_refused"] == refused
    assert report["commands_timed_out"] == timed_out
    # A vehicle's own count is its show-sequence commands not done (refused or unanswered).
    assert sum(v["commands_refused"] for v in report["vehicles"]) <= refused + timed_out
    for key in ("safe", "vehicles", "min_separation_m", "max_tracking_error_m", "landed",
                "pattern_error_m", "led_timing_error_s", "setpoint_lateness_ms", "link"):
        assert key in report
