"""When a vehicle is replanned with MPC, and when it is handed back to its path (pure).

A vehicle follows its path (:mod:`groundctl.execute.paths`) until one of two
things says that streaming the path would make its autopilot dash for a
setpoint metres away, or fly it into a neighbour:

* its tracking error (telemetry against its path now) exceeds
  ``trigger_error_m`` on ``confirm_ticks`` consecutive ticks (one late sample is
  not a deviation);
* a loss of separation is predicted within the horizon: every flying vehicle
  is predicted on its path shifted by its current error, plus that error's
  rate of change damped over about a second (a drone being pushed keeps
  drifting for a moment; :func:`error_forecast`), and a pair closer than the
  separation limit puts both under MPC.

A third reason is a weak vehicle (:mod:`groundctl.execute.authority`) whose
path over the next tens of seconds asks more than it can fly: it is under MPC
(its path re-timed to what it can do) while that lasts.

It is handed back once its error has stayed below ``release_error_m`` for
``release_after_s`` and no conflict or demand is predicted for it.  No activation in a
calm flight: the default trigger is about three times the calm-air RMS
tracking error of real ArduCopter.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from groundctl.show.model import MpcSettings

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Activation:
    """A vehicle put under MPC."""

    sysid: int
    """MAVLink system id."""
    why: str
    """What triggered it (for the operator and the event log)."""
    error_m: float
    """Its tracking error then, m."""


@dataclass(frozen=True)
class Release:
    """A vehicle handed back to its path."""

    sysid: int
    """MAVLink system id."""
    after_s: float
    """How long it was under MPC, s."""


def error_forecast(error: FloatArray, error_rate: FloatArray, horizon: FloatArray,
                   settle_s: float = 1.0) -> FloatArray:
    """(n, K, 3) each vehicle's error over the horizon offsets ``horizon`` (K,): the error
    now plus its rate of change, damped as the autopilot takes it back within about
    ``settle_s`` (a drone being pushed keeps drifting a little; one on its path stays)."""
    tau = np.asarray(horizon, dtype=float)
    gain = settle_s * (1.0 - np.exp(-tau / settle_s))
    return np.asarray(error)[:, None, :] + np.asarray(error_rate)[:, None, :] * gain[None, :,
                                                                                      None]


#: Up to this many vehicles :func:`predicted_conflicts` compares every pair directly.
BRUTE_FORCE_VEHICLES = 24


def predicted_conflicts(ids: Sequence[int], path_pos: FloatArray, errors: FloatArray,
                        limit_m: float) -> dict[int, tuple[int, float]]:
    """Vehicles whose predicted positions (path at the horizon's instants, ``path_pos``
    (n, K, 3), shifted by each one's error ``errors``: (n, 3) now, or (n, K, 3) as it is
    expected to evolve) come closer than ``limit_m`` to another's: system id -> (the
    other's id, the closest distance)."""
    n = len(ids)
    if n < 2:
        return {}
    err = np.asarray(errors, dtype=float)
    pred = np.asarray(path_pos, dtype=float) + (err[:, None, :] if err.ndim == 2 else err)
    out: dict[int, tuple[int, float]] = {}
    if n <= BRUTE_FORCE_VEHICLES:
        # Every pair at every instant in one pass (a KD-tree per instant costs more
        # than that on a small fleet): each vehicle's closest approach over the horizon.
        diff = pred[:, None] - pred[None, :]
        closest = np.sqrt(np.add.reduce(diff * diff, axis=-1)).min(axis=2)
        closest[np.diag_indices(n)] = np.inf
        for a in map(int, np.flatnonzero(closest.min(axis=1) <= limit_m)):
            b = int(np.argmin(closest[a]))
            out[ids[a]] = (ids[b], float(closest[a, b]))
        return out
    for k in range(pred.shape[1]):
        tree = cKDTree(pred[:, k])
        for i, j in tree.query_pairs(limit_m):
            d = float(np.linalg.norm(pred[i, k] - pred[j, k]))
            for a, b in ((i, j), (j, i)):
                if ids[a] not in out or d < out[ids[a]][1]:
                    out[ids[a]] = (ids[b], d)
    return out


class ReplanSupervisor:
    """Decides each tick who is under MPC; see the module docstring."""

    def __init__(self, settings: MpcSettings, confirm_ticks: int = 2) -> None:
        if confirm_ticks < 1:
            raise ValueError("`confirm_ticks` must be at least 1")
        self.settings = settings
        self.confirm_ticks = confirm_ticks
        self.active: dict[int, float] = {}
        """System id -> our time it was put under MPC."""
        self.activations = 0
        """Activations so far."""
        self.vehicles: set[int] = set()
        """Every vehicle that was ever under MPC."""
        self._over: dict[int, int] = {}
        self._calm_since: dict[int, float] = {}

    def tick(self, now: float, errors: Mapping[int, float],
             conflicts: Mapping[int, tuple[int, float]] | None = None,
             eligible: Collection[int] | None = None,
             demands: Mapping[int, str] | None = None
             ) -> tuple[list[Activation], list[Release]]:
        """One tick: ``errors`` (system id -> tracking error, m) of the vehicles flying a
        path, ``conflicts`` from :func:`predicted_conflicts`; ``eligible`` (default: those
        with an error) may be replanned; ``demands``: vehicles whose path ahead asks more
        than they can fly (system id -> what), under MPC while it does.  Returns who
        starts and who ends."""
        cfg = self.settings
        conflicts = conflicts or {}
        demands = demands or {}
        eligible = set(errors if eligible is None else eligible)
        started: list[Activation] = []
        ended: list[Release] = []
        for sysid in sorted(self.active):
            if sysid not in eligible:  # landed, lost, taken out: no longer ours to replan
                ended.append(Release(sysid, now - self.active.pop(sysid)))
                self._calm_since.pop(sysid, None)
        for sysid in [s for s in self._over if s not in eligible]:
            del self._over[sysid]  # heard again later, it needs its confirming ticks afresh
        for sysid in sorted(eligible):
            e = errors.get(sysid)
            if e is None:
                continue
            self._over[sysid] = self._over.get(sysid, 0) + 1 if e > cfg.trigger_error_m else 0
            if sysid in self.active:
                if e <= cfg.release_error_m and sysid not in conflicts and \
                        sysid not in demands:
                    since = self._calm_since.setdefault(sysid, now)
                    if now - since >= cfg.release_after_s:
                        ended.append(Release(sysid, now - self.active.pop(sysid)))
                        del self._calm_since[sysid]
                else:
                    self._calm_since.pop(sysid, None)
                continue
            why = None
            if self._over[sysid] >= self.confirm_ticks:
                why = f"{e:.2f} m off its path (trigger {cfg.trigger_error_m:.2f} m)"
            elif sysid in conflicts:
                other, d = conflicts[sysid]
                why = f"predicted within {d:.2f} m of vehicle {other}"
            elif sysid in demands:
                why = f"its path ahead asks more than it can fly: {demands[sysid]}"
            if why is not None:
                self.active[sysid] = now
                self.activations += 1
                self.vehicles.add(sysid)
                started.append(Activation(sysid, why, e))
        return started, ended
