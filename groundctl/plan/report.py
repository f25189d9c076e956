"""The metrics table and JSON of a planned show (pure: strings and dicts, no printing)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from groundctl.plan.plan import SparePlan
from groundctl.plan.planner import PlanResult


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def report_dict(result: PlanResult) -> dict[str, Any]:
    """The plan's figures as one JSON-ready object (keys are a contract)."""
    ver = result.verification
    plan = result.plan
    transitions = []
    for tr, w, pe in zip(result.transitions, ver.windows, ver.pattern_errors, strict=True):
        transitions.append({
            "index": tr.index,
            "name": tr.name,
            "drones": plan.drones,
            "steps": tr.steps,
            "iterations": tr.iterations,
            "seconds_per_iteration": tr.seconds / max(tr.iterations, 1),
            "plan_seconds": tr.seconds,
            "qp_drones": tr.qp_drones,
            "straight_lines": tr.straight,
            "converged": tr.converged,
            "straight_min_separation_m": _finite(tr.straight_min_separation),
            "path_length_mean_m": w.path_length_mean,
            "straight_length_mean_m": tr.straight_length,
            "min_separation_m": w.min_separation,
            "worst_violation_m": max(0.0, plan.limits.min_separation - w.min_separation),
            "max_speed_mps": w.max_speed_h,
            "max_accel_mps2": w.max_accel,
            "pattern_error_m": pe,
        })
    o = ver.overall
    return {
        "show": plan.show_name,
        "model": plan.model,
        "drones": plan.drones,
        "duration_s": plan.duration,
        "transitions": transitions,
        "min_separation_m": o.min_separation,
        "min_separation_pair": list(o.min_separation_pair),
        "worst_violation_m": ver.worst_violation,
        "max_speed_mps": o.max_speed_h,
        "max_climb_mps": o.max_speed_up,
        "max_descent_mps": o.max_speed_down,
        "max_accel_mps2": o.max_accel,
        "min_altitude_m": o.min_alt,
        "max_altitude_m": o.max_alt,
        "pattern_error_m": max(ver.pattern_errors, default=0.0),
        "plan_seconds": result.seconds,
        "violations": list(ver.violations),
        "safe": ver.safe,
        **({} if plan.spares is None else {"spares": _spares(plan.spares)}),
    }


def _spares(sp: SparePlan) -> dict[str, Any]:
    """Where the spares wait (``spares`` of the report)."""
    return {"count": sp.count, "standby": sp.standby, "given": sp.given,
            "clearance_m": sp.clearance_m,
            "pads": np.round(sp.pads, 3).tolist(), "points": np.round(sp.points, 3).tolist()}


COLUMNS = (
    ("#", "{index}", 3), ("into", "{name}", 12), ("drones", "{drones}", 6),
    ("steps", "{steps}", 5), ("iter", "{iterations}", 4),
    ("s/iter", "{seconds_per_iteration:.3f}", 7), ("total s", "{plan_seconds:.2f}", 7),
    ("path m", "{path_length_mean_m:.1f}", 7), ("line m", "{straight_length_mean_m:.1f}", 7),
    ("min sep m", "{min_separation_m:.3f}", 9), ("violation", "{worst_violation_m:.3f}", 9),
    ("v max", "{max_speed_mps:.2f}", 6), ("a max", "{max_accel_mps2:.2f}", 6),
    ("pattern m", "{pattern_error_m:.3f}", 9),
)


def report_table(report: dict[str, Any]) -> str:
    """The paper-style table, one row per transition, and a verdict line."""
    head = " ".join(f"{title:>{width}}" for title, _, width in COLUMNS)
    lines = [f"show '{report['show']}': {report['drones']} drones, {report['model']} model, "
             f"{report['duration_s']:.1f} s", head, "-" * len(head)]
    for row in report["transitions"]:
        lines.append(" ".join(f"{fmt.format(**row):>{width}}"[-width:] if title != "into"
                              else f"{fmt.format(**row):>{width}.{width}}"
                              for title, fmt, width in COLUMNS))
    lines.append("-" * len(head))
    verdict = "SAFE" if report["safe"] else "UNSAFE"
    lines.append(
        f"{verdict}: min separation {report['min_separation_m']:.3f} m, max speed "
        f"{report['max_speed_mps']:.2f} m/s, max accel {report['max_accel_mps2']:.2f} m/s^2, "
        f"pattern error {report['pattern_error_m']:.3f} m, planned in "
        f"{report['plan_seconds']:.2f} s")
    lines.extend(f"  violation: {v}" for v in report["violations"])
    spares = report.get("spares")
    if spares is not None:
        where = "on their pads" if spares["standby"] == "ground" else "in the air over their pads"
        laid = "as the show file gives them" if spares["given"] else \
            "laid out beside the takeoff grid"
        lines.append(f"spares: {spares['count']} waiting {where}, {laid}, clear of every show "
                     f"drone and each other by {spares['clearance_m']:.2f} m")
    lines.extend(
        f"  transition {row['index']} '{row['name']}': the [planner] budget ran out before "
        "the SCP converged; its last iterate, which keeps every pair apart, is the plan "
        "(a larger budget polishes it to less effort)"
        for row in report["transitions"] if not row.get("converged", True))
    return "\n".join(lines)
