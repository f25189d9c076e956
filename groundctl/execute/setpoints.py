"""Setpoints and LED colours for the whole fleet at one instant, in each vehicle's frame.

A setpoint sent at our time ``now`` reaches the vehicle a little later and is
tracked with the vehicle's own response delay, so :meth:`SetpointStream.at`
evaluates the plan each vehicle's lead ahead of the show clock (one lead for
all, or per vehicle from :mod:`groundctl.execute.lead`); ``time_boot_ms``
stamps the same instant on the vehicle's clock (vehicle time = our time +
TIMESYNC offset).  Everything is vectorised over
the fleet: one plan evaluation, one geodetic conversion per tick.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from groundctl.execute.frames import show_to_ned, show_vel_to_ned
from groundctl.execute.paths import Path, PathClocks, plan_path, sample_paths
from groundctl.execute.showclock import ShowClock
from groundctl.link.state import GeoPoint, Vec3
from groundctl.plan.plan import Plan

FloatArray = NDArray[np.float64]

DEFAULT_LEAD_S = 0.15


@dataclass(frozen=True)
class StreamTarget:
    """One vehicle to stream to."""

    sysid: int
    """MAVLink system id."""
    track: int
    """The plan track it flies."""
    ekf_origin: GeoPoint
    """Its local NED origin (GPS_GLOBAL_ORIGIN)."""


@dataclass(frozen=True)
class Setpoint:
    """What to send one vehicle this tick."""

    sysid: int
    """MAVLink system id."""
    time_boot_ms: int
    """The instant the setpoint is for, on the vehicle's clock (0 if its offset is unknown)."""
    pos_ned: Vec3
    """Position in its local NED frame, m."""
    vel_ned: Vec3
    """Velocity feed-forward, m/s."""
    acc_ned: Vec3
    """Acceleration feed-forward, m/s^2."""
    rgb: tuple[int, int, int]
    """LED colour, 0-255 each."""


@dataclass(frozen=True)
class Setpoints:
    """The fleet's setpoints for one tick, row i for ``sysids[i]``."""

    sysids: tuple[int, ...]
    """System ids, in the stream's target order."""
    time_boot_ms: NDArray[np.int64]
    """(n,) vehicle-clock stamps, ms."""
    pos_ned: FloatArray
    """(n, 3) positions, each in its vehicle's NED frame."""
    vel_ned: FloatArray
    """(n, 3) velocity feed-forward."""
    acc_ned: FloatArray
    """(n, 3) acceleration feed-forward."""
    rgb: NDArray[np.uint8]
    """(n, 3) colours, 0-255."""

    def __iter__(self) -> Iterator[Setpoint]:
        for i, sysid in enumerate(self.sysids):
            yield Setpoint(sysid, int(self.time_boot_ms[i]),
                           tuple(map(float, self.pos_ned[i])),  # type: ignore[arg-type]
                           tuple(map(float, self.vel_ned[i])),  # type: ignore[arg-type]
                           tuple(map(float, self.acc_ned[i])),  # type: ignore[arg-type]
                           (int(self.rgb[i, 0]), int(self.rgb[i, 1]), int(self.rgb[i, 2])))

    def __len__(self) -> int:
        return len(self.sysids)


def quantise_rgb(rgb: ArrayLike) -> NDArray[np.uint8]:
    """Colours in [0, 1] as 0-255 integers (rounded, clipped)."""
    return np.clip(np.rint(np.asarray(rgb, dtype=float) * 255.0), 0, 255).astype(np.uint8)


