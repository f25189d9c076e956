"""How far ahead of the show clock to send each vehicle its setpoints, from its own flight.

A setpoint for show time ``s(now + L)`` reaches a vehicle a one-way link
delay later, and the vehicle then tracks it with its own response delay
(position, velocity and acceleration feed-forward make that small on
ArduCopter, larger on a softer tuning).  With a lead ``L`` and an effective
response delay ``r`` (link included) the vehicle flies ``L - r`` ahead of the
plan, so its position error is, to first order,

    e = p_measured - p_plan(s(now)) = w + (L - r) v

with ``v`` the planned velocity and ``w`` whatever does not scale with speed
(a steady wind offset, the GPS estimate's bias).  Regressing ``y = e - L v``
on ``v`` with an intercept gives ``-r`` as the slope, per vehicle, whatever
lead was in use when each sample was taken.  :class:`LeadEstimator` keeps the
regression's sums with exponential forgetting (a time constant of seconds,
so a change in the vehicle shows within one transition) and moves each
vehicle's lead toward its ``r`` at a bounded rate, never below its one-way
link delay (a setpoint cannot act before it arrives) nor above ``max_s``, and
only while the estimate's standard error is small: in gusting wind most of
the error is the wind's, and the lead then stays where it is.

Only samples that carry information count: the vehicle on its plan, the show
clock running at full rate, the planned speed above ``min_speed``, an error
below ``max_error_m`` (a gust or a glitch is the guard's business, not a
timing offset).  Pure arithmetic over the fleet: times are arguments.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LeadConfig:
    """Tuning of the per-vehicle lead estimate (seconds unless named otherwise)."""

    initial_s: float = 0.05
    """Lead of a vehicle before its own flight says otherwise (real ArduCopter with
    full feed-forward needs almost none; a soft tuning 0.1-0.2 s)."""
    max_s: float = 0.6
    """Largest lead ever used: beyond it a vehicle is too slow to fly a show."""
    memory_s: float = 15.0
    """Time constant of the exponential forgetting of old samples."""
    min_speed: float = 0.3
    """Samples where the plan moves slower than this (m/s) are left out."""
    max_error_m: float = 1.5
    """Samples farther than this from the plan are left out (not a timing error)."""
    min_information: float = 3.0
    """Weighted sum of squared velocity deviations, (m/s)^2 samples, needed before the
    estimate moves the lead: with 2 cm of tracking noise its standard error is then about
    0.02 / sqrt(3) = 12 ms, and the slew limit smooths what is left."""
    slew_s_per_s: float = 0.1
    """Fastest change of a lead: 0.1 s per second moves a 2 m/s setpoint 0.2 m/s."""
    max_stderr_s: float = 0.02
    """The lead follows an estimate only while its standard error is below this: in
    gusting wind the tracking error is mostly the wind's, and says little about timing."""
    correlation_samples: float = 10.0
    """Telemetry samples per independent error (errors stay correlated for about a second
    at 10 Hz), inflating the naive standard error by its square root."""

    def __post_init__(self) -> None:
        if not 0 <= self.initial_s <= self.max_s:
            raise ValueError("`initial_s` must be within [0, `max_s`]")
        for name in ("memory_s", "min_information", "slew_s_per_s", "max_error_m",
                     "max_stderr_s", "correlation_samples"):
            if not getattr(self, name) > 0:
                raise ValueError(f"`{name}` must be positive")
        if self.min_speed < 0:
            raise ValueError("`min_speed` must be non-negative")


@dataclass(frozen=True)
class LeadEstimate:
    """One vehicle's timing, as measured."""

    lead_s: float
    """The lead in use now."""
    response_s: float | None
    """Its estimated effective response delay (link included), the last one made from
    enough motion; None: not enough motion yet."""
    information: float
    """The regression's information, (m/s)^2 samples (see ``LeadConfig.min_information``)."""
    stderr_s: float | None
    """Standard error of the current estimate, s (None: not enough motion)."""
    samples: int
    """Samples used so far."""


