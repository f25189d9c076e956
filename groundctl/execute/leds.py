"""When to send each vehicle its LED colour, so that it appears on time.

Stock ArduPilot applies LED_CONTROL on arrival (the message has no
timestamp), so a colour must leave one link delay before the show instant
it is for.  :class:`LedSchedule` finds, once, every instant at which a
track's quantised plan colour changes, exactly: between two keyframes each
channel is linear, and ``rint(255 x)`` steps where ``255 x`` crosses
``k + 0.5``, so the crossings are solved for per segment, vectorised over
drones and channels, rather than found by sampling.  Each call then only
looks those instants up (one ``searchsorted`` for the whole fleet), shifted
earlier by each vehicle's delay.

Rate cap.  In a long fade the quantised colour can change every few
milliseconds; a vehicle is sent at most one colour per ``min_interval_s``.
The kept changes are chosen *among the exact change instants*, backwards
from the end of each burst (a run of changes less than ``min_interval_s``
apart): the burst's last change is kept, then the latest change at least
``min_interval_s`` before it, and so on.  So

* every colour sent is the plan's colour at the instant it appears, sent
  for the instant the plan starts showing it: its timing error is zero (the
  dry-run's monitor dates a shown colour against the first instant the plan
  shows it, so a colour sent late in its run would count as late);
* the last colour of every burst (the end of a fade) is always sent on
  time, so the LED never rests on an intermediate colour;
* consecutive sends to a vehicle are never closer than ``min_interval_s``;
  what is dropped are intermediate fade steps, at most ``min_interval_s``
  plus one step behind the plan.

Nothing here does I/O or reads a clock: show times and delays are arguments.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from groundctl.execute.setpoints import StreamTarget, quantise_rgb
from groundctl.plan.plan import Plan

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

DEFAULT_MIN_INTERVAL_S = 0.05
#: A change is dated this long after the exact crossing of ``k + 0.5``: at the
#: crossing itself ``rint`` rounds half to even and float rounding decides, a
#: nanosecond later the new colour is unambiguous (evaluated by anyone).
CHANGE_GUARD_S = 1e-9


@dataclass(frozen=True)
class LedChange:
    """One colour to send one vehicle."""

    sysid: int
    """MAVLink system id."""
    show_time: float
    """Show time the colour must appear on the vehicle: when the plan starts showing it, s."""
    send_at: float
    """Show time to send it: ``show_time`` minus the vehicle's one-way delay, s."""
    rgb: tuple[int, int, int]
    """The colour, 0-255 each."""


@dataclass(frozen=True)
class LedBatch:
    """The changes due in one window, as arrays sorted by ``send_at``."""

    rows: IntArray
    """(m,) row of each change's vehicle in the schedule's target order."""
    sysids: IntArray
    """(m,) system ids."""
    show_time: FloatArray
    """(m,) show time each colour must appear, s."""
    send_at: FloatArray
    """(m,) show time to send each, s."""
    rgb: NDArray[np.uint8]
    """(m, 3) colours, 0-255."""

    def __len__(self) -> int:
        return len(self.rows)

    def changes(self) -> list[LedChange]:
        """The batch as :class:`LedChange` values, in the same order."""
        return [LedChange(int(s), float(t), float(a), (int(c[0]), int(c[1]), int(c[2])))
                for s, t, a, c in zip(self.sysids.tolist(), self.show_time.tolist(),
                                      self.send_at.tolist(), self.rgb.tolist(), strict=True)]


def colour_changes(plan: Plan, tracks: ArrayLike) -> tuple[IntArray, FloatArray,
                                                           NDArray[np.uint8]]:
    """Every change of the quantised plan colour of ``tracks``.

    Returns ``(row, show_time, rgb)`` sorted by row (index into ``tracks``)
    then time: the instant (``CHANGE_GUARD_S`` after the exact crossing) and
    the colour from then on.  Before a row's first change it shows
    ``quantise_rgb`` of its first keyframe.
    """
    rows_of = np.asarray(tracks, dtype=np.int64)
    times = np.asarray(plan.color_times, dtype=float)
    level = 255.0 * np.asarray(plan.colors, dtype=float)[rows_of]  # (n, K, 3)
    n = len(rows_of)
    if len(times) < 2 or n == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3), np.uint8)
    va, vb = level[:, :-1], level[:, 1:]                          # (n, K-1, 3)
    ta, tb = times[:-1], times[1:]
    lo, hi = np.minimum(va, vb), np.maximum(va, vb)
    # Half-integers m + 0.5 in [lo, hi]; only m in 0..254 can change the
    # clipped 0-255 value.  Endpoints count: a segment that starts on a tie
    # may step at its start (the colour comparison below drops non-changes).
    first = np.maximum(np.ceil(lo - 0.5), 0.0)
    last = np.minimum(np.floor(hi - 0.5), 254.0)
    count = np.where(va == vb, 0, np.maximum(last - first + 1.0, 0.0)).astype(np.int64)
    step = (tb == ta)[None, :, None] & (va != vb)
    count = np.where(step, 1, count)  # a step changes everything at once, at its time
    flat = np.flatnonzero(count)
    per = count.ravel()[flat]
    cand = np.repeat(flat, per)
    offset = np.arange(len(cand)) - np.repeat(np.cumsum(per) - per, per)
    row, seg, _ = np.unravel_index(cand, count.shape)
    a, b = va.ravel()[cand], vb.ravel()[cand]
    h = first.ravel()[cand] + offset + 0.5
    t_a, dt = ta[seg], (tb - ta)[seg]
    ramp = dt > 0
    frac = np.divide(h - a, b - a, out=np.zeros_like(h), where=ramp)
    t = np.where(ramp, t_a + np.clip(frac, 0.0, 1.0) * dt, t_a) + CHANGE_GUARD_S
    order = np.lexsort((t, row))
    row, t = row[order].astype(np.int64), t[order]
    rgb = _quantised_at(plan, rows_of[row], t)
    # Keep candidates where the colour really differs from the one before
    # (crossings of several channels at once, ties at segment ends).
    before = np.empty_like(rgb)
    before[1:] = rgb[:-1]
    new_row = np.ones(len(row), dtype=bool)
    new_row[1:] = row[1:] != row[:-1]
    before[new_row] = quantise_rgb(plan.colors[rows_of[row[new_row]], 0])
    changed = (rgb != before).any(axis=1)
    return row[changed], t[changed], rgb[changed]


