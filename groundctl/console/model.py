"""The console's view model: plain dataclasses computed from the runner's state.

No Textual here, and no clock of its own: :meth:`ConsoleModel.view` takes the
time and reads the runner's public state (its sequence, the link's vehicle
states, the monitor, the pre-flight report, its records); the widgets of
:mod:`groundctl.console.app` only render what it returns.  Unit-testable
without a terminal, and the same numbers the plain mode prints.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from groundctl.execute.mapping import Assignment
from groundctl.execute.preflight import PreflightReport
from groundctl.execute.sequence import ShowPhase, VehiclePhase, VehicleRun
from groundctl.flight.monitor import nearest_pair
from groundctl.flight.runner import PERMANENT_CHECKS, ShowRunner
from groundctl.link.state import VehicleState
from groundctl.plan.plan import Plan
from groundctl.vehicleid import network_index

Severity = Literal["ok", "warn", "bad", "off"]
"""How a row (or a header figure) is coloured: fine, needs a look, act now, not flying."""
CheckState = Literal["pass", "fail", "wait"]
"""A pre-flight check: passed, failed in a way waiting cannot fix, or not yet."""

#: Phases in which a vehicle is (or may be) in the air.
AIRBORNE = frozenset({VehiclePhase.TAKEOFF, VehiclePhase.READY, VehiclePhase.JOINING,
                      VehiclePhase.SHOW,
                      VehiclePhase.LEAVING, VehiclePhase.RETURNING, VehiclePhase.LANDING,
                      VehiclePhase.LOST})
#: A drone this far off its path is held for by the guard (GuardConfig), m.
FAR_OFF_M = 2.0
#: Link loss above this is worth a look, fraction.
LOSSY = 0.05
#: Fleet table columns: key, title, width (fixed: cells are updated in place).
COLUMNS: tuple[tuple[str, str, int], ...] = (
    ("sysid", "id", 4), ("track", "trk", 4), ("phase", "phase", 9), ("mode", "mode", 10),
    ("armed", "arm", 5), ("battery", "batt", 5), ("gps", "gps/rtk age", 12), ("loss", "loss", 6),
    ("rtt", "rtt", 4), ("error", "err m", 6), ("max_error", "max m", 6), ("led", "led", 4),
    ("alarm", "alarm", 48))
#: Sort orders of the fleet table (``s`` cycles through them).
SORTS: tuple[str, ...] = ("sysid", "problems", "error", "battery", "phase")


@dataclass(frozen=True)
class Header:
    """The top lines: where the show is."""

    show: str
    """Show name."""
    phase: str
    """connecting / pre-flight / armed / show / holding / landing / done."""
    detail: str
    """What the phase waits for, or why it holds ("" if nothing)."""
    show_time_s: float | None
    """The show clock, s (None before the show starts)."""
    duration_s: float
    """The show's length, s."""
    formation: str
    """The formation flown now ("" if none): its name, or "-> name" while flying into it."""
    next_formation: str
    """The next formation ("" if none)."""
    next_in_s: float | None
    """Show seconds until the next formation is reached."""
    worst_error_m: float | None
    """Largest tracking error now (against each vehicle's path), m."""
    worst_error_sysid: int | None
    """Whose it is."""
    min_separation_m: float | None
    """Closest pair of airborne vehicles now, m."""
    min_separation_pair: tuple[int, int] | None
    """That pair."""
    separation_limit_m: float
    """The show's minimum separation, m."""
    link: str
    """Link summary: heard, lost, loss, RTT."""
    link_severity: Severity
    """Colour of the link summary."""
    cue: str = ""
    """The show's cues on its clock (an imported Skybrush show's): the last one passed and
    the next with the seconds to it ("" when the show has none)."""
    networks: tuple[tuple[str, Severity], ...] = ()
    """With several MAVLink networks, one summary per network (its name, heard, lost,
    loss, RTT, how long it has been silent) and its colour; empty with one network."""

    @property
    def progress(self) -> float:
        """Show time over the show's length, 0..1."""
        if self.show_time_s is None or self.duration_s <= 0:
            return 0.0
        return min(max(self.show_time_s / self.duration_s, 0.0), 1.0)

    @property
    def separation_severity(self) -> Severity:
        """Bad within 0.1 m of the limit (where the guard holds), warning within 0.5 m."""
        d = self.min_separation_m
        if d is None:
            return "ok"
        if d < self.separation_limit_m + 0.1:
            return "bad"
        return "warn" if d < self.separation_limit_m + 0.5 else "ok"


