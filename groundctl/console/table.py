"""The fleet table: a light line-based widget for hundreds of rows at 5 Hz.

Textual's DataTable renders every visible cell through Rich again whenever any
cell changes (at 200 vehicles, about 50 rows x 13 cells, tens of milliseconds
per refresh of the executor's own interpreter).  Here each row is one
:class:`~textual.strip.Strip`, built when its line is drawn and rebuilt only after its
text or colour changed (so a refresh of 1,000 changing rows builds the few dozen on
the screen), and only the lines of changed rows are repainted.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from rich.segment import Segment
from rich.style import Style
from textual import events
from textual.binding import Binding, BindingType
from textual.geometry import Region, Size
from textual.scroll_view import ScrollView
from textual.strip import Strip

from groundctl.console.model import Severity, VehicleRow

_SEVERITY: dict[Severity, Style] = {
    "ok": Style(color="green"), "warn": Style(color="yellow", bold=True),
    "bad": Style(color="white", bgcolor="red", bold=True), "off": Style(color="grey50")}
_PLAIN = Style()
_HEADER = Style(bold=True, underline=True)
_CURSOR = Style(reverse=True)
#: Columns coloured by the row's severity.
COLOURED = frozenset({"sysid", "phase", "alarm"})


class FleetTable(ScrollView, can_focus=True):
    """One line per vehicle under a fixed header line; a row cursor (arrows, page keys,
    home / end, click) selects a vehicle."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("up", "cursor(-1)", show=False), Binding("down", "cursor(1)", show=False),
        Binding("pageup", "page(-1)", show=False), Binding("pagedown", "page(1)", show=False),
        Binding("home", "cursor(-100000)", show=False),
        Binding("end", "cursor(100000)", show=False),
    ]
    DEFAULT_CSS = "FleetTable { height: 1fr; }"

    def __init__(self, columns: Sequence[tuple[str, str, int]], *, id: str | None = None
                 ) -> None:
        super().__init__(id=id)
        self.columns = tuple(columns)
        self.cursor_row = 0
        self._order: list[int] = []
        self._cells: dict[int, dict[str, str]] = {}
        self._severity: dict[int, Severity] = {}
        self._strips: dict[int, Strip] = {}
        self._width = sum(w + 1 for _, _, w in self.columns)
        self._header = Strip([Segment(self._fit(title, w), _HEADER)
                              for _, title, w in self.columns], self._width)
        self.virtual_size = Size(self._width, 1)

    # -- data ---------------------------------------------------------------------------
    @property
    def row_count(self) -> int:
        return len(self._order)

    @property
    def order(self) -> list[int]:
        """System ids, top to bottom."""
        return list(self._order)

    def cell(self, sysid: int, key: str) -> str:
        """The text shown in ``sysid``'s row under column ``key``."""
        return self._cells[sysid][key]

    @property
    def selected(self) -> int | None:
        """The system id under the cursor (None: no rows)."""
        return self._order[self.cursor_row] if self._order else None

    def set_rows(self, rows: Sequence[VehicleRow]) -> int:
        """Show ``rows`` in this order; returns how many rows were rebuilt."""
        selected = self.selected
        order = [r.sysid for r in rows]
        reordered = order != self._order
        changed: list[int] = []
        keep = set(order)
        for sysid in [s for s in self._cells if s not in keep]:
            del self._cells[sysid], self._severity[sysid]
            self._strips.pop(sysid, None)
        for i, row in enumerate(rows):
            cells = row.cells()
            if cells != self._cells.get(row.sysid) or row.severity != \
                    self._severity.get(row.sysid):
                self._cells[row.sysid] = cells
                self._severity[row.sysid] = row.severity
                # Built when its line is drawn: of 1,000 rows changing every refresh,
                # the forty on the screen.
                self._strips.pop(row.sysid, None)
                changed.append(i)
        self._order = order
        if reordered:
            self.virtual_size = Size(self._width, len(order) + 1)
            # The cursor stays on its vehicle when rows move.
            if selected in keep:
                self.cursor_row = order.index(selected)
            self.cursor_row = min(self.cursor_row, max(len(order) - 1, 0))
            self.refresh()
        else:
            top = int(self.scroll_offset.y)
            height = self.size.height
            for i in changed:
                line = i - top + 1
                if 1 <= line < height:
                    self.refresh(Region(0, line, self.size.width, 1))
        return len(changed)

    def _strip(self, cells: dict[str, str], severity: Severity) -> Strip:
        # Neighbouring cells of one style are one segment: fewer objects per row.
        segments: list[Segment] = []
        run: list[str] = []
        run_style = _PLAIN
        colour = _SEVERITY[severity]
        for key, _, width in self.columns:
            text = cells[key]
            if key == "led":
                piece, style = " " * (width - 1), Style(bgcolor=text) if text else _PLAIN
            else:
                piece = text[:width].ljust(width)
                style = colour if key in COLOURED else _PLAIN
            if style is not run_style and run:
                segments.append(Segment("".join(run), run_style))
                run = []
            run_style = style
            run.append(piece)
            if key == "led":  # the gap after a swatch is not coloured
                segments.append(Segment("".join(run), run_style))
                run, run_style = [" "], _PLAIN
            else:
                run.append(" ")
        if run:
            segments.append(Segment("".join(run), run_style))
        return Strip(segments, self._width)

    @staticmethod
    def _fit(text: str, width: int) -> str:
        return (text[:width].ljust(width)) + " "

    # -- rendering ------------------------------------------------------------------------
    def render_line(self, y: int) -> Strip:
        scroll_x, scroll_y = self.scroll_offset
        width = self.size.width
        if y == 0:
            return self._header.crop(scroll_x, scroll_x + width)
        index = scroll_y + y - 1
        if index >= len(self._order):
            return Strip.blank(width)
        sysid = self._order[index]
        strip = self._strips.get(sysid)
        if strip is None:
            strip = self._strips[sysid] = self._strip(self._cells[sysid], self._severity[sysid])
        if index == self.cursor_row and self.has_focus:
            strip = strip.apply_style(_CURSOR)
        elif index == self.cursor_row:
            strip = strip.apply_style(Style(underline=True))
        return strip.crop(scroll_x, scroll_x + width)

    # -- the cursor ---------------------------------------------------------------------
    def move_cursor(self, row: int) -> None:
        """Put the cursor on ``row`` (clamped) and scroll it into view."""
        if not self._order:
            return
        self.cursor_row = min(max(row, 0), len(self._order) - 1)
        top = int(self.scroll_offset.y)
        visible = max(self.size.height - 1, 1)
        if self.cursor_row < top:
            self.scroll_to(y=self.cursor_row, animate=False)
        elif self.cursor_row >= top + visible:
            self.scroll_to(y=self.cursor_row - visible + 1, animate=False)
        self.refresh()

    def action_cursor(self, step: int) -> None:
        self.move_cursor(self.cursor_row + step)

    def action_page(self, step: int) -> None:
        self.move_cursor(self.cursor_row + step * max(self.size.height - 2, 1))

    def on_click(self, event: events.Click) -> None:
        if event.y >= 1:
            self.move_cursor(int(self.scroll_offset.y) + event.y - 1)

    def on_focus(self) -> None:
        self.refresh()

    def on_blur(self) -> None:
        self.refresh()
