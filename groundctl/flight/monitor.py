"""What the flight actually did, measured from telemetry: a pure accumulator.

The driver calls :meth:`FlightMonitor.observe` every tick with the link's
vehicle states; nothing here does I/O or reads a clock.  Telemetry arrives
at different instants per vehicle (LOCAL_POSITION_NED at 10 Hz), so each
vehicle's last sample is carried to the tick's instant with its own velocity:
the sample's vehicle timestamp (``time_boot_ms``) is put on our clock with
the TIMESYNC offset.  Without that, two drones passing each other at 4 m/s
would be compared 50 ms apart on average, an error of 0.2 m in their
distance.

Measured: min separation (any two vehicles heard, flying or on the ground),
per-vehicle max and RMS tracking error against the plan at the show clock
(split, while the plan moves, into along-track (early or late) and cross-track
parts, with how far ahead of the plan the vehicle flew in seconds),
the worst distance to the formation slots while each formation is held, and
(when the LEDs can be observed, as in the dry-run) how early or late each
colour change appeared.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from groundctl.execute.frames import ned_to_show
from groundctl.link.state import VehicleState
from groundctl.plan.plan import Plan
from groundctl.show.checks import closest_pair

FloatArray = NDArray[np.float64]

#: The along/cross-track split counts ticks where the plan moves at least this fast, m/s.
MOVING_MPS = 0.3
#: Telemetry older than this is not used (the vehicle is as good as unheard), s.
MAX_SAMPLE_AGE_S = 1.0
#: LED change matched against plan colours within this window either side, s.
LED_WINDOW_S = 2.0
#: Plan colours sampled this finely when matching an LED change, s.
LED_STEP_S = 0.02
#: A shown colour further than this (per 0-255 channel) from every plan colour is unmatched.
LED_COLOUR_TOL = 3
#: An excursion is a vehicle in the show farther than this from its plan; it has
#: recovered once it is back within it, m.
RECOVERED_M = 0.5


@dataclass
class VehicleTrack:
    """Running tracking-error figures of one vehicle."""

    max_error_m: float = 0.0
    """Largest distance from the plan while in the show, m."""
    max_error_at_s: float | None = None
    """Show time of the largest distance, s."""
    sum_sq: float = 0.0
    """Sum of squared errors, m^2."""
    samples: int = 0
    """Ticks measured."""
    moving_samples: int = 0
    """Ticks measured while the plan moved faster than :data:`MOVING_MPS`."""
    along_sq: float = 0.0
    """Sum of squared along-track errors (along the planned velocity) while moving, m^2."""
    cross_sq: float = 0.0
    """Sum of squared cross-track errors while moving, m^2."""
    ev_sum: float = 0.0
    """Sum of error . planned velocity while moving, m^2/s (the time-offset numerator)."""
    vv_sum: float = 0.0
    """Sum of squared planned speeds while moving, m^2/s^2."""
    led_errors_s: list[float] = field(default_factory=list)
    """Per observed LED change: shown time minus planned time, s (negative: early)."""
    led_unmatched: int = 0
    """LED changes to a colour the plan does not show nearby."""
    recoveries_s: list[float] = field(default_factory=list)
    """Per excursion (farther than :data:`RECOVERED_M` from the plan) that ended back
    within it while in the show: how long it lasted, s of our clock."""
    excursion_from: float | None = None
    """Our time the excursion under way began (None: within :data:`RECOVERED_M`)."""

    @property
    def recovery_s(self) -> list[float | None]:
        """Every excursion's time back within :data:`RECOVERED_M`, s; the last None if it
        never came back while in the show (it left the show off its plan, or the flight
        ended)."""
        return [*self.recoveries_s, *([None] if self.excursion_from is not None else [])]

    @property
    def rms_error_m(self) -> float:
        return math.sqrt(self.sum_sq / self.samples) if self.samples else 0.0

    @property
    def along_rms_m(self) -> float | None:
        """RMS along-track error while moving (lead or lag), m."""
        return math.sqrt(self.along_sq / self.moving_samples) if self.moving_samples else None

    @property
    def cross_rms_m(self) -> float | None:
        """RMS cross-track error while moving, m."""
        return math.sqrt(self.cross_sq / self.moving_samples) if self.moving_samples else None

    @property
    def ahead_s(self) -> float | None:
        """How far ahead of the plan it flew (negative: behind), least squares over the
        moving samples: sum(e . v) / sum(|v|^2), s."""
        return self.ev_sum / self.vv_sum if self.vv_sum > 0 else None


@dataclass
class FormationError:
    """Distance to the formation's slots while it is held."""

    index: int
    """1-based formation index."""
    name: str
    """Formation name."""
    max_m: float = 0.0
    """Worst vehicle's distance to its slot, m."""
    sum_m: float = 0.0
    """Sum of per-vehicle distances, m."""
    samples: int = 0
    """Vehicle-ticks measured."""
    slots: int | None = None
    """The fewest of its slots held by a drone on its plan at any tick of the hold (the
    drones flying the show then; a track left dark is a hole in the formation)."""

    @property
    def mean_m(self) -> float:
        return self.sum_m / self.samples if self.samples else 0.0