@dataclass(frozen=True)
class VehicleRow:
    """One fleet table row."""

    sysid: int
    track: int | None
    phase: str
    mode: str
    armed: bool
    battery_pct: float | None
    gps_fix: int | None
    satellites: int | None
    loss_ratio: float | None
    rtt_ms: float | None
    error_m: float | None
    """Tracking error now (against its path), m."""
    max_error_m: float | None
    """Largest tracking error in the show so far, m."""
    led: tuple[int, int, int] | None
    """The colour it is told to show now."""
    alarm: str
    """What is wrong ("" if nothing)."""
    severity: Severity
    rtk_age_s: float | None = None
    """Seconds since RTK corrections last went to it (None: no ``--rtk`` or none yet)."""

    def cells(self) -> dict[str, str]:
        """The row as text, one entry per :data:`COLUMNS` key (the LED as ``#rrggbb``)."""
        def num(x: float | None, fmt: str, unit: str = "") -> str:
            return "-" if x is None else format(x, fmt) + unit
        gps = "-" if self.gps_fix is None else \
            f"{_FIX.get(self.gps_fix, str(self.gps_fix))}/{self.satellites or 0}"
        if self.rtk_age_s is not None:
            gps += f" {min(self.rtk_age_s, 99.0):.0f}s" if self.rtk_age_s >= 10 \
                else f" {self.rtk_age_s:.1f}s"
        return {
            "sysid": str(self.sysid), "track": "-" if self.track is None else str(self.track),
            "phase": self.phase, "mode": self.mode, "armed": "ARMED" if self.armed else "-",
            "battery": num(self.battery_pct, ".0f", "%"), "gps": gps,
            "loss": num(None if self.loss_ratio is None else self.loss_ratio * 100, ".1f", "%"),
            "rtt": num(self.rtt_ms, ".0f"), "error": num(self.error_m, ".2f"),
            "max_error": num(self.max_error_m, ".2f"),
            "led": "" if self.led is None else "#{:02x}{:02x}{:02x}".format(*self.led),
            "alarm": self.alarm,
        }

    def sort_key(self, order: str) -> tuple[float, ...]:
        """The row's place in ``order`` (one of :data:`SORTS`)."""
        rank = {"bad": 0, "warn": 1, "ok": 2, "off": 3}[self.severity]
        if order == "problems":
            return (rank, self.sysid)
        if order == "error":
            return (-(self.error_m or 0.0), self.sysid)
        if order == "battery":
            return (self.battery_pct if self.battery_pct is not None else -1.0, self.sysid)
        if order == "phase":
            return (_PHASE_ORDER.get(self.phase, 99), self.sysid)
        return (self.sysid,)


_FIX = {0: "none", 1: "none", 2: "2D", 3: "3D", 4: "DGPS", 5: "RTKf", 6: "RTK"}
_PHASE_ORDER = {str(p): i for i, p in enumerate(VehiclePhase)}


@dataclass(frozen=True)
class CheckCell:
    """One pre-flight check of one vehicle."""

    name: str
    state: CheckState
    detail: str


@dataclass(frozen=True)
class PreflightRow:
    """One vehicle's pre-flight checks."""

    sysid: int
    track: int | None
    cells: tuple[CheckCell, ...]
    excluded: bool
    status: str
    """``ready``, ``waiting``, ``failed``, ``excluded``."""


@dataclass(frozen=True)
class PreflightView:
    """Every check for every vehicle, and the go / no-go line."""

    checks: tuple[str, ...]
    """Check names, in column order."""
    rows: tuple[PreflightRow, ...]
    go: bool
    """Every vehicle that is not excluded passed: the show may arm."""
    go_line: str
    """``GO: ...`` or ``NO-GO: ...`` with the fleet-wide summary."""
    awaiting_go: bool
    """The runner waits for the operator's go now."""
    ignored: tuple[str, ...]
    """Vehicles heard but not needed by the show, with why."""


