"""``dry-run`` / ``fly --rerun``: the flight streamed to Rerun while it flies.

The control loop never waits on Rerun.  On the loop's thread each tick only
appends a snapshot to a deque: the positions the flight monitor measured this
tick (the array it made, not a copy), the show clock and the tick's setpoint
lateness, and once a second the batteries; events are teed the same way.  A
thread of its own is woken right after every :data:`BATCH_TICKS`-th tick (so
that its few milliseconds of work fall in the idle time before the next
tick, when the loop does not want the interpreter), turns the snapshots into
arrays (LED colours from the plan at the show time, tracking
error against the plan, the closest pair), and sends them with one
``send_columns`` per entity, in the layout of :mod:`groundctl.viz.scene`.
Rerun's own sinks (file, gRPC) then run in Rerun's threads.

A tick's snapshot costs a few microseconds on the loop's thread; the
batching thread competes for the interpreter only for the milliseconds a
batch takes, a few times a second (measured: ``benchmarks/bench_rerun.py``).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import GroundctlError
from groundctl.plan.plan import Plan
from groundctl.viz import scene
from groundctl.viz.eventlog import LogLine, event_line
from groundctl.viz.flight import FlightArrays, separations

if TYPE_CHECKING:
    from groundctl.flight.runner import ShowRunner
    from groundctl.record.events import EventSink

FloatArray = NDArray[np.float64]

#: Snapshots are sent every this many ticks (half a second at 10 Hz) ...
BATCH_TICKS = 5
#: ... or after this many wall seconds without ticks (events before the flight).
IDLE_S = 1.0
#: Batteries are read every this many seconds of the executor's clock.
BATTERY_EVERY_S = 1.0
#: Longest wait for Rerun to take the last batch when the flight ends, s.
CLOSE_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class _Tick:
    unix: float
    show: float  # the show_time timeline, NaN before the show clock started
    clock: float  # the show clock, NaN before it started / after the show
    ids: Sequence[int]
    pos: FloatArray
    lateness_s: float
    battery: dict[int, float] | None


class _Tee:
    """An event sink that passes every event on, and a copy to the live stream."""

    def __init__(self, inner: EventSink | None, live: LiveRerun) -> None:
        self.inner = inner
        self.live = live

    def emit(self, event: str, /, **fields: Any) -> None:
        if self.inner is not None:
            self.inner.emit(event, **fields)
        self.live.event(event, fields)

    def flush(self) -> None:
        flush = getattr(self.inner, "flush", None)
        if flush is not None:
            flush()


class LiveRerun:
    """Streams one flight to ``targets``; :meth:`attach` it to the runner, :meth:`close`
    it when the flight is over (it sends what is left)."""

    def __init__(self, plan: Plan, targets: Sequence[scene.RerunTarget]) -> None:
        self.plan = plan
        self.rec = scene.open_recording(targets, f"flight {plan.show_name}")
        self._ticks: deque[_Tick] = deque()
        self._events: deque[tuple[float, float, LogLine]] = deque()
        self._runner: ShowRunner | None = None
        self._sysids: tuple[int, ...] = ()
        self._tracks: dict[int, int] = {}
        self._end_now: float | None = None
        self._battery_at = -np.inf
        self._history: list[_Tick] = []
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._since_batch = 0
        self._thread = threading.Thread(target=self._run, name="rerun-live", daemon=True)
        self.batches = 0
        self.errors: list[str] = []
        scene.log_plan(self.rec, plan)
        self._thread.start()

    # -- on the loop's thread ---------------------------------------------------------
    def attach(self, runner: ShowRunner) -> None:
        """Chain after ``runner.on_tick`` and tee its and its link's event sinks."""
        self._runner = runner
        previous = runner.on_tick

        def tick(now: float, show_time: float) -> None:
            if previous is not None:
                previous(now, show_time)
            self._tick(runner, now, show_time)

        runner.on_tick = tick
        runner.events = _Tee(runner.events, self)
        runner.link.events = _Tee(runner.link.events, self)

    def _timeline(self, now: float, show_time: float, started: bool) -> tuple[float, float]:
        """(the show_time timeline, the show clock) at ``now``: as the replay's
        (:meth:`ShowClockTable.timeline`) once the show started, NaN before."""
        if not started:
            return np.nan, np.nan
        if self._end_now is None and show_time >= self.plan.duration - 1e-6:
            self._end_now = now
        if self._end_now is not None:
            return self.plan.duration + (now - self._end_now), np.nan
        return show_time, show_time

    def _tick(self, runner: ShowRunner, now: float, show_time: float) -> None:
        mon, seq = runner.monitor, runner.sequence
        if mon is None or seq is None or mon.last_positions is None:
            return
        if not self._sysids:
            self._tracks = dict(mon.tracks)
            self._sysids = tuple(sorted(mon.tracks))
        show, clock = self._timeline(now, show_time, seq.started_at is not None)
        battery = None
        if now - self._battery_at >= BATTERY_EVERY_S:
            self._battery_at = now
            battery = {s: v.battery_remaining_pct for s, v in runner.link.vehicles.items()
                       if v.battery_remaining_pct is not None}
        _, ids, pos = mon.last_positions
        behind = runner.clock.wall_interval(max(runner.clock.now() - now, 0.0))
        self._ticks.append(_Tick(time.time() - behind, show, clock, ids, pos,
                                 runner.lateness_s[-1] if runner.lateness_s else np.nan,
                                 battery))
        self._since_batch += 1
        if self._since_batch >= BATCH_TICKS:
            self._since_batch = 0
            self._wake.set()  # the batch runs now, in the idle time before the next tick

    def event(self, event: str, fields: dict[str, Any]) -> None:
        """One event (from the tee)."""
        runner = self._runner
        now = runner.clock.now() if runner is not None else 0.0
        line = event_line({"t": now, "event": event, **fields})
        if line is None:
            return
        show = np.nan
        seq = runner.sequence if runner is not None else None
        if seq is not None and seq.started_at is not None:
            show, _ = self._timeline(now, seq.show_time(now), True)
        self._events.append((time.time(), show, line))

    # -- on its own thread ------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(IDLE_S)
            self._wake.clear()
            self._send()
        self._send()

    def _send(self) -> None:
        try:
            self._send_events()
            self._send_ticks()
        except Exception as exc:  # the flight goes on; said once at the end
            if len(self.errors) < 5:
                self.errors.append(f"{type(exc).__name__}: {exc}")

    def _send_events(self) -> None:
        got = [self._events.popleft() for _ in range(len(self._events))]
        if not got:
            return
        unix = np.array([g[0] for g in got])
        show = np.array([g[1] for g in got])
        for keep in (np.isfinite(show), ~np.isfinite(show)):
            if keep.any():
                scene.log_lines(self.rec, show[keep], unix[keep],
                                [g[2] for g, k in zip(got, keep, strict=True) if k])

    def _send_ticks(self) -> None:
        new = [self._ticks.popleft() for _ in range(len(self._ticks))]
        if not new or not self._sysids:
            return
        if self.batches == 0:
            scene.log_styles(self.rec, self._sysids, self.plan.limits.min_separation)
        self.batches += 1
        ticks = self._history + new
        fa = self._arrays(ticks, len(ticks) - len(new))
        self._history = ticks[-scene.TRAIL_TICKS:]
        first_new = len(ticks) - len(new)
        limit = self.plan.limits.min_separation
        started = np.isfinite(fa.show_time)
        for keep in (started, ~started):
            mask = keep.copy()
            mask[:first_new] = False
            if not mask.any():
                continue
            # History rows stay in for the trails; only new rows are sent.
            sub = fa.rows(keep)
            sent = np.flatnonzero(mask[keep])
            rows = slice(int(sent[0]), None)
            scene.log_vehicles(self.rec, sub, rows)
            scene.log_series(self.rec, sub, limit, rows)

    def _arrays(self, ticks: list[_Tick], first_new: int) -> FlightArrays:
        """The ticks as arrays; the closest pair only from ``first_new`` on (the rows
        before are kept for the trails)."""
        sysids = self._sysids
        col = {s: j for j, s in enumerate(sysids)}
        t_count, n = len(ticks), len(sysids)
        positions = np.full((t_count, n, 3), np.nan)
        battery = np.full((t_count, n), np.nan)
        for k, tk in enumerate(ticks):
            cols = [col.get(s, -1) for s in tk.ids]
            keep = [i for i, c in enumerate(cols) if c >= 0]
            if keep:
                positions[k, [cols[i] for i in keep]] = tk.pos[keep]
        last_battery: dict[int, float] = {}
        for k, tk in enumerate(ticks):
            if tk.battery is not None:
                last_battery = tk.battery
            for s, v in last_battery.items():
                if s in col:
                    battery[k, col[s]] = v
        clock = np.array([tk.clock for tk in ticks])
        track_of = np.array([self._tracks[s] for s in sysids], dtype=np.intp)
        colours = np.full((t_count, n, 3), 90, dtype=np.uint8)
        error = np.full((t_count, n), np.nan)
        on = np.isfinite(clock)
        if on.any():
            times = clock[on]
            colours[on] = scene.plan_colours(self.plan, times)[track_of].transpose(1, 0, 2)
            planned, _, _ = self.plan.trajectories.evaluate(times, track_of)  # (n, T', 3)
            error[on] = np.linalg.norm(positions[on] - planned.transpose(1, 0, 2), axis=2)
        sep = np.full(t_count, np.nan)
        pair = np.zeros((t_count, 2), dtype=np.int64)
        sep[first_new:], pair[first_new:] = separations(positions[first_new:], sysids)
        return FlightArrays(
            sysids=sysids, tracks=self._tracks, origin=self.plan.origin,
            unix_s=np.array([tk.unix for tk in ticks]),
            show_time=np.array([tk.show for tk in ticks]), show_clock=clock,
            positions=positions, colours=colours, tracking_error=error, min_separation=sep,
            min_pair=pair, lateness_ms=np.array([tk.lateness_s for tk in ticks]) * 1000.0,
            battery=battery, estimated_clock=False)

    def close(self) -> list[str]:
        """Send what is left, wait (bounded) for Rerun to take it; the errors met, if any."""
        self._stop.set()
        self._wake.set()
        self._thread.join(CLOSE_TIMEOUT_S)
        try:
            scene.close_recording(self.rec, CLOSE_TIMEOUT_S)
        except GroundctlError as exc:
            self.errors.append(str(exc))
        return self.errors