class LeadEstimator:
    """Per-vehicle leads for ``sysids``; see the module docstring."""

    def __init__(self, sysids: Sequence[int], config: LeadConfig | None = None) -> None:
        self.config = config or LeadConfig()
        self.sysids = tuple(sysids)
        self._row = {s: i for i, s in enumerate(self.sysids)}
        n = len(self.sysids)
        self.leads = np.full(n, self.config.initial_s)
        """(n,) lead in use per vehicle, s."""
        self._w = np.zeros(n)
        self._sv = np.zeros((n, 3))
        self._sy = np.zeros((n, 3))
        self._svv = np.zeros(n)
        self._syv = np.zeros(n)
        self._syy = np.zeros(n)
        self._count = np.zeros(n, dtype=np.int64)
        self._known = np.full(n, np.nan)
        self._last: float | None = None

    def lead(self, sysid: int) -> float:
        """The lead in use for ``sysid``."""
        return float(self.leads[self._row[sysid]])

    def as_dict(self) -> dict[int, float]:
        """System id -> lead in use."""
        return {s: float(x) for s, x in zip(self.sysids, self.leads, strict=True)}

    def _stats(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(information, response delay, its standard error) per vehicle; the delay and
        error are NaN where there is not enough motion."""
        cfg = self.config
        w = np.maximum(self._w, 1e-12)
        var = self._svv - np.einsum("ij,ij->i", self._sv, self._sv) / w
        cov = self._syv - np.einsum("ij,ij->i", self._sy, self._sv) / w
        yy = self._syy - np.einsum("ij,ij->i", self._sy, self._sy) / w
        enough = var >= cfg.min_information
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(enough, -cov / var, np.nan)
            # Residual variance per coordinate (3 per sample, 4 parameters fitted).
            rss = np.maximum(yy - np.where(enough, cov * cov / var, 0.0), 0.0)
            sigma2 = rss / np.maximum(3.0 * self._w - 4.0, 1.0)
            se = np.where(enough, np.sqrt(sigma2 * cfg.correlation_samples / var), np.nan)
        return var, r, se

    def estimate(self, sysid: int) -> LeadEstimate:
        """What is known of ``sysid``'s timing."""
        i = self._row[sysid]
        info, _, se = self._stats()
        resp = None if np.isnan(self._known[i]) else float(self._known[i])
        return LeadEstimate(float(self.leads[i]), resp, float(info[i]),
                            None if np.isnan(se[i]) else float(se[i]), int(self._count[i]))

    def observe(self, now: float, sysids: Sequence[int], errors: ArrayLike,
                velocities: ArrayLike) -> None:
        """Samples at our time ``now``: measured minus planned position (k, 3) and the
        planned velocity (k, 3) of ``sysids``, each flying its plan on a steady clock.

        Every vehicle's sums decay by the time since the last call, whether or not it
        has a sample now.
        """
        cfg = self.config
        if self._last is not None and now > self._last:
            decay = float(np.exp(-(now - self._last) / cfg.memory_s))
            for a in (self._w, self._sv, self._sy, self._svv, self._syv, self._syy):
                a *= decay
        self._last = now if self._last is None else max(self._last, now)
        if not sysids:
            return
        e = np.asarray(errors, dtype=float).reshape(-1, 3)
        v = np.asarray(velocities, dtype=float).reshape(-1, 3)
        if len(e) != len(sysids) or len(v) != len(sysids):
            raise ValueError("`errors` and `velocities` need one row per system id")
        rows = np.array([self._row.get(s, -1) for s in sysids])
        speed = np.linalg.norm(v, axis=1)
        ok = (rows >= 0) & (speed >= cfg.min_speed) \
            & (np.linalg.norm(e, axis=1) <= cfg.max_error_m) & np.isfinite(e).all(axis=1)
        if not ok.any():
            return
        r, e, v = rows[ok], e[ok], v[ok]
        y = e - self.leads[r][:, None] * v
        np.add.at(self._w, r, 1.0)
        np.add.at(self._sv, r, v)
        np.add.at(self._sy, r, y)
        np.add.at(self._svv, r, np.einsum("ij,ij->i", v, v))
        np.add.at(self._syv, r, np.einsum("ij,ij->i", y, v))
        np.add.at(self._syy, r, np.einsum("ij,ij->i", y, y))
        np.add.at(self._count, r, 1)

    def update(self, dt: float, link_delays: Mapping[int, float | None]) -> FloatArray:
        """Move each lead toward its vehicle's response delay (at most ``slew_s_per_s``
        times ``dt``), kept within [one-way link delay, ``max_s``]; returns the leads."""
        if dt < 0:
            raise ValueError("`dt` must be non-negative")
        cfg = self.config
        _, r, se = self._stats()
        r = np.where(se <= cfg.max_stderr_s, r, np.nan)  # NaN compares False: unknown stays
        self._known = np.where(np.isnan(r), self._known, r)
        floor = np.array([min(max(link_delays.get(s) or 0.0, 0.0), cfg.max_s)
                          for s in self.sysids])
        target = np.where(np.isnan(r), self.leads, r)
        target = np.clip(np.maximum(target, floor), 0.0, cfg.max_s)
        step = cfg.slew_s_per_s * dt
        self.leads = self.leads + np.clip(target - self.leads, -step, step)
        return self.leads


def late_vehicles(leads: Mapping[int, float], link_delays: Mapping[int, float | None],
                  late: set[int], margin_s: float = 0.005) -> tuple[set[int], set[int]]:
    """(newly late, no longer late): a vehicle is late while its recent one-way link delay
    exceeds the lead it is given by more than ``margin_s`` (its setpoints arrive after the
    instant they are for); it clears once the delay is back within its lead."""
    newly, cleared = set(), set()
    for sysid, lead in leads.items():
        delay = link_delays.get(sysid)
        if delay is None:
            continue
        if sysid not in late and delay > lead + margin_s:
            newly.add(sysid)
        elif sysid in late and delay <= lead:
            cleared.add(sysid)
    return newly, cleared


class LateWatch:
    """Late vehicles, judged once a second (:func:`late_vehicles`) and flagged only when
    a vehicle is late on two checks in a row: one TIMESYNC step in the recent median,
    which a measured lead follows within the second, flags nobody."""

    def __init__(self, margin_s: float = 0.005) -> None:
        self.margin_s = margin_s
        self._suspects: set[int] = set()

    def check(self, leads: Mapping[int, float], link_delays: Mapping[int, float | None],
              late: set[int]) -> tuple[set[int], set[int]]:
        """(newly late, no longer late) of the vehicles in ``leads`` given those flagged
        ``late`` now; a suspect not late again on the next check is forgotten."""
        newly, cleared = late_vehicles(leads, link_delays, late, self.margin_s)
        confirmed = newly & self._suspects
        self._suspects = newly - confirmed
        return confirmed, cleared