@dataclass(frozen=True)
class Detail:
    """The selected vehicle."""

    sysid: int
    lines: tuple[str, ...]


@dataclass(frozen=True)
class ConsoleView:
    """Everything on the screen at one instant."""

    header: Header
    rows: tuple[VehicleRow, ...]
    """Fleet table rows in system id order."""
    preflight: PreflightView | None
    """The pre-flight grid (None until the first checks ran, or not asked for)."""
    detail: Detail | None
    """The selected vehicle (None: none selected)."""
    armed: bool
    """The sequence has started (the fleet view is the main one from then on)."""


class ConsoleModel:
    """Computes :class:`ConsoleView` from a runner (attached once it exists).

    ``show`` and ``duration_s`` name the show before the runner exists;
    :attr:`outcome` is set by whoever runs the flight when it is over.
    """

    def __init__(self, show: str = "", duration_s: float = 0.0,
                 separation_limit_m: float = 0.0) -> None:
        self.runner: ShowRunner | None = None
        self.outcome: str | None = None
        """How the flight ended ("" while it runs)."""
        self._show = show
        self._duration = duration_s
        self._limit = separation_limit_m
        self._grid: _Grid | None = None
        """The last pre-flight grid: 1,000 vehicles' ten checks are built once per
        pre-flight pass, not on every refresh."""

    def attach(self, runner: ShowRunner) -> None:
        """The runner to read from."""
        self.runner = runner
        self._show = runner.plan.show_name
        self._duration = runner.plan.duration
        self._limit = runner.plan.limits.min_separation

    def now(self) -> float:
        """The flight's clock (0 before there is a runner)."""
        return self.runner.clock.now() if self.runner is not None else 0.0

    # -- the view -----------------------------------------------------------------
    def view(self, now: float, selected: int | None = None,
             preflight: bool = True) -> ConsoleView:
        """Everything on the screen at ``now`` (the flight's clock); the pre-flight grid
        only if ``preflight`` (it is not shown)."""
        runner = self.runner
        if runner is None:
            header = Header(self._show, "done" if self.outcome else "connecting",
                            self.outcome or "starting", None, self._duration, "", "", None,
                            None, None, None, None, self._limit, "no link yet", "warn")
            return ConsoleView(header, (), None, None, False)
        errors = self._errors(runner)
        leds = _leds(runner, now)
        rows = tuple(self._row(runner, s, errors.get(s), leds, now)
                     for s in self._sysids(runner))
        header = self._header(runner, now, errors)
        pre = self._preflight(runner) if preflight and runner.preflight_report is not None \
            else None
        detail = self._detail(runner, selected, errors, now) if selected is not None else None
        return ConsoleView(header, rows, pre, detail, runner.sequence is not None)

    @staticmethod
    def _sysids(runner: ShowRunner) -> list[int]:
        ids = set(runner.link.vehicles)
        if runner.expected_ids is not None:
            ids |= set(runner.expected_ids)
        if runner.sequence is not None:
            ids |= set(runner.sequence.vehicles)
        return sorted(ids)

    @staticmethod
    def _errors(runner: ShowRunner) -> dict[int, float]:
        """Each streamed vehicle's distance from where its path puts it (the guard's
        measure), at the last tick."""
        mon, cmd = runner.monitor, runner.commanded_now()
        if mon is None or cmd is None or mon.last_positions is None:
            return {}
        at, wanted = cmd
        t, ids, pos = mon.last_positions
        if t != at:
            return {}
        out = {}
        for k, sysid in enumerate(ids):
            want = wanted.get(sysid)
            if want is not None:
                out[sysid] = float(np.linalg.norm(pos[k] - want))
        return out

    def _phase(self, runner: ShowRunner) -> tuple[str, str]:
        if self.outcome:
            return "done", self.outcome
        seq = runner.sequence
        if seq is None:
            if runner.preflight_report is None:
                return "connecting", f"{len(runner.link.vehicles)} vehicle(s) heard"
            if runner.awaiting_go:
                return "pre-flight", "every check passed: waiting for the operator's go"
            return "pre-flight", "checking"
        phase = seq.phase
        if phase in (ShowPhase.PREFLIGHT, ShowPhase.ARMING, ShowPhase.TAKEOFF):
            return "armed", str(phase)
        holds = sorted(seq.holds)
        if phase is ShowPhase.SHOW:
            if seq.paused:
                return "holding", "hold: " + ", ".join(holds)
            return "show", ""
        if phase is ShowPhase.LANDING:
            return "landing", ("hold: " + ", ".join(holds)) if holds else ""
        return "done", "every vehicle is down"

    def _header(self, runner: ShowRunner, now: float, errors: dict[int, float]) -> Header:
        plan, seq = runner.plan, runner.sequence
        phase, detail = self._phase(runner)
        t = seq.show_time(now) if seq is not None and seq.started_at is not None else None
        formation, nxt, nxt_in = _formations(runner, t)
        worst = max(errors.items(), key=lambda kv: kv[1]) if errors else None
        sep, pair = self._separation(runner)
        link, link_sev = _link_summary(runner, now)
        return Header(plan.show_name, phase, detail, t, plan.duration, formation, nxt,
                      nxt_in, worst[1] if worst else None, worst[0] if worst else None,
                      sep, pair, plan.limits.min_separation, link, link_sev,
                      cue=cue_text(plan, t), networks=_network_summaries(runner, now))

    @staticmethod
    def _separation(runner: ShowRunner) -> tuple[float | None, tuple[int, int] | None]:
        mon, seq = runner.monitor, runner.sequence
        if mon is None or seq is None or mon.last_positions is None:
            return None, None
        _, ids, pos = mon.last_positions
        rows = [k for k, s in enumerate(ids) if s in seq.vehicles
                and seq.vehicles[s].phase in AIRBORNE and pos[k][2] > 0.5]
        if len(rows) < 2:
            return None, None
        near = nearest_pair([ids[k] for k in rows], pos[rows])
        return (near.distance_m if math.isfinite(near.distance_m) else None), near.pair

    def _row(self, runner: ShowRunner, sysid: int, error: float | None,
             leds: np.ndarray | None, now: float) -> VehicleRow:
        state = runner.link.vehicles.get(sysid)
        seq = runner.sequence
        run = seq.vehicles.get(sysid) if seq is not None else None
        excluded = sysid in runner.config.excluded
        track = (run.track if run.track >= 0 else None) if run is not None else (
            runner.assignment.tracks.get(sysid) if runner.assignment is not None else None)
        if run is not None:
            phase = str(run.phase)
        elif excluded:
            phase = "excluded"
        elif state is None:
            phase = "unheard"
        else:
            phase = "preflight"
        mon = runner.monitor
        vt = mon.vehicles.get(sysid) if mon is not None else None
        max_err = vt.max_error_m if vt is not None and vt.samples else None
        led = None
        if track is not None and leds is not None:
            led = (int(leds[track][0]), int(leds[track][1]), int(leds[track][2]))
        alarm, severity = self._alarm(runner, sysid, state, run, error, excluded, now)
        if state is None:
            return VehicleRow(sysid, track, phase, "-", False, None, None, None, None, None,
                              error, max_err, led, alarm, severity)
        rtt = state.rtt_s
        return VehicleRow(sysid, track, phase, state.mode, state.armed,
                          state.battery_remaining_pct, state.gps_fix_type,
                          state.gps_satellites, state.loss_ratio,
                          None if rtt is None else rtt * 1000.0, error, max_err, led, alarm,
                          severity,
                          runner.rtk.age_of(sysid, now) if runner.rtk is not None else None)

    @staticmethod
    def _alarm(runner: ShowRunner, sysid: int, state: VehicleState | None,
               run: VehicleRun | None, error: float | None, excluded: bool,
               now: float) -> tuple[str, Severity]:
        """What is wrong with one vehicle, worst first, and the row's colour."""
        if excluded:
            return "excluded by the operator", "off"
        if state is None:
            return "not heard", "bad" if run is not None else "warn"
        bad: list[str] = []
        warn: list[str] = []
        limits = runner.plan.limits
        if run is not None:
            if run.phase is VehiclePhase.LOST:
                bad.append(f"LOST, silent {state.silent_for(now):.0f} s")
            elif run.phase in (VehiclePhase.KILLED, VehiclePhase.FAILED):
                bad.append(f"{run.phase}" + (f": {run.reason}" if run.reason else ""))
            elif run.reason and run.phase is not VehiclePhase.LANDED:
                warn.append(run.reason)
        pct = state.battery_remaining_pct
        if pct is not None and run is not None and run.phase in AIRBORNE:
            if pct < limits.land_battery_pct / 2:
                bad.append(f"battery critical {pct:.0f}%")
            elif pct < limits.land_battery_pct:
                warn.append(f"battery low {pct:.0f}%")
        if error is not None:
            if error > FAR_OFF_M:
                bad.append(f"{error:.1f} m off its path")
            elif error > runner.plan.mpc.trigger_error_m:
                warn.append(f"{error:.1f} m off its path")
        rec = runner.records.get(sysid)
        if rec is not None and rec.late:
            warn.append("late")
        if runner.replanner is not None and sysid in runner.replanner.supervisor.active:
            warn.append("MPC")
        if rec is not None and rec.last_refusal and run is not None \
                and run.phase not in (VehiclePhase.LANDED,):
            warn.append(f"refused: {rec.last_refusal}")
        if run is None and runner.preflight_report is not None:
            results = runner.preflight_report.results.get(sysid, [])
            failed = [r for r in results if not r.ok]
            hard = [r.name for r in failed if _check_state(r.name, r.detail) == "fail"]
            soft = [r.name for r in failed if r.name not in hard]
            if hard:
                bad.append("failed: " + ", ".join(hard))
            if soft:
                warn.append("waiting: " + ", ".join(soft))
            if not failed and sysid in runner.preflight_report.extra:
                return "not in the show (ignored)", "off"
        loss = state.loss_ratio
        if loss > LOSSY:
            warn.append(f"loss {loss:.0%}")
        if state.link_conflicts and run is not None:
            warn.append(f"{state.link_conflicts} link conflicts")
        if bad:
            return "; ".join(bad + warn), "bad"
        if warn:
            return "; ".join(warn), "warn"
        if run is not None and run.phase in (VehiclePhase.LANDED,):
            return "", "off"
        return "", "ok"

    def _preflight(self, runner: ShowRunner) -> PreflightView:
        report = runner.preflight_report
        assert report is not None
        grid = self._grid
        if grid is None or grid.report is not report or grid.assignment is not \
                runner.assignment or grid.excluded is not runner.config.excluded:
            grid = self._grid = _grid(runner, report)
        if runner.sequence is not None:
            line = f"GO given: {grid.summary}"
        elif grid.go and runner.awaiting_go:
            line = f"GO: {grid.summary}; press g to arm and fly"
        elif grid.go:
            line = f"GO: {grid.summary}"
        else:
            line = f"NO-GO: {grid.summary}"
        return PreflightView(grid.checks, grid.rows, grid.go, line, runner.awaiting_go,
                             grid.ignored)

    @staticmethod
    def _detail(runner: ShowRunner, sysid: int, errors: dict[int, float],
                now: float) -> Detail:
        state = runner.link.vehicles.get(sysid)
        seq = runner.sequence
        run = seq.vehicles.get(sysid) if seq is not None else None
        lines = [f"vehicle {sysid}"]
        if run is not None:
            lines.append((f"track {run.track}" if run.track >= 0 else "spare")
                         + f", {run.phase}"
                         + (f" ({run.reason})" if run.reason else ""))
            path = seq.path(sysid, now) if seq is not None else None
            if path is not None:
                lines.append(f"flies {path.reason}")
        mon = runner.monitor
        if mon is not None and mon.last_positions is not None:
            _, ids, pos = mon.last_positions
            if sysid in ids:
                e, n, u = pos[ids.index(sysid)]
                lines.append(f"position E {e:.2f} N {n:.2f} U {u:.2f} m (show frame)")
        if sysid in errors:
            lines.append(f"error {errors[sysid]:.2f} m from its path")
        vt = mon.vehicles.get(sysid) if mon is not None else None
        if vt is not None and vt.samples:
            lines.append(f"max error {vt.max_error_m:.2f} m at show time "
                         f"{vt.max_error_at_s:.1f} s")
        lead = runner.lead_of(sysid)
        if lead is not None:
            lines.append(f"setpoint lead {lead * 1000:.0f} ms")
        if run is not None and run.pending is not None:
            lines.append(f"pending: {type(run.pending).__name__.lower()} "
                         f"(attempt {run.attempts}, sent {now - run.sent_at:.1f} s ago)")
        else:
            lines.append("pending: none")
        rec = runner.records.get(sysid)
        if rec is not None and rec.last_refusal:
            lines.append(f"last refusal: {rec.last_refusal} ({rec.commands_refused} in all)")
        if state is None:
            lines.append("never heard")
        else:
            lines.append(f"heard {state.silent_for(now):.1f} s ago, {state.packets} packets, "
                         f"{state.bad_packets} bad, {state.link_conflicts} conflicts")
            texts = list(state.statustexts)[-5:]
            if texts:
                lines.append("STATUSTEXT:")
                lines += [f"  {now - x.at:5.0f} s ago [{x.severity}] {x.text}" for x in texts]
        if runner.preflight_report is not None and run is None:
            for r in runner.preflight_report.results.get(sysid, []):
                if not r.ok:
                    lines.append(f"check {r.name}: {r.detail}")
        return Detail(sysid, tuple(lines))