def _quantised_at(plan: Plan, tracks: IntArray, t: FloatArray) -> NDArray[np.uint8]:
    """(m, 3) quantised colour of track ``tracks[j]`` at ``t[j]``, as :meth:`Plan.colors_at`."""
    times = plan.color_times
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    span = times[k + 1] - times[k]
    w = np.divide(t - times[k], span, out=np.ones_like(t), where=span > 0)
    w = np.clip(w, 0.0, 1.0)[:, None]  # held before the first and after the last key
    c = (1.0 - w) * plan.colors[tracks, k] + w * plan.colors[tracks, k + 1]
    return quantise_rgb(c)


def rate_cap(row: IntArray, t: FloatArray, min_interval_s: float) -> NDArray[np.bool_]:
    """Which changes to keep so a row's kept changes are ``min_interval_s`` apart.

    ``row``/``t`` sorted by row then time.  Backwards from the end of each
    burst (see the module docstring), vectorised over all bursts at once:
    one ``searchsorted`` per kept change of the longest burst.
    """
    m = len(t)
    keep = np.zeros(m, dtype=bool)
    if m == 0:
        return keep
    if min_interval_s <= 0:
        keep[:] = True
        return keep
    # Sort key that keeps rows apart: row * span + time, rows >= 1 s apart.
    base = float(t.min()) - 1.0
    span = float(t.max()) - base + 1.0
    key = row * span + (t - base)
    gap = np.full(m, np.inf)
    same = row[1:] == row[:-1]
    gap[:-1] = np.where(same, t[1:] - t[:-1], np.inf)
    end = np.flatnonzero(gap >= min_interval_s)   # burst ends: always kept
    starts_at = np.ones(m, dtype=bool)
    starts_at[1:] = gap[:-1] >= min_interval_s    # burst starts
    start = np.flatnonzero(starts_at)             # same order as ``end``
    keep[end] = True
    current, floor = end, start
    while len(current):
        nxt = np.searchsorted(key, key[current] - min_interval_s, side="right") - 1
        ok = nxt >= floor
        current, floor = nxt[ok], floor[ok]
        keep[current] = True
    return keep