class SetpointStream:
    """Turns plan states into per-vehicle setpoints for a fixed set of vehicles."""

    def __init__(self, plan: Plan, targets: Sequence[StreamTarget],
                 lead_s: float = DEFAULT_LEAD_S) -> None:
        if lead_s < 0:
            raise ValueError(f"`lead_s` must be non-negative, got {lead_s}")
        tracks = [t.track for t in targets]
        bad = [t for t in tracks if not 0 <= t < plan.drones]
        if bad:
            raise ValueError(f"`targets` name tracks {bad} outside the plan's 0..{plan.drones - 1}")
        if len({t.sysid for t in targets}) != len(targets):
            raise ValueError("`targets` must not repeat a system id")
        self.plan = plan
        self.targets = tuple(targets)
        self.lead_s = lead_s
        """The lead every vehicle starts with (all of them, unless :meth:`set_leads`)."""
        self.leads = np.full(len(self.targets), float(lead_s))
        """(n,) lead per target, s, in the targets' order."""
        self.sysids = tuple(t.sysid for t in targets)
        self._tracks = np.array(tracks, dtype=int)
        self._origins = [t.ekf_origin for t in targets]
        self._index = {t.sysid: i for i, t in enumerate(targets)}

    def retrack(self, sysid: int, track: int) -> None:
        """``sysid`` flies ``track`` from now on (a spare taking over a track: two
        vehicles may share a track while one leaves it and the other joins)."""
        if not 0 <= track < self.plan.drones:
            raise ValueError(f"track {track} is outside the plan's 0..{self.plan.drones - 1}")
        self._tracks[self._index[sysid]] = track
        self.targets = tuple(StreamTarget(t.sysid, track, t.ekf_origin) if t.sysid == sysid
                             else t for t in self.targets)

    def set_leads(self, leads: Mapping[int, float]) -> None:
        """Per-vehicle leads (system id -> s); vehicles not named keep theirs."""
        for sysid, lead in leads.items():
            if not lead >= 0:
                raise ValueError(f"the lead of vehicle {sysid} must be non-negative, got {lead}")
            self.leads[self._index[sysid]] = float(lead)

    @property
    def typical_lead(self) -> float:
        """The median lead of the fleet, s (the show time the last setpoints were for)."""
        return float(np.median(self.leads)) if len(self.leads) else self.lead_s

    def lead_of(self, sysid: int) -> float:
        """The lead ``sysid`` is streamed with, s."""
        return float(self.leads[self._index[sysid]])

    def landing_slots(self) -> FloatArray:
        """(n, 3) show-frame points the targets descend from: above their landing spots."""
        return self.plan.landing_hover[self._tracks]

    def at(self, now: float, clock_offsets: Mapping[int, float | None], *,
           clock: ShowClock | None = None, show_time: float = 0.0, ended: bool = False,
           paths: Mapping[int, Path] | None = None, clocks: PathClocks | None = None,
           replanned: Mapping[int, tuple[ArrayLike, ArrayLike, ArrayLike]] | None = None,
           delays: NDArray[np.float64] | None = None) -> Setpoints:
        """Setpoints at our time ``now``, each for the instant its vehicle's lead later.

        Each vehicle is sampled on its path (``paths``, system id -> Path, on ``clocks``;
        a vehicle without one, on its plan track): velocity and acceleration scaled by
        the clock's rate (``rate * p'``, ``rate**2 * p'' + rate' * p'``), so a braking
        clock brakes every drone along its own path.  Without a running ``clock``
        (before the start, after the end) the plan at ``show_time`` is held with no
        feed-forward.  ``replanned`` (system id -> show-frame position, velocity,
        acceleration, already evaluated at that vehicle's instant ``now + lead``) replaces
        the path of a vehicle under MPC.  ``delays`` (per vehicle, in stream order): how
        long after ``now`` each vehicle's setpoint leaves (the tick spread over its
        period): it is taken for its own sending instant, its lead after that.
        """
        duration = self.plan.duration
        stamp_s = now + self.leads if delays is None else now + self.leads + delays
        if clocks is None:
            clocks = PathClocks(self.plan, clock, show_time, ended)
        paths = paths or {}
        bad = [s for s in paths if s not in self._index]
        if bad:
            raise ValueError(f"`paths` names vehicle {bad[0]}, which is not streamed")
        rows = [paths.get(t.sysid) or plan_path(t.track)
                for t in self.targets]
        pos, vel, acc = sample_paths(rows, stamp_s, clocks)
        for sysid, (p, v, a) in (replanned or {}).items():
            i = self._index.get(sysid)
            if i is None:
                raise ValueError(f"`replanned` names vehicle {sysid}, which is not streamed")
            pos[i], vel[i], acc[i] = p, v, a
        clock, ended, show_time = clocks.show, clocks.ended, clocks.show_time
        t0 = min(max(show_time, 0.0), duration)
        offsets = np.array([np.nan if (o := clock_offsets.get(s)) is None else o
                            for s in self.sysids], dtype=float)
        # Unknown offset: 0 is what autopilots read as "no timestamp" (both
        # stock ArduPilot and PX4 act on a setpoint on arrival anyway).
        ms = np.where(np.isnan(offsets), 0.0, np.maximum((stamp_s + offsets) * 1000.0, 0.0))
        # Colours of the show clock *now*, not of the look-ahead: LED_CONTROL is applied
        # on arrival (the runner schedules changes per vehicle; this is the fallback).
        now_t = min(max(clock.show_time(now), 0.0), duration) \
            if clock is not None and not ended else t0
        return Setpoints(
            sysids=self.sysids,
            time_boot_ms=ms.astype(np.int64),
            pos_ned=show_to_ned(self.plan.origin, self._origins, pos),
            vel_ned=show_vel_to_ned(self.plan.origin, vel),
            acc_ned=show_vel_to_ned(self.plan.origin, acc),
            rgb=quantise_rgb(self.plan.colors_at(now_t)[self._tracks]),
        )


class LedTracker:
    """Decides when to send each vehicle LED_CONTROL.

    LED_CONTROL is never acknowledged, so a lost packet would leave a drone
    the wrong colour indefinitely: send on every change of the quantised
    colour, and repeat the current colour every ``refresh_s`` regardless.
    """

    def __init__(self, refresh_s: float = 1.0) -> None:
        if refresh_s <= 0:
            raise ValueError(f"`refresh_s` must be positive, got {refresh_s}")
        self.refresh_s = refresh_s
        self._sent: dict[int, tuple[tuple[int, int, int], float]] = {}

    def due(self, sysids: Sequence[int], rgb: ArrayLike,
            now: float) -> list[tuple[int, tuple[int, int, int]]]:
        """The (system id, colour) pairs to send now; records them as sent.

        ``rgb`` is (n, 3) 0-255 for ``sysids``.
        """
        colours = np.asarray(rgb)
        if colours.shape != (len(sysids), 3):
            raise ValueError(f"`rgb` must have shape ({len(sysids)}, 3), got {colours.shape}")
        out = []
        for sysid, row in zip(sysids, colours, strict=True):
            colour = (int(row[0]), int(row[1]), int(row[2]))
            last = self._sent.get(sysid)
            if last is None or last[0] != colour or now - last[1] >= self.refresh_s:
                self._sent[sysid] = (colour, now)
                out.append((sysid, colour))
        return out

    def last(self, sysid: int) -> tuple[tuple[int, int, int], float] | None:
        """The last colour sent to ``sysid`` and when, if any."""
        return self._sent.get(sysid)

    def sent(self, sysid: int, colour: tuple[int, int, int], now: float) -> None:
        """Record a colour sent to ``sysid`` outside :meth:`due` (a scheduled change)."""
        self._sent[sysid] = (colour, now)

    def forget(self, sysid: int) -> None:
        """Drop what was sent to ``sysid`` (it rebooted or came back): it gets a fresh send."""
        self._sent.pop(sysid, None)