@dataclass(frozen=True)
class _Grid:
    """What the pre-flight view shows of one report, and what it was built from (the
    runner replaces a report, its assignment and its exclusions, never changes them)."""

    report: PreflightReport
    assignment: Assignment | None
    excluded: frozenset[int]
    checks: tuple[str, ...]
    rows: tuple[PreflightRow, ...]
    go: bool
    summary: str
    ignored: tuple[str, ...]


def _grid(runner: ShowRunner, report: PreflightReport) -> _Grid:
    """The pre-flight grid of ``report``: check names in column order, a row per vehicle,
    the go / no-go and its fleet-wide summary."""
    excluded = runner.config.excluded
    names: list[str] = []
    rows = []
    for sysid in sorted(report.results):
        cells = []
        for r in report.results[sysid]:
            if r.name not in names:
                names.append(r.name)
            cells.append(CheckCell(r.name, "pass" if r.ok else _check_state(r.name, r.detail),
                                   r.detail))
        states = {c.state for c in cells}
        status = "excluded" if sysid in excluded else "failed" if "fail" in states \
            else "waiting" if "wait" in states else "ready"
        track = runner.assignment.tracks.get(sysid) if runner.assignment else None
        rows.append(PreflightRow(sysid, track, tuple(cells), sysid in excluded, status))
    missing = _missing(runner)
    summary = report.summary(excluded)
    if missing:
        summary += f"; no vehicle for track(s) {missing}"
    ignored = tuple(f"vehicle {s}: {why}" for s, why in sorted(report.extra.items()))
    return _Grid(report, runner.assignment, excluded, tuple(names), tuple(rows),
                 not report.failures(excluded) and not missing, summary, ignored)


