"""How much thrust a vehicle has left, from its hover throttle, against its fleet.  Pure.

Drones of one show are one airframe: a healthy one hovers at about the same
throttle as the others (ArduCopter learns it as MOT_THST_HOVER and reports its
motor output in VFR_HUD.throttle).  A weak motor or a tired battery makes less
thrust per unit of throttle, so that vehicle hovers higher: its share of the
fleet's thrust -- its *authority* -- is the fleet's typical hover throttle over
its own.  That is known within seconds of take-off, long before the vehicle
falls behind a fast stretch of its path, which is what lets the MPC re-time its
path in advance (:mod:`groundctl.execute.retime`) instead of chasing it.

A throttle sample counts only while the vehicle's path barely accelerates
(the thrust then is its weight: a climb's extra throttle is not weakness); it
is scaled by the thrust the path's acceleration needs.  Each vehicle's hover
throttle is an exponential average over ``tau_s``; the authority is reported
once a vehicle has ``min_samples`` and at least ``min_fleet`` vehicles have
enough to make a typical value (their median), clipped to [``floor``, 1], and
1 within ``dead_band`` of it (a healthy fleet's spread is not weakness).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from groundctl.show.model import Limits

GRAVITY = 9.80665


@dataclass
class AuthorityEstimator:
    """Every vehicle's authority; feed :meth:`sample` each tick, read :meth:`authority`."""

    tau_s: float = 5.0
    """Averaging time of the hover throttle, s."""
    min_samples: int = 8
    """Samples a vehicle needs before its authority is given."""
    min_fleet: int = 3
    """Vehicles with enough samples before anyone's authority is given."""
    max_accel: float = 0.5
    """Samples are taken while the path's acceleration is below this, m/s^2."""
    floor: float = 0.2
    """The least authority reported."""
    dead_band: float = 0.1
    """Authorities within this of 1 are reported as 1 (measured: in 6 m/s gusting about
    4 m/s, healthy PX4 vehicles' hover throttles spread enough for 0.94-0.95)."""
    _hover: dict[int, float] = field(default_factory=dict)
    _count: dict[int, int] = field(default_factory=dict)
    _at: dict[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (self.tau_s > 0 and self.min_samples >= 1 and self.min_fleet >= 1):
            raise ValueError("`tau_s`, `min_samples` and `min_fleet` must be positive")
        if not 0 < self.floor <= 1 or not 0 <= self.dead_band < 1:
            raise ValueError("`floor` must be in (0, 1] and `dead_band` in [0, 1)")

    def sample(self, now: float, sysid: int, throttle_pct: float,
               path_acc: np.ndarray) -> None:
        """One VFR_HUD throttle reading of a flying vehicle, received at ``now`` (a
        reading already sampled at that time is not counted again), with its path's
        acceleration (show frame, m/s^2) at that instant."""
        if self._at.get(sysid) == now:
            return
        acc = np.asarray(path_acc, dtype=float)
        if not (0 < throttle_pct <= 100) or float(np.linalg.norm(acc)) > self.max_accel:
            return
        need = float(np.linalg.norm(acc + np.array([0.0, 0.0, GRAVITY]))) / GRAVITY
        hover = throttle_pct / need
        old = self._hover.get(sysid)
        last = self._at.get(sysid)
        k = 1.0 if old is None or last is None else min(1.0, max(now - last, 0.0) / self.tau_s)
        self._hover[sysid] = hover if old is None else old + k * (hover - old)
        self._at[sysid] = now
        self._count[sysid] = self._count.get(sysid, 0) + 1

    def authority(self) -> dict[int, float]:
        """System id -> authority in [floor, 1], for the vehicles it is known of."""
        ready = {s: h for s, h in self._hover.items() if self._count[s] >= self.min_samples}
        if len(ready) < self.min_fleet:
            return {}
        typical = float(np.median(list(ready.values())))
        out = {}
        for sysid, hover in ready.items():
            a = min(1.0, max(self.floor, typical / hover))
            out[sysid] = 1.0 if a >= 1.0 - self.dead_band else a
        return out


def scaled_limits(limits: Limits, authority: float) -> Limits:
    """``limits`` with the speeds and the acceleration scaled by ``authority``."""
    return limits.scaled(authority, authority)


def beyond(limits: Limits, vel: np.ndarray, acc: np.ndarray, tol: float = 0.02) -> str | None:
    """What of the path samples ``vel``, ``acc`` (T, 3) exceeds ``limits`` (None: nothing),
    for the operator: "descent 1.12 m/s (it manages 0.90)"."""
    vh = float(np.linalg.norm(vel[:, :2], axis=1).max(initial=0.0))
    up = float(vel[:, 2].max(initial=0.0))
    down = float(-vel[:, 2].min(initial=0.0))
    an = float(np.linalg.norm(acc, axis=1).max(initial=0.0))
    k = 1.0 + tol
    for what, value, lim, unit in (("descent", down, limits.max_speed_down, "m/s"),
                                   ("climb", up, limits.max_speed_up, "m/s"),
                                   ("speed", vh, limits.max_speed_h, "m/s"),
                                   ("acceleration", an, limits.max_accel, "m/s^2")):
        if value > lim * k:
            return f"{what} {value:.2f} {unit} (it manages {lim:.2f})"
    return None
