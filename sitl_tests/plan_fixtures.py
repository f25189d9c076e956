"""Small shows built in code for the planner tests."""

from __future__ import annotations

import numpy as np

from groundctl.show.model import (
    Formation,
    GeoOrigin,
    Limits,
    PlannerSettings,
    QuadrotorModel,
    Show,
)


def points_show(home: np.ndarray, targets: list[np.ndarray], transition: float = 10.0,
                limits: Limits | None = None, takeoff_altitude: float = 5.0) -> Show:
    """A quadrotor show flying ``home`` (raised) through explicit point formations."""
    n = len(home)
    forms = tuple(
        Formation(name=f"f{i + 1}", shape="points", points=np.asarray(t, dtype=float),
                  colors=np.tile([1.0, 0.0, 0.0], (len(t), 1)), transition_s=transition,
                  hold_s=1.0, index=i + 1)
        for i, t in enumerate(targets))
    return Show(name="test", drones=n, origin=GeoOrigin(47.0, 8.0, 400.0),
                limits=limits or Limits(min_separation=1.5, min_alt=1.0, max_alt=50.0),
                model=QuadrotorModel(), home=np.asarray(home, dtype=float),
                takeoff_altitude=takeoff_altitude, formations=forms,
                planner=PlannerSettings())