@dataclass(frozen=True)
class Separation:
    """The closest approach seen."""

    distance_m: float
    """Distance, m (inf until two vehicles were seen at once)."""
    pair: tuple[int, int] | None = None
    """System ids of the two vehicles."""
    at_s: float | None = None
    """Our time it happened."""
    commanded_m: float | None = None
    """How far apart their paths put the two at that instant, m (None: not known): well
    apart, the drones were pushed together (wind, a gust, a weak motor), not flown so."""
    wind_m_s: float | None = None
    """The fleet's wind estimate at that instant, m/s (:mod:`groundctl.execute.wind`)."""


def nearest_pair(ids: list[int], pos: FloatArray) -> Separation:
    """The closest two of ``pos`` (rows for ``ids``), named by system id, low first
    (:func:`~groundctl.show.checks.closest_pair`)."""
    d, i, j = closest_pair(pos)
    if i < 0:
        return Separation(math.inf)
    return Separation(d, (min(ids[i], ids[j]), max(ids[i], ids[j])))


def telemetry_positions(plan: Plan, states: Mapping[int, VehicleState],
                        now: float) -> tuple[list[int], FloatArray]:
    """Show-frame positions of every vehicle with fresh telemetry, carried to ``now``.

    Vehicles that are lost, have no EKF origin or local position, or whose
    sample is older than :data:`MAX_SAMPLE_AGE_S` are left out.
    """
    ids: list[int] = []
    origins = []
    ned = []
    for sysid, s in states.items():
        if s.lost or s.ekf_origin is None or s.position_ned is None:
            continue
        age = 0.0
        offset = s.clock_offset_s
        if s.local_time_boot_ms is not None and offset is not None:
            sampled = s.local_time_boot_ms / 1000.0 - offset
            if s.local_received_at is not None:
                # Never after it arrived: a TIMESYNC offset estimated on a busy machine
                # (every round trip delayed one way) can date it up to tenths of a second
                # in the future, and a sample taken as fresher than it is goes
                # uncarried.
                sampled = min(sampled, s.local_received_at)
            age = now - sampled
        elif s.last_heard is not None:
            age = now - s.last_heard
        if age > MAX_SAMPLE_AGE_S:
            continue
        p = np.asarray(s.position_ned, dtype=float)
        if s.velocity_ned is not None and age > 0:
            p = p + np.asarray(s.velocity_ned, dtype=float) * age
        ids.append(sysid)
        origins.append(s.ekf_origin)
        ned.append(p)
    if not ids:
        return [], np.zeros((0, 3))
    return ids, ned_to_show(plan.origin, origins, np.array(ned))