def _check_state(name: str, detail: str) -> CheckState:
    """A failing check waiting cannot fix once its value is known (battery, slot)."""
    if name in PERMANENT_CHECKS and "unknown" not in detail:
        return "fail"
    return "wait"


def _missing(runner: ShowRunner) -> list[int]:
    a = runner.assignment
    if a is None:
        return []
    excl = {t for s, t in a.tracks.items() if s in runner.config.excluded}
    return [t for t in a.unassigned_tracks if t not in excl]


def _formations(runner: ShowRunner, t: float | None) -> tuple[str, str, float | None]:
    """The formation now ("-> name" while flying into it), the next one and the show
    seconds until it is reached."""
    windows = sorted(runner.plan.formations, key=lambda w: w.start)
    if not windows:
        return "", "", None
    if t is None:
        return "", windows[0].name, None
    now = ""
    nxt = None
    for w in windows:
        if w.start <= t < w.arrive:
            now = f"-> {w.name}"
        elif w.arrive <= t <= w.end:
            now = w.name
        if nxt is None and w.arrive > t and not (w.start <= t < w.arrive):
            nxt = w
    if nxt is None:
        return now, "", None
    return now, nxt.name, nxt.arrive - t


#: Longest cue name the header shows, characters (two must fit one line).
CUE_NAME_CHARS = 30


