"""The operator console, headless (``App.run_test``), with real peers.

The flights are real quick-show dry-runs over loopback UDP against the built-in
simulator (four times real time), driven through the console's keys and command
line; the 200-row test renders a fabricated 200-vehicle fleet (no network).
Each main view is saved as an SVG screenshot under ``artifacts/console/`` (not
committed; ``GROUNDCTL_ARTIFACTS`` moves it).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
from console_fixtures import fabricated_runner, grid_plan, refresh_preflight, screenshot_dir
from flight_fixtures import FAST, quick_plan, show_time, until
from textual.events import Key
from textual.pilot import Pilot
from textual.widgets import DataTable

from groundctl.commands.console_mode import console_config
from groundctl.commands.flying import Interrupts
from groundctl.console.app import MAX_SHARE, REFRESH_HZ, ConsoleApp
from groundctl.console.session import ConsoleSession
from groundctl.console.table import FleetTable
from groundctl.errors import NoGo
from groundctl.execute.preflight import remaining_plan_conflicts
from groundctl.execute.sequence import VehiclePhase
from groundctl.flight.dryrun import DryRunOptions, DryRunResult, fly_dry_run
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.record.events import read_events

SIZE = (200, 50)
Script = Callable[[Pilot[None], ConsoleSession, ShowRunner, Interrupts], Awaitable[None]]


def shot(app: ConsoleApp, name: str) -> Path:
    """Save the screen as ``artifacts/console/NAME.svg``."""
    path = screenshot_dir() / f"{name}.svg"
    app.save_screenshot(path.name, path=str(path.parent))
    return path


def console_flight(record: Path, script: Script) -> tuple[DryRunResult, Interrupts]:
    """The quick show's dry-run with the console; ``script`` drives it meanwhile."""

    async def main() -> tuple[DryRunResult, Interrupts]:
        plan = quick_plan()
        interrupts = Interrupts(lambda text: None)
        session = ConsoleSession(interrupts.stop, show=plan.show_name,
                                 duration_s=plan.duration,
                                 separation_limit_m=plan.limits.min_separation, linger_s=0.0)
        runners: list[ShowRunner] = []

        def on_runner(runner: ShowRunner) -> None:
            runners.append(runner)
            interrupts.attach(runner)
            session.attach(runner)

        # x4, not the x8 of the other flights: the scripts press keys and pause on the
        # wall clock, and at x8 the show could end between two key presses.
        options = DryRunOptions(**{**FAST, "speed": 4.0}, record_dir=record,
                                runner=console_config(RunnerConfig()))
        async with session.app.run_test(size=SIZE) as pilot:
            interrupts.install()
            flight = asyncio.create_task(fly_dry_run(plan, options, notify=session.notify,
                                                     on_runner=on_runner))
            while not runners:
                await asyncio.sleep(0.01)
            try:
                await asyncio.wait_for(script(pilot, session, runners[0], interrupts), 120)
                result = await asyncio.wait_for(flight, 120)
            finally:
                interrupts.uninstall()
                flight.cancel()
            session.app.flight_over("test over")
            await pilot.pause(0.1)
        return result, interrupts

    return asyncio.run(main())


#: The characters of the named keys the scripts press (a single character is itself).
_CHARACTERS = {"enter": "\r", "colon": ":", "space": " ", "escape": "\x1b", "tab": "\t"}


async def keys(pilot: Pilot[None], *pressed: str) -> None:
    """Press ``pressed`` in turn, each handled by the screen before the next.

    Not ``pilot.press``: after every key it waits for the *process* to go idle
    (Textual's ``wait_for_idle``, up to a second, twice), and a process flying a show
    never is: every key took 2 s of wall time while the flight went on at x4, eight
    simulated seconds of both fleets' CPU a key.  The key goes to the app as the driver
    sends it; the screen is waited for twice (the app hands a key on to the focused
    widget, whose queue the first wait may have passed)."""
    for key in pressed:
        pilot.app.post_message(Key(key, _CHARACTERS.get(key, key if len(key) == 1 else None)))
        await pilot.pause(0)
        await pilot.pause(0)
    await pilot.pause(0.05)


