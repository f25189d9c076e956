"""The executor's MPC replanning: who is replanned, their requests, their trajectories.

Every tick, after the monitor has carried telemetry to the tick's instant,
:meth:`Replanner.tick`:

1. takes the worker's last batch if it came back within its deadline;
2. measures each flying vehicle's error against its path, predicts every
   flying vehicle on its path shifted by that error over the horizon, and lets
   the :class:`~groundctl.execute.replan.ReplanSupervisor` decide who is under
   MPC (a confirmed deviation, or a predicted loss of separation);
3. for those, builds one :class:`~groundctl.execute.mpc.MpcRequest` each (its
   path over the horizon as the reference, neighbours within reach predicted by
   what they are told -- their MPC trajectory, else their path -- shifted by
   their deviation from it as it is expected to drift) and hands the batch to
   the worker, if it is idle.  The start state is the vehicle's measured state
   carried to the tick grid only if it is more than ``REINIT_M`` from what it
   was told (pushed metres off: a rejoin); closer, it is the state of what it
   was told (its MPC trajectory, or its path) at that instant, and its
   neighbours are then given relative to its own forecast deviation from that
   reference (the separation is between where they will be, not between
   references: without it two references 1.5 m apart let vehicles 0.45 m off
   them come to 1.06 m, measured with PX4 in the demo's gusts).  Started from
   the measured state every tick, the MPC's trajectory begins where a gust has
   just put the vehicle, so the autopilot, tracking it, no longer pushes back:
   measured on the demo in 6 m/s gusting about 4 m/s, that let neighbours drift
   to 1.49 m where the path alone kept 1.62 m.

The stream then sends a vehicle under MPC its last accepted trajectory
(:meth:`overrides`), sampled at its own lead.  The guard still judges every
drone against its path: the plan is what keeps the fleet apart, and an MPC
trajectory starts where the vehicle is, so a drone blown far off would never
look off against it.  A trajectory older than
``STALE_S`` (the worker fell behind) is dropped and the vehicle gets its path
again.  A ``fallback`` (the verified stop, or an escape) is flown like a
solution; a ``path`` or ``unsafe`` result is never flown: the vehicle keeps its
path, and a notice says so.  Nothing here blocks: solves run in :mod:`groundctl.flight.mpcworker`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from groundctl.clock import Clock
from groundctl.execute.authority import AuthorityEstimator, beyond, scaled_limits
from groundctl.execute.mpc import MpcConfig, MpcRequest, MpcResult, speed_violations
from groundctl.execute.paths import Path, PathClocks, sample_paths
from groundctl.execute.replan import (
    Activation,
    ReplanSupervisor,
    error_forecast,
    predicted_conflicts,
)
from groundctl.execute.retime import clip_speed
from groundctl.flight.mpcworker import MpcWorker
from groundctl.plan.plan import Plan
from groundctl.show.model import MpcSettings

FloatArray = NDArray[np.float64]

#: A trajectory older than this is not flown any more (the vehicle gets its path), s.
STALE_S = 1.0
#: Instants over the horizon at which conflicts are predicted (every half second).
CONFLICT_SAMPLES = 7
#: A weak vehicle's look ahead along its path: samples and their step (20 s).
LOOKAHEAD_STEPS = 80
LOOKAHEAD_DT = 0.25
#: A vehicle within this of what it is told (its MPC trajectory, else its path) is
#: replanned from that reference's state, farther off from its measured state, m.
REINIT_M = 1.0


@dataclass
class ReplanStats:
    """What the MPC did over the flight (the report's ``mpc``)."""

    solve_ms: list[float] = field(default_factory=list)
    """Every solve's time, ms: CPU time of the worker's thread (what the solve cost; on a
    busy machine its wall time is longer, and its batch's deadline says whether it came
    in time: ``late``)."""
    fallbacks: int = 0
    """Solves that gave the verified stop (or an unsafe result) instead of a correction."""
    unsafe: int = 0
    """Results not flown at all (even the stop broke a limit)."""
    batches: int = 0
    """Batches solved in time."""
    recovered: int = 0
    """Start states above a speed limit flown back within it (each episode once: a
    vehicle's first solved result from such a state after any other)."""


@dataclass(frozen=True)
class _Measured:
    """The flying vehicles this tick, measured against their paths (computed once)."""

    ids: list[int]
    paths: list[Path]
    here: FloatArray
    """(n, 3) telemetry positions carried to now."""
    error: FloatArray
    """(n, 3) position minus path position now."""
    dev: FloatArray
    """(n, 3) position minus what it is commanded now (its MPC trajectory, or its path)."""
    dev_rate: FloatArray
    """(n, 3) velocity minus the commanded velocity now."""


Event = tuple[str, str, dict[str, Any]]
"""(event name, operator text, fields)."""


class Replanner:
    """MPC replanning of the fleet; see the module docstring."""

    def __init__(self, plan: Plan, settings: MpcSettings, rate_hz: float,
                 deadline_s: float, clock: Clock | None = None) -> None:
        """``deadline_s``: real seconds at the pace of ``clock`` (the flight's) a batch of
        solves may take (:class:`~groundctl.flight.mpcworker.MpcWorker`)."""
        self.plan = plan
        self.settings = settings
        steps = max(2, round(settings.horizon_s * rate_hz))
        self.config = MpcConfig(dt=1.0 / rate_hz, steps=steps)
        self.supervisor = ReplanSupervisor(settings)
        self.worker = MpcWorker(self.config, deadline_s, clock)
        self.stats = ReplanStats()
        self.results: dict[int, MpcResult] = {}
        """The trajectory each vehicle under MPC flies now (accepted, or the stop)."""
        self._status: dict[int, str] = {}
        self.authority = AuthorityEstimator()
        """Every vehicle's thrust authority from its hover throttle."""
        self._weak: dict[int, float] = {}

    # -- life cycle -------------------------------------------------------------------
    def start(self) -> None:
        self.worker.start()

    def close(self) -> None:
        self.worker.close()

    def drop_trajectories(self) -> None:
        """Forget every MPC trajectory (our loop stalled and the show clock was put back:
        they were checked against the neighbours on the clock as it was); the vehicles
        get their paths until the next batch."""
        self.results.clear()

    @property
    def active(self) -> set[int]:
        return set(self.supervisor.active)

    # -- what is streamed -------------------------------------------------------------
    def _fresh(self, sysid: int, now: float) -> MpcResult | None:
        res = self.results.get(sysid)
        if res is None or sysid not in self.supervisor.active or now - res.t0 > STALE_S:
            return None
        return res

    def overrides(self, now: float, lead_of: Callable[[int], float]
                  ) -> dict[int, tuple[FloatArray, FloatArray, FloatArray]]:
        """System id -> (position, velocity, acceleration) of its MPC trajectory at its own
        instant ``now + lead`` (show frame), for the vehicles flying one."""
        out = {}
        for sysid in self.supervisor.active:
            res = self._fresh(sysid, now)
            at = now + lead_of(sysid)
            if res is not None and at <= res.end:  # never past what was verified
                p, v, a = res.sample(at)
                out[sysid] = (np.asarray(p), np.asarray(v), np.asarray(a))
        return out

    # -- the tick ---------------------------------------------------------------------
    def tick(self, now: float, paths: Mapping[int, Path], clocks: PathClocks,
             positions: Mapping[int, FloatArray], velocities: Mapping[int, FloatArray],
             obstacles: Mapping[int, FloatArray],
             throttles: Mapping[int, tuple[float, float]] | None = None) -> list[Event]:
        """One tick; ``paths`` of the vehicles flying one (eligible for MPC) with telemetry
        ``positions`` / ``velocities`` (show frame, carried to ``now``); ``obstacles`` are
        the other vehicles in the air (descending, say), predicted where they are;
        ``throttles`` their last VFR_HUD throttle, % and when it came (their authority;
        not sampled while under MPC: their acceleration is not their path's then).
        Returns the events to log."""
        events: list[Event] = []
        if self.worker.hung():
            self.worker.close()
            self.worker.start()
            events.append(("mpc_fallback", "MPC worker stuck: restarted (vehicles keep their "
                                           "paths meanwhile)", {"status": "restarted"}))
        events += self._collect(now)
        ids = [s for s in sorted(paths) if s in positions]
        m: _Measured | None = None
        if not ids:
            started, ended = self.supervisor.tick(now, {}, {}, eligible=())
        else:
            plist = [paths[s] for s in ids]
            here = np.array([positions[s] for s in ids])
            on_path, path_vel, path_acc = sample_paths(plist, np.full(len(ids), now), clocks)
            for i, sysid in enumerate(ids):
                thr = (throttles or {}).get(sysid)
                if thr is not None and sysid not in self.supervisor.active:
                    self.authority.sample(thr[1], sysid, thr[0], path_acc[i])
            self._weak = {s: a for s, a in self.authority.authority().items() if a < 1.0}
            demands = self._demands(ids, plist, clocks, now)
            vel = np.array([velocities.get(s, path_vel[i]) for i, s in enumerate(ids)])
            dev, dev_rate = here - on_path, vel - path_vel
            for i, sysid in enumerate(ids):
                res = self._fresh(sysid, now)
                if res is not None:
                    p_now, v_now, _ = res.sample(now)
                    dev[i], dev_rate[i] = here[i] - p_now, vel[i] - v_now
            m = _Measured(ids, plist, here, here - on_path, dev, dev_rate)
            norms = np.linalg.norm(m.error, axis=1)
            errors = {s: float(e) for s, e in zip(ids, norms, strict=True)}
            offsets = np.linspace(0.0, self.config.horizon_s, CONFLICT_SAMPLES)
            future = self._future(m, now + offsets, clocks, now)
            conflicts = predicted_conflicts(ids, future, np.zeros((len(ids), 3)),
                                            self.plan.limits.min_separation) \
                if len(ids) > 1 else {}
            started, ended = self.supervisor.tick(now, errors, conflicts, eligible=ids,
                                                  demands=demands)
        for a in started:
            events.append(self._started(a))
        for r in ended:
            self.results.pop(r.sysid, None)
            self._status.pop(r.sysid, None)
            events.append(("mpc_ended", f"vehicle {r.sysid} back on its path after "
                                        f"{r.after_s:.1f} s of MPC",
                           {"system_id": r.sysid, "after_s": round(r.after_s, 2)}))
        active = [s for s in sorted(self.supervisor.active) if s in positions and s in paths]
        if active and m is not None and not self.worker.busy:
            self.worker.submit(self._requests(now, active, m, clocks, velocities, obstacles))
        return events

    def _started(self, a: Activation) -> Event:
        return ("mpc_started", f"vehicle {a.sysid} replanned with MPC: {a.why}",
                {"system_id": a.sysid, "why": a.why, "error_m": round(a.error_m, 3)})

    def _collect(self, now: float) -> list[Event]:
        results = self.worker.collect()
        if results is None:
            return []
        self.stats.batches += 1
        events: list[Event] = []
        for sysid, res in results.items():
            self.stats.solve_ms.append(res.solve_ms)
            if sysid not in self.supervisor.active:
                continue
            if res.status != "solved":
                self.stats.fallbacks += 1
            if res.status in ("path", "unsafe"):
                self.stats.unsafe += res.status == "unsafe"
                self.results.pop(sysid, None)  # not flown: its path is streamed instead
            else:
                self.results[sysid] = res
            if res.status != self._status.get(sysid, "solved") and res.status != "solved":
                escaping = "best escape" in res.reason
                what = {"fallback": "flying the escape" if escaping else "stopping it",
                        "path": "keeping its path"}.get(
                    res.status, "keeping its path (nothing safer was found)")
                events.append(("mpc_fallback", f"vehicle {sysid}: MPC {res.reason}; {what}",
                               {"system_id": sysid, "status": res.status,
                                "reason": res.reason}))
            status = "recovering" if res.recovering else res.status
            if res.recovering and self._status.get(sysid) != status:
                self.stats.recovered += 1
                events.append(("mpc_recovering", f"vehicle {sysid}: MPC {res.reason}",
                               {"system_id": sysid, "reason": res.reason}))
            self._status[sysid] = status
        return events

    def _future(self, m: _Measured, times: FloatArray, clocks: PathClocks,
                now: float) -> FloatArray:
        """(n, K, 3) where each flying vehicle is expected at ``times``: what it is
        commanded (its path, or its MPC trajectory) plus its deviation from that, now and
        as it is expected to drift (:func:`~groundctl.execute.replan.error_forecast`).

        Deviation from the MPC trajectory too, not only from the path: a vehicle being
        pushed moves off whatever it is told to fly, and its MPC trajectory (which
        brakes from its measured state at the solve instant) does not say so."""
        n, k = len(m.ids), len(times)
        rep = [p for p in m.paths for _ in range(k)]
        pos, _, _ = sample_paths(rep, np.tile(times, n), clocks)
        pos = pos.reshape(n, k, 3)
        for i, sysid in enumerate(m.ids):
            res = self._fresh(sysid, now)
            if res is not None:
                pos[i] = np.asarray(res.sample(times)[0])
        return np.asarray(pos + error_forecast(m.dev, m.dev_rate, np.maximum(times - now, 0.0)))

    def _demands(self, ids: Sequence[int], plist: Sequence[Path], clocks: PathClocks,
                 now: float) -> dict[int, str]:
        """Weak vehicles whose path over the look ahead asks more than their own limits:
        system id -> what (for the trigger)."""
        out: dict[int, str] = {}
        times = now + LOOKAHEAD_DT * np.arange(LOOKAHEAD_STEPS + 1, dtype=float)
        for sysid, path in zip(ids, plist, strict=True):
            a = self._weak.get(sysid)
            if a is None:
                continue
            _, vel, acc = sample_paths([path] * len(times), times, clocks)
            what = beyond(scaled_limits(self.plan.limits, a), vel, acc)
            if what is not None:
                out[sysid] = f"{what}, at {a:.0%} of its fleet's thrust"
        return out

    def _requests(self, now: float, active: Sequence[int], m: _Measured, clocks: PathClocks,
                  velocities: Mapping[int, FloatArray],
                  obstacles: Mapping[int, FloatArray]) -> list[MpcRequest]:
        cfg = self.config
        dt, n_steps = cfg.dt, cfg.steps
        t0 = round(now / dt) * dt  # on the tick grid: consecutive solves warm-start
        times: FloatArray = t0 + dt * np.arange(n_steps + 1, dtype=float)
        # Everyone's prediction over the horizon: path + error as it is expected to drift
        # (the trigger's forecast), or their MPC trajectory.
        ids, here = m.ids, m.here
        future = self._future(m, times, clocks, now)
        row = {s: i for i, s in enumerate(ids)}
        reach = cfg.reach_m + 2.0 * cfg.horizon_s * self.plan.limits.max_speed_h
        dist = np.linalg.norm(here[None, :, :] - here[[row[s] for s in active]][:, None, :],
                              axis=2)  # (active, n), one numpy call
        requests = []
        for a_i, sysid in enumerate(active):
            i = row[sysid]
            v0 = np.asarray(velocities.get(sysid, np.zeros(3)), dtype=float)
            p0 = here[i] + v0 * (t0 - now)
            rep = [m.paths[i]] * (n_steps + 1)
            rp, rv, ra = sample_paths(rep, times, clocks)
            # Within REINIT_M of what it is told, it is replanned from there (module
            # docstring): the autopilot keeps fighting the gust, as on its path.
            res = self._fresh(sysid, now)
            told_p, told_v = (rp[0], rv[0]) if res is None else res.sample(t0)[:2]
            weak = self._weak.get(sysid)
            limits = self.plan.limits if weak is None else scaled_limits(self.plan.limits, weak)
            own = np.zeros((n_steps + 1, 3))
            if np.linalg.norm(p0 - told_p) <= REINIT_M \
                    and not speed_violations(told_v, limits, self.config.limit_tol):
                p0, v0 = told_p, told_v
                # It flies its reference offset by its deviation, drifting as forecast:
                # the separation is between where the vehicles will be, so the others are
                # given relative to that (its reference keeps clear of them shifted back).
                own = error_forecast(m.dev[i:i + 1], m.dev_rate[i:i + 1],
                                     np.maximum(times - now, 0.0))[0]
            elif weak is not None:
                # Its limits are an estimate (its share of the fleet's thrust): measured a
                # little faster, it is planned from the fastest it is taken to manage.
                v0 = clip_speed(v0, limits)
            others, other_ids = [], []
            for j in map(int, np.flatnonzero(dist[a_i] <= reach)):
                if ids[j] != sysid:
                    others.append(future[j] - own)
                    other_ids.append(ids[j])
            for other, where in obstacles.items():
                if other not in row and np.linalg.norm(where - here[i]) <= reach:
                    others.append(np.repeat(np.asarray(where, dtype=float)[None],
                                            n_steps + 1, 0) - own)
                    other_ids.append(other)
            ahead = None
            if weak is not None:
                at = t0 + LOOKAHEAD_DT * np.arange(LOOKAHEAD_STEPS + 1, dtype=float)
                ahead = sample_paths([m.paths[i]] * len(at), at, clocks)[0]
            requests.append(MpcRequest(
                sysid=sysid, t0=float(t0), p0=p0, v0=v0, ref_pos=rp, ref_vel=rv, ref_acc=ra,
                limits=limits, lookahead=ahead, lookahead_dt=LOOKAHEAD_DT,
                own=own if np.any(own) else None,
                neighbours=np.stack(others) if others else None,
                neighbour_ids=np.array(other_ids, dtype=np.intp) if others else None))
        return requests

    def weakest(self, sysids: Iterable[int]) -> tuple[float, int | None]:
        """The least thrust authority among ``sysids`` and whose it is ((1.0, None): none
        of them is known to be weak)."""
        out: tuple[float, int | None] = (1.0, None)
        for sysid in sysids:
            a = self._weak.get(sysid, 1.0)
            if a < out[0]:
                out = (a, sysid)
        return out

    @staticmethod
    def off_report() -> dict[str, Any]:
        """The report's ``mpc`` object of a flight without MPC."""
        return {"enabled": False, "activations": 0, "vehicles": [],
                "solve_ms": {"p50": None, "p95": None, "p99": None, "max": None, "solves": 0},
                "fallbacks": 0, "unsafe": 0, "recovered": 0, "late": 0, "failed": 0,
                "weak": {}}

    def report(self) -> dict[str, Any]:
        """The report's ``mpc`` object (the same keys as :meth:`off_report`)."""
        ms = np.array(self.stats.solve_ms)

        def pct(q: float) -> float | None:
            return round(float(np.percentile(ms, q)), 2) if ms.size else None
        return {
            "enabled": True,
            "activations": self.supervisor.activations,
            "vehicles": sorted(self.supervisor.vehicles),
            "solve_ms": {"p50": pct(50), "p95": pct(95), "p99": pct(99),
                         "max": round(float(ms.max()), 2) if ms.size else None,
                         "solves": int(ms.size)},
            "fallbacks": self.stats.fallbacks,
            "unsafe": self.stats.unsafe,
            "recovered": self.stats.recovered,
            "late": self.worker.late,
            "failed": self.worker.failed,
            "weak": {str(s): round(a, 2) for s, a in sorted(self._weak.items())},
        }