def _short(name: str) -> str:
    return name if len(name) <= CUE_NAME_CHARS else name[:CUE_NAME_CHARS - 1] + "…"


def cue_text(plan: Plan, t: float | None) -> str:
    """``cue Intro · next Chorus in 12.0 s`` on the show clock ``t`` (before the show: the
    first cue); "" for a show without cues."""
    if not plan.cues:
        return ""
    last, nxt = plan.cue_at(-math.inf if t is None else t)
    parts = [f"cue {_short(last.name)}"] if last is not None else []
    if nxt is not None:
        parts.append(f"next {_short(nxt.name)}" + (f" in {nxt.time - t:.1f} s"
                                                   if t is not None
                                                   else f" at {nxt.time:.1f} s"))
    return " · ".join(parts)


def _leds(runner: ShowRunner, now: float) -> np.ndarray | None:
    """Every track's colour now, 0..255 (None before the show starts)."""
    seq = runner.sequence
    if seq is None or seq.started_at is None:
        return None
    colours = np.clip(runner.plan.colors_at(seq.show_time(now)), 0.0, 1.0)
    return np.rint(colours * 255).astype(int)


def _link_text(states: Sequence[VehicleState], expected: int, now: float
               ) -> tuple[str, int, int, list[float]]:
    """``heard/expected heard, N lost, loss ..., RTT max ...`` of these vehicles, and
    (heard, lost, losses) to judge it by."""
    heard = sum(1 for s in states if s.silent_for(now) < 2.0)
    lost = sum(1 for s in states if s.lost)
    losses = [s.loss_ratio for s in states]
    rtts = [r for r in (s.rtt_s for s in states) if r is not None]
    text = f"{heard}/{expected} heard"
    if lost:
        text += f", {lost} lost"
    if losses:
        text += f", loss {np.mean(losses):.1%} (max {max(losses):.0%})"
    if rtts:
        text += f", RTT max {max(rtts) * 1000:.0f} ms"
    return text, heard, lost, losses


