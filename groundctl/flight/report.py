"""The flight report: one JSON-able dict, and its text rendering.

Keys relied on elsewhere (scripts, CI): ``safe``, ``vehicles``,
``min_separation_m``, ``max_tracking_error_m``, ``landed``, ``pattern_error_m``,
``led_timing_error_s``, ``setpoint_lateness_ms``, ``link``.

``commands_refused`` and ``commands_timed_out`` at the top count every
COMMAND_LONG exchange of the flight that failed (pre-flight requests included, but
not its polls for the EKF origin and home, which are refused until the EKF has them),
one for one with the ``command_refused`` and ``command_timeout`` events; a vehicle's
``commands_refused`` counts only the show sequence's commands to it.  A
formation never flown (the flight ended before it) has ``"flown": false`` and
null pattern errors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from groundctl.execute.sequence import VehiclePhase
from groundctl.flight.monitor import FormationError
from groundctl.flight.replanning import Replanner
from groundctl.flight.runner import ShowRunner
from groundctl.vehicleid import network_of, spell


def _r(x: float | None, nd: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def _recovery(r: dict[str, float | int | None]) -> dict[str, float | int | None]:
    return {k: _r(v, 2) if isinstance(v, float) else v for k, v in r.items()}


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else _r(seconds * 1000.0, 1)


def _formation(f: FormationError, drones: int) -> dict[str, Any]:
    # No sample means no formation: 0.0 would read as a perfect one.
    flown = f.samples > 0
    return {"formation": f.name, "index": f.index, "flown": flown,
            "max_m": _r(f.max_m) if flown else None, "mean_m": _r(f.mean_m) if flown else None,
            # The fewest slots held at once while it was held, and whether every one was.
            "slots": f.slots, "complete": f.slots == drones}


def flight_report(runner: ShowRunner, error: str | None = None,
                  more_reasons: Sequence[str] = ()) -> dict[str, Any]:
    """Everything measured about the flight; ``error`` is why it stopped early, if it did.

    ``more_reasons`` are unsafe findings from elsewhere (the dry-run's truth): they
    count towards ``safe`` like the report's own.
    """
    plan = runner.plan
    seq, mon = runner.sequence, runner.monitor
    limit = plan.limits.min_separation
    vehicles: list[dict[str, Any]] = []
    flown = seq.vehicles if seq is not None else {}
    for sysid in sorted(set(flown) | set(runner.link.vehicles)):
        state = runner.link.vehicles.get(sysid)
        run = flown.get(sysid)
        rec = runner.records.get(sysid)
        track = mon.vehicles.get(sysid) if mon is not None else None
        leds = track.led_errors_s if track is not None else []
        vehicles.append({
            "system_id": sysid,  # the vehicle id: its system id on network 1, 1017 for 2:17
            "vehicle": spell(sysid),
            "network": network_of(sysid),
            "track": run.track if run is not None and run.track >= 0 else None,
            # The track's drone name in the show it was imported from (Skybrush), or None.
            "name": plan.name_of(run.track) if run is not None and run.track >= 0 else None,
            "phase": str(run.phase) if run is not None else
            ("excluded" if sysid in runner.config.excluded else "not flown"),
            "landed": run is not None and run.phase is VehiclePhase.LANDED,
            "reason": run.reason if run is not None else None,
            "max_tracking_error_m": _r(track.max_error_m) if track else None,
            "rms_tracking_error_m": _r(track.rms_error_m) if track else None,
            "max_tracking_error_at_s": _r(track.max_error_at_s, 2) if track else None,
            "led_timing_error_max_s": _r(max(map(abs, leds))) if leds else None,
            "commands_refused": rec.commands_refused if rec is not None else 0,
            "last_refusal": rec.last_refusal if rec is not None else None,
            "late": rec.late if rec is not None else False,
            "late_count": rec.late_count if rec is not None else 0,
            "lead_ms": _ms(runner.lead_of(sysid)),
            "response_ms": _ms(runner.response_of(sysid)),
            "along_track_rms_m": _r(track.along_rms_m) if track else None,
            "cross_track_rms_m": _r(track.cross_rms_m) if track else None,
            "ahead_ms": _ms(track.ahead_s) if track else None,
            # Per excursion beyond 0.5 m of its plan in the show: s until back within it
            # (null: never, while in the show).
            "recovery_s": [_r(t, 2) for t in track.recovery_s] if track else [],
            "loss_ratio": _r(state.loss_ratio, 4) if state is not None else None,
            "rtt_ms": _r(state.rtt_s * 1000, 1) if state and state.rtt_s is not None else None,
            # The last round trip is one draw of a wandering delay; this is the link's.
            "median_rtt_ms": _r(state.median_rtt_s * 1000, 1)
            if state and state.median_rtt_s is not None else None,
            "bad_packets": state.bad_packets if state is not None else 0,
            "link_conflicts": state.link_conflicts if state is not None else 0,
            "last_conflict": state.last_conflict if state is not None else None,
            "bad_signatures": state.bad_signatures if state is not None else 0,
            "fix_type": state.gps_fix_type if state is not None else None,
            "rtk_correction_age_s": _r(runner.rtk.age_of(sysid), 2)
            if runner.rtk is not None else None,
        })
    # Given up on the ground (arming refused, say): it stands on its slot, never flew.
    never = {s: v for s, v in flown.items()
             if v.phase is VehiclePhase.FAILED and v.never_flew and not v.fell}
    landed = seq is not None and bool(flown) and all(
        v.phase is VehiclePhase.LANDED for s, v in flown.items() if s not in never)
    min_sep = mon.separation.distance_m if mon is not None else math.inf
    reasons: list[str] = []
    if error is not None:
        reasons.append(error)
    if seq is None:
        reasons.append("the flight never started")
    if seq is not None and seq.aborted is not None:
        reasons.append(f"the show was called off: {seq.aborted}")
    elif flown and len(never) == len(flown):
        reasons.append("no vehicle took off")
    if seq is not None and not landed:
        down = [s for s, v in flown.items()
                if v.phase is not VehiclePhase.LANDED and s not in never]
        reasons.append(f"vehicle(s) [{', '.join(spell(s) for s in down)}] did not land "
                       "under control")
    commanded = mon.separation.commanded_m if mon is not None else None
    if min_sep < limit:
        pair = mon.separation.pair if mon is not None else None
        named = f"({spell(pair[0])}, {spell(pair[1])})" if pair else "(unknown)"
        why = f"separation {min_sep:.2f} m between vehicles {named} (limit {limit:.2f} m)"
        if commanded is not None and commanded >= limit:
            wind = mon.separation.wind_m_s if mon is not None else None
            strong = runner.guard.wind.limit is not None and wind is not None \
                and wind >= 0.5 * runner.guard.wind.limit
            cause = (f"the wind: the vehicles estimated {wind:.1f} m/s then, or a gust, a "
                     "weak vehicle" if strong else "wind, a gust, a weak vehicle")
            why += (f" while their paths kept them {commanded:.2f} m apart: pushed together "
                    f"({cause}), not flown there")
        reasons.append(why)
    reasons += more_reasons
    led = mon.led_errors() if mon is not None else []
    unmatched = sum(v.led_unmatched for v in mon.vehicles.values()) if mon is not None else 0
    late = np.array(runner.lateness_s) * 1000.0
    stats = runner.link.stats
    report: dict[str, Any] = {
        "show": plan.show_name,
        "safe": not reasons,
        "unsafe_reasons": reasons,
        "landed": landed,
        "never_took_off": [{"system_id": s, "vehicle": spell(s), "reason": v.reason}
                           for s, v in sorted(never.items())],
        "vehicles": vehicles,
        "min_separation_m": _r(min_sep),
        "min_separation_pair": list(mon.separation.pair) if mon and mon.separation.pair else None,
        # The same pair spelled as everywhere else ("2:17" on network 2, "17" on one).
        "min_separation_vehicles": [spell(s) for s in mon.separation.pair]
        if mon and mon.separation.pair else None,
        "min_separation_commanded_m": _r(commanded) if commanded is not None else None,
        "min_separation_wind_m_s": _r(mon.separation.wind_m_s)
        if mon is not None and mon.separation.wind_m_s is not None else None,
        "min_separation_at_s": _r(mon.separation.at_s - seq.started_at, 2)
        if mon and seq and seq.started_at is not None and mon.separation.at_s is not None
        else None,
        "separation_limit_m": limit,
        "max_tracking_error_m": _r(mon.max_tracking_error()) if mon is not None else None,
        "rms_tracking_error_m": _r(mon.rms_tracking_error()) if mon is not None else None,
        "tracking_split": _split(mon.tracking_split()) if mon is not None else None,
        # Excursions beyond 0.5 m of the plan in the show, the longest time back, and
        # how many never came back (per vehicle: "recovery_s").
        "recovery": _recovery(mon.recovery()) if mon is not None else None,
        "lead": {"adaptive": runner.leads is not None,
                 "initial_ms": _ms(runner.config.initial_lead_s)},
        "pattern_error_m": [_formation(f, plan.drones)
                            for f in (mon.formations if mon is not None else [])],
        # Spares (issue 29): how many stood ready, how many went, each replacement.
        "spares": ({"asked": plan.spares.count, **(seq.spares_report() if seq is not None
                                                  else {"ready": 0, "used": 0,
                                                        "replacements": []})}
                   if plan.spares is not None else None),
        "led_timing_error_s": {
            "changes": len(led),
            "unmatched": unmatched,
            "mean_abs": _r(float(np.mean(np.abs(led)))) if led else None,
            "max_abs": _r(float(np.max(np.abs(led)))) if led else None,
        },
        "commands_refused": stats.commands_refused,
        "commands_timed_out": stats.commands_timed_out,
        "setpoint_lateness_ms": {
            "p50": _r(float(np.percentile(late, 50)), 2) if late.size else None,
            "p99": _r(float(np.percentile(late, 99)), 2) if late.size else None,
            "max": _r(float(late.max()), 2) if late.size else None,
            "ticks": int(late.size),
            "overruns": runner.overruns,
        },
        "link": {k: int(v) for k, v in vars(stats).items()},
        "wind": {"limit_m_s": runner.guard.wind.limit,
                 "strongest_estimated_m_s": _r(runner.guard.wind.strongest)
                 if runner.guard.wind.strongest is not None else None,
                 "holds": runner.guard.wind.holds,
                 "landed_for_wind": runner.guard.wind.landed},
        "mpc": runner.replanner.report() if runner.replanner is not None
        else runner.mpc_summary if runner.mpc_summary is not None
        else Replanner.off_report(),
    }
    if runner.rtk is not None:
        report["rtk"] = runner.rtk.report()
    return report


def _split(split: dict[str, float | None]) -> dict[str, float | None]:
    return {"along_rms_m": _r(split["along_rms_m"]), "cross_rms_m": _r(split["cross_rms_m"]),
            "ahead_ms": _ms(split["ahead_s"])}


def _fix_age(v: dict[str, Any]) -> str:
    """``RTK fixed 0.4s``: a vehicle's fix type and correction age, one column."""
    from groundctl.rtk.options import fix_name

    age = v.get("rtk_correction_age_s")
    return fix_name(v.get("fix_type")) + ("" if age is None else f" {age:.1f}s")


def render_report(report: dict[str, Any]) -> str:
    """The report as a few lines and a per-vehicle table for the terminal."""
    lines = [f"show {report['show']}: {'SAFE' if report['safe'] else 'NOT SAFE'}"]
    for why in report["unsafe_reasons"]:
        lines.append(f"  - {why}")
    for v in report.get("never_took_off", []):
        lines.append(f"  vehicle {v['system_id']} never took off: {v['reason']} (it stands on "
                     "its slot; its part of the show was dark)")
    if "separation_limit_m" not in report:
        return "\n".join(lines)  # the flight never started: nothing was measured
    sep = report["min_separation_m"]
    lines.append(f"min separation flown {sep if sep is not None else '-'} m "
                 f"(limit {report['separation_limit_m']} m)"
                 + (f", true {report['true_min_separation_m']} m"
                    if report.get("true_min_separation_m") is not None else ""))
    lines.append(f"tracking error max {report['max_tracking_error_m']} m, "
                 f"RMS {report['rms_tracking_error_m']} m")
    split = report.get("tracking_split")
    if split and split["along_rms_m"] is not None:
        ahead = split["ahead_ms"]
        lines.append(f"  while moving: along-track RMS {split['along_rms_m']} m, cross-track RMS "
                     f"{split['cross_rms_m']} m; flown "
                     + (f"{abs(ahead):.0f} ms {'ahead of' if ahead >= 0 else 'behind'}"
                        if ahead is not None else "on") + " the show clock")
    leads = [v["lead_ms"] for v in report["vehicles"] if v.get("lead_ms") is not None]
    if leads:
        how = "measured per vehicle" if report.get("lead", {}).get("adaptive") else "fixed"
        lines.append(f"setpoint lead ({how}): {min(leads):.0f}-{max(leads):.0f} ms")
    for f in report["pattern_error_m"]:
        if f.get("flown", True):
            lines.append(f"  formation {f['index']} {f['formation']}: pattern error max "
                         f"{f['max_m']} m, mean {f['mean_m']} m")
        else:
            lines.append(f"  formation {f['index']} {f['formation']}: not flown")
    led = report["led_timing_error_s"]
    if led["changes"]:
        lines.append(f"LED colour timing: {led['changes']} changes, mean |error| "
                     f"{led['mean_abs']} s, max {led['max_abs']} s, unmatched {led['unmatched']}")
    pacing = report.get("pacing")
    if pacing and pacing.get("paced") and pacing.get("effective_speed") is not None:
        lines.append(f"dry-run pace: x{pacing['effective_speed']:g} of x{report['speed']:g} "
                     f"(the clock waited {pacing['held_by_simulator_s']:g} s for the "
                     f"simulator, {pacing['held_by_ground_station_s']:g} s for the ground "
                     "station)")
    lat = report["setpoint_lateness_ms"]
    lines.append(f"setpoint lateness p50 {lat['p50']} ms, p99 {lat['p99']} ms, max {lat['max']} "
                 f"ms over {lat['ticks']} ticks")
    flight = sum(v["commands_refused"] for v in report["vehicles"])
    lines.append(f"flight commands refused or unanswered: {flight}; all commands refused "
                 f"{report['commands_refused']}"
                 + (f", timed out {report['commands_timed_out']}"
                    if report.get("commands_timed_out") else "")
                 + " (pre-flight's polls for each vehicle's origin and home not counted)")
    mpc = report.get("mpc")
    if mpc and mpc["enabled"]:
        ms = mpc["solve_ms"]
        if not mpc["activations"]:
            lines.append("MPC: on, never needed (no drone off its path)")
        else:
            lines.append(f"MPC: {mpc['activations']} activation(s) on vehicle(s) "
                         f"{mpc['vehicles']}; solve p50 {ms['p50']} ms, p95 {ms['p95']} ms, "
                         f"max {ms['max']} ms over {ms['solves']}; fallbacks "
                         f"{mpc['fallbacks']}, late {mpc['late']}")
    elif mpc:
        lines.append("MPC: off")
    link = report["link"]
    lines.append(f"link: {link['packets']} packets in, {link['sent']} out, {link['bad_packets']} "
                 f"bad, {link['unknown_system_packets']} from unknown systems")
    rtk = report.get("rtk")
    if rtk:
        lines.append(f"RTK corrections ({rtk['kind']}): {rtk['messages_sent']} messages, "
                     f"{rtk['bytes_sent']} bytes, {rtk['rate_bps']} bit/s; bad CRC "
                     f"{rtk['bad_crc']}, too large {rtk['too_large']}, rate-dropped "
                     f"{rtk['rate_dropped']}, source failures {rtk['source_errors']}")
    lines.append(f"{'sysid':>5} {'track':>5} {'phase':<9} {'max err':>7} {'rms':>6} "
                 f"{'loss':>6} {'rtt ms':>6} {'lead ms':>7} {'refused':>7} {'fix/age':>14}"
                 f"  note")
    for v in report["vehicles"]:
        def f(x: Any, fmt: str) -> str:
            return "-" if x is None else format(x, fmt)
        note = v["reason"] or ("late" if v["late"] else
                               f"was late {v['late_count']}x" if v.get("late_count") else "")
        if v.get("name"):
            note = f"{v['name']}: {note}" if note else v["name"]
        lines.append(f"{v['system_id']:>5} {f(v['track'], 'd'):>5} {v['phase']:<9} "
                     f"{f(v['max_tracking_error_m'], '.2f'):>7} "
                     f"{f(v['rms_tracking_error_m'], '.2f'):>6} {f(v['loss_ratio'], '.1%'):>6} "
                     f"{f(v['rtt_ms'], '.0f'):>6} {f(v.get('lead_ms'), '.0f'):>7} "
                     f"{v['commands_refused']:>7} {_fix_age(v):>14}  {note}")
    return "\n".join(lines)
