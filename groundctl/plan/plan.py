"""A planned show: every drone's state and colour at any time, saved to one file.

The plan file is a NumPy ``.npz`` archive: the arrays of the trajectories and
colour keyframes, plus one JSON document (``meta``) with the show's name,
origin, limits, the formation timeline and the hash of the show file it was
planned from.  It holds no pickled objects, so loading a plan from elsewhere
cannot run code, and :meth:`Plan.load` checks every header, array and value
before trusting any (:mod:`groundctl.plan.planfile`).  The limits it carries
are not trusted for flying: :mod:`groundctl.plan.provenance` ties a plan to
its show.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from groundctl.plan.planfile import PLAN_FORMAT, read_plan_file
from groundctl.plan.trajectory import Trajectories
from groundctl.show.model import GeoOrigin, Limits, MpcSettings

FloatArray = NDArray[np.float64]

__all__ = ["PLAN_FORMAT", "Cue", "FormationWindow", "Plan", "SparePlan", "State"]


@dataclass(frozen=True)
class Cue:
    """A named moment of the show (a Skybrush show's cues: the chorus, a firework)."""

    time: float
    """Plan time, s (negative: before the plan starts, during the takeoff)."""
    name: str
    """Its name."""


@dataclass(frozen=True)
class FormationWindow:
    """When the fleet flies into one formation and holds it."""

    index: int
    """1-based formation index in the show file."""
    name: str
    """Formation name."""
    start: float
    """Show time the transition into it begins, s."""
    arrive: float
    """Show time the formation is reached, s."""
    end: float
    """Show time the hold ends (the next transition begins), s."""
    goals: FloatArray
    """(n, 3) slot each drone was assigned in this formation."""


@dataclass(frozen=True)
class SparePlan:
    """Where the show's spare drones wait (:mod:`groundctl.plan.spares`), verified clear
    of every show drone."""

    standby: str
    """"ground" (waiting on their pads) or "air" (hovering above them)."""
    pads: FloatArray
    """(k, 3) each spare's pad on the ground, show frame, m: it takes off and lands there."""
    points: FloatArray
    """(k, 3) where each waits: the pad itself on the ground, or the point above it."""
    clearance_m: float
    """The closest any spare waiting, or climbing to or from its point, comes to a show
    drone or another spare, m (verified in continuous time)."""
    given: bool = False
    """The show file gave the pads or points (False: laid out by the planner)."""

    @property
    def count(self) -> int:
        return len(self.pads)


@dataclass(frozen=True)
class State:
    """The fleet at one instant."""

    pos: FloatArray
    """(n, 3) positions, show frame, m."""
    vel: FloatArray
    """(n, 3) velocities, m/s."""
    acc: FloatArray
    """(n, 3) accelerations, m/s^2."""
    rgb: FloatArray
    """(n, 3) LED colours in [0, 1]."""


@dataclass(frozen=True)
class Plan:
    """A whole planned show, from the end of takeoff to the start of landing."""

    show_name: str
    """Name of the show it was planned from."""
    origin: GeoOrigin
    """Geodetic anchor and heading of the show frame."""
    limits: Limits
    """The envelope it was planned and verified against."""
    model: str
    """Dynamics model it was planned with ("quadrotor" or "unicycle")."""
    home: FloatArray
    """(n, 3) takeoff and landing spots on the ground."""
    takeoff_altitude: float
    """Height above home at which the plan starts and ends, m."""
    trajectories: Trajectories
    """Every drone's trajectory, show time 0 to ``duration``."""
    color_times: FloatArray
    """(F,) colour keyframe times, s."""
    colors: FloatArray
    """(n, F, 3) colours at the keyframes; linear in between."""
    formations: tuple[FormationWindow, ...]
    """The formation timeline."""
    mpc: MpcSettings = field(default_factory=MpcSettings)
    """The show's MPC replanning settings (flown with the plan)."""
    show_digest: str = ""
    """:attr:`Show.digest <groundctl.show.model.Show.digest>` of the show file it was
    planned from ("" for a plan built in code or saved before plans recorded it)."""
    names: tuple[str, ...] = ()
    """Each track's drone name in the show it was imported from (a Skybrush show's
    ``drone_7``), in track order; empty: the tracks are only numbered."""
    cues: tuple[Cue, ...] = ()
    """The show's cues in time order (a Skybrush show's), plan time."""
    spares: SparePlan | None = None
    """Where the show's spare drones wait; None: the show has none."""

    def name_of(self, track: int) -> str | None:
        """Track ``track``'s drone name, or None if the plan names none."""
        return self.names[track] if 0 <= track < len(self.names) else None

    def cue_at(self, t: float) -> tuple[Cue | None, Cue | None]:
        """The last cue at or before plan time ``t`` and the next one after it."""
        last = nxt = None
        for c in self.cues:
            if c.time <= t:
                last = c
            else:
                nxt = c
                break
        return last, nxt

    @property
    def drones(self) -> int:
        return self.trajectories.drones

    @property
    def duration(self) -> float:
        return self.trajectories.end

    @property
    def landing(self) -> FloatArray:
        """(n, 3) ground spots each track lands on: below its final plan point.

        Not its own takeoff spot: the landing formation is assigned like any
        other, so a drone may land on a neighbour's takeoff spot.
        """
        end = self.trajectories.evaluate(self.duration)[0]
        return np.column_stack([end[:, :2], self.home[:, 2]])

    @property
    def landing_hover(self) -> FloatArray:
        """(n, 3) the points above :attr:`landing` at takeoff altitude (where the plan ends)."""
        return self.landing + np.array([0.0, 0.0, self.takeoff_altitude])

    def colors_at(self, t: float) -> FloatArray:
        """(n, 3) colours at show time ``t`` (held before the first and after the last key)."""
        times = self.color_times
        if t <= times[0]:
            return self.colors[:, 0].copy()
        if t >= times[-1]:
            return self.colors[:, -1].copy()
        k = int(np.searchsorted(times, t, side="right") - 1)
        w = (t - times[k]) / (times[k + 1] - times[k])
        return (1 - w) * self.colors[:, k] + w * self.colors[:, k + 1]

    def state_at(self, t: float) -> State:
        """Position, velocity, acceleration and colour of every drone at show time ``t``."""
        pos, vel, acc = self.trajectories.evaluate(float(t))
        return State(pos=pos, vel=vel, acc=acc, rgb=self.colors_at(float(t)))

    # -- file --------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the plan to ``path`` (``.npz`` is appended by NumPy if missing)."""
        path = Path(path)
        meta = {
            "format": PLAN_FORMAT,
            "show_name": self.show_name,
            "origin": asdict(self.origin),
            "limits": asdict(self.limits),
            "mpc": asdict(self.mpc),
            "model": self.model,
            "takeoff_altitude": self.takeoff_altitude,
            "formations": [{"index": f.index, "name": f.name, "start": f.start,
                            "arrive": f.arrive, "end": f.end} for f in self.formations],
        }
        if self.show_digest:
            meta["show_digest"] = self.show_digest
        if self.names:
            meta["names"] = list(self.names)
        if self.cues:
            meta["cues"] = [{"time": c.time, "name": c.name} for c in self.cues]
        if self.spares is not None:
            meta["spares"] = {"standby": self.spares.standby, "given": self.spares.given,
                              "clearance_m": self.spares.clearance_m}
        arrays: dict[str, Any] = {
            "meta": np.array(json.dumps(meta)),
            "times": self.trajectories.times,
            "pos": self.trajectories.pos,
            "vel": self.trajectories.vel,
            "home": self.home,
            "color_times": self.color_times,
            "colors": self.colors,
        }
        for i, f in enumerate(self.formations):
            arrays[f"goals_{i}"] = f.goals
        if self.spares is not None:
            arrays["spare_pads"] = self.spares.pads
            arrays["spare_points"] = self.spares.points
        with path.open("wb") as fh:
            np.savez_compressed(fh, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Plan:
        """Read a plan written by :meth:`save`; PlanFileError if it is not one.

        Every header is checked before any array is read, and every array and
        value before the plan is built (:func:`~groundctl.plan.planfile.read_plan_file`).
        """
        c = read_plan_file(path)
        formations = tuple(
            FormationWindow(index=w.index, name=w.name, start=w.start, arrive=w.arrive,
                            end=w.end, goals=g)
            for w, g in zip(c.windows, c.goals, strict=True))
        return cls(show_name=c.show_name, origin=c.origin, limits=c.limits, model=c.model,
                   home=c.home, takeoff_altitude=c.takeoff_altitude,
                   trajectories=Trajectories(c.times, c.pos, c.vel), color_times=c.color_times,
                   colors=c.colors, formations=formations, mpc=c.mpc,
                   show_digest=c.show_digest, names=c.names,
                   cues=tuple(Cue(t, n) for t, n in c.cues),
                   spares=None if c.spares is None else SparePlan(*c.spares))