def _severity(silent: bool, heard: int, lost: int, expected: int,
              losses: list[float]) -> Severity:
    return "bad" if silent or lost else \
        "warn" if heard < expected or (losses and max(losses) > LOSSY) else "ok"


def _link_summary(runner: ShowRunner, now: float) -> tuple[str, Severity]:
    expected = len(runner.expected_ids) if runner.expected_ids is not None \
        else runner.plan.drones
    text, heard, lost, losses = _link_text(list(runner.link.vehicles.values()), expected,
                                           now)
    silent = runner.link.fleet_silent
    if silent:
        text = "FLEET SILENT; " + text
    return text, _severity(silent, heard, lost, expected, losses)


def _network_summaries(runner: ShowRunner, now: float) -> tuple[tuple[str, Severity], ...]:
    """One line per network when there are several (at 1,000 drones the fleet's line
    hides a whole network gone quiet behind 750 heard)."""
    link = runner.link
    count = len(link.listens)
    if count < 2:
        return ()
    expected_ids = runner.expected_ids
    out = []
    for k in range(count):
        states = [v for s, v in link.vehicles.items() if network_index(s) == k]
        expected = (sum(1 for s in expected_ids if network_index(s) == k)
                    if expected_ids is not None else len(states))
        if not states and not expected:
            continue  # a network this show does not use (a fleet file's spare link)
        text, heard, lost, losses = _link_text(states, expected, now)
        quiet = link.network_silent_for(k, now)
        silent = quiet > link.fleet_silence
        if silent:
            text = ("SILENT" if math.isinf(quiet) else f"SILENT {quiet:.0f} s") + "; " + text
        out.append((f"net {k + 1}: {text}",
                    _severity(silent, heard, lost, expected, losses)))
    return tuple(out)