def test_quick_show_flown_through_the_console_to_the_end(tmp_path: Path) -> None:
    """Nothing arms before the go; hold, resume, land selected, land all (confirmed) reach
    the runner; the flight ends safe and every operator action is in events.jsonl."""
    seen: dict[str, object] = {}

    async def script(pilot: Pilot[None], session: ConsoleSession, runner: ShowRunner,
                     _: Interrupts) -> None:
        gate = session.gate
        assert gate is not None
        await until(runner, lambda: gate.waiting, 60.0)
        await asyncio.sleep(0.5)  # half a second of waiting: still nothing armed
        assert runner.sequence is None and gate.waiting
        await pilot.pause(0.3)
        checks = pilot.app.query_one("#checks", DataTable)
        assert checks.row_count == 9
        seen["preflight"] = shot(session.app, "preflight")
        await keys(pilot, "g")
        assert session.controller.question is not None
        await keys(pilot, "n", "enter")  # not yet
        assert gate.waiting and runner.sequence is None
        await keys(pilot, "g")
        await keys(pilot, "y", "enter")
        await until(runner, lambda: show_time(runner) > 4.0, 90.0)
        fleet = pilot.app.query_one("#fleet", FleetTable)
        assert fleet.row_count == 9
        seen["fleet"] = shot(session.app, "fleet")
        seq = runner.sequence
        assert seq is not None
        await keys(pilot, "h")
        assert "operator" in seq.holds
        await until(runner, lambda: seq.clock.stopped(runner.clock.now()), 20.0)
        await pilot.pause(0.3)
        seen["holding"] = shot(session.app, "holding")
        fleet.focus()  # while held (a key press may take a second in a busy process)
        fleet.move_cursor(8)  # sysid order: vehicle 9
        assert fleet.selected == 9
        await keys(pilot, "l")
        v9 = seq.vehicles[9]  # leaving at its next formation instant, or landing now
        assert v9.leave_at is not None or v9.phase is not VehiclePhase.SHOW
        await keys(pilot, "f")  # the log of vehicle 9 only
        await pilot.pause(0.3)
        seen["vehicle_log"] = shot(session.app, "vehicle-log")
        await keys(pilot, "f", "r")
        assert "operator" not in seq.holds
        await keys(pilot, "a")
        assert session.controller.question is not None
        await keys(pilot, "y", "enter")
        assert seq.ended

    result, _ = console_flight(tmp_path / "rec", script)
    assert result.error is None, result.error
    assert result.report["safe"], result.report["unsafe_reasons"]
    events = read_events(tmp_path / "rec" / "events.jsonl")
    operator = [e["command"] for e in events if e["event"] == "operator"]
    assert operator[:2] == ["go", "hold"] and "resume" in operator
    assert "land 9" in operator and operator[-1] == "land all"
    steps = {(e["action"], e["step"]) for e in events if e["event"] == "console"}
    assert {("go", "asked"), ("go", "cancelled"), ("go", "confirmed"), ("land-all", "asked"),
            ("land-all", "confirmed"), ("hold", "done"), ("land 9", "done")} <= steps
    for path in seen.values():
        assert isinstance(path, Path) and path.stat().st_size > 10_000


def test_kill_needs_the_system_id_and_quit_lands_everyone_like_ctrl_c(tmp_path: Path) -> None:
    async def script(pilot: Pilot[None], session: ConsoleSession, runner: ShowRunner,
                     _: Interrupts) -> None:
        await until(runner, lambda: session.gate is not None and session.gate.waiting, 60.0)
        await keys(pilot, "colon")
        for ch in "go":
            await keys(pilot, ch)
        await keys(pilot, "enter", "y", "enter")
        await until(runner, lambda: runner.sequence is not None
                    and runner.sequence.started_at is not None, 60.0)
        seq = runner.sequence
        assert seq is not None
        await keys(pilot, "h")  # held: the show cannot end while the keys are pressed
        assert "operator" in seq.holds
        await pilot.pause(0.3)
        fleet = pilot.app.query_one("#fleet", FleetTable)
        fleet.focus()
        fleet.move_cursor(0)
        await keys(pilot, "k")
        await keys(pilot, "2", "enter")  # not its id: cancelled
        assert seq.vehicles[1].phase is not VehiclePhase.KILLED
        await keys(pilot, "k", "1", "enter")
        assert seq.vehicles[1].phase is VehiclePhase.KILLED
        await keys(pilot, "q")
        assert session.controller.question is not None
        await keys(pilot, "y", "enter")
        assert seq.ended

    result, interrupts = console_flight(tmp_path / "rec", script)
    assert interrupts.aborted and interrupts.presses == 1
    assert result.error is None and result.flown
    phases = {v["system_id"]: v["phase"] for v in result.report["vehicles"]}
    assert phases[1] == "killed" and all(p == "landed" for s, p in phases.items() if s != 1)
    events = read_events(tmp_path / "rec" / "events.jsonl")
    assert any(e["event"] == "signal" and e["signal"] == "quit (console)" for e in events), \
        [e for e in events if e["event"] in ("signal", "operator", "console")][-6:]
    steps = [(e["action"], e["step"]) for e in events if e["event"] == "console"]
    assert ("kill", "cancelled") in steps and ("kill", "confirmed") in steps
    assert [e["command"] for e in events if e["event"] == "operator"][-3:] == \
        ["hold", "kill 1", "land all"]


