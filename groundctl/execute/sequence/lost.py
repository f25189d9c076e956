"""A vehicle lost, heard again, off its plan or given up: stranded off its plan it
holds and leaves on a way out (too many at once land the fleet), and a drone given up
on its slot may abort the show."""

from __future__ import annotations

from functools import cache

import numpy as np

from groundctl.execute.preflight import remaining_plan_conflicts
from groundctl.execute.sequence.commands import OperatorCommands
from groundctl.execute.sequence.lifecycle import Event
from groundctl.execute.sequence.policies.rejoin import Landing, Rejoin, heard_landing, rejoin
from groundctl.execute.sequence.policies.stranded import (
    ArmedAgain,
    GivenUp,
    armed_again,
    given_up,
    too_many_stranded,
)
from groundctl.execute.sequence.types import (
    _DONE,
    _FLIGHT_MODE,
    _STREAMED,
    OFF_PLAN_WINDOW_S,
    Action,
    Land,
    Notice,
    VehiclePhase,
    VehicleRun,
)
from groundctl.link.state import VehicleState


class OffPlan(OperatorCommands):
    """Lost, off-plan, stranded and given-up vehicles (a layer of :class:`ShowSequence`)."""

    def _lose(self, v: VehicleRun, now: float, state: VehicleState | None) -> list[Action]:
        silent = "never heard" if state is None else f"silent for {state.silent_for(now):.1f} s"
        was = v.phase
        self._to(v, Event.LOST)
        v.pending, v.reason = None, f"link lost ({silent})"
        v.lost_from, v.retaking = was, None
        still = ("still streamed its plan in case it hears us, otherwise its failsafe is in "
                 "charge" if was in _STREAMED else "its failsafe is in charge")
        actions: list[Action] = [
            Notice(v.sysid, f"vehicle {v.sysid} lost during {was} ({silent}); {still}; "
                            "the show goes on", "lost", f"lost during {was}; {still}")]
        if was is VehiclePhase.ARMING:
            actions += self._left_on_slot(v, now)
        return actions

    def _rejoin(self, v: VehicleRun, now: float, state: VehicleState) -> list[Action]:
        assert v.lost_from is not None
        v.gap_seen, v.gap_at = state.stream_gaps, now  # this silence is handled here
        off = self._off_plan(v, now) if v.lost_from is VehiclePhase.SHOW else None
        how = rejoin(v.lost_from, off is not None)
        if how is Rejoin.STAND_DOWN:
            self._to(v, Event.HEARD_AGAIN, v.lost_from)
            v.lost_from = None
            return [Notice(v.sysid, f"vehicle {v.sysid} heard again before the show: "
                                    "standing it down", "heard_again", "heard again: "
                                    "standing down"), *self._land(v, now)]
        if how is Rejoin.STRANDED:
            assert off is not None
            v.lost_from = None
            return self._strand(v, off, now, "heard again")
        self._to(v, Event.HEARD_AGAIN, v.lost_from)
        v.lost_from, v.reason = None, None
        if v.phase is VehiclePhase.READY and self.started_at is not None and v.pad is None:
            # Ready but silent when the show started (or ended): it catches up.
            self._to(v, Event.SHOW_STARTS if not self._ended else Event.SHOW_ENDS)
        if v.phase is VehiclePhase.LANDING:
            return self._rejoin_landing(v, state, now)
        return [Notice(v.sysid, f"vehicle {v.sysid} heard again: back in the sequence "
                                f"({v.phase})", "heard_again", f"heard again ({v.phase})")]

    def _rejoin_landing(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        """Heard again after being lost while landing: what it does now
        (:func:`.policies.rejoin.heard_landing`) decides what is still needed."""
        doing = heard_landing(v.flavour, state)
        if doing is Landing.DOWN:
            text = "down and disarmed"
        elif doing is Landing.DESCENDING:
            text = "landing"
        elif doing is Landing.LAND_LOST:
            return [Notice(v.sysid, f"vehicle {v.sysid} heard again still in {state.mode}: "
                                    "its LAND was lost, sending it again", "heard_again",
                           f"heard again in {state.mode}: LAND re-sent"),
                    self._send(v, Land(v.sysid), now)]
        else:
            text = f"in {state.mode} (its failsafe or a pilot)"
        return [Notice(v.sysid, f"vehicle {v.sysid} heard again: {text}", "heard_again",
                       f"heard again: {text}")]

    def _off_plan(self, v: VehicleRun, now: float
                  ) -> tuple[float, tuple[float, float, float]] | None:
        """(distance, position) if a vehicle is mid-show farther than
        ``rejoin_tolerance_m`` from its plan over the last ``OFF_PLAN_WINDOW_S`` (so a
        late telemetry sample or a lagging autopilot does not count); None otherwise."""
        pos = self._mid_show_at(v)
        if pos is None:
            return None
        t = self.show_time(now)
        recent = np.linspace(max(t - OFF_PLAN_WINDOW_S, 0.0), t, 6)
        path = self.plan.trajectories.evaluate(recent, np.array([v.track]))[0][0]
        distance = float(np.linalg.norm(path - pos, axis=1).min())
        if distance <= self.config.rejoin_tolerance_m:
            return None
        return distance, (float(pos[0]), float(pos[1]), float(pos[2]))

    def _mid_show_at(self, v: VehicleRun) -> np.ndarray | None:
        """Where a vehicle is, while the show runs (None before or after it, or unheard)."""
        if self.started_at is None or self._ended:
            return None
        return self._positions.get(v.sysid)

    def _strand(self, v: VehicleRun, off: tuple[float, tuple[float, float, float]],
                now: float, how: str) -> list[Action]:
        """Off its plan mid-show (its autopilot held the last setpoint through a link drop,
        say): snapping back would be a dash across the formation.  Hold where it is,
        then leave the show on a way out planned from there."""
        distance, here = off
        self._to(v, Event.STRANDED)
        v.reason = f"{how} {distance:.1f} m off its plan"
        v.hold_point, v.leave = self._held_apart({v.sysid: here}, now)[v.sysid], None
        v.leave_at = self._hold_leave_time(v, now)
        if v.leave_at is None:
            return [Notice(v.sysid, f"vehicle {v.sysid} {how} {distance:.1f} m off its plan: "
                                    "holding where it is until the show ends, then to its "
                                    "landing spot", "stranded", "off its plan: holding "
                                    "where it is until the show ends")]
        return [Notice(v.sysid, f"vehicle {v.sysid} {how} {distance:.1f} m off its plan: "
                                "holding where it is, then leaving the show on a way out "
                                "planned from there", "stranded", "off its plan: holding, "
                                "then leaving on a way out")]

    def _armed_again(self, v: VehicleRun, state: VehicleState, now: float) -> list[Action]:
        """Given up as disarmed in the air, but its own telemetry says it is armed, in the
        air, in the flight mode: the disarm it was given up for was not real (believed
        from reports the link could not check).  Left alone it would hover where it was
        with nobody in charge while the show flies past: it holds there and leaves on a
        way out, as a vehicle heard again off its plan does; after the show, it lands."""
        off = cache(lambda: self._off_plan(v, now))
        verdict = armed_again(armed=state.armed, lost=state.lost,
                              altitude_m=self._altitude(state),
                              in_flight_mode=state.mode == _FLIGHT_MODE[v.flavour],
                              in_show=self._mid_show_at(v) is not None,
                              off_plan=lambda: off() is not None)
        if verdict is ArmedAgain.NOT_FLYING:
            return []
        v.fell, v.reason = False, None
        if verdict is ArmedAgain.LAND_HERE:
            self._to(v, Event.LAND)
            return [Notice(v.sysid, f"vehicle {v.sysid} is armed in the air after all: "
                                    "landing it where it is"), self._send(v, Land(v.sysid), now)]
        if verdict in (ArmedAgain.BACK, ArmedAgain.STRANDED) and v.track < 0:
            # A spare given up while it stood by: there is no plan to go back to.
            self._to(v, Event.LAND)
            return [Notice(v.sysid, f"spare {v.sysid} is armed in the air after all: landing "
                                    "it where it is, over its pad"),
                    self._send(v, Land(v.sysid), now)]
        if verdict is ArmedAgain.BACK and v.replaced_by is not None:
            # A spare has its track now: it holds where it is and leaves on a way out.
            pos = self._positions.get(v.sysid)
            if pos is None:
                self._to(v, Event.LAND)
                return [Notice(v.sysid, f"vehicle {v.sysid} is armed in the air after all: "
                                        "landing it where it is"),
                        self._send(v, Land(v.sysid), now)]
            here = (float(pos[0]), float(pos[1]), float(pos[2]))
            planned = self.plan.trajectories.evaluate(self.show_time(now),
                                                      np.array([v.track]))[0][0]
            away = float(np.linalg.norm(np.asarray(here) - planned))
            return self._strand(v, (away, here), now, f"armed in the air after all (spare "
                                                     f"{v.replaced_by} has its track),")
        if verdict is ArmedAgain.BACK:
            self._to(v, Event.ALIVE)
            return [Notice(v.sysid, f"vehicle {v.sysid} is armed in the air after all, on its "
                                    "plan: back in the show")]
        stranded = off()
        assert stranded is not None
        return self._strand(v, stranded, now, "armed in the air after all,")

    def _land_all_if_stranded(self, now: float) -> list[Action]:
        """Land the whole fleet when STRANDED_LAND_ALL or more hold off their plans."""
        if self._ended:
            return []
        stranded = sorted(v.sysid for v in self.vehicles.values()
                          if v.hold_point is not None
                          and self.streamed_as(v) is VehiclePhase.LEAVING)
        if not too_many_stranded(len(stranded)):
            return []
        names = ", ".join(str(s) for s in stranded)
        return [Notice(None, f"vehicles {names} are off their plans at once: landing the whole "
                             "fleet on one collision-free return planned from where each "
                             "hovers", "stranded_land_all"), *self.land_all(now)]

    def take_out(self, sysid: int, now: float, distance: float,
                 why: str = "taken out of the show") -> list[Action]:
        """Take a vehicle off its path out of the show from where it is (the guard's
        response): it holds there and leaves on a way out planned from there, or lands
        there if there is none."""
        v = self.vehicles.get(sysid)
        pos = self._positions.get(sysid)
        if v is None or v.phase is not VehiclePhase.SHOW or pos is None or self._ended:
            return []
        here = (float(pos[0]), float(pos[1]), float(pos[2]))
        return self._strand(v, (distance, here), now, why)

    def _give_up(self, v: VehicleRun, why: str, now: float) -> list[Action]:
        where = given_up(v.phase)
        v.reason, v.pending = why, None
        self._to(v, Event.GIVE_UP)
        if where is GivenUp.BY_HAND:
            return [Notice(v.sysid, f"vehicle {v.sysid}: {why}; land it by hand")]
        actions: list[Action] = [Notice(v.sysid, f"vehicle {v.sysid}: {why}")]
        if where is GivenUp.ON_THE_GROUND:
            v.never_flew = True
            return actions + self._left_on_slot(v, now)
        self._to(v, Event.LAND)
        actions.append(self._send(v, Land(v.sysid), now))
        if where is GivenUp.LAND_ON_SLOT:
            actions += self._left_on_slot(v, now)
        return actions

    def _left_on_slot(self, v: VehicleRun, now: float) -> list[Action]:
        # A drone that never took off stands on its slot: an obstacle for its
        # neighbours' takeoff and landing.  If it is in their way, stop the show.
        if v.pad is not None:
            return []  # a spare on its pad, verified clear of the show (down_positions)
        self.grounded_tracks.add(v.track)
        flying = {u.track for u in self.vehicles.values() if u.phase not in _DONE}
        conflicts = [c for c in remaining_plan_conflicts(self.plan, self.grounded_tracks)
                     if c.track in flying]
        if not conflicts or self._ended:
            return []
        self.aborted = f"vehicle {v.sysid} stays on its slot and {conflicts[0]}"
        return [Notice(None, f"aborting the show: {conflicts[0]}"), *self.land_all(now)]
