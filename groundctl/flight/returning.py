"""Land-all in the middle of a show: a collision-free way home, planned on the spot.

Straight lines from wherever the show was interrupted to the landing points
cross each other (a vertical ring flying home to a flat grid, say): the
first end-to-end hold/land-all test flew two drones 1.37 m apart that way.
So land-all first freezes the show clock (every drone hovers on its plan
point, which the plan keeps separated), then plans one more quadrotor
transition with the same SCP planner and limits as the show itself (with a
tracking margin, whatever the show file says), from those points to the
landing points, and the fleet flies it.  Planning takes
well under a second for a hundred drones; they hover meanwhile.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from groundctl.plan.feasibility import min_transition_time
from groundctl.plan.plan import Plan
from groundctl.plan.scp_quad import plan_quad_transition
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import PlannerSettings, QuadrotorModel

#: Extra separation the return is planned with, m: it is flown at once, with
#: whatever tracking error the moment has, and unlike the show it was never
#: rehearsed (the first land-all test flew a pair 1.497 m apart at a 1.5 m limit).
TRACKING_MARGIN_M = 0.25
#: The return takes this many times the slowest drone's straight-line minimum.
TIME_MARGIN = 1.5
#: ... and at least this long, s.
MIN_DURATION_S = 4.0


def plan_return(plan: Plan, tracks: list[int], start: NDArray[np.float64]) -> Trajectories:
    """Trajectories (one row per entry of ``tracks``) from ``start`` to their landing points.

    Raises the planner's InfeasibleTransition / PlanningError if it cannot.
    """
    start = np.asarray(start, dtype=float)
    goal = plan.landing_hover[tracks]
    bound = min_transition_time(start, goal, plan.limits, QuadrotorModel())
    duration = max(bound.seconds * TIME_MARGIN, MIN_DURATION_S)
    # The planner's own tracking margin: per pair, as far as its two ends allow.
    result = plan_quad_transition(0, "return", start, goal, duration, plan.limits,
                                  PlannerSettings(tracking_margin=TRACKING_MARGIN_M))
    return result.trajectories
