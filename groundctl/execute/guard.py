"""The flight guard: when the show must hold, resume or end, decided each tick.  Pure.

Two kinds of trouble, told apart by their evidence:

* **the ground station is the problem** -- its loop started a tick long after
  the tick's instant (a *stall*: the drones stood on the last setpoints they
  got), ticks keep overrunning (*overload*), or the whole fleet went quiet at
  once (*silence*: our receive path or the whole link, never any one vehicle).
  The show clock stops (after a stall, back at the last setpoints' show time;
  otherwise braking along the paths), one line says why, and the show resumes
  once the loop has kept time for ``recover_s`` and the fleet has settled on
  its hold points.  If it keeps happening (``max_held_s`` held in all, or
  ``max_freezes`` times) the fleet is landed along a planned return.
* **the flight is going wrong** -- a pair of drones closing below the limit
  plus a margin, or a drone off its commanded point by more than
  ``off_path_m`` for ``off_path_for_s``.  The fleet holds (a *safety* hold);
  once stopped for ``safety_settle_s``, a drone still off its point is taken
  out of the show (a way out planned from where it is, or landed there).  The
  show resumes when nothing is wrong for ``safety_settle_s``; after
  ``max_safety_holds`` such holds the fleet is landed.
* **the weather is beyond the show** -- the vehicles' own wind estimates above the
  show's ``limits.max_wind``: the show holds (or does not start), and lands if the wind
  stays (:mod:`groundctl.execute.wind`).

The driver measures, calls :meth:`FlightGuard.tick` and carries out the
returned actions on the sequence; nothing here reads a clock.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from groundctl.execute.sequence import FLEET_HOLDS
from groundctl.execute.wind import WindConfig, WindVerdict, WindWatch


@dataclass(frozen=True)
class GuardConfig:
    """Thresholds of the guard; times are seconds of the flight's clock."""

    stall_s: float = 0.3
    """A tick starting this late is a stall of the ground station."""
    overload_ticks: int = 5
    """This many overrun ticks (late by a whole period) ..."""
    overload_window_s: float = 2.0
    """... within this long is an overload."""
    recover_s: float = 2.0
    """The loop must keep time this long before the show resumes."""
    resume_tolerance_m: float = 0.5
    """... and every drone be this close to its hold point ..."""
    settle_timeout_s: float = 10.0
    """... or this long must have passed since it kept time again."""
    max_held_s: float = 30.0
    """Held for the ground station's own trouble this long in all: land the fleet."""
    max_freezes: int = 5
    """Or this many times."""
    separation_margin_m: float = 0.1
    """A pair closing within the limit plus this triggers a safety hold, m."""
    off_path_m: float = 2.0
    """A drone this far from where it is told to be ..."""
    off_path_for_s: float = 1.0
    """... for this long triggers a safety hold."""
    safety_settle_s: float = 3.0
    """Stopped this long before drones still off their point are taken out, and clear
    this long before the show resumes."""
    max_safety_holds: int = 3
    """Safety holds before the fleet is landed."""
    max_safety_hold_s: float = 30.0
    """A safety hold that has not cleared after this long lands the fleet."""
    closing_below_plan_m: float = 0.05
    """A pair within the margin counts only if it is also this much closer than the plan
    has it (plans keep pairs just above the limit by design)."""
    wind: WindConfig = field(default_factory=WindConfig)
    """The wind hold's timing."""


@dataclass(frozen=True)
class Hold:
    """Hold the show for ``reason`` (braking), or stop it at ``show_time`` at once."""

    reason: str
    text: str
    show_time: float | None = None


@dataclass(frozen=True)
class Release:
    """Drop the hold ``reason``."""

    reason: str
    text: str


@dataclass(frozen=True)
class TakeOut:
    """Take vehicle ``sysid`` out of the show from where it is."""

    sysid: int
    distance_m: float
    text: str


@dataclass(frozen=True)
class LandAll:
    """Land the whole fleet along a planned return."""

    text: str


GuardAction = Hold | Release | TakeOut | LandAll


@dataclass(frozen=True)
class TickFacts:
    """What the driver measured this tick."""

    now: float
    """Our time at the start of the tick."""
    lag_s: float
    """How late the tick started against its scheduled instant."""
    period_s: float
    """The loop's period."""
    last_sent_show_time: float | None
    """Show time of the last setpoints sent (None before the show)."""
    fleet_silent: bool
    """No vehicle heard for the link's fleet-silence time."""
    errors_m: Mapping[int, float] = field(default_factory=dict)
    """Distance of each vehicle flying the show from where it is told to be, m."""
    closest_m: float = math.inf
    """The closest pair's distance from telemetry, m."""
    closest_pair: tuple[int, int] | None = None
    """Its system ids."""
    closing_mps: float = 0.0
    """Its range rate (negative: closing), m/s."""
    closest_planned_m: float = math.inf
    """The distance the plan has between that pair now, m."""
    unheard: int = 0
    """Vehicles flying our setpoints without fresh telemetry."""
    limit_m: float = 0.0
    """The separation limit, m."""
    in_show: bool = False
    """The show clock is running or held mid-show (not before the start or after the end)."""
    flying: bool = False
    """Drones are flying our setpoints on a clock (the show, or a return after it)."""
    stopped: bool = False
    """The show clock is at rest (held and done braking)."""
    show_airborne: bool = False
    """Drones are in the air for the show (ready for its start, or flying it)."""
    wind_mps: tuple[float, ...] = ()
    """The fresh wind estimates of the vehicles in the air, m/s horizontal."""


