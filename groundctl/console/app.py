"""The operator console (Textual): renders :class:`~groundctl.console.model.ConsoleView`.

The widgets hold no flight state: every refresh (at most :data:`REFRESH_HZ`)
asks the model for a view at the flight clock's time and renders what
changed; keys and the command line go to the
:class:`~groundctl.console.commands.Controller`.  The app runs in the same
event loop as the runner: a refresh is a few milliseconds of work between two
ticks, and the fleet table is updated cell by cell (only the cells whose text
changed), never rebuilt.

The terminal can never make that loop wait (:mod:`groundctl.console.terminal`
argues the design): :class:`ConsoleDriver` is Textual's Linux driver with its
writer replaced by a :class:`~groundctl.console.terminal.TerminalWriter` (frames
a terminal does not take are dropped, and the whole screen is repainted once it
reads again), and a terminal that goes away (a failed write or read, a hangup)
is reported through :attr:`ConsoleApp.on_terminal_lost` instead of panicking.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import itertools
import time
from collections import deque
from typing import Any, ClassVar, cast

from rich.text import Text
from textual.app import App, ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.css.scalar import Scalar
from textual.driver import Driver
from textual.drivers import linux_driver
from textual.widget import Widget
from textual.widgets import ContentSwitcher, DataTable, Input, RichLog, Static
from textual.widgets.data_table import CellDoesNotExist

from groundctl.console.commands import Controller
from groundctl.console.feed import Entry, EventFeed
from groundctl.console.model import (
    COLUMNS,
    SORTS,
    ConsoleModel,
    ConsoleView,
    Header,
    PreflightView,
    Severity,
    VehicleRow,
)
from groundctl.console.table import FleetTable
from groundctl.console.terminal import TerminalWriter
from groundctl.vehicleid import parse_vehicle, spell

#: Refreshes per second at most: an operator reads no faster, and every refresh is
#: time the control loop's interpreter is not ticking.
REFRESH_HZ = 5.0
#: The share of the control loop's interpreter the refreshes may take at most: a refresh
#: that took longer than MAX_SHARE / REFRESH_HZ (10 ms; the view of 1,000 rows takes
#: several) spaces the next ones out, so the console's cost stays bounded whatever the
#: fleet, and the operator sees the picture a little less often instead of the flight
#: being late.
MAX_SHARE = 0.05


def refresh_interval(cost_s: float) -> float:
    """Seconds between refreshes that cost ``cost_s`` each: 1 / REFRESH_HZ, or longer
    when that would give them more than MAX_SHARE of the loop."""
    return max(1.0 / REFRESH_HZ, cost_s / MAX_SHARE)

_SEVERITY_STYLE: dict[Severity, str] = {"ok": "green", "warn": "bold yellow",
                                        "bad": "bold white on red", "off": "grey50"}
_CHECK_STYLE = {"pass": "green", "fail": "bold white on red", "wait": "yellow"}
_CHECK_TEXT = {"pass": "ok", "fail": "FAIL", "wait": "wait"}
_STATUS_STYLE = {"ready": "green", "waiting": "yellow", "failed": "bold white on red",
                 "excluded": "grey50"}
#: The keys line at the bottom.
KEYS = Text.assemble(*(x for key, what in (
    ("h", "hold"), ("r", "resume"), ("a", "land all"), ("l", "land sel."),
    ("d", "land here"), ("e", "replace sel."), ("k", "kill sel."), ("x", "exclude"),
    ("g", "go"), ("q", "quit"),
    ("p", "problems"), ("s", "sort"), ("f", "log sel."), ("v", "view"), (":", "command"),
    ("esc", "cancel")) for x in ((f" {key} ", "bold reverse"), (f" {what} ", ""))))


class ConsoleDriver(linux_driver.LinuxDriver):
    """Textual's Linux driver whose terminal can never block the event loop.

    Its writer is a :class:`TerminalWriter` (non-blocking, frames dropped when the
    terminal is not reading, a hangup noticed), and a failed read of the terminal
    (EIO once it hung up) is a lost terminal, not a panic.
    """

    def start_application_mode(self) -> None:
        app = cast(ConsoleApp, self._app)  # the one app that uses this driver
        loop = asyncio.get_running_loop()

        def writer(file: Any) -> TerminalWriter:
            return TerminalWriter(file, loop=loop, on_lost=app.terminal_lost,
                                  on_caught_up=app.terminal_caught_up, name="console-writer")

        # Textual 8 builds its WriterThread inside this method and offers no hook: the
        # module's name points at ours for the call, on the loop's thread.
        original = linux_driver.WriterThread
        linux_driver.WriterThread = writer  # type: ignore[misc,assignment]
        try:
            super().start_application_mode()
        finally:
            linux_driver.WriterThread = original  # type: ignore[misc]

    def run_input_thread(self) -> None:
        try:
            super().run_input_thread()
        except OSError as exc:  # EIO once the terminal hung up: the app must not panic
            app = cast(ConsoleApp, self._app)
            if app._loop is not None:
                with contextlib.suppress(RuntimeError):
                    app._loop.call_soon_threadsafe(
                        app.terminal_lost, f"reading it failed ({exc.strerror or exc})")


def progress_bar(fraction: float, width: int = 30) -> str:
    """``[██████░░░░]``: ``fraction`` of ``width`` cells filled."""
    filled = round(min(max(fraction, 0.0), 1.0) * width)
    return "[" + "█" * filled + "░" * (width - filled) + "]"


def header_text(h: Header) -> Text:
    """The header's three lines."""
    t = Text()
    phase_style = {"holding": "bold black on yellow", "landing": "bold black on cyan",
                   "done": "bold black on green", "show": "bold black on green"}.get(
        h.phase, "bold black on white")
    t.append(f" {h.show} ", "bold")
    t.append(f" {h.phase.upper()} ", phase_style)
    if h.detail:
        t.append(f"  {h.detail}")
    t.append("\n")
    if h.show_time_s is None:
        t.append(f"show clock  -  / {h.duration_s:.0f} s {progress_bar(0.0)}")
    else:
        t.append(f"show clock {h.show_time_s:6.1f} / {h.duration_s:.0f} s "
                 f"{progress_bar(h.progress)} {h.progress:4.0%}")
    t.append(f"   now: {h.formation or '-'}")
    if h.next_formation:
        t.append(f"   next: {h.next_formation}"
                 + (f" in {h.next_in_s:.1f} s" if h.next_in_s is not None else ""))
    t.append("\n")
    if h.cue:  # a line of its own: the show's cues (an imported Skybrush show's)
        t.append("cues       ")
        t.append(h.cue, "bold magenta")
        t.append("\n")
    t.append("worst error ")
    t.append("-" if h.worst_error_m is None else
             f"{h.worst_error_m:.2f} m (#{spell(h.worst_error_sysid or 0)})",
             "bold yellow" if (h.worst_error_m or 0.0) > 0.4 else "")
    t.append("   min separation ")
    sep = "-" if h.min_separation_m is None else f"{h.min_separation_m:.2f} m" + (
        f" ({spell(h.min_separation_pair[0])}-{spell(h.min_separation_pair[1])})"
        if h.min_separation_pair else "")
    t.append(sep, _SEVERITY_STYLE[h.separation_severity])
    t.append(f" limit {h.separation_limit_m:.2f} m   link ")
    t.append(h.link, _SEVERITY_STYLE[h.link_severity])
    for text, severity in h.networks:
        t.append("\n  ")
        t.append(text, _SEVERITY_STYLE[severity])
    return t


