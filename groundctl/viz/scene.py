"""Writing plans and flights to Rerun: entities, timelines, blueprint.

Entity layout (shared by ``plan --rerun``, ``replay`` and the live stream):

- ``world/site/takeoff``, ``world/site/geofence`` -- static geometry;
- ``world/plan/paths`` (line segments in plan colours), ``world/plan/targets/<i>``
  (formation slots), ``world/plan/closest/<i>`` (each transition's closest approach);
- ``world/vehicles`` -- one row per tick: every vehicle's position (show frame,
  east-north-up metres before the show's heading), its LED colour, its system
  id as label; ``world/trails`` their last seconds; ``world/closest_pair`` the
  pair closest at that tick;
- ``series/separation/min`` and ``series/separation/limit``,
  ``series/tracking_error`` (one line per vehicle), ``series/lateness_ms``,
  ``series/battery`` (one line per vehicle);
- ``log`` -- events as a text log with levels.

Timelines: ``show_time`` (a duration, s) and ``wall_time`` (a timestamp).
Everything temporal goes through ``send_columns``, one call per entity.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import NDArray

from groundctl.errors import GroundctlError
from groundctl.plan.plan import Plan
from groundctl.vehicleid import spell
from groundctl.viz.eventlog import LogLine
from groundctl.viz.flight import FlightArrays

FloatArray = NDArray[np.float64]

APP_ID = "groundctl"
#: Vehicle sphere radius, m.
VEHICLE_RADIUS = 0.3
#: A trail's length and the spacing of its points, in ticks.
TRAIL_TICKS, TRAIL_STEP = 20, 2
#: Plan paths are drawn from samples this far apart, s.
PATH_STEP_S = 0.25
#: The planned fleet of ``plan --rerun`` moves in steps of this, s.
PLAN_FRAME_S = 0.1
#: Longest wait for a viewer (``connect``, ``spawn``) to take a recording at the end, s.
FLUSH_TIMEOUT_S = 30.0

#: A viewer spawned beside a flight keeps to this much of the machine's memory (Rerun's
#: default, 75 %, can push the ground station into swap on a long show: loop stalls).
VIEWER_MEMORY = "25%"


@dataclass(frozen=True)
class RerunTarget:
    """Where a Rerun recording goes: ``save PATH``, ``spawn`` a viewer, ``connect URL``."""

    kind: Literal["save", "spawn", "connect"]
    """What to do."""
    where: str | None = None
    """The file for ``save``, the gRPC URL for ``connect`` (None: Rerun's default)."""


def blueprint() -> rrb.Blueprint:
    """3D view, the time series and the event log side by side, on the show's time."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", name="show"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/series/separation", name="minimum separation (m)"),
                rrb.TimeSeriesView(origin="/series/tracking_error", name="tracking error (m)"),
                rrb.TimeSeriesView(origin="/series/lateness_ms", name="setpoint lateness (ms)"),
                rrb.TimeSeriesView(origin="/series/battery", name="battery (%)"),
            ),
            rrb.TextLogView(origin="/log", name="events"),
            column_shares=[3, 2, 2],
        ),
        rrb.TimePanel(timeline="show_time"),
        collapse_panels=False,
    )


def open_recording(targets: Sequence[RerunTarget], name: str) -> rr.RecordingStream:
    """A new recording stream sent to every one of ``targets``, with the blueprint."""
    rec = rr.RecordingStream(APP_ID, make_default=False)
    bp = blueprint()
    try:
        for target in targets:
            if target.kind == "save" and target.where:
                Path(target.where).parent.mkdir(parents=True, exist_ok=True)
        if len(targets) == 1:
            target = targets[0]
            if target.kind == "save":
                assert target.where is not None
                rec.save(target.where, default_blueprint=bp)
            elif target.kind == "spawn":
                rec.spawn(default_blueprint=bp, memory_limit=VIEWER_MEMORY)
            else:
                rec.connect_grpc(target.where, default_blueprint=bp)
        else:
            sinks: list[rr.FileSink | rr.GrpcSink] = []
            for target in targets:
                if target.kind == "save":
                    sinks.append(rr.FileSink(str(target.where)))
                else:
                    if target.kind == "spawn":
                        rr.spawn(connect=False, recording=rec, memory_limit=VIEWER_MEMORY)
                    sinks.append(rr.GrpcSink(target.where) if target.where else rr.GrpcSink())
            rec.set_sinks(*sinks, default_blueprint=bp)
    except (OSError, RuntimeError, ValueError) as exc:
        what = ", ".join(f"{t.kind} {t.where or ''}".strip() for t in targets)
        raise GroundctlError(f"rerun ({what}): {exc}") from exc
    rec.send_recording_name(name)
    return rec


def close_recording(rec: rr.RecordingStream, timeout_s: float = FLUSH_TIMEOUT_S) -> None:
    """Flush (at most ``timeout_s``) and disconnect; a viewer that cannot be reached is one
    :class:`GroundctlError` (what went to a file is written all the same)."""
    try:
        rec.flush(timeout_sec=timeout_s)
    except RuntimeError as exc:
        raise GroundctlError(f"rerun: {exc}") from exc
    finally:
        rec.disconnect()


def _times(show: FloatArray, unix: FloatArray | None) -> list[rr.TimeColumn]:
    """The rows' time columns; a live stream's rows before the show clock started have
    no show time (NaN) and are on ``wall_time`` only."""
    show = np.asarray(show, dtype=float)
    cols = []
    if unix is None or np.isfinite(show).all():
        cols.append(rr.TimeColumn("show_time", duration=show))
    if unix is not None:
        cols.append(rr.TimeColumn("wall_time", timestamp=np.asarray(unix, dtype=float)))
    return cols


def _rgb(colors01: FloatArray) -> NDArray[np.uint8]:
    return np.clip(np.rint(np.asarray(colors01) * 255.0), 0, 255).astype(np.uint8)


def plan_colours(plan: Plan, times: FloatArray) -> NDArray[np.uint8]:
    """(n, T, 3) every track's plan colour at ``times`` (linear between colour keys, held
    beyond them, as ``Plan.colors_at``)."""
    keys, cols = plan.color_times, plan.colors  # (K,), (n, K, 3)
    t = np.clip(np.asarray(times, dtype=float), keys[0], keys[-1])
    hi = np.clip(np.searchsorted(keys, t, side="right"), 1, len(keys) - 1)
    lo = hi - 1
    span = keys[hi] - keys[lo]
    w = np.where(span > 0, (t - keys[lo]) / np.where(span > 0, span, 1.0), 0.0)
    if len(keys) == 1:
        return _rgb(np.repeat(cols[:, :1], len(t), axis=1))
    out = cols[:, lo] * (1.0 - w)[None, :, None] + cols[:, hi] * w[None, :, None]
    return _rgb(out)


# -- static geometry --------------------------------------------------------------------
def log_site(rec: rr.RecordingStream, plan: Plan) -> None:
    """Takeoff grid and geofence (a prism from the lowest to the highest altitude)."""
    rec.log("world/site/takeoff", rr.Points3D(plan.home, radii=0.1, colors=(160, 160, 160),
                                              labels=[f"T{i}" for i in range(plan.drones)],
                                              show_labels=False), static=True)
    fence = plan.limits.geofence
    if fence:
        xy = np.array((*fence, fence[0]), dtype=float)
        lo = np.column_stack([xy, np.full(len(xy), plan.limits.min_alt)])
        hi = np.column_stack([xy, np.full(len(xy), plan.limits.max_alt)])
        posts = [np.stack([a, b]) for a, b in zip(lo[:-1], hi[:-1], strict=True)]
        rec.log("world/site/geofence", rr.LineStrips3D([lo, hi, *posts], radii=0.05,
                                                       colors=(255, 80, 0)), static=True)


def log_plan(rec: rr.RecordingStream, plan: Plan) -> None:
    """The planned paths in plan colours, the formation slots, the site, and each
    transition's closest approach (a segment between the pair, labelled)."""
    from groundctl.plan.verify import verify

    log_site(rec, plan)
    times = np.arange(0.0, plan.duration + PATH_STEP_S, PATH_STEP_S)
    times[-1] = min(times[-1], plan.duration)
    pos, _, _ = plan.trajectories.evaluate(times)  # (n, S, 3)
    cols = plan_colours(plan, times)
    seg = np.stack([pos[:, :-1], pos[:, 1:]], axis=2).reshape(-1, 2, 3)
    # (segments, 2, 3) is a batch of strips; the stubs want a sequence.
    rec.log("world/plan/paths", rr.LineStrips3D(cast(Any, seg), radii=0.03,
                                                colors=cols[:, :-1].reshape(-1, 3)),
            static=True)
    for w in plan.formations:
        rec.log(f"world/plan/targets/{w.index}", rr.Points3D(
            w.goals, radii=0.08, colors=plan_colours(plan, np.array([w.arrive]))[:, 0],
            labels=[w.name] * len(w.goals), show_labels=False), static=True)
    ver = verify(plan)
    for w, m in zip(plan.formations, ver.windows, strict=True):
        a, b = m.min_separation_pair
        if a < 1 or b < 1:
            continue
        at, _, _ = plan.trajectories.evaluate(m.min_separation_time,
                                              np.array([a - 1, b - 1], dtype=np.intp))
        close = m.min_separation < plan.limits.min_separation
        label = (f"into {w.name}: {m.min_separation:.2f} m (limit "
                 f"{plan.limits.min_separation:g}) tracks {a - 1} & {b - 1} at "
                 f"t={m.min_separation_time:.1f} s")
        rec.log(f"world/plan/closest/{w.index}", rr.LineStrips3D(
            [at], radii=0.06, colors=(255, 0, 0) if close else (255, 220, 0),
            labels=[label], show_labels=True), static=True)


