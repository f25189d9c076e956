"""``dry-run`` / ``fly --rerun``: the flight streamed to Rerun while it flies.

The control loop never waits on Rerun, and shares no interpreter with it:
the Rerun side runs in a sender process of its own (``spawn``).  On the
loop's thread each tick pickles a snapshot (the positions the flight
monitor measured this tick, the show clock, the tick's setpoint lateness,
once a second the batteries) and writes it to a non-blocking pipe; what the
pipe cannot take now waits in a buffer for the next tick (bounded: beyond
:data:`MAX_PENDING` bytes snapshots are dropped and counted), so a slow
sender never blocks a tick.  Events are teed the same way.  No thread of
ours runs in the flight's process.  The sender wakes every :data:`BATCH_S`
seconds, turns what came into arrays (LED colours from the plan at the show time,
tracking error against the plan, the closest pair) and sends them with one
``send_columns`` per entity, in the layout of :mod:`groundctl.viz.scene`,
at a lower priority (nice :data:`SENDER_NICE`) than the flight.

(Tried first and measured: a sender thread, then a ``multiprocessing.Queue``,
whose feeder thread pickles; on a busy machine a descheduled thread holding
the interpreter delayed ticks by milliseconds at 200 vehicles.)
"""

from __future__ import annotations

import contextlib
import fcntl
import multiprocessing as mp
import os
import pickle
import queue
import select
import signal
import struct
import time
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

#: The sender sends what came every this many wall seconds.
BATCH_S = 0.5
#: Batteries are read every this many seconds of the executor's clock.
BATTERY_EVERY_S = 1.0
#: Longest wait for the sender to start (open its file or viewer), s.
START_TIMEOUT_S = 60.0
#: Longest wait for Rerun to take the last batch when the flight ends, s.
CLOSE_TIMEOUT_S = 30.0
#: The sender process's niceness (lower priority than the flight).
SENDER_NICE = 10
#: Snapshots waiting for the pipe beyond this many bytes are dropped (the sender is stuck).
MAX_PENDING = 64 << 20
#: The pipe's capacity asked of Linux (F_SETPIPE_SZ), bytes.
PIPE_BYTES = 1 << 20
_F_SETPIPE_SZ = 1031
_FRAME = struct.Struct(">I")