def test_exclude_in_preflight_and_quit_before_arming_is_a_no_go(tmp_path: Path) -> None:
    """The exclusion safety check applies: a vehicle whose slot another lands on is
    refused, one that leaves the show safe is excluded; quit before arming is a no-go."""
    plan = quick_plan()
    safe = [t for t in range(plan.drones) if not remaining_plan_conflicts(plan, {t})]
    unsafe = [t for t in range(plan.drones) if t not in safe]
    assert safe and unsafe
    picked: dict[str, int] = {}

    async def exclude(pilot: Pilot[None], runner: ShowRunner, track: int) -> int:
        assert runner.assignment is not None
        sysid = next(s for s, t in runner.assignment.tracks.items() if t == track)
        checks = pilot.app.query_one("#checks", DataTable)
        checks.focus()
        checks.move_cursor(row=sysid - 1)  # sysid order
        await keys(pilot, "x")
        return sysid

    async def script(pilot: Pilot[None], session: ConsoleSession, runner: ShowRunner,
                     _: Interrupts) -> None:
        await until(runner, lambda: runner.assignment is not None
                    and len(runner.assignment.tracks) == plan.drones, 60.0)
        await pilot.pause(0.3)
        refused = await exclude(pilot, runner, unsafe[0])
        assert refused not in runner.config.excluded
        assert "the rest of the show would be unsafe" in session.feed.lines()[-1].text
        picked["excluded"] = await exclude(pilot, runner, safe[0])
        assert picked["excluded"] in runner.config.excluded
        await until(runner, lambda: session.gate is not None and session.gate.waiting, 60.0)
        await pilot.pause(0.3)
        shot(session.app, "preflight-excluded")
        await keys(pilot, "q", "y", "enter")

    result, _ = console_flight(tmp_path / "rec", script)
    assert isinstance(result.error, NoGo) and not result.flown
    events = read_events(tmp_path / "rec" / "events.jsonl")
    operator = [e["command"] for e in events if e["event"] == "operator"]
    assert operator == [f"exclude {picked['excluded']}", "no-go"]


def test_refreshes_that_cost_more_than_their_share_are_spaced_out() -> None:
    """A refresh costs the control loop's interpreter its time: past MAX_SHARE of the
    period (a view of thousands of rows), the refreshes come less often, and as often as
    before once they are cheap again."""
    session = ConsoleSession(lambda label: None, linger_s=0.0)
    app = session.app
    assert app.refresh_interval == pytest.approx(1.0 / REFRESH_HZ)
    app.refresh_s.extend([0.004, 0.006])  # within 5 % of 200 ms
    assert app.refresh_interval == pytest.approx(1.0 / REFRESH_HZ)
    app.refresh_s.append(0.030)  # 30 ms: at most every 0.6 s
    assert app.refresh_interval == pytest.approx(0.030 / MAX_SHARE)
    app.refresh_s.extend([0.005, 0.005])  # one slow refresh among the last three counts
    assert app.refresh_interval == pytest.approx(0.030 / MAX_SHARE)
    app.refresh_s.append(0.005)
    assert app.refresh_interval == pytest.approx(1.0 / REFRESH_HZ)


def test_fleet_table_of_200_vehicles_updates_in_place_and_bad_input_is_reported() -> None:
    plan = grid_plan(200)
    runner = fabricated_runner(plan)
    session = ConsoleSession(lambda label: None, linger_s=0.0)
    session.attach(runner)

    async def main() -> None:
        app = session.app
        async with app.run_test(size=SIZE) as pilot:
            await keys(pilot, "v")  # the fleet view
            await pilot.pause(0.2)
            fleet = app.query_one("#fleet", FleetTable)
            assert fleet.row_count == 200
            order = fleet.order
            runner.link.vehicles[150].battery_remaining_pct = 12.0
            runner.link.vehicles[7].gps_fix_type = 1
            refresh_preflight(runner, 100.0)
            app.refresh_view()
            assert fleet.cell(150, "battery") == "12%"
            assert fleet.order == order
            assert "failed: battery" in fleet.cell(150, "alarm")
            runner.link.vehicles[33].battery_remaining_pct = 80.0
            assert fleet.set_rows(app.model.view(app.model.now()).rows) == 1  # one row rebuilt
            await pilot.pause(0.1)
            # Only the rows on the screen are drawn: vehicle 150's changed row waits until
            # it is scrolled into view (at 1,000 vehicles every row changes every refresh).
            assert fleet.cell(150, "battery") == "12%" and 150 not in fleet._strips
            assert 0 < len(fleet._strips) <= SIZE[1]
            await keys(pilot, "p")  # problems only
            assert sorted(fleet.order) == [7, 150]
            await keys(pilot, "p", "s")  # everyone again, sorted by problems first
            assert fleet.row_count == 200
            assert fleet.order[:2] == [150, 7]
            shot(app, "fleet-200")
            await keys(pilot, "colon")
            for ch in "fly away":
                await keys(pilot, "space" if ch == " " else ch)
            await keys(pilot, "enter")
            await keys(pilot, "colon", "k", "i", "l", "l", "space", "x", "enter")
            await pilot.pause(0.3)
            texts = [e.text for e in session.feed.lines()]
            assert any(t.startswith("unknown command 'fly'") for t in texts)
            assert "kill: 'x' is not a system id (1-255)" in texts
            assert app.is_running and app.refreshes > 0

    asyncio.run(main())