def log_planned_fleet(rec: rr.RecordingStream, plan: Plan) -> None:
    """``plan --rerun``: the fleet flying its plan on ``show_time``, labelled by track."""
    times = np.arange(0.0, plan.duration + 1e-9, PLAN_FRAME_S)
    pos, _, _ = plan.trajectories.evaluate(times)  # (n, T, 3)
    cols = plan_colours(plan, times)
    n, t_count = plan.drones, len(times)
    rec.log("world/vehicles", rr.Points3D.from_fields(radii=VEHICLE_RADIUS), static=True)
    rec.send_columns("world/vehicles", indexes=_times(times, None), columns=rr.Points3D.columns(
        positions=pos.transpose(1, 0, 2).reshape(-1, 3),
        colors=cols.transpose(1, 0, 2).reshape(-1, 3),
        labels=np.tile([str(i) for i in range(n)], t_count)).partition(np.full(t_count, n)))


# -- a flight ---------------------------------------------------------------------------
def log_vehicles(rec: rr.RecordingStream, fa: FlightArrays, rows: slice | None = None
                 ) -> None:
    """``world/vehicles``, ``world/trails`` and ``world/closest_pair`` for ticks ``rows``."""
    sl = rows or slice(None)
    show, unix = fa.show_time[sl], fa.unix_s[sl]
    pos, colours = fa.positions[sl], fa.colours[sl]
    mask = np.isfinite(pos[..., 0])
    labels = np.array([spell(int(s)) for s in fa.sysids])
    rec.send_columns("world/vehicles", indexes=_times(show, unix), columns=rr.Points3D.columns(
        positions=pos[mask], colors=colours[mask],
        labels=np.broadcast_to(labels, mask.shape)[mask]).partition(mask.sum(axis=1)))
    log_trails(rec, fa, sl)
    pairs = fa.min_pair[sl]
    ok = np.isfinite(fa.min_separation[sl]) & (pairs[:, 0] > 0)
    if ok.any():
        index = {s: j for j, s in enumerate(fa.sysids)}
        ia = np.array([index.get(int(s), 0) for s in pairs[ok, 0]])
        ib = np.array([index.get(int(s), 0) for s in pairs[ok, 1]])
        k = np.flatnonzero(ok)
        strips = np.stack([pos[k, ia], pos[k, ib]], axis=1)
        rec.send_columns("world/closest_pair", indexes=_times(show[ok], unix[ok]),
                         columns=rr.LineStrips3D.columns(
                             strips=strips,
                             labels=[f"{d:.2f} m" for d in fa.min_separation[sl][ok]]))


