"""Pre-flight checks: pure functions of what the link knows, the assignment and the time.

Every check returns a :class:`CheckResult` whose ``detail`` says the value
and the rule, so the operator sees why a vehicle is held back.  A
:class:`PreflightReport` collects them, renders one line per vehicle and
raises :class:`~groundctl.errors.PreflightFailed` unless every show vehicle
that is not excluded passed.

A vehicle the show does not need (every track already has a vehicle, and it
has none: a stray system id, a spoofed HEARTBEAT) is reported and ignored, never
checked: it cannot block the others.  A spare standing on its pad
(:attr:`Assignment.spares <groundctl.execute.mapping.Assignment.spares>`) is checked
like a show vehicle, since it may take over a track in flight, but it never blocks
either: one that fails is a spare fewer (:meth:`PreflightReport.ready_spares`), not a
show that cannot start.

Excluding a vehicle keeps the rest of the show valid (the same trajectories
minus some drones), but the excluded drone still stands on its takeoff slot:
:func:`remaining_plan_conflicts` checks the neighbours' takeoff and landing
do not pass too close to it.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

import numpy as np

from groundctl.errors import PreflightFailed
from groundctl.execute.mapping import (
    DEFAULT_SLOT_HEIGHT_TOLERANCE_M,
    DEFAULT_SLOT_TOLERANCE_M,
    Assignment,
)
from groundctl.link.state import VehicleState
from groundctl.plan.plan import Plan
from groundctl.vehicleid import spell_many


@dataclass(frozen=True)
class Thresholds:
    """Limits the pre-flight checks hold every vehicle to."""

    heartbeat_timeout_s: float = 2.0
    """Max age of the last autopilot HEARTBEAT, s."""
    min_fix_type: int = 3
    """Min GPS_RAW_INT.fix_type (3 = 3D fix)."""
    min_battery_pct: float = 60.0
    """Min remaining battery, percent."""
    slot_tolerance_m: float = DEFAULT_SLOT_TOLERANCE_M
    """Max horizontal distance from the assigned takeoff slot, m."""
    slot_height_tolerance_m: float = DEFAULT_SLOT_HEIGHT_TOLERANCE_M
    """Max height above or below the assigned takeoff slot, m (the show's origin
    altitude against the vehicles' own)."""
    max_loss_ratio: float = 0.2
    """Max fraction of packets lost."""
    max_rtt_s: float = 0.25
    """Max TIMESYNC round-trip time, s."""
    require_fix_type: int | None = None
    """``--require-rtk``: min GPS_RAW_INT.fix_type (5 RTK float, 6 RTK fixed); None: no
    ``rtk`` check."""
    max_wind: float | None = None
    """The show's ``limits.max_wind`` (or ``--max-wind``), m/s: a vehicle estimating a
    stronger wind fails ``wind``; None: no ``wind`` check."""


@dataclass(frozen=True)
class CheckResult:
    """The outcome of one check on one vehicle."""

    name: str
    """Short check name: ``heartbeat``, ``gps``, ``rtk``, ``position``, ``battery``,
    ``slot``, ``link``, ``wind``, ``autopilot``."""
    ok: bool
    """True if the vehicle passed."""
    detail: str
    """The value and, on failure, the rule it broke."""

    def __str__(self) -> str:
        return f"{self.name}: {self.detail}"


def check_heartbeat(state: VehicleState, now: float, th: Thresholds) -> CheckResult:
    """The autopilot's HEARTBEAT is recent."""
    if state.last_heartbeat is None:
        return CheckResult("heartbeat", False, "no autopilot HEARTBEAT yet")
    age = now - state.last_heartbeat
    if age >= th.heartbeat_timeout_s:
        return CheckResult("heartbeat", False,
                           f"last HEARTBEAT {age:.1f} s ago (limit {th.heartbeat_timeout_s:.1f} s)")
    return CheckResult("heartbeat", True, f"{age:.1f} s ago")


def check_gps(state: VehicleState, th: Thresholds) -> CheckResult:
    """The GPS has a 3D fix (or better)."""
    fix = state.gps_fix_type
    if fix is None:
        return CheckResult("gps", False, "no GPS_RAW_INT yet")
    if fix < th.min_fix_type:
        return CheckResult("gps", False, f"fix type {fix} (need {th.min_fix_type}: 3D fix)")
    return CheckResult("gps", True, f"fix type {fix}")


def check_rtk(state: VehicleState, th: Thresholds) -> CheckResult:
    """``--require-rtk``: the GPS has an RTK float (5) or fixed (6) solution."""
    from groundctl.rtk.options import fix_name

    need = th.require_fix_type or 0
    fix = state.gps_fix_type
    if fix is None or fix < need:
        return CheckResult("rtk", False, f"fix {fix_name(fix)}, need {fix_name(need)}")
    return CheckResult("rtk", True, f"fix {fix_name(fix)}")


def check_position(state: VehicleState) -> CheckResult:
    """The EKF has an origin and a local position, and the autopilot's own pre-arm checks pass.

    The pre-arm bit of SYS_STATUS is how ArduPilot and PX4 say "I would arm
    now"; an EKF origin alone comes well before that (SITL: 20 s vs 40 s).
    """
    if state.ekf_origin is None:
        return CheckResult("position", False, "EKF origin unknown (no GPS_GLOBAL_ORIGIN)")
    if state.position_ned is None:
        return CheckResult("position", False, "no local position (no LOCAL_POSITION_NED)")
    if state.prearm_ok is False:
        last = next((t.text for t in reversed(state.statustexts)
                     if t.text.lower().startswith(("prearm", "arm:", "preflight"))), None)
        why = f" ({last})" if last else ""
        return CheckResult("position", False, f"autopilot pre-arm checks failing{why}")
    return CheckResult("position", True, "EKF origin and local position known, pre-arm "
                       + ("ok" if state.prearm_ok else "not reported"))


def check_battery(state: VehicleState, th: Thresholds) -> CheckResult:
    """Enough battery for the show."""
    pct = state.battery_remaining_pct
    if pct is None:
        return CheckResult("battery", False, "battery level unknown")
    if pct < th.min_battery_pct:
        return CheckResult("battery", False,
                           f"{pct:.0f} % (minimum {th.min_battery_pct:.0f} %)")
    return CheckResult("battery", True, f"{pct:.0f} %")


def check_slot(sysid: int, assignment: Assignment, th: Thresholds) -> CheckResult:
    """The vehicle has a track and stands on its takeoff slot (a spare: on its pad)."""
    if sysid in assignment.refused:
        return CheckResult("slot", False, assignment.refused[sysid])
    if sysid in assignment.spares:
        what, spot = f"spare {assignment.spares[sysid] + 1}", "pad"
    elif sysid in assignment.tracks:
        what, spot = f"track {assignment.tracks[sysid]}", "slot"
    else:
        return CheckResult("slot", False, "no track assigned (extra vehicle)")
    d = assignment.distances.get(sysid)
    if d is None:
        return CheckResult("slot", False, f"{what}, distance to its {spot} unknown")
    if d > th.slot_tolerance_m:
        return CheckResult("slot", False, f"{what}, {d:.1f} m from its {spot} "
                                          f"(tolerance {th.slot_tolerance_m:.1f} m)")
    dz = assignment.heights.get(sysid)
    if dz is not None and abs(dz) > th.slot_height_tolerance_m:
        # The show frame's altitude is not the field's: every setpoint would be that far
        # off vertically (a show in the ground, or hundreds of metres up).
        return CheckResult("slot", False, (
            f"{what}, {d:.1f} m from its {spot} but {abs(dz):.0f} m "
            f"{'above' if dz > 0 else 'below'} it (tolerance "
            f"{th.slot_height_tolerance_m:.0f} m): the show's origin altitude is not the "
            "field's"))
    return CheckResult("slot", True, f"{what}, {d:.1f} m from its {spot}")


def check_link(state: VehicleState, th: Thresholds) -> CheckResult:
    """Few packets lost and a short round trip (and a known clock offset)."""
    loss, rtt = state.loss_ratio, state.rtt_s
    if rtt is None:
        return CheckResult("link", False, "no TIMESYNC answer yet (clock offset unknown)")
    problems = []
    if loss >= th.max_loss_ratio:
        problems.append(f"loss {loss:.0%} (limit {th.max_loss_ratio:.0%})")
    if rtt >= th.max_rtt_s:
        problems.append(f"RTT {rtt * 1000:.0f} ms (limit {th.max_rtt_s * 1000:.0f} ms)")
    if problems:
        return CheckResult("link", False, ", ".join(problems))
    detail = f"loss {loss:.0%}, RTT {rtt * 1000:.0f} ms"
    # Shown, never failed on: a spoofer's packets must not keep a vehicle on the ground
    # (what they said was not believed).
    if state.link_conflicts:
        detail += f", {state.link_conflicts} link conflict(s)"
    if state.bad_signatures:
        detail += f", {state.bad_signatures} bad signature(s)"
    return CheckResult("link", True, detail)


#: A wind estimate older than this is not the wind now, s (they stream at 1 Hz).
WIND_FRESH_S = 5.0


def check_wind(state: VehicleState, now: float, th: Thresholds) -> CheckResult:
    """The vehicle's own wind estimate is within the show's limit.  Without one it passes
    (said so): a multirotor's estimator learns the wind in flight, and the limit is
    watched again in the air before the show starts (:mod:`groundctl.execute.wind`)."""
    assert th.max_wind is not None
    speed = state.wind_speed(now, WIND_FRESH_S)
    if speed is None:
        return CheckResult("wind", True, f"no estimate yet (limit {th.max_wind:g} m/s)")
    if speed > th.max_wind:
        return CheckResult("wind", False, f"{speed:.1f} m/s estimated, above the show's "
                                          f"limit of {th.max_wind:g} m/s")
    return CheckResult("wind", True, f"{speed:.1f} m/s (limit {th.max_wind:g} m/s)")


def check_autopilot(state: VehicleState) -> CheckResult:
    """The autopilot is one whose modes we know how to command."""
    if state.flavour is None:
        return CheckResult("autopilot", False, "autopilot unknown: cannot command its modes")
    return CheckResult("autopilot", True, f"{state.flavour}, mode {state.mode}")


def check_vehicle(state: VehicleState, assignment: Assignment, now: float,
                  thresholds: Thresholds | None = None) -> list[CheckResult]:
    """Every pre-flight check on one vehicle, in a fixed order."""
    th = thresholds or Thresholds()
    rtk = [check_rtk(state, th)] if th.require_fix_type is not None else []
    wind = [check_wind(state, now, th)] if th.max_wind is not None else []
    return [
        check_heartbeat(state, now, th),
        check_gps(state, th),
        *rtk,
        check_position(state),
        check_battery(state, th),
        check_slot(state.system_id, assignment, th),
        check_link(state, th),
        *wind,
        check_autopilot(state),
    ]


@dataclass(frozen=True)
class PreflightReport:
    """Every vehicle's check results at one instant."""

    results: dict[int, list[CheckResult]]
    """System id -> its check results (the vehicles that may fly, spares included)."""
    extra: dict[int, str] = field(default_factory=dict)
    """System id -> why it is ignored: heard, but not needed by the show (every track
    has a vehicle and it has none).  Never checked, never blocking."""
    spares: dict[int, int] = field(default_factory=dict)
    """System id -> spare pad index (0-based) of the vehicles in :attr:`results`
    standing by as spares: checked, but never blocking (not in :meth:`failures`)."""

    def _failed(self, sysid: int) -> list[str]:
        return [str(r) for r in self.results[sysid] if not r.ok]

    def failures(self, excluded: Collection[int] = ()) -> dict[int, list[str]]:
        """System id -> failed checks as text, for the show's vehicles not ``excluded``
        (spares: :meth:`spare_failures`)."""
        out = {sysid: self._failed(sysid) for sysid in self.results
               if sysid not in excluded and sysid not in self.spares}
        return {sysid: why for sysid, why in out.items() if why}

    def spare_failures(self, excluded: Collection[int] = ()) -> dict[int, list[str]]:
        """System id -> failed checks as text, for the spares not ``excluded``."""
        out = {sysid: self._failed(sysid) for sysid in self.spares if sysid not in excluded}
        return {sysid: why for sysid, why in out.items() if why}

    def ready_spares(self, excluded: Collection[int] = ()) -> dict[int, int]:
        """System id -> pad index of the spares that passed every check and are not
        ``excluded``: the ones that may take over a track."""
        return {sysid: pad for sysid, pad in sorted(self.spares.items())
                if sysid not in excluded and not self._failed(sysid)}

    def lines(self, excluded: Collection[int] = ()) -> list[str]:
        """One line per vehicle, in system id order."""
        out = []
        for sysid in sorted({*self.results, *self.extra}):
            if sysid in self.extra:
                out.append(f"vehicle {sysid}: ignored: {self.extra[sysid]}")
                continue
            failed = self._failed(sysid)
            if sysid in excluded:
                status = "excluded by the operator"
            elif failed:
                status = "NOT READY: " + "; ".join(failed)
            else:
                status = "ready"
            name = f"vehicle {sysid}" + (f" (spare {self.spares[sysid] + 1})"
                                         if sysid in self.spares else "")
            out.append(f"{name}: {status}")
        return out

    def render(self, excluded: Collection[int] = ()) -> str:
        return "\n".join(self.lines(excluded))

    def summary(self, excluded: Collection[int] = ()) -> str:
        """One fleet-wide line: ``61/64 ready, waiting for 3: gps (12, 40), battery (7)``
        (the show's vehicles; then ``; spares 1/2 ready`` where spares stand by)."""
        flying = [s for s in sorted(self.results) if s not in excluded and s not in self.spares]
        waiting: dict[str, list[int]] = {}
        for sysid in flying:
            for r in self.results[sysid]:
                if not r.ok:
                    waiting.setdefault(r.name, []).append(sysid)
        not_ready = {s for ids in waiting.values() for s in ids}
        line = f"{len(flying) - len(not_ready)}/{len(flying)} ready"
        if excluded:
            line += f" ({len(set(excluded) & set(self.results))} excluded)"
        if not_ready:
            line += f", waiting for {len(not_ready)}: " + ", ".join(
                f"{name} ({spell_many(ids)})" for name, ids in waiting.items())
        if self.spares:
            standing = [s for s in self.spares if s not in excluded]
            line += f"; spares {len(self.ready_spares(excluded))}/{len(standing)} ready"
        if self.extra:
            line += (f"; {len(self.extra)} not in the show, ignored: "
                     + spell_many(self.extra))
        return line

    def failing_by_check(self, excluded: Collection[int] = (), most: int = 4) -> list[str]:
        """One line per failing check, fleet-wide, with the vehicles grouped by what it
        says: ``gps: no GPS_RAW_INT yet (12, 40)``; at most ``most`` different details
        each (then "and N more vehicles").  For a terminal that must not get a line per
        vehicle.  The show's vehicles only: a spare never holds the show."""
        by_check: dict[str, dict[str, list[int]]] = {}
        for sysid in sorted(self.results):
            if sysid in excluded or sysid in self.spares:
                continue
            for r in self.results[sysid]:
                if not r.ok:
                    by_check.setdefault(r.name, {}).setdefault(r.detail, []).append(sysid)
        out = []
        for name, details in by_check.items():
            shown = list(details.items())[:most]
            parts = [f"{detail} ({', '.join(map(str, ids))})" for detail, ids in shown]
            rest = sum(len(ids) for _, ids in list(details.items())[most:])
            if rest:
                parts.append(f"and {rest} more vehicle{'s' if rest > 1 else ''}")
            out.append(f"  {name}: " + "; ".join(parts))
        return out

    def failing_lines(self, excluded: Collection[int] = ()) -> list[str]:
        """The lines of the vehicles that fail a check (the others are ready)."""
        return [line for line in self.lines(excluded) if "NOT READY" in line]

    def require_all(self, excluded: Collection[int] = ()) -> None:
        """Raise PreflightFailed unless every vehicle not ``excluded`` passed every check."""
        failures = self.failures(excluded)
        if failures:
            raise PreflightFailed(failures)


def run_preflight(vehicles: Mapping[int, VehicleState], assignment: Assignment, now: float,
                  thresholds: Thresholds | None = None) -> PreflightReport:
    """Check every vehicle in ``vehicles`` the show may need.

    Once every track of the plan has a vehicle, one without a track is not needed:
    it goes in :attr:`PreflightReport.extra` (reported, ignored).  While some track
    still has none, every vehicle is checked (it may be the one that will take it).
    A spare on its pad is always checked, and kept apart (:attr:`PreflightReport.spares`).
    """
    results: dict[int, list[CheckResult]] = {}
    extra: dict[int, str] = {}
    for sysid, state in sorted(vehicles.items()):
        if sysid in assignment.spares:
            results[sysid] = check_vehicle(state, assignment, now, thresholds)
            continue
        if sysid not in assignment.tracks and not assignment.unassigned_tracks:
            why = assignment.refused.get(sysid)
            extra[sysid] = ("not in the show (every track has a vehicle"
                            + (f"; {why}" if why else "") + ")")
            continue
        results[sysid] = check_vehicle(state, assignment, now, thresholds)
    spares = {s: k for s, k in assignment.spares.items() if s in results}
    return PreflightReport(results, extra, spares)


@dataclass(frozen=True)
class Conflict:
    """A flying drone passing too close to an excluded drone left on its slot."""

    track: int
    """The flying drone's track."""
    excluded_track: int
    """The excluded drone's track (its home slot is the obstacle)."""
    phase: str
    """``takeoff``, ``landing``, ``show start`` or ``show end``."""
    time: float
    """Show time of the closest approach (0 for takeoff, the duration for landing), s."""
    distance: float
    """Closest approach to the excluded drone's home spot, m."""
    min_separation: float
    """The plan's minimum separation, m."""

    def __str__(self) -> str:
        return (f"track {self.track} passes {self.distance:.2f} m from excluded track "
                f"{self.excluded_track}'s takeoff slot during {self.phase} at t={self.time:.1f} s "
                f"(minimum separation {self.min_separation:.2f} m)")


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` (E, 3) to segments a-b (n, 3): (n, E)."""
    ab = b - a
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    t = np.einsum("nej,nj->ne", p[None, :, :] - a[:, None, :], ab) / denom[:, None]
    t = np.clip(t, 0.0, 1.0)
    closest = a[:, None, :] + t[..., None] * ab[:, None, :]
    return np.linalg.norm(p[None, :, :] - closest, axis=2)


def remaining_plan_conflicts(plan: Plan, excluded_tracks: Collection[int],
                             window_s: float = 5.0, step_s: float = 0.1) -> list[Conflict]:
    """Where the remaining drones come within min_separation of an excluded drone on the ground.

    Checked: each remaining drone's vertical climb from its slot to takeoff
    altitude and its final descent, and its trajectory during the first and
    last ``window_s`` seconds of the show, when it is low and near the slots.
    One conflict (the closest approach) is reported per pair and phase.
    Empty means the show may fly without the excluded drones.
    """
    if window_s <= 0:
        raise ValueError(f"`window_s` must be positive, got {window_s}")
    if step_s <= 0:
        raise ValueError(f"`step_s` must be positive, got {step_s}")
    excl = sorted(set(excluded_tracks))
    bad = [t for t in excl if not 0 <= t < plan.drones]
    if bad:
        raise ValueError(f"`excluded_tracks` {bad} are not tracks of this plan "
                         f"(0..{plan.drones - 1})")
    keep = np.array([t for t in range(plan.drones) if t not in set(excl)], dtype=int)
    if not excl or len(keep) == 0:
        return []
    sep = plan.limits.min_separation
    obstacles = plan.home[excl]  # (E, 3) on the ground
    conflicts: list[Conflict] = []

    def collect(phase: str, dist: np.ndarray, times: np.ndarray | float) -> None:
        # dist: (n_keep, E) closest approach; times: matching show times.
        for i, e in zip(*np.nonzero(dist < sep), strict=True):
            t = float(times if np.ndim(times) == 0 else times[i, e])  # type: ignore[index]
            conflicts.append(Conflict(int(keep[i]), excl[e], phase, t, float(dist[i, e]), sep))

    rise = np.array([0.0, 0.0, plan.takeoff_altitude])
    collect("takeoff", segment_distance(obstacles, plan.home[keep], plan.home[keep] + rise), 0.0)
    down = plan.landing[keep]  # a drone may land on another's takeoff spot
    collect("landing", segment_distance(obstacles, down, down + rise), plan.duration)

    n_steps = max(int(np.ceil(min(window_s, plan.duration) / step_s)), 1)
    windows: list[tuple[str, np.ndarray]] = [
        ("show start", np.linspace(0.0, min(window_s, plan.duration), n_steps + 1)),
        ("show end", np.linspace(max(plan.duration - window_s, 0.0), plan.duration,
                                 n_steps + 1)),
    ]
    for phase, times in windows:
        pos, _, _ = plan.trajectories.evaluate(times)  # (n, T, 3)
        d = np.linalg.norm(pos[keep][:, :, None, :] - obstacles[None, None, :, :], axis=3)
        k = d.argmin(axis=1)  # (n_keep, E) closest time index
        collect(phase, d.min(axis=1), times[k])
    return conflicts
