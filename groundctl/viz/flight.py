"""What a replay shows, computed from a decoded tlog: pure numpy, no Rerun, no files.

Everything is put on the executor's ticks (the recording's show clock log):
there the flight monitor measured the flight, so the positions, the minimum
separation and the tracking error shown are the ones the report measured.
As the monitor does (:func:`groundctl.flight.monitor.telemetry_positions`),
each vehicle's last LOCAL_POSITION_NED received before a tick is carried to
the tick with its own velocity, from the instant it was measured: the
vehicle's ``time_boot_ms`` put on Unix time by a fit of the vehicle's clock
against the recording's stamps (the rate of the vehicle clock, and the
earliest any packet arrived).  A sample older than
:data:`~groundctl.flight.monitor.MAX_SAMPLE_AGE_S` is not used.

NED becomes show frame through each vehicle's own EKF origin and the plan's
origin and heading, by the same pymap3d conversions as
:func:`groundctl.execute.frames.ned_to_show`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
import pymap3d
from numpy.typing import NDArray

from groundctl.execute.frames import geodetic_to_show, ned_vel_to_show
from groundctl.flight.monitor import MAX_SAMPLE_AGE_S, nearest_pair
from groundctl.plan.plan import Plan
from groundctl.record.showclock import ShowClockTable
from groundctl.show.model import GeoOrigin
from groundctl.viz.tlogread import TlogData

FloatArray = NDArray[np.float64]

#: Half the tlog's resolution (its stamps are whole microseconds): two stamps this close are
#: the same instant.
STAMP_TOLERANCE_S = 0.5e-6
#: Colour of a vehicle before any LED_CONTROL was sent to it.
NO_LED = (90, 90, 90)
#: Tick period assumed for a bare tlog (no show clock log), in vehicle seconds.
BARE_TICK_S = 0.1
#: Clock rates a bare tlog's ticks are laid out at, at most and at least, and the longest
#: stretch of it replayed (a day).
MIN_RATE, MAX_RATE = 0.1, 100.0
MAX_BARE_S = 86400.0


@dataclass(frozen=True)
class FlightArrays:
    """A flight on its ticks: ``T`` ticks, ``n`` vehicles (columns in ``sysids`` order)."""

    sysids: tuple[int, ...]
    """The vehicles, ascending."""
    tracks: dict[int, int]
    """Plan track of each vehicle that has one."""
    origin: GeoOrigin
    """The show frame (the plan's origin, or a vehicle's EKF origin without a plan)."""
    unix_s: FloatArray
    """(T,) Unix time of each tick."""
    show_time: FloatArray
    """(T,) the ``show_time`` timeline (:meth:`ShowClockTable.timeline`)."""
    show_clock: FloatArray
    """(T,) the show clock itself (NaN before it started, or without a clock log)."""
    positions: FloatArray
    """(T, n, 3) show-frame positions, NaN where a vehicle had no fresh telemetry."""
    colours: NDArray[np.uint8]
    """(T, n, 3) the LED colour last commanded to each vehicle."""
    tracking_error: FloatArray
    """(T, n) distance from the plan at the show clock, m (NaN outside the show)."""
    min_separation: FloatArray
    """(T,) closest distance between any two vehicles heard, m (NaN with fewer than two)."""
    min_pair: NDArray[np.int64]
    """(T, 2) system ids of that pair (0, 0 where none)."""
    lateness_ms: FloatArray
    """(T,) setpoint lateness of the tick, ms (NaN: unknown)."""
    battery: FloatArray
    """(T, n) remaining battery, % (NaN: not reported yet)."""
    estimated_clock: bool
    """True without a show clock log: ticks and ``show_time`` estimated from the tlog."""
    speed: float = 1.0
    """Executor (simulated) seconds per Unix second: 1 for a real flight, K for a dry-run
    at ``--speed K``."""

    def rows(self, keep: NDArray[np.bool_]) -> FlightArrays:
        """The same flight on the ticks where ``keep`` is true."""
        return replace(self, unix_s=self.unix_s[keep], show_time=self.show_time[keep],
                       show_clock=self.show_clock[keep], positions=self.positions[keep],
                       colours=self.colours[keep], tracking_error=self.tracking_error[keep],
                       min_separation=self.min_separation[keep], min_pair=self.min_pair[keep],
                       lateness_ms=self.lateness_ms[keep], battery=self.battery[keep])

    def show_time_at(self, unix_s: FloatArray) -> FloatArray:
        """The ``show_time`` timeline at Unix times: between the ticks interpolated, before
        the first and after the last run on at :attr:`speed` (pre-flight, shutdown)."""
        u = np.asarray(unix_s, dtype=float)
        if len(self.unix_s) == 0:
            return np.zeros_like(u)
        inside = np.interp(u, self.unix_s, self.show_time)
        before = self.show_time[0] + (u - self.unix_s[0]) * self.speed
        after = self.show_time[-1] + (u - self.unix_s[-1]) * self.speed
        return np.where(u < self.unix_s[0], before, np.where(u > self.unix_s[-1], after,
                                                             inside))


def show_frame_origin(plan: Plan | None, data: TlogData) -> GeoOrigin:
    """The plan's origin, or (no plan) the lowest system id's first EKF origin, heading 0."""
    if plan is not None:
        return plan.origin
    for sysid in sorted(data.origins):
        _, lat, lon, alt = data.origins[sysid][0]
        return GeoOrigin(lat, lon, alt, 0.0)
    return GeoOrigin(0.0, 0.0, 0.0, 0.0)


def sample_origins(data: TlogData, sysid: int, unix_s: FloatArray) -> FloatArray | None:
    """(m, 3) lat, lon, alt of the EKF origin in force for each of ``sysid``'s samples
    (the latest received before it, else its first), or None if it never sent one."""
    got = data.origins.get(sysid)
    if not got:
        return None
    arr = np.array(got, dtype=float)
    k = np.clip(np.searchsorted(arr[:, 0], unix_s, side="right") - 1, 0, len(arr) - 1)
    return arr[k, 1:]


def ned_rows_to_show(origin: GeoOrigin, ekf: FloatArray, ned: FloatArray) -> FloatArray:
    """(m, 3) local NED rows, each with its own EKF origin row (lat, lon, alt), as show
    frame: NED -> geodetic at the EKF origin -> show frame (as ``frames.ned_to_show``)."""
    lat, lon, alt = pymap3d.ned2geodetic(ned[:, 0], ned[:, 1], ned[:, 2],
                                         ekf[:, 0], ekf[:, 1], ekf[:, 2])
    return geodetic_to_show(origin, lat, lon, alt)


def measured_at(unix_s: FloatArray, boot_s: FloatArray) -> tuple[FloatArray, float]:
    """When each sample was measured, on Unix time, and the vehicle clock's rate
    (vehicle seconds per Unix second).

    The vehicle clock against the stamps is a line (a dry-run's vehicles run
    K times faster); fitted by least squares for its slope and placed by the
    earliest-arriving sample (no packet arrives before it was sent).
    """
    if len(unix_s) < 2 or np.ptp(boot_s) <= 0 or np.ptp(unix_s) <= 0:
        return unix_s.copy(), 1.0
    rate, _ = np.polyfit(unix_s - unix_s[0], boot_s - boot_s[0], 1)
    if not rate > 0:
        return unix_s.copy(), 1.0
    wall = boot_s / rate
    offset = float(np.min(unix_s - wall))
    return wall + offset, float(rate)


def led_at(data: TlogData, sysid: int, unix_s: FloatArray) -> NDArray[np.uint8]:
    """(T, 3) the colour last sent to ``sysid`` (or to every vehicle) before each time."""
    times = []
    cols = []
    for target in (sysid, 0):
        if target in data.leds:
            times.append(data.leds[target][0])
            cols.append(data.leds[target][1])
    out = np.tile(np.array(NO_LED, dtype=np.uint8), (len(unix_s), 1))
    if not times:
        return out
    t = np.concatenate(times)
    c = np.concatenate(cols)
    order = np.argsort(t, kind="stable")
    t, c = t[order], c[order]
    # At or before: the tlog stamps to the microsecond and the tick's time went through
    # decimal text, so a colour sent at the tick's own instant (a paced clock stands still
    # within a tick) may read a fraction of a microsecond later.
    k = np.searchsorted(t, np.asarray(unix_s) + STAMP_TOLERANCE_S, side="right") - 1
    ok = k >= 0
    out[ok] = c[k[ok]]
    return out


def separations(positions: FloatArray, sysids: tuple[int, ...]
                ) -> tuple[FloatArray, NDArray[np.int64]]:
    """Per tick: the closest distance between any two vehicles present and their ids
    (the monitor's own :func:`~groundctl.flight.monitor.nearest_pair` per tick)."""
    t_count = positions.shape[0]
    dist = np.full(t_count, np.nan)
    pair = np.zeros((t_count, 2), dtype=np.int64)
    ids = np.asarray(sysids, dtype=np.int64)
    present = np.isfinite(positions[..., 0])
    for k in np.flatnonzero(present.sum(axis=1) >= 2):
        cols = np.flatnonzero(present[k])
        sep = nearest_pair([int(s) for s in ids[cols]], positions[k, cols])
        assert sep.pair is not None  # two or more present
        dist[k] = sep.distance_m
        pair[k] = sep.pair
    return dist, pair


def _ticks(data: TlogData, clock: ShowClockTable | None, rate: float
           ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, float]:
    """(unix, show_time timeline, show clock, lateness, speed) of the ticks."""
    if clock is not None and clock.ticks >= 2:
        speed = float((clock.now_s[-1] - clock.now_s[0])
                      / max(clock.wall_unix_s[-1] - clock.wall_unix_s[0], 1e-9))
        return (clock.wall_unix_s, clock.timeline(), clock.show_time_s, clock.lateness_ms,
                speed)
    # A bare tlog: ticks every BARE_TICK_S of the vehicles' clock, time from the first packet.
    first = data.first_unix_s or 0.0
    last = data.last_unix_s or first
    # The vehicles' clock rate against the tlog's (x1 flown, x2 a dry-run at speed 2): a
    # file with reboots or stray stamps must not ask for billions of ticks.
    rate = min(max(rate, MIN_RATE), MAX_RATE)
    last = min(last, first + MAX_BARE_S)
    unix = np.arange(first, last + 1e-9, BARE_TICK_S / rate)
    nan = np.full(len(unix), np.nan)
    return unix, (unix - first) * rate, nan, nan, rate


def flight_arrays(data: TlogData, plan: Plan | None, clock: ShowClockTable | None,
                  tracks: Mapping[int, int] | None = None) -> FlightArrays:
    """The flight on its ticks (see the module docstring); ``tracks`` maps system ids to
    plan tracks (from the report or the pre-flight event), None if unknown."""
    origin = show_frame_origin(plan, data)
    pos = data.positions
    sysids = tuple(sorted(set(int(s) for s in np.unique(pos.sysid)) & set(data.origins)))
    per: dict[int, tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = {}
    rates = []
    for sysid in sysids:
        rows = pos.sysid == sysid
        recv = pos.unix_s[rows]
        measured, rate = measured_at(recv, pos.boot_s[rows])
        rates.append(rate)
        ekf = sample_origins(data, sysid, recv)
        assert ekf is not None
        xyz = ned_rows_to_show(origin, ekf, pos.ned[rows])
        vel = ned_vel_to_show(origin, pos.vel_ned[rows])
        per[sysid] = (recv, measured, xyz, vel)
    rate = float(np.median(rates)) if rates else 1.0
    unix, timeline, show_clock, lateness, speed = _ticks(data, clock, rate)
    t_count, n = len(unix), len(sysids)
    positions = np.full((t_count, n, 3), np.nan)
    colours = np.zeros((t_count, n, 3), dtype=np.uint8)
    battery = np.full((t_count, n), np.nan)
    for j, sysid in enumerate(sysids):
        recv, measured, xyz, vel = per[sysid]
        k = np.searchsorted(recv, unix, side="right") - 1
        ok = k >= 0
        kk = np.where(ok, k, 0)
        age = (unix - measured[kk]) * speed  # in the vehicles' (simulated) seconds
        ok &= age <= MAX_SAMPLE_AGE_S
        carried = xyz[kk] + vel[kk] * np.maximum(age, 0.0)[:, None]
        positions[ok, j] = carried[ok]
        colours[:, j] = led_at(data, sysid, unix)
        if sysid in data.battery:
            bt, bv = data.battery[sysid]
            b = np.searchsorted(bt, unix, side="right") - 1
            battery[b >= 0, j] = bv[b[b >= 0]]
    min_sep, min_pair = separations(positions, sysids)
    known = {s: t for s, t in (tracks or {}).items() if s in sysids}
    error = np.full((t_count, n), np.nan)
    if plan is not None and known:
        # As the monitor: while the show runs, not while the fleet lands after its end.
        in_show = np.isfinite(show_clock) & (show_clock >= 0)
        ended = np.flatnonzero(in_show & (show_clock >= plan.duration - 1e-6))
        if ended.size:
            in_show[ended[0] + 1:] = False
        cols = np.array([sysids.index(s) for s in known])
        trk = np.array(list(known.values()), dtype=np.intp)
        if in_show.any():
            planned, _, _ = plan.trajectories.evaluate(show_clock[in_show], trk)  # (m, T', 3)
            here = positions[in_show][:, cols]  # (T', m, 3)
            error[np.ix_(in_show, cols)] = np.linalg.norm(here - planned.transpose(1, 0, 2),
                                                          axis=2)
    return FlightArrays(sysids=sysids, tracks=known, origin=origin, unix_s=unix,
                        show_time=timeline, show_clock=show_clock, positions=positions,
                        colours=colours, tracking_error=error, min_separation=min_sep,
                        min_pair=min_pair, lateness_ms=lateness, battery=battery,
                        estimated_clock=clock is None or clock.ticks < 2, speed=speed)