class FlightMonitor:
    """Accumulates what the flight did; see the module docstring."""

    def __init__(self, plan: Plan, tracks: Mapping[int, int]) -> None:
        self.plan = plan
        self.tracks = dict(tracks)
        self.vehicles: dict[int, VehicleTrack] = {s: VehicleTrack() for s in self.tracks}
        self.formations = [FormationError(w.index, w.name) for w in plan.formations]
        self.separation = Separation(math.inf)
        self.true_separation = Separation(math.inf)
        self.ticks = 0
        self.last_positions: tuple[float, list[int], FloatArray] | None = None
        """(time, system ids, show-frame positions) of the last :meth:`observe`."""
        self._led_shown: dict[int, float | None] = {}
        self.dark: Collection[int] = frozenset()
        """Vehicles the ground station keeps dark (spares on their way in, drones that
        left the show): their LEDs are not timed against their track's colours."""

    def add(self, sysid: int, track: int) -> None:
        """``sysid`` (a spare) flies ``track`` from now on; its own figures start now."""
        self.tracks[sysid] = track
        self.vehicles.setdefault(sysid, VehicleTrack())

    def observe(self, now: float, show_time: float, in_show: Collection[int],
                states: Mapping[int, VehicleState], rate: float = 1.0) -> None:
        """One tick: ``in_show`` are the vehicles flying the plan (tracking error counts);
        ``rate`` is the show clock's (the planned velocity is ``rate * p'``)."""
        self.ticks += 1
        ids, pos = telemetry_positions(self.plan, states, now)
        self.last_positions = (now, ids, pos)
        sep = nearest_pair(ids, pos)
        if sep.distance_m < self.separation.distance_m:
            self.separation = Separation(sep.distance_m, sep.pair, now)
        rows = [k for k, s in enumerate(ids) if s in in_show and s in self.tracks]
        if not rows:
            return
        tracks = np.array([self.tracks[ids[k]] for k in rows])
        here = pos[rows]
        planned, pvel, _ = self.plan.trajectories.evaluate(show_time, tracks)
        pvel = rate * pvel
        diff = here - planned
        err = np.linalg.norm(diff, axis=1)
        speed = np.linalg.norm(pvel, axis=1)
        ev = np.einsum("ij,ij->i", diff, pvel)
        along = ev / np.maximum(speed, 1e-12)
        cross_sq = np.maximum(err * err - along * along, 0.0)
        for j, (k, e) in enumerate(zip(rows, err, strict=True)):
            v = self.vehicles[ids[k]]
            if e > v.max_error_m:
                v.max_error_m, v.max_error_at_s = float(e), show_time
            v.sum_sq += float(e) ** 2
            v.samples += 1
            if e > RECOVERED_M and v.excursion_from is None:
                v.excursion_from = now
            elif e <= RECOVERED_M and v.excursion_from is not None:
                v.recoveries_s.append(now - v.excursion_from)
                v.excursion_from = None
            if speed[j] >= MOVING_MPS:
                v.moving_samples += 1
                v.along_sq += float(along[j]) ** 2
                v.cross_sq += float(cross_sq[j])
                v.ev_sum += float(ev[j])
                v.vv_sum += float(speed[j]) ** 2
        for w, f in zip(self.plan.formations, self.formations, strict=True):
            if w.arrive <= show_time <= w.end:
                d = np.linalg.norm(here - w.goals[tracks], axis=1)
                f.max_m = max(f.max_m, float(d.max()))
                f.sum_m += float(d.sum())
                f.samples += len(d)
                # Slots held by a drone flying the show, heard this tick or not (a late
                # telemetry sample is no hole).
                held = len({self.tracks[s] for s in in_show if s in self.tracks})
                f.slots = held if f.slots is None else min(f.slots, held)

    def observe_truth(self, now: float, ids: list[int], pos: FloatArray) -> None:
        """Ground truth positions (dry-run only: the simulator knows where drones really are)."""
        sep = nearest_pair(ids, pos)
        if sep.distance_m < self.true_separation.distance_m:
            self.true_separation = Separation(sep.distance_m, sep.pair, now)

    def observe_led(self, sysid: int, rgb: tuple[int, int, int], changed_at: float | None,
                    show_time_of: float | None) -> None:
        """A vehicle's LED as observed (dry-run): colour and when it last changed.

        ``show_time_of`` is ``changed_at`` on the show clock (None before the
        show clock started: takeoff colours are not timed).
        """
        if sysid not in self.tracks or changed_at is None or sysid in self.dark:
            return
        if self._led_shown.get(sysid) == changed_at:
            return
        self._led_shown[sysid] = changed_at
        if show_time_of is None:
            return
        v = self.vehicles[sysid]
        error = self._led_error(self.tracks[sysid], np.asarray(rgb, dtype=float), show_time_of)
        if error is None:
            v.led_unmatched += 1
        else:
            v.led_errors_s.append(error)

    def _led_error(self, track: int, rgb: FloatArray, shown_at: float) -> float | None:
        times = np.arange(shown_at - LED_WINDOW_S, shown_at + LED_WINDOW_S + 1e-9, LED_STEP_S)
        keys, cols = self.plan.color_times, self.plan.colors[track]
        plan_rgb = np.rint(np.column_stack(
            [np.interp(times, keys, cols[:, c]) for c in range(3)]) * 255.0)
        # The closest plan colour (exact, unless the LED quantises differently):
        # in a fade only a few instants match exactly, and a tolerance band
        # would date the change early by the band's width.
        dist = np.abs(plan_rgb - rgb).max(axis=1)
        if dist.min() > LED_COLOUR_TOL:
            return None
        match = dist <= dist.min() + 0.5
        # The instant the plan first shows this colour in the window's matching
        # run nearest to when it was shown.
        hits = np.flatnonzero(match)
        k = hits[np.argmin(np.abs(times[hits] - shown_at))]
        while k > 0 and match[k - 1]:
            k -= 1
        if k == 0:
            return None  # the plan showed it since before the window: no change to time
        return float(shown_at - times[k])

    # -- results ---------------------------------------------------------------------
    def max_tracking_error(self) -> float:
        return max((v.max_error_m for v in self.vehicles.values()), default=0.0)

    def rms_tracking_error(self) -> float:
        n = sum(v.samples for v in self.vehicles.values())
        return math.sqrt(sum(v.sum_sq for v in self.vehicles.values()) / n) if n else 0.0

    def tracking_split(self) -> dict[str, float | None]:
        """Fleet-wide along-track RMS, cross-track RMS (while moving, m) and how far ahead
        of the plan the fleet flew (s, negative: behind)."""
        tracks = list(self.vehicles.values())
        n = sum(v.moving_samples for v in tracks)
        vv = sum(v.vv_sum for v in tracks)
        return {
            "along_rms_m": math.sqrt(sum(v.along_sq for v in tracks) / n) if n else None,
            "cross_rms_m": math.sqrt(sum(v.cross_sq for v in tracks) / n) if n else None,
            "ahead_s": sum(v.ev_sum for v in tracks) / vv if vv > 0 else None,
        }

    def recovery(self) -> dict[str, float | int | None]:
        """The fleet's excursions beyond :data:`RECOVERED_M`: how many, the longest time
        back within it (s), and how many never came back while in the show."""
        times = [t for v in self.vehicles.values() for t in v.recovery_s]
        back = [t for t in times if t is not None]
        return {"excursions": len(times), "max_s": max(back, default=None),
                "never": len(times) - len(back)}

    def led_errors(self) -> list[float]:
        return [e for v in self.vehicles.values() for e in v.led_errors_s]