#: The header's lines with one network (one more per network when there are several, and
#: one for a show's cues).
HEADER_LINES = 3


class ConsoleApp(App[None]):
    """The operator console; see the module docstring."""

    TITLE = "groundctl console"
    CSS = """
    #header { height: 3; background: $boost; }
    #main { height: 1fr; }
    #views { width: 1fr; }
    #side { width: 64; }
    #detail { height: 14; border: round $primary; }
    #log { height: 1fr; border: round $primary; }
    #go { height: 2; }
    #cell { height: 2; }
    #prompt { height: 1; background: $warning 30%; }
    #cmd { height: 3; }
    #keys { height: 1; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("ctrl+c", "quit_show", "quit", priority=True, show=False),
        Binding("ctrl+q", "quit_show", "quit", priority=True, show=False),
        Binding("q", "quit_show", "quit"),
        Binding("h", "hold", "hold"),
        Binding("r", "resume", "resume"),
        Binding("a", "land_all", "land all"),
        Binding("l", "land_one", "land sel."),
        Binding("d", "land_here", "land here"),
        Binding("e", "replace", "replace sel."),
        Binding("k", "kill", "kill sel."),
        Binding("x", "exclude", "exclude"),
        Binding("g", "go", "go"),
        Binding("p", "problems", "problems"),
        Binding("s", "sort", "sort"),
        Binding("f", "log_filter", "log sel."),
        Binding("v", "view", "view"),
        Binding("colon", "command_line", "command"),
        Binding("escape", "escape", "cancel", show=False),
    ]

    def __init__(self, model: ConsoleModel, controller: Controller, feed: EventFeed, *,
                 linger_s: float = 2.0) -> None:
        super().__init__()
        self.model = model
        self.controller = controller
        self.feed = feed
        self.linger_s = linger_s
        """Wall seconds the final screen stays up once the flight is over."""
        self.problems_only = False
        self.sort_order = "sysid"
        self.refreshes = 0
        """Refreshes rendered (tests and benchmarks read it)."""
        self.refresh_s: deque[float] = deque(maxlen=10_000)
        """How long each of the last refreshes took (view model and widget updates; the
        screen itself is drawn afterwards by Textual), s."""
        self.last_view: ConsoleView | None = None
        self._check_cells: dict[int, tuple[str, ...]] = {}
        self._check_columns: tuple[str, ...] = ()
        self._log_seq = 0
        self._log_filter: int | None = None
        self._switched = False
        self._task_factory: Any = None
        self._over = False
        self._mounted = False
        self._pending_outcome: str | None = None
        self._shown: dict[str, Any] = {}
        self._last_refresh = -1e9
        self._tick_queued = False
        self.on_terminal_lost: Any = None
        """Called once (on the loop) with why, when the terminal is gone."""
        self.terminal_gone: str | None = None
        """Why the terminal is gone (None while it is there)."""

    def get_driver_class(self) -> type[Driver]:
        driver = super().get_driver_class()
        return ConsoleDriver if driver is linux_driver.LinuxDriver else driver

    # -- the terminal -----------------------------------------------------------------
    def terminal_lost(self, why: str) -> None:
        """The terminal is gone: stop drawing and reading, say so once."""
        if self.terminal_gone is not None:
            return
        self.terminal_gone = why
        self._mounted = False  # no more refreshes
        with contextlib.suppress(Exception):
            if self._driver is not None:
                self._driver.disable_input()
        if self.on_terminal_lost is not None:
            self.on_terminal_lost(why)
        self.exit()

    def terminal_caught_up(self, dropped: int) -> None:
        """The terminal reads again after ``dropped`` frames were skipped: repaint all."""
        self.feed.console(f"console: the terminal was not reading; {dropped} screen "
                          "update(s) skipped, redrawn")
        with contextlib.suppress(Exception):
            self.screen.refresh()

    # -- layout -----------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Static(id="header")
        with Horizontal(id="main"):
            with ContentSwitcher(initial="preflight", id="views"):
                with Vertical(id="preflight"):
                    yield Static(id="go")
                    yield DataTable(id="checks", cursor_type="cell", zebra_stripes=True)
                    yield Static(id="cell")
                yield FleetTable(COLUMNS, id="fleet")
            with Vertical(id="side"):
                yield Static(id="detail")
                yield RichLog(id="log", max_lines=2000, wrap=False, markup=False)
        yield Static(id="prompt")
        yield Input(id="cmd", placeholder="command (: to type, help for the list)")
        # A fixed line, not Textual's Footer: the Footer rebuilds itself on every focus
        # change (tens of milliseconds of the control loop's interpreter).
        yield Static(KEYS, id="keys")

    def on_mount(self) -> None:
        # Textual (on Python 3.12+) makes the loop's tasks eager; the runner's were
        # written for ordinary ones (a task registered after create_task returns).
        loop = asyncio.get_running_loop()
        if self._task_factory is not None and loop.get_task_factory() is not \
                self._task_factory[0]:
            loop.set_task_factory(self._task_factory[0])
        self.set_interval(1.0 / REFRESH_HZ, self._idle_refresh)
        self.refresh_view()
        self.query_one("#checks", DataTable).focus()
        self._mounted = True
        if self._pending_outcome is not None:
            self.flight_over(self._pending_outcome)

    def remember_task_factory(self) -> None:
        """Called before the app starts: the loop's task factory to restore."""
        self._task_factory = (asyncio.get_running_loop().get_task_factory(),)

    # -- rendering --------------------------------------------------------------------
    def tick(self) -> None:
        """Called by the runner right after each tick's setpoints left (its ``on_tick``):
        a refresh now, at most :data:`REFRESH_HZ`, lands in the idle part of the tick's
        period instead of on a setpoint's instant."""
        if self._mounted and not self._tick_queued \
                and time.monotonic() - self._last_refresh >= 0.95 * self.refresh_interval:
            self._tick_queued = True
            self.call_next(self._tick_refresh)  # on the app's own message pump

    @property
    def refresh_interval(self) -> float:
        """Seconds between refreshes: 1 / REFRESH_HZ, or longer while the last refreshes
        cost more than MAX_SHARE of that (the slowest of the last three counts)."""
        return refresh_interval(max(itertools.islice(reversed(self.refresh_s), 3),
                                    default=0.0))

    def _tick_refresh(self) -> None:
        self._tick_queued = False
        self.refresh_view()

    def _idle_refresh(self) -> None:
        # The timer refreshes only while no tick does (connecting, pre-flight, a stall).
        if time.monotonic() - self._last_refresh >= 2.5 * self.refresh_interval:
            self.refresh_view()

    def _set(self, widget_id: str, content: Text) -> None:
        """A Static's content, only when it changed, and without a layout pass (their
        sizes are fixed by the CSS)."""
        if self._shown.get(widget_id) != content:
            self._shown[widget_id] = content
            self.query_one(f"#{widget_id}", Static).update(content, layout=False)

    def refresh_view(self) -> None:
        """One refresh: a view from the model, rendered where it changed."""
        started = time.perf_counter()
        self._last_refresh = time.monotonic()
        try:
            switcher = self.query_one("#views", ContentSwitcher)
            view = self.model.view(self.model.now(), self.selected(),
                                   preflight=switcher.current == "preflight")
            self.last_view = view
            lines = HEADER_LINES + bool(view.header.cue) + len(view.header.networks)
            header = self.query_one("#header", Static)
            if header.styles.height != Scalar.from_number(lines):
                header.styles.height = lines  # a line per network: laid out once, when known
            self._set("header", header_text(view.header))
            if view.armed and not self._switched:
                self._switched = True  # armed: the fleet is what matters from now on
                self.query_one("#views", ContentSwitcher).current = "fleet"
                self.query_one("#fleet", FleetTable).focus()
                # Everything built so far (plan, fleet state, widgets) lives to the end:
                # out of the collector's sight, the garbage of the refreshes costs
                # short young-generation collections, not full ones mid-show.
                gc.freeze()
            self._render_fleet(view)
            if view.preflight is not None:
                self._render_checks(view.preflight)
            self._render_detail(view)
            self._render_log()
            q = self.controller.question
            self._set("prompt", Text(q.prompt, "bold") if q is not None else Text(""))
            self.refreshes += 1
            self.refresh_s.append(time.perf_counter() - started)
        except Exception as exc:  # a rendering bug must never take the flight with it
            self.log.error(f"console refresh failed: {exc!r}")
            with contextlib.suppress(Exception):
                self.query_one("#prompt", Static).update(f"console refresh failed: {exc!r}")

    def _visible(self, row: VehicleRow) -> bool:
        return not self.problems_only or row.severity in ("warn", "bad")

    def _render_fleet(self, view: ConsoleView) -> None:
        rows = sorted((r for r in view.rows if self._visible(r)),
                      key=lambda r: r.sort_key(self.sort_order))
        self.query_one("#fleet", FleetTable).set_rows(rows)

    def _render_checks(self, pre: PreflightView) -> None:
        table = self.query_one("#checks", DataTable)
        go = Text(pre.go_line, "bold green" if pre.go else "bold red")
        for line in pre.ignored[:1]:
            go.append(f"\n{line}" + (f" (and {len(pre.ignored) - 1} more)"
                                     if len(pre.ignored) > 1 else ""), "grey50")
        self._set("go", go)
        if pre.checks != self._check_columns:
            table.clear(columns=True)
            table.add_column("id", key="sysid")
            table.add_column("trk", key="track")
            table.add_column("status", key="status")
            for name in pre.checks:
                table.add_column(name, key=name)
            self._check_columns = pre.checks
            self._check_cells.clear()
        keys = ("sysid", "track", "status", *pre.checks)
        for row in pre.rows:
            texts = (str(row.sysid), "-" if row.track is None else str(row.track),
                     row.status, *(c.state for c in row.cells))
            cells = [Text(texts[0]), Text(texts[1]),
                     Text(row.status, _STATUS_STYLE.get(row.status, ""))]
            cells += [Text(_CHECK_TEXT[c.state], "grey50" if row.excluded
                           else _CHECK_STYLE[c.state]) for c in row.cells]
            old = self._check_cells.get(row.sysid)
            if old is None:
                table.add_row(*cells, key=str(row.sysid))
            else:
                for i, key in enumerate(keys):
                    if i < len(texts) and i < len(old) and texts[i] != old[i]:
                        with contextlib.suppress(CellDoesNotExist):
                            table.update_cell(str(row.sysid), key, cells[i])
            self._check_cells[row.sysid] = texts
        # The reason of the selected cell.
        reason = Text("")
        if table.row_count and pre.rows:
            by_id = {row.sysid: row for row in pre.rows}
            with contextlib.suppress(CellDoesNotExist, ValueError, KeyError, IndexError):
                cell_key = table.coordinate_to_cell_key(table.cursor_coordinate)
                row = by_id[parse_vehicle(str(cell_key.row_key.value))]
                col = str(cell_key.column_key.value)
                if col in pre.checks:
                    cell = row.cells[pre.checks.index(col)]
                    reason = Text(f"vehicle {row.sysid} {cell.name}: {cell.detail}",
                                  _CHECK_STYLE[cell.state])
                else:
                    failing = [x for x in row.cells if x.state != "pass"]
                    reason = Text(f"vehicle {row.sysid}: " + ("; ".join(
                        f"{x.name}: {x.detail}" for x in failing) or "every check passed"))
        self._set("cell", reason)

    def _render_detail(self, view: ConsoleView) -> None:
        if view.detail is None:
            self._set("detail", Text("select a vehicle (arrow keys)"))
        else:
            self._set("detail", Text("\n".join(view.detail.lines)))

    def _render_log(self) -> None:
        log = self.query_one("#log", RichLog)
        wanted = self.controller.log_filter
        if wanted != self._log_filter:
            self._log_filter = wanted
            log.clear()
            self._log_seq = 0
            log.write(Text("log: " + ("fleet-wide" if wanted is None else
                                      f"vehicle {wanted} only (f again: fleet-wide)"),
                           "bold"))
        entries = self.feed.lines(wanted, after=self._log_seq, most=300)
        if entries:  # one write per refresh: each write costs a scroll and a layout
            text = Text("\n").join(_log_line(e) for e in entries)
            log.write(text)
        self._log_seq = self.feed.last_seq

    # -- selection --------------------------------------------------------------------
    def selected(self) -> int | None:
        """The system id under the cursor of the view shown (None: no row)."""
        try:
            switcher = self.query_one("#views", ContentSwitcher)
            if switcher.current == "fleet":
                return self.query_one("#fleet", FleetTable).selected
            table = self.query_one("#checks", DataTable)
            if not table.row_count:
                return None
            key = table.coordinate_to_cell_key(table.cursor_coordinate)
            return parse_vehicle(str(key.row_key.value))
        except Exception:  # no table yet, an empty one, a row just removed
            return None

    # -- actions ----------------------------------------------------------------------
    def _after(self) -> None:
        if self.controller.question is not None:
            self.query_one("#cmd", Input).focus()
        self.refresh_view()

    def action_hold(self) -> None:
        self.controller.hold()
        self._after()

    def action_resume(self) -> None:
        self.controller.resume()
        self._after()

    def action_land_all(self) -> None:
        self.controller.land_all()
        self._after()

    def action_land_one(self) -> None:
        self.controller.land_one(self.selected())
        self._after()

    def action_land_here(self) -> None:
        self.controller.land_here(self.selected())
        self._after()

    def action_replace(self) -> None:
        self.controller.replace(self.selected())
        self._after()

    def action_kill(self) -> None:
        self.controller.kill(self.selected())
        self._after()

    def action_exclude(self) -> None:
        self.controller.exclude(self.selected())
        self._after()

    def action_go(self) -> None:
        self.controller.go()
        self._after()

    def action_quit_show(self) -> None:
        if self._over:
            self.exit()
            return
        self.controller.quit()
        self._after()

    def action_problems(self) -> None:
        self.problems_only = not self.problems_only
        self.feed.console("fleet table: " + ("problems only" if self.problems_only
                                             else "every vehicle"))
        self.refresh_view()

    def action_sort(self) -> None:
        self.sort_order = SORTS[(SORTS.index(self.sort_order) + 1) % len(SORTS)]
        self.feed.console(f"fleet table sorted by {self.sort_order}")
        self.refresh_view()

    def action_log_filter(self) -> None:
        sysid = self.selected()
        self.controller.log_filter = None if self.controller.log_filter is not None \
            else sysid
        self.refresh_view()

    def action_view(self) -> None:
        switcher = self.query_one("#views", ContentSwitcher)
        switcher.current = "preflight" if switcher.current == "fleet" else "fleet"
        self._focus_table()
        self.refresh_view()

    def action_command_line(self) -> None:
        self.query_one("#cmd", Input).focus()

    def action_escape(self) -> None:
        self.controller.cancel()
        self.query_one("#cmd", Input).value = ""
        self._focus_table()
        self.refresh_view()

    def _focus_table(self) -> None:
        switcher = self.query_one("#views", ContentSwitcher)
        widget: Widget = self.query_one("#fleet", FleetTable) if switcher.current == "fleet" \
            else self.query_one("#checks", DataTable)
        widget.focus()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        text = event.value
        event.input.value = ""
        self.controller.line(text)
        if self.controller.question is None:
            self._focus_table()
        self.refresh_view()

    # -- the end ----------------------------------------------------------------------
    def flight_over(self, outcome: str) -> None:
        """The flight is over: show it, then close after :attr:`linger_s`."""
        if not self._mounted:
            self._pending_outcome = outcome  # over before the app came up
            return
        self._over = True
        self.model.outcome = outcome
        self.refresh_view()
        self.set_timer(max(self.linger_s, 0.01), self.exit)


def _log_line(e: Entry) -> Text:
    style = {"console": "cyan", "vehicle_lost": "bold red", "fleet_silent": "bold red",
             "error": "bold red", "signal": "bold yellow"}.get(e.kind, "")
    who = f"#{e.sysid:<3} " if e.sysid is not None else "     "
    return Text(f"{e.t:7.1f} {who}{e.text}", style)