class LedSchedule:
    """The LED colour changes of a fixed set of vehicles, precomputed, looked up per window.

    Row ``i`` is the vehicle ``sysids[i]`` flying plan track ``tracks[i]``;
    ``delays`` passed to the methods are (n,) one-way link delays in that
    order, s.  Changes are returned by the window their *send* instant falls
    in, ``(t0, t1]`` on the show clock: consecutive windows never repeat or
    miss a change while the delays stay the same.  (If a vehicle's delay
    grows between calls, a change whose send instant moves back across the
    window boundary is not returned; the periodic refresh from
    :meth:`colour_at` repairs it.)
    """

    def __init__(self, plan: Plan, tracks: ArrayLike, sysids: Sequence[int],
                 min_interval_s: float = DEFAULT_MIN_INTERVAL_S) -> None:
        rows = np.asarray(tracks, dtype=np.int64).reshape(-1)
        ids = np.asarray(sysids, dtype=np.int64).reshape(-1)
        if not np.isfinite(min_interval_s) or min_interval_s < 0:
            raise ValueError(f"`min_interval_s` must be non-negative, got {min_interval_s}")
        if ids.shape != rows.shape:
            raise ValueError(f"`sysids` must have shape {rows.shape} like `tracks`, "
                             f"got {ids.shape}")
        bad = rows[(rows < 0) | (rows >= plan.drones)]
        if len(bad):
            raise ValueError(f"`tracks` names tracks {bad.tolist()} outside the plan's "
                             f"0..{plan.drones - 1}")
        if len(np.unique(ids)) != len(ids):
            raise ValueError("`sysids` must not repeat a system id")
        self.plan = plan
        self.tracks = rows
        self.sysids = ids
        self.min_interval_s = float(min_interval_s)
        self.initial = quantise_rgb(plan.colors[rows, 0]) if len(rows) else \
            np.zeros((0, 3), np.uint8)
        """(n, 3) colour each vehicle shows before its first change."""
        row, t, rgb = colour_changes(plan, rows)
        self.planned_changes = len(t)
        """Changes of the quantised plan colour before the rate cap."""
        keep = rate_cap(row, t, self.min_interval_s)
        self._row, self._time, self._rgb = row[keep], t[keep], rgb[keep]
        # One sorted key for the whole fleet: row * span + time, with every
        # row's times at least 1 s inside its own band, so one searchsorted
        # answers every vehicle's query and clipping a query to its band
        # cannot reach a neighbour's.
        lo = float(plan.color_times[0]) if len(plan.color_times) else 0.0
        hi = float(plan.color_times[-1]) if len(plan.color_times) else 0.0
        self._base = lo - 1.0
        self._span = hi - self._base + 2.0
        self._key = self._row * self._span + (self._time - self._base)
        self._band = np.arange(len(rows)) * self._span
        self._start = np.searchsorted(self._key, self._band).astype(np.int64)

    @classmethod
    def from_targets(cls, plan: Plan, targets: Sequence[StreamTarget],
                     min_interval_s: float = DEFAULT_MIN_INTERVAL_S) -> LedSchedule:
        """The schedule for the vehicles a :class:`SetpointStream` streams to, in its order."""
        return cls(plan, [t.track for t in targets], [t.sysid for t in targets], min_interval_s)

    def retrack(self, sysid: int, track: int) -> LedSchedule:
        """The schedule with ``sysid`` flying ``track`` (a spare taking over a track)."""
        rows = self.tracks.copy()
        rows[int(np.flatnonzero(self.sysids == sysid)[0])] = track
        return LedSchedule(self.plan, rows, self.sysids.tolist(), self.min_interval_s)

    def __len__(self) -> int:
        """Changes kept after the rate cap, all vehicles."""
        return len(self._time)

    def _delays(self, delays: ArrayLike) -> FloatArray:
        d = np.asarray(delays, dtype=float)
        n = len(self.tracks)
        if d.shape != (n,):
            raise ValueError(f"`delays` must have shape ({n},), got {d.shape}")
        if not np.isfinite(d).all() or (d < 0).any():
            raise ValueError(f"`delays` must be finite and non-negative, got {d.tolist()}")
        return d

    def _index(self, show_times: FloatArray) -> IntArray:
        """Per row, how many of its kept changes have show time <= ``show_times[row]``,
        as a position in the flat arrays."""
        q = self._band + np.clip(show_times - self._base, 0.0, self._span)
        return np.searchsorted(self._key, q, side="right").astype(np.int64)

    def window(self, t0: float, t1: float, delays: ArrayLike) -> LedBatch:
        """The changes to send with send instant in ``(t0, t1]``, sorted by send instant.

        The send instant of a change is its show time minus its vehicle's
        delay; the caller sends each at its ``send_at`` (not all at the
        window's start, which would make them up to a window early).
        """
        if not (np.isfinite(t0) and np.isfinite(t1)):
            raise ValueError(f"`t0` and `t1` must be finite, got {t0} and {t1}")
        if t1 < t0:
            raise ValueError(f"`t1` must not be before `t0`, got t0={t0}, t1={t1}")
        d = self._delays(delays)
        a = self._index(t0 + d)
        b = self._index(t1 + d)
        per = b - a
        total = int(per.sum())
        idx = np.repeat(a - (np.cumsum(per) - per), per) + np.arange(total)
        row = self._row[idx]
        show = self._time[idx]
        send = show - d[row]
        order = np.argsort(send, kind="stable")
        row, show, send, idx = row[order], show[order], send[order], idx[order]
        return LedBatch(rows=row, sysids=self.sysids[row], show_time=show, send_at=send,
                        rgb=self._rgb[idx])

    def changes(self, t0: float, t1: float, delays: ArrayLike) -> list[LedChange]:
        """:meth:`window` as a list of :class:`LedChange`, sorted by ``send_at``."""
        return self.window(t0, t1, delays).changes()

    def colour_at(self, show_time: float, delays: ArrayLike) -> NDArray[np.uint8]:
        """(n, 3) the colour each vehicle should show when a packet sent at ``show_time`` arrives.

        The scheduled (rate-capped) colour at ``show_time + delays[i]``, so a
        refresh repeats what the changes set and never shows a step the cap
        dropped.  For the periodic re-send: LED_CONTROL is never acknowledged.
        """
        if not np.isfinite(show_time):
            raise ValueError(f"`show_time` must be finite, got {show_time}")
        d = self._delays(delays)
        last = self._index(show_time + d) - 1
        has = last >= self._start  # else the row has had no change yet
        out = self.initial.copy()
        out[has] = self._rgb[last[has]]
        return out
