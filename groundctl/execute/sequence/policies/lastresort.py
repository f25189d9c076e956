"""The last resort (no return plan, drones off their plans): every drone holds where it is
and they land straight down, one column at a time -- whether a drone's column is clear,
and whether it has waited long enough for the operator to hear of it."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from groundctl.execute.sequence.types import COLUMN_WAIT_S


def column_clear(here: NDArray[np.float64],
                 others: Iterable[tuple[NDArray[np.float64], bool]], *, limit_m: float,
                 above_m: float, margin_m: float = 0.0, ground_m: float | None = None) -> bool:
    """Whether a drone at ``here`` may go straight down: no other drone (``others``: each
    position, and whether it is down on the ground) within ``limit_m + margin_m``
    horizontally of its column, counting drones up to ``above_m`` above it.  With
    ``ground_m``, a drone down on the ground counts only within ``ground_m`` of where it
    lands: a landed drone is not flying into anyone."""
    for pos, down in others:
        reach = ground_m if ground_m is not None and down else limit_m + margin_m
        if pos[2] < here[2] + above_m and float(np.hypot(*(pos[:2] - here[:2]))) < reach:
            return False
    return True


def say_blocked(waiting_since: float | None, now: float, said: bool) -> bool:
    """Whether to tell the operator a drone still waits for its column to clear (once,
    after :data:`COLUMN_WAIT_S`: a drone below it is lost, or still landing)."""
    return waiting_since is not None and now - waiting_since >= COLUMN_WAIT_S and not said