class _Writer:
    """Length-prefixed pickles on a non-blocking pipe; never blocks (see the module)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        os.set_blocking(fd, False)
        with contextlib.suppress(OSError):
            fcntl.fcntl(fd, _F_SETPIPE_SZ, PIPE_BYTES)
        self.pending = bytearray()
        self.dropped = 0
        self.broken = False

    def send(self, obj: object) -> None:
        if self.broken:
            return
        if len(self.pending) > MAX_PENDING:
            self.dropped += 1
            return
        body = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        self.pending += _FRAME.pack(len(body)) + body
        self.flush()

    def flush(self) -> None:
        try:
            while self.pending:
                n = os.write(self.fd, self.pending)
                del self.pending[:n]
        except BlockingIOError:
            pass  # the rest goes with the next tick
        except OSError:
            self.broken = True  # the sender is gone: nothing more to stream
            self.pending.clear()

    def finish(self, timeout_s: float) -> None:
        """Write what is left, waiting at most ``timeout_s`` (the flight is over)."""
        deadline = time.monotonic() + timeout_s
        while self.pending and not self.broken and time.monotonic() < deadline:
            select.select([], [self.fd], [], 0.1)
            self.flush()


class _Reader:
    """The sender's end: it sleeps, then takes every frame the pipe holds.

    It never waits on the pipe itself (no ``select``): a process blocked on a
    pipe is woken by every write, and on a busy machine a woken sender can
    preempt the control loop that wrote.  A sleeping one is woken by its own
    timer only, twice a second.
    """

    def __init__(self, fd: int) -> None:
        self.fd = fd
        os.set_blocking(fd, False)
        self.buffer = bytearray()
        self.eof = False

    def read(self, wait_s: float) -> list[object]:
        time.sleep(wait_s)
        while True:
            try:
                data = os.read(self.fd, PIPE_BYTES)
            except BlockingIOError:
                break
            if not data:
                self.eof = True
                break
            self.buffer += data
        out: list[object] = []
        while len(self.buffer) >= _FRAME.size:
            (n,) = _FRAME.unpack_from(self.buffer)
            if len(self.buffer) < _FRAME.size + n:
                break
            out.append(pickle.loads(bytes(self.buffer[_FRAME.size:_FRAME.size + n])))
            del self.buffer[:_FRAME.size + n]
        return out


@dataclass(frozen=True)
class _Tick:
    unix: float
    show: float  # the show_time timeline, NaN before the show clock started
    clock: float  # the show clock, NaN before it started / after the show
    ids: Sequence[int]
    pos: FloatArray
    lateness_s: float
    battery: dict[int, float] | None


@dataclass(frozen=True)
class _Fleet:
    tracks: dict[int, int]


@dataclass(frozen=True)
class _Event:
    unix: float
    show: float
    line: LogLine


@dataclass(frozen=True)
class LiveResult:
    """What the sender did, reported when it closes."""

    errors: list[str]
    batches: int
    batch_s: list[float]


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
    it when the flight is over (the sender sends what is left)."""

    def __init__(self, plan: Plan, targets: Sequence[scene.RerunTarget]) -> None:
        self.plan = plan
        ctx = mp.get_context("spawn")
        reader, writer = ctx.Pipe(duplex=False)
        self._results: Any = ctx.Queue()
        self._proc = ctx.Process(target=_serve, name="groundctl-rerun", daemon=True,
                                 args=(plan, list(targets), reader, self._results))
        self._proc.start()
        reader.close()
        self._conn = writer  # keeps the fd open
        self._pipe = _Writer(writer.fileno())
        try:
            opened = self._results.get(timeout=START_TIMEOUT_S)
        except queue.Empty:
            opened = f"the Rerun sender did not start within {START_TIMEOUT_S:.0f} s"
        if opened is not None:
            self._stop_process()
            raise GroundctlError(str(opened))
        self._runner: ShowRunner | None = None
        self._fleet_sent = False
        self._end_now: float | None = None
        self._battery_at = -np.inf
        self.result: LiveResult | None = None
        self.tick_s: list[float] = []
        """What each tick's snapshot cost the loop's thread, s."""

    # -- on the loop's thread ---------------------------------------------------------
    def attach(self, runner: ShowRunner) -> None:
        """Chain after ``runner.on_tick`` and tee its and its link's event sinks."""
        self._runner = runner
        previous = runner.on_tick

        def tick(now: float, show_time: float) -> None:
            if previous is not None:
                previous(now, show_time)
            t0 = time.perf_counter()
            self._tick(runner, now, show_time)
            self.tick_s.append(time.perf_counter() - t0)

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
        if not self._fleet_sent:
            self._fleet_sent = True
            self._pipe.send(_Fleet(dict(mon.tracks)))
        show, clock = self._timeline(now, show_time, seq.started_at is not None)
        battery = None
        if now - self._battery_at >= BATTERY_EVERY_S:
            self._battery_at = now
            battery = {s: v.battery_remaining_pct for s, v in runner.link.vehicles.items()
                       if v.battery_remaining_pct is not None}
        _, ids, pos = mon.last_positions
        behind = runner.clock.wall_interval(max(runner.clock.now() - now, 0.0))
        self._pipe.send(_Tick(time.time() - behind, show, clock, ids, np.asarray(pos),
                              runner.lateness_s[-1] if runner.lateness_s else np.nan,
                              battery))

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
        self._pipe.send(_Event(time.time(), show, line))

    def close(self) -> list[str]:
        """Tell the sender to send what is left; wait (bounded) for it; the errors met."""
        try:
            self._pipe.send(None)
            self._pipe.finish(CLOSE_TIMEOUT_S)
            self.result = self._wait_result(CLOSE_TIMEOUT_S)
        except queue.Empty:
            self.result = LiveResult([f"the Rerun sender did not finish within "
                                      f"{CLOSE_TIMEOUT_S:.0f} s"], 0, [])
        finally:
            self._stop_process()
        assert self.result is not None
        if self._pipe.dropped:
            self.result.errors.append(f"{self._pipe.dropped} snapshots dropped: the Rerun "
                                      "sender fell behind")
        return self.result.errors

    def _wait_result(self, timeout_s: float) -> LiveResult:
        """The sender's result, polled: a sender that died gives up at once, not after
        ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                result: LiveResult = self._results.get(timeout=0.2)
                return result
            except queue.Empty:
                if not self._proc.is_alive() or time.monotonic() > deadline:
                    raise

    def _stop_process(self) -> None:
        self._proc.join(5.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5.0)
        with contextlib.suppress(OSError):
            self._conn.close()


def _serve(plan: Plan, targets: list[scene.RerunTarget], inbox: Any, results: Any) -> None:
    """The sender process: open the recording, then batch what comes until ``None``."""
    # Stop signals reach the whole process group (Ctrl-C, a closed terminal, a service
    # manager): the flight decides what they mean, and this process is told to finish by
    # the ``None`` at the end (or stopped) -- never cut off in the middle of a land-all.
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    # Below the flight's priority: on a busy machine a sender woken by a snapshot must not
    # preempt the control loop that wrote it.
    with contextlib.suppress(OSError):
        os.nice(SENDER_NICE)
    reader = _Reader(inbox.fileno())
    try:
        sender = _Sender(plan, targets)
    except Exception as exc:  # one line for the parent to raise
        results.put(str(exc) if isinstance(exc, GroundctlError) else f"rerun: {exc}")
        return
    results.put(None)
    done = False
    while not done and not reader.eof:
        for msg in reader.read(BATCH_S):
            if msg is None:
                done = True
                break
            sender.take(msg)
        sender.send()
    try:
        scene.close_recording(sender.rec, CLOSE_TIMEOUT_S)
    except GroundctlError as exc:
        sender.errors.append(str(exc))
    results.put(LiveResult(sender.errors, sender.batches, sender.batch_s))


class _Sender:
    """Turns snapshots into Rerun batches (in the sender process)."""

    def __init__(self, plan: Plan, targets: Sequence[scene.RerunTarget]) -> None:
        self.plan = plan
        self.rec = scene.open_recording(targets, f"flight {plan.show_name}")
        scene.log_plan(self.rec, plan)
        self._ticks: list[_Tick] = []
        self._events: list[_Event] = []
        self._history: list[_Tick] = []
        self._sysids: tuple[int, ...] = ()
        self._tracks: dict[int, int] = {}
        self.batches = 0
        self.batch_s: list[float] = []
        self.errors: list[str] = []

    @property
    def pending(self) -> int:
        return len(self._ticks)

    def take(self, msg: object) -> None:
        if isinstance(msg, _Tick):
            self._ticks.append(msg)
        elif isinstance(msg, _Event):
            self._events.append(msg)
        elif isinstance(msg, _Fleet):
            self._tracks = dict(msg.tracks)
            self._sysids = tuple(sorted(msg.tracks))
            scene.log_styles(self.rec, self._sysids, self.plan.limits.min_separation)

    def send(self) -> None:
        t0 = time.perf_counter()
        try:
            self._send_events()
            if self._send_ticks():
                self.batch_s.append(time.perf_counter() - t0)
        except Exception as exc:  # the flight goes on; said once at the end
            if len(self.errors) < 5:
                self.errors.append(f"{type(exc).__name__}: {exc}")

    def _send_events(self) -> None:
        got, self._events = self._events, []
        if not got:
            return
        unix = np.array([g.unix for g in got])
        show = np.array([g.show for g in got])
        for keep in (np.isfinite(show), ~np.isfinite(show)):
            if keep.any():
                scene.log_lines(self.rec, show[keep], unix[keep],
                                [g.line for g, k in zip(got, keep, strict=True) if k])

    def _send_ticks(self) -> bool:
        new, self._ticks = self._ticks, []
        if not new or not self._sysids:
            return False
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
        return True

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
