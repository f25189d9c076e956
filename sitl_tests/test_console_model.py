"""The console's pure parts without a terminal: view model, controller, event feed, and the
plain mode's fleet-wide pre-flight lines."""

from __future__ import annotations

import time
from typing import Any

import pytest
from console_fixtures import fabricated_runner, grid_plan, ready_state, refresh_preflight

from groundctl.clock import ScaledClock
from groundctl.console.app import header_text
from groundctl.console.commands import Controller, GoGate
from groundctl.console.feed import EventFeed
from groundctl.console.model import ConsoleModel
from groundctl.errors import FlightError
from groundctl.flight.runner import RunnerConfig, ShowRunner
from groundctl.link.fleet import FleetLink

NOW = 100.0


class Sink:
    """Records what is emitted (the recording's stand-in)."""

    def __init__(self) -> None:
        self.events: list[tuple[str, dict[str, Any]]] = []

    def emit(self, event: str, /, **fields: Any) -> None:
        self.events.append((event, fields))


class Target:
    """A console target that records the calls it gets (a runner's operator methods)."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []
        self.sequence: object | None = object()  # armed

    def hold(self) -> None:
        self.calls.append(("hold",))

    def resume(self) -> None:
        self.calls.append(("resume",))

    def land_all(self) -> None:
        self.calls.append(("land_all",))

    def land_one(self, sysid: int) -> None:
        self.calls.append(("land_one", sysid))

    def land_here(self, sysid: int) -> None:
        self.calls.append(("land_here", sysid))

    def replace(self, sysid: int) -> None:
        self.calls.append(("replace", sysid))

    def kill(self, sysid: int, confirm: bool = False) -> None:
        self.calls.append(("kill", sysid, confirm))

    def exclude(self, sysid: int) -> None:
        raise FlightError(f"exclude {sysid}: the show is already armed; land it instead")

    def status_line(self) -> str:
        return "show t=1.0/30 s"


def controller() -> tuple[Controller, Target, EventFeed, Sink, list[str]]:
    sink = Sink()
    feed = EventFeed(sink)
    stops: list[str] = []
    c = Controller(feed, stops.append, GoGate())
    target = Target()
    c.target = target
    return c, target, feed, sink, stops


def said(feed: EventFeed) -> list[str]:
    return [e.text for e in feed.lines()]


def test_preflight_view_has_every_check_of_every_vehicle_and_a_go_line() -> None:
    plan = grid_plan(9)
    runner = fabricated_runner(plan)
    runner.link.vehicles[4].battery_remaining_pct = 35.0   # cannot be fixed by waiting
    runner.link.vehicles[7].gps_fix_type = 1               # may come by waiting
    runner.link.vehicles[8].gps_fix_type = None
    refresh_preflight(runner, NOW)
    model = ConsoleModel()
    model.attach(runner)
    view = model.view(NOW, selected=4)
    pre = view.preflight
    assert pre is not None
    assert pre.checks == ("heartbeat", "gps", "position", "battery", "slot", "link", "wind",
                          "autopilot")
    assert len(pre.rows) == 9 and all(len(r.cells) == 8 for r in pre.rows)
    cells = {r.sysid: {c.name: c for c in r.cells} for r in pre.rows}
    assert cells[4]["battery"].state == "fail"
    assert cells[4]["battery"].detail == "35 % (minimum 60 %)"
    assert cells[7]["gps"].state == "wait" and cells[8]["gps"].state == "wait"
    assert cells[1]["gps"].state == "pass"
    statuses = {r.sysid: r.status for r in pre.rows}
    assert statuses[4] == "failed" and statuses[7] == "waiting" and statuses[1] == "ready"
    assert not pre.go
    assert pre.go_line == "NO-GO: 6/9 ready, waiting for 3: battery (4), gps (7, 8)"
    assert view.header.phase == "pre-flight"
    assert view.detail is not None and "check battery: 35 % (minimum 60 %)" in view.detail.lines
    row4 = next(r for r in view.rows if r.sysid == 4)
    assert row4.severity == "bad" and row4.alarm == "failed: battery"


def test_the_preflight_grid_is_built_once_per_report_and_again_when_it_changes() -> None:
    """1,000 vehicles' checks are ten thousand cells: built when a pre-flight pass gives a
    new report (or the exclusions change), not on every refresh."""
    plan = grid_plan(9)
    runner = fabricated_runner(plan)
    model = ConsoleModel()
    model.attach(runner)
    first = model.view(NOW).preflight
    again = model.view(NOW).preflight
    assert first is not None and again is not None
    assert again.rows is first.rows  # the same report: the same grid
    runner.link.vehicles[4].battery_remaining_pct = 35.0
    assert model.view(NOW).preflight.rows is first.rows  # type: ignore[union-attr]
    refresh_preflight(runner, NOW)  # the next pass sees it
    after = model.view(NOW).preflight
    assert after is not None and after.rows is not first.rows
    assert next(r for r in after.rows if r.sysid == 4).status == "failed"
    runner.exclude(4)
    excluded = model.view(NOW).preflight
    assert excluded is not None
    assert next(r for r in excluded.rows if r.sysid == 4).status == "excluded"
    assert excluded.go


def test_go_line_once_every_vehicle_passes_and_exclusion_counts() -> None:
    plan = grid_plan(9)
    runner = fabricated_runner(plan)
    runner.awaiting_go = True
    model = ConsoleModel()
    model.attach(runner)
    pre = model.view(NOW).preflight
    assert pre is not None and pre.go
    assert pre.go_line == "GO: 9/9 ready; press g to arm and fly"
    runner.link.vehicles[5].battery_remaining_pct = 10.0
    refresh_preflight(runner, NOW)
    runner.exclude(5)  # a corner of a 3 x 3 grid on the ground: clear of the others
    pre = model.view(NOW).preflight
    assert pre is not None and pre.go
    assert pre.go_line.startswith("GO: 8/8 ready (1 excluded)")
    row5 = next(r for r in model.view(NOW).rows if r.sysid == 5)
    assert row5.phase == "excluded" and row5.severity == "off"
    with pytest.raises(FlightError, match="already excluded"):
        runner.exclude(5)
    with pytest.raises(FlightError, match="not a vehicle of this show"):
        runner.exclude(77)


def test_header_before_the_runner_and_the_link_summary() -> None:
    model = ConsoleModel("quick", 33.0, 1.5)
    view = model.view(0.0)
    assert view.header.phase == "connecting" and view.rows == () and view.preflight is None
    plan = grid_plan(4)
    runner = fabricated_runner(plan, n=3)  # one of four never heard
    model.attach(runner)
    view = model.view(NOW)
    assert view.header.link.startswith("3/4 heard")
    assert view.header.link_severity == "warn"
    assert [r.sysid for r in view.rows] == [1, 2, 3, 4]
    unheard = view.rows[3]
    assert unheard.phase == "unheard" and unheard.alarm == "not heard"
    assert view.header.next_formation == "line" and view.header.show_time_s is None
    cells = view.rows[0].cells()
    assert cells["battery"] == "95%" and cells["gps"] == "3D/14" and cells["rtt"] == "4"


def test_the_header_has_one_link_summary_per_network() -> None:
    plan = grid_plan(6)
    ids = [1, 2, 3, 1001, 1002, 1003]  # 1-3 and 2:1-2:3
    clock = ScaledClock(1.0, epoch=time.monotonic() - NOW)
    link = FleetLink([("127.0.0.1", 0), ("127.0.0.1", 0)], clock=clock, expected_ids=ids)
    runner = ShowRunner(plan, link, clock, RunnerConfig(), expected_ids=ids)
    for k, vid in enumerate(ids[:-1]):  # 2:3 never heard
        link.vehicles[vid] = ready_state(vid, plan, k, NOW)
    link.vehicles[1002].lost = True
    link.silence_ids = set(ids)
    model = ConsoleModel()
    model.attach(runner)
    header = model.view(NOW).header
    assert header.link.startswith("5/6 heard, 1 lost")
    rest = ", loss 0.0% (max 0%), RTT max 4 ms"
    assert header.networks == (("net 1: 3/3 heard" + rest, "ok"),
                               ("net 2: 2/3 heard, 1 lost" + rest, "bad"))
    for vid in (1001, 1002):  # network 2 quiet for 12 s
        link.vehicles[vid].last_heard = NOW - 12.0
    later = model.view(NOW).header.networks
    assert later[0] == ("net 1: 3/3 heard" + rest, "ok")
    assert later[1][0].startswith("net 2: SILENT 12 s; 0/3 heard") and later[1][1] == "bad"
    text = header_text(model.view(NOW).header).plain
    assert text.splitlines()[-2:] == ["  net 1: 3/3 heard" + rest, "  " + later[1][0]]
    # A third network the show does not use (a fleet file's spare link): no line for it.
    link3 = FleetLink([("127.0.0.1", 0)] * 3, clock=clock, expected_ids=ids)
    runner3 = ShowRunner(plan, link3, clock, RunnerConfig(), expected_ids=ids)
    for k, vid in enumerate(ids):
        link3.vehicles[vid] = ready_state(vid, plan, k, NOW)
    link3.silence_ids = set(ids)
    three = ConsoleModel()
    three.attach(runner3)
    assert [t for t, _ in three.view(NOW).header.networks] == [
        "net 1: 3/3 heard" + rest, "net 2: 3/3 heard" + rest]
    # One network: no per-network lines.
    assert fabricated_runner(grid_plan(3)) and ConsoleModel().view(NOW).header.networks == ()


def test_replace_from_the_key_and_the_command_line() -> None:
    """Issue 29: `e` replaces the selected vehicle, `replace SYSID` the one named; without
    a vehicle it says how, and a bad id is one line."""
    c, target, feed, _, _ = controller()
    c.replace(7)  # the key, vehicle 7 selected
    c.line("replace 2:4")
    assert target.calls == [("replace", 7), ("replace", 1004)]
    c.replace(None)
    assert said(feed)[-1].startswith("replace: select a vehicle")
    c.line("replace")
    assert said(feed)[-1].startswith("replace needs a system id")
    c.line("replace x")
    assert said(feed)[-1].startswith("replace: 'x' is not a system id")
    assert len(target.calls) == 2


def test_controller_confirms_land_all_and_kill_and_reports_bad_input() -> None:
    c, target, feed, sink, _ = controller()
    c.line("hold")
    c.line("resume")
    assert target.calls == [("hold",), ("resume",)]
    c.land_all()
    assert c.question is not None and target.calls[-1] == ("resume",)
    c.line("n")
    assert ("land_all",) not in target.calls and "land-all: cancelled" in said(feed)
    c.line("land")
    c.line("y")
    assert target.calls[-1] == ("land_all",)
    c.kill(12)
    c.line("13")  # the wrong id cancels
    assert not any(call[0] == "kill" for call in target.calls)
    assert "kill 12: cancelled (typed '13', not 12)" in said(feed)
    c.line("kill 12")
    c.line("12")
    assert target.calls[-1] == ("kill", 12, True)
    c.land_one(None)
    assert said(feed)[-1].startswith("land: select a vehicle")
    for bad, message in [("fly away", "unknown command 'fly'"),
                         ("land-here", "land-here needs a system id"),
                         ("kill abc", "kill: 'abc' is not a system id (1-255)"),
                         ("land 300", "land: '300' is not a system id (1-255)"),
                         ("hold now", "hold: too many arguments 'now'")]:
        c.line(bad)
        assert said(feed)[-1].startswith(message), (bad, said(feed)[-1])
    c.line("exclude 3")  # the runner refuses: said, not raised
    assert said(feed)[-1] == "exclude 3: the show is already armed; land it instead"
    steps = [(f["action"], f["step"]) for e, f in sink.events if e == "console"]
    assert ("land-all", "cancelled") in steps and ("kill", "confirmed") in steps
    assert ("fly", "bad_input") in steps and ("exclude 3", "refused") in steps


def test_quit_asks_then_stops_like_ctrl_c_and_go_answers_the_gate() -> None:
    import asyncio

    c, _, feed, _, stops = controller()
    c.quit()
    assert c.question is not None and "land every vehicle first" in c.question.prompt
    c.line("no")
    assert stops == []
    c.quit()
    c.line("y")
    assert stops == ["quit (console)"]
    c.quit()
    assert c.question is not None and "ABANDON" in c.question.prompt
    c.cancel()

    async def gate() -> bool:
        assert c.gate is not None
        waiting = asyncio.ensure_future(c.gate(None))  # type: ignore[arg-type]
        await asyncio.sleep(0)
        c.go()
        c.line("y")
        return await waiting

    c.go()
    assert said(feed)[-1] == "go: not waiting for a go"
    assert asyncio.run(gate()) is True


def test_feed_passes_every_event_on_and_splits_fleet_and_vehicle_lines() -> None:
    sink = Sink()
    feed = EventFeed(sink)
    feed.emit("mode_changed", system_id=3, mode="GUIDED")
    feed.emit("sequence", text="vehicle 3 landed", system_id=3, kind="landed")
    feed.notice("8 vehicles (2-9): landed")
    feed.emit("vehicle_lost", system_id=5, silent_for_s=3.1)
    feed.emit("preflight", lines=["vehicle 1: ready"])
    feed.emit("link_started", address="127.0.0.1:1")
    assert [e for e, _ in sink.events] == ["mode_changed", "sequence", "vehicle_lost",
                                          "preflight", "link_started"]
    assert [e.text for e in feed.lines()] == ["8 vehicles (2-9): landed",
                                              "vehicle lost: silent_for_s=3.1"]
    assert [e.text for e in feed.lines(3)] == ["mode changed: mode=GUIDED",
                                               "vehicle 3 landed"]
    assert [e.text for e in feed.lines(after=feed.last_seq - 1)] == \
        ["vehicle lost: silent_for_s=3.1"]


def test_plain_preflight_refusal_is_one_line_per_check_not_per_vehicle() -> None:
    plan = grid_plan(64)
    runner = fabricated_runner(plan)
    for sysid in (12, 40):
        runner.link.vehicles[sysid].gps_fix_type = None
    for sysid in range(20, 30):
        runner.link.vehicles[sysid].battery_remaining_pct = 30.0 + sysid
    refresh_preflight(runner, NOW)
    report = runner.preflight_report
    assert report is not None
    assert report.summary() == "52/64 ready, waiting for 12: gps (12, 40), battery (20-29)"
    lines = report.failing_by_check()
    assert lines == ["  gps: no GPS_RAW_INT yet (12, 40)",
                     "  battery: 50 % (minimum 60 %) (20); 51 % (minimum 60 %) (21); "
                     "52 % (minimum 60 %) (22); 53 % (minimum 60 %) (23); and 6 more vehicles"]