def log_trails(rec: rr.RecordingStream, fa: FlightArrays, sl: slice) -> None:
    """Each vehicle's last :data:`TRAIL_TICKS` ticks, one row every :data:`TRAIL_STEP`.

    A trail point where the vehicle was not heard repeats its present position
    (fixed-length strips, built without a loop over vehicles)."""
    t_all = np.arange(len(fa.unix_s))[sl]
    rows = t_all[::TRAIL_STEP]
    if rows.size == 0:
        return
    back = np.arange(-TRAIL_TICKS + TRAIL_STEP, 1, TRAIL_STEP)  # e.g. -18, -16, ..., 0
    idx = np.clip(rows[:, None] + back[None, :], 0, None)  # (R, L)
    win = fa.positions[idx].transpose(0, 2, 1, 3)  # (R, n, L, 3)
    here = win[:, :, -1]  # (R, n, 3)
    present = np.isfinite(here[..., 0])  # (R, n)
    filled = np.where(np.isfinite(win), win, here[:, :, None, :])
    strips = filled[present]  # (S, L, 3)
    if len(strips) == 0:
        return
    colours = fa.colours[rows][present]
    rec.send_columns("world/trails", indexes=_times(fa.show_time[rows], fa.unix_s[rows]),
                     columns=rr.LineStrips3D.columns(strips=cast(Any, strips), colors=colours)
                     .partition(present.sum(axis=1)))


