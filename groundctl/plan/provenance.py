"""Which limits a saved plan is checked and flown against: its show's, not its own.

A plan file carries the limits it was verified against, but anyone can edit
them: a plan edited to ``min_separation = 0.2`` with two drones 0.3 m apart
"verifies" as safe against its own copy.  So checking or flying a plan file
needs the show it was planned from:

* ``--show SHOW`` names it; by default it is the plan's sibling
  (``X.plan.npz`` or ``X.npz`` -> ``X.toml``), where ``groundctl plan X.toml``
  writes the plan;
* a plan records its show's digest (SHA-256 of the show file and the point
  files it reads) when it is planned; a show with another digest, or a plan
  without one, is refused;
* the plan's own copy of what comes from the show (name, origin, limits,
  model, takeoff slots and altitude, MPC settings) must equal the show's: a
  plan edited after it was planned is refused, whatever the edit;
* ``--accept-plan-limits`` is the operator's explicit way out: the plan is
  checked against the limits it carries (a plan saved before plans recorded
  their show, a plan from elsewhere without its show).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from groundctl.errors import UntrustedPlan
from groundctl.plan.plan import Plan
from groundctl.show.model import Show

#: The flag that trusts a plan's own limits, as the messages name it.
ACCEPT_FLAG = "--accept-plan-limits"


@dataclass(frozen=True)
class PlanSource:
    """A plan and where the limits it is checked against come from."""

    plan: Plan
    """The plan (its limits are the show's when ``show`` is set)."""
    show: Path | None
    """The show file it was matched with; None when the operator accepted the plan's own
    limits."""

    @property
    def limits_from(self) -> str:
        """For reports: ``shows/demo.toml`` or what the operator accepted instead."""
        return str(self.show) if self.show is not None else \
            f"the plan file itself ({ACCEPT_FLAG})"


def sibling_show(plan_path: str | Path) -> Path:
    """``X.plan.npz`` or ``X.npz`` -> ``X.toml``: where ``groundctl plan X.toml`` put it."""
    p = Path(plan_path)
    stem = p.name.removesuffix(".npz").removesuffix(".plan")
    return p.with_name(f"{stem}.toml")


def check_against_show(plan: Plan, show: Show, plan_path: str | Path) -> None:
    """UntrustedPlan unless ``plan`` was planned from ``show`` and not edited since."""
    where = show.source or "the show"
    replan = f"re-plan it with 'groundctl plan {where}'"
    if not plan.show_digest:
        raise UntrustedPlan(plan_path, (
            f"records no show hash (saved before plans recorded their show, or not planned "
            f"from a show file), so it cannot be matched with {where}: {replan}, or pass "
            f"{ACCEPT_FLAG} to trust the limits it carries"), where)
    if plan.show_digest != show.digest:
        raise UntrustedPlan(plan_path, (
            f"was not planned from {where} (the show's hash differs: the show was edited "
            f"after planning, or it is another show): {replan}, or pass {ACCEPT_FLAG} to "
            f"trust the limits the plan carries"), where)
    differs = _first_difference(plan, show)
    if differs:
        raise UntrustedPlan(plan_path, (
            f"its {differs}: the plan was edited after it was planned from {where}; "
            f"{replan}"), where)


def _first_difference(plan: Plan, show: Show) -> str | None:
    """What the plan holds that is not what its show says, or None."""
    if plan.limits != show.limits:
        mine, theirs = asdict(plan.limits), asdict(show.limits)
        key = next(k for k in mine if mine[k] != theirs[k])
        return f"limits differ from the show's ({key} {mine[key]} in the plan, " \
               f"{theirs[key]} in the show)"
    if plan.origin != show.origin:
        return "origin differs from the show's"
    if plan.drones != show.drones or not np.array_equal(plan.home, show.home):
        return "takeoff slots differ from the show's"
    if plan.takeoff_altitude != show.takeoff_altitude:
        return "takeoff altitude differs from the show's"
    if plan.model != show.model.kind:
        return f"model '{plan.model}' differs from the show's '{show.model.kind}'"
    if plan.mpc != show.mpc:
        return "MPC settings differ from the show's"
    if plan.show_name != show.name:
        return "show name differs from the show's"
    return _spares_difference(plan, show)


def _spares_difference(plan: Plan, show: Show) -> str | None:
    """The spares the plan places against the show's ``[spares]``: how many, how they
    wait, and where, if the show file says."""
    sp, asked = plan.spares, show.spares
    if sp is None or asked is None:
        return None if sp is None and asked is None else "spares differ from the show's"
    if sp.count != asked.count or sp.standby != asked.standby:
        return f"spares ({sp.count} waiting on the {sp.standby}) differ from the show's " \
               f"({asked.count} on the {asked.standby})"
    given = asked.points if asked.points is not None else asked.pads
    if given is not None:
        mine = sp.points if asked.points is not None else sp.pads[:, :2]
        if not sp.given or not np.array_equal(mine, given):
            return "spares' positions differ from the show's"
    elif sp.given:
        return "spares' positions differ from the show's (it lets the planner lay them out)"
    else:
        from groundctl.errors import SpareError
        from groundctl.plan.spares import place_spares

        # Laid out by the planner: laid out again, the same way (it is deterministic).
        try:
            again = place_spares(asked, replace(plan, spares=None))
        except SpareError:
            return "spares' positions differ from where the planner lays them out"
        if not (np.allclose(again.pads, sp.pads, atol=1e-9)
                and np.allclose(again.points, sp.points, atol=1e-9)):
            return "spares' positions differ from where the planner lays them out"
    return None


def plan_source(plan: Plan, plan_path: str | Path, show_path: str | Path | None = None,
                accept_plan_limits: bool = False,
                points_dirs: Sequence[str | Path] = ()) -> PlanSource:
    """Tie ``plan`` (read from ``plan_path``) to the show it is checked and flown against.

    ``show_path`` (default: :func:`sibling_show`) is loaded and matched
    (:func:`check_against_show`); without one, UntrustedPlan says how to
    proceed.  ``accept_plan_limits`` skips the show: the plan's own limits.
    """
    from groundctl.show.loader import load_show

    if accept_plan_limits:
        return PlanSource(plan, None)
    path = Path(show_path) if show_path is not None else sibling_show(plan_path)
    if show_path is None and not path.is_file():
        raise UntrustedPlan(plan_path, (
            f"no show file to check its limits against (looked for {path}): give the show it "
            f"was planned from with --show SHOW.toml, or pass {ACCEPT_FLAG} to trust the "
            f"limits the plan file carries"))
    show = load_show(path, points_dirs)
    check_against_show(plan, show, plan_path)
    return PlanSource(plan, path)