class FlightGuard:
    """See the module docstring."""

    def __init__(self, config: GuardConfig | None = None,
                 max_wind: float | None = None) -> None:
        self.config = config or GuardConfig()
        self.wind = WindWatch(max_wind, self.config.wind)
        """The show's wind limit in the air."""
        self.active: dict[str, float] = {}
        """Holds in force, by reason, with our time they started."""
        self.freezes = 0
        """Holds for the ground station's own trouble (stall, overload, silence)."""
        self.safety_holds = 0
        """Safety holds."""
        self.held_s = 0.0
        """Time held for the ground station's own trouble, s."""
        self.landed_all = False
        self._overruns: deque[float] = deque()
        self._quiet_since: float | None = None
        self._off_since: dict[int, float] = {}
        self._taken_out: set[int] = set()
        self._stopped_since: float | None = None
        self._clear_since: float | None = None
        self._last_now: float | None = None
        self._heard_again_at: float | None = None

    def tick(self, f: TickFacts) -> list[GuardAction]:
        cfg = self.config
        out: list[GuardAction] = []
        if self._last_now is not None and any(r in self.active for r in _OWN):
            self.held_s += f.now - self._last_now
        self._last_now = f.now
        # -- the ground station's own trouble ------------------------------------------
        overrun = f.lag_s > f.period_s
        if overrun:
            self._overruns.append(f.now)
        while self._overruns and f.now - self._overruns[0] > cfg.overload_window_s:
            self._overruns.popleft()
        if f.lag_s > cfg.stall_s or overrun:
            self._quiet_since = None
        elif self._quiet_since is None:
            self._quiet_since = f.now
        busy = f.in_show or f.flying
        if busy and f.lag_s > cfg.stall_s:
            out += self._hold("stall", f, f"the ground station stalled for {f.lag_s:.1f} s: "
                                          "the show holds where its last setpoints were until "
                                          "it keeps time again",
                              f.last_sent_show_time)
        elif busy and len(self._overruns) >= cfg.overload_ticks:
            out += self._hold("overload", f, f"the ground station is overloaded "
                                             f"({len(self._overruns)} late ticks in "
                                             f"{cfg.overload_window_s:.0f} s): holding the "
                                             "show until it keeps time again")
        if busy and f.fleet_silent:
            out += self._hold("silence", f, "no vehicle heard for a while (the whole link, "
                                            "or our receive path): holding the show; every "
                                            "drone brakes along its path and hovers")
        settled = all(e <= cfg.resume_tolerance_m for e in f.errors_m.values())
        quiet_for = -math.inf if self._quiet_since is None else f.now - self._quiet_since
        for reason in ("stall", "overload"):
            if reason in self.active and quiet_for >= cfg.recover_s \
                    and (settled or quiet_for >= cfg.settle_timeout_s):
                out.append(self._release(reason, "the ground station keeps time again: "
                                                 "resuming the show"))
        if f.fleet_silent:
            self._heard_again_at = None
        elif self._heard_again_at is None:
            self._heard_again_at = f.now
        if "silence" in self.active and not f.fleet_silent:
            # Every drone flying our setpoints must be heard again (and settled), or the
            # settle time must have passed since the fleet was heard again.
            since = f.now - (self._heard_again_at if self._heard_again_at is not None
                             else f.now)
            if (settled and f.unheard == 0) or since >= cfg.settle_timeout_s:
                out.append(self._release("silence", "the fleet is heard again: resuming "
                                                    "the show"))
        if not self.landed_all and (self.held_s > cfg.max_held_s
                                    or self.freezes > cfg.max_freezes):
            self._land_all()
            out.append(LandAll(f"the ground station cannot keep the show's time (held "
                               f"{self.held_s:.0f} s, {self.freezes} times): landing every "
                               "vehicle"))
        # -- the flight going wrong ------------------------------------------------------
        if f.in_show and not self.landed_all:
            out += self._safety(f)
        # -- the weather beyond the show -------------------------------------------------
        if not self.landed_all:
            out += self._wind(f)
        return out

    def _wind(self, f: TickFacts) -> list[GuardAction]:
        watch = self.wind
        verdict = watch.tick(f.now, f.wind_mps, f.show_airborne,
                             started=f.in_show)
        wind = watch.wind if watch.wind is not None else 0.0
        limit = watch.limit if watch.limit is not None else math.inf
        if verdict is WindVerdict.HOLD:
            what = ("holding the show; every drone brakes along its path" if f.in_show
                    else "the show does not start; the fleet hovers")
            return self._hold("wind", f, f"the vehicles estimate {wind:.1f} m/s of wind, "
                                         f"above the show's limit of {limit:g} m/s: {what}")
        if verdict is WindVerdict.RELEASE:
            if watch.released_why == "grounded":
                return [self._release("wind", "wind hold dropped: no drone is in the air "
                                              "for the show")]
            what = "resuming the show" if f.in_show else "the show may start"
            return [self._release("wind", f"the wind is down to {wind:.1f} m/s: {what}")]
        if verdict is WindVerdict.LAND:
            self._land_all()
            cfg = self.config.wind
            return [LandAll(f"the wind has not cleared (at most "
                            f"{cfg.clear_fraction * limit:g} m/s for {cfg.clear_for_s:.0f} s) "
                            f"in {watch.held_s:.0f} s of holding for it (limit {limit:g} m/s; "
                            f"up to {watch.hold_peak:.1f} m/s, now {wind:.1f}): landing every "
                            "vehicle")]
        return []

    def _safety(self, f: TickFacts) -> list[GuardAction]:
        cfg = self.config
        out: list[GuardAction] = []
        for sysid in list(self._off_since):
            if sysid not in f.errors_m:
                del self._off_since[sysid]
        off = []
        for sysid, e in f.errors_m.items():
            if sysid in self._taken_out or e <= cfg.off_path_m:
                self._off_since.pop(sysid, None)
                continue
            since = self._off_since.setdefault(sysid, f.now)
            if f.now - since >= cfg.off_path_for_s:
                off.append((sysid, e))
        close = f.closest_m < f.limit_m or (
            f.closest_m < f.limit_m + cfg.separation_margin_m and f.closing_mps < 0
            and f.closest_m < f.closest_planned_m - cfg.closing_below_plan_m)
        trouble = bool(off) or close
        if trouble:
            self._clear_since = None
            if "safety" not in self.active:
                self.safety_holds += 1
                if self.safety_holds > cfg.max_safety_holds:
                    self._land_all()
                    return [LandAll(f"the flight keeps going wrong ({self.safety_holds - 1} "
                                    "safety holds): landing every vehicle")]
                if close:
                    why = (f"vehicles {f.closest_pair} are {f.closest_m:.2f} m apart "
                           f"(limit {f.limit_m:.2f} m)")
                else:
                    worst = max(off, key=lambda x: x[1])
                    why = f"vehicle {worst[0]} is {worst[1]:.1f} m off its path"
                    if len(off) > 1:
                        why += f" ({len(off)} vehicles off their paths)"
                out += self._hold("safety", f, f"safety hold: {why}; every drone brakes "
                                               "along its path")
        elif self._clear_since is None:
            self._clear_since = f.now
        if "safety" not in self.active:
            self._stopped_since = None
            return out
        if f.now - self.active["safety"] > cfg.max_safety_hold_s:
            self._land_all()
            return [*out, LandAll(f"the safety hold has not cleared in "
                                  f"{cfg.max_safety_hold_s:.0f} s: landing every vehicle")]
        if f.stopped:
            if self._stopped_since is None:
                self._stopped_since = f.now
        else:
            self._stopped_since = None
        stopped_for = -math.inf if self._stopped_since is None else f.now - self._stopped_since
        if stopped_for >= cfg.safety_settle_s:
            for sysid, e in f.errors_m.items():
                if e > cfg.off_path_m and sysid not in self._taken_out:
                    self._taken_out.add(sysid)
                    out.append(TakeOut(sysid, e, f"vehicle {sysid} is still {e:.1f} m off its "
                                                 "path with the show stopped: taking it out "
                                                 "of the show from where it is"))
        if self._clear_since is not None and f.now - self._clear_since >= cfg.safety_settle_s \
                and stopped_for >= cfg.safety_settle_s:
            out.append(self._release("safety", "the fleet is back on its paths: resuming the "
                                               "show"))
        return out

    def _land_all(self) -> None:
        # The show is over: the land-all return takes no safety hold with it.
        self.landed_all = True
        self.active.pop("safety", None)
        self.active.pop("wind", None)
        self.wind.stopped = True

    def _hold(self, reason: str, f: TickFacts, text: str,
              show_time: float | None = None) -> list[GuardAction]:
        if reason in self.active:
            return []
        self.active[reason] = f.now
        if reason in _OWN:
            self.freezes += 1
        return [Hold(reason, text, show_time)]

    def _release(self, reason: str, text: str) -> Release:
        self.active.pop(reason, None)
        if reason == "safety":
            self._clear_since = self._stopped_since = None
        return Release(reason, text)


#: Reasons that are the ground station's own trouble.
_OWN = FLEET_HOLDS
#: The guard's holds of the show itself, dropped when it lands the fleet.
GUARD_SHOW_HOLDS = ("safety", "wind")