def log_styles(rec: rr.RecordingStream, sysids: Sequence[int], limit: float | None) -> None:
    """Static styles: vehicle and trail radii, series line names (one per vehicle)."""
    rec.log("world/vehicles", rr.Points3D.from_fields(radii=VEHICLE_RADIUS), static=True)
    rec.log("world/trails", rr.LineStrips3D.from_fields(radii=0.04), static=True)
    rec.log("world/closest_pair", rr.LineStrips3D.from_fields(radii=0.03, colors=(255, 60, 60)),
            static=True)
    names = [f"vehicle {spell(int(s))}" for s in sysids]
    rec.log("series/tracking_error", rr.SeriesLines(names=names), static=True)
    rec.log("series/battery", rr.SeriesLines(names=names), static=True)
    rec.log("series/separation/min", rr.SeriesLines(names="closest pair", colors=(0, 160, 255)),
            static=True)
    if limit is not None:
        rec.log("series/separation/limit", rr.SeriesLines(names=f"limit {limit:g} m",
                                                          colors=(255, 0, 0)), static=True)


def log_series(rec: rr.RecordingStream, fa: FlightArrays, limit: float | None,
               rows: slice | None = None) -> None:
    """Minimum separation (with the limit), tracking error, lateness, battery."""
    sl = rows or slice(None)
    show, unix = fa.show_time[sl], fa.unix_s[sl]
    if len(show) == 0:
        return
    sep = fa.min_separation[sl]
    ok = np.isfinite(sep)
    if ok.any():
        rec.send_columns("series/separation/min", indexes=_times(show[ok], unix[ok]),
                         columns=rr.Scalars.columns(scalars=sep[ok]))
    if limit is not None:
        ends = np.array([0, len(show) - 1])
        rec.send_columns("series/separation/limit", indexes=_times(show[ends], unix[ends]),
                         columns=rr.Scalars.columns(scalars=np.full(2, limit)))
    n = len(fa.sysids)
    for path, values in (("series/tracking_error", fa.tracking_error[sl]),
                         ("series/battery", fa.battery[sl])):
        some = np.isfinite(values).any(axis=1)
        if n and some.any():
            rec.send_columns(path, indexes=_times(show[some], unix[some]),
                             columns=rr.Scalars.columns(scalars=values[some].reshape(-1))
                             .partition(np.full(int(some.sum()), n)))
    late = fa.lateness_ms[sl]
    ok = np.isfinite(late)
    if ok.any():
        rec.send_columns("series/lateness_ms", indexes=_times(show[ok], unix[ok]),
                         columns=rr.Scalars.columns(scalars=late[ok]))


def log_lines(rec: rr.RecordingStream, show: FloatArray, unix: FloatArray | None,
              lines: Sequence[LogLine]) -> None:
    """``log``: one text line per event, with its level."""
    if not lines:
        return
    order = np.argsort(show if unix is None else unix, kind="stable")
    rec.send_columns("log", indexes=_times(show[order], None if unix is None else unix[order]),
                     columns=rr.TextLog.columns(text=[lines[k].text for k in order],
                                                level=[lines[k].level for k in order]))
