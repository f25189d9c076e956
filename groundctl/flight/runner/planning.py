"""Planning in worker processes: the workers started early, the returns and
ways out the sequence asks for planned as tasks and handed back to it."""

from __future__ import annotations

import asyncio

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import FlightError, GroundctlError, PlanningTimeout
from groundctl.execute.frames import show_positions
from groundctl.execute.paths import PathKind
from groundctl.execute.sequence import ShowSequence, VehiclePhase
from groundctl.flight.replanning import Replanner
from groundctl.flight.returning import assign_landing, column
from groundctl.flight.runner.commands import Commands
from groundctl.flight.workers import PlannerPool


class Planning(Commands):
    """Planning in workers (a layer of :class:`ShowRunner`)."""

    # -- planning in worker processes ---------------------------------------------------
    def _start_workers(self) -> None:
        """Start the planning (and MPC) workers loading numpy, scipy, OSQP and the plan
        in their own processes, while the link comes up and pre-flight runs."""
        if self.plan.model != "quadrotor" or self._finished:
            return
        if self._pool is None:
            self._pool = PlannerPool(self.plan)
            self._pool.start()
        cfg = self.config
        mpc_on = self.plan.mpc.enabled if cfg.mpc is None else cfg.mpc
        if mpc_on and self.replanner is None:
            self.replanner = Replanner(self.plan, self.plan.mpc, cfg.rate_hz,
                                       cfg.mpc_deadline_s, self.clock)
            self.replanner.start()

    async def _planner_ready(self) -> None:
        """Wait, before arming, until the planning worker can answer at once: a way out
        (land-one) or a way home asked for early in the show has only seconds to be
        planned, and a worker still importing numpy (nice, on a busy machine) spent them
        all (a land-one 7 s ahead missed its formation and landed after the show)."""
        if self._pool is None:
            return
        started = self.clock.now()
        try:
            await self._pool.warm_up()
        except PlanningTimeout as exc:
            raise FlightError(f"the planning worker did not start: {exc}; nothing "
                              "armed") from None
        waited = self.clock.now() - started
        if waited >= 1.0:
            self._say(f"waited {waited:.1f} s for the planning worker to load before arming",
                      "planner_wait", wait_s=round(waited, 2))

    def _start_planning(self, seq: ShowSequence) -> None:
        if seq.return_needed is not None and self._return_task is None:
            self._return_task = asyncio.create_task(self._plan_return(seq))
            self._own(self._return_task)
        # One way out at a time: each is planned around the ways out already set, so
        # several planned at once would each take the others for drones that stay
        # where they are (a link cut stranded all nine of a PX4 fleet at once under
        # load, and their nine ways out, planned side by side, crossed at 0.58 m).
        needed = seq.leave_needed
        if needed and not self._leave_tasks and not self._join_tasks:
            sysid, track, at, start = needed[0]
            self._leave_tasks[sysid] = task = asyncio.create_task(
                self._plan_leave(seq, sysid, track, at, start))
            self._own(task)
        # A spare's way into a vacated track: one at a time too, and not beside a way out
        # (each is planned around the other once it is set).
        joining = seq.join_needed
        if joining and not self._join_tasks and not self._leave_tasks:
            track, spare, pad = joining[0]
            self._join_tasks[track] = task = asyncio.create_task(
                self._plan_join(seq, track, spare, pad))
            self._own(task)

    def _own(self, task: asyncio.Task[None]) -> None:
        # Cancelled with the rest on the way out (see _drain).
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _planner(self) -> PlannerPool:
        if self._finished:
            raise FlightError("the flight is over: nothing more is planned")
        if self._pool is None:
            self._pool = PlannerPool(self.plan)
            self._pool.start()
        return self._pool

    async def _plan_return(self, seq: ShowSequence) -> None:
        cfg = self.config
        try:
            for attempt in range(1, cfg.planning_attempts + 1):
                needed = seq.return_needed
                if not needed:
                    return
                sysids = [s for s, _ in needed]
                tracks = [t for _, t in needed]
                now = self.clock.now()
                start = np.array([seq.return_start(s, now) for s in sysids])
                down = np.array(seq.down_positions()).reshape(-1, 3)
                # Drones descending on their own spots are no spot thieves, but their
                # columns are in the way of a path that crosses them.
                descending = [p for p in seq.landing_positions() if len(down) == 0
                              or np.min(np.linalg.norm(down - p, axis=1)) > 0.01]
                reserved = np.array(seq.reserved_spots(sysids)).reshape(-1, 3)
                try:
                    goals = assign_landing(self.plan, tracks, start, down, reserved)
                    obstacles = list(down) + descending
                    static = np.concatenate([column(p) for p in obstacles]) if obstacles \
                        else None
                    authority, weakest = (1.0, None) if self.replanner is None \
                        else self.replanner.weakest(sysids)
                    self._say(f"planning a collision-free return for {len(sysids)} "
                              "vehicle(s); they brake along their paths and hover meanwhile"
                              + (f" ({len(down)} drone(s) down kept clear)" if len(down)
                                 else "")
                              + (f" (within {authority:.0%} of the limits: vehicle "
                                 f"{weakest} is weak)" if weakest is not None else ""),
                              "return_planning", attempt=attempt,
                              authority=round(authority, 2))
                    traj = await self._planner().plan_return(
                        tracks, start, cfg.return_deadline_s, static, goals=goals,
                        authority=authority)
                except PlanningTimeout as exc:
                    self._say(f"return planning attempt {attempt}: {exc}", "return_late")
                    continue
                except GroundctlError as exc:
                    self._perform(seq.return_failed(str(exc), self.clock.now()))
                    return
                self._perform(seq.set_return(traj, sysids, self.clock.now(), goals))
                return
            self._perform(seq.return_failed(f"no plan within {cfg.planning_attempts} attempts "
                                            f"of {cfg.return_deadline_s:.0f} s",
                                            self.clock.now()))
        finally:
            self._return_task = None

    async def _plan_leave(self, seq: ShowSequence, sysid: int, track: int, at: float,
                          start: tuple[float, float, float] | None) -> None:
        """Plan ``sysid``'s way out of the show (land-one mid-show, or heard again off its
        plan: from ``start``) around everyone else, in a worker, before its instant."""
        try:
            absent, static = self._not_on_plan(seq, sysid)
            now = self.clock.now()
            # It must be ready before its instant comes on the show clock (which stands
            # still while the show holds: then the planner has all the time it needs).
            ahead = max(at - seq.show_time(now), 0.0)
            wall = max(self.clock.wall_interval(max(ahead - 0.3, 0.5)), 0.05) \
                if not seq.paused else self.config.return_deadline_s
            self._say(f"planning vehicle {sysid}'s way out of the show (leaving at show time "
                      f"{at:.1f} s)", "leave_planning", system_id=sysid, at=round(at, 2))
            try:
                leave = await self._planner().plan_leave(
                    track, at, seq.leaves, absent, static,
                    None if start is None else np.asarray(start, dtype=float),
                    wall,
                    what=f"planning vehicle {sysid}'s way out", joins=seq.joins,
                    replaced=seq.replaced_leaves)
            except PlanningTimeout as exc:
                self._perform(seq.leave_late(sysid, str(exc), self.clock.now()))
                return
            except GroundctlError as exc:
                self._perform(seq.leave_failed(sysid, str(exc), self.clock.now()))
                return
            self._perform(seq.set_leave(sysid, leave, self.clock.now()))
        finally:
            self._leave_tasks.pop(sysid, None)

    async def _plan_join(self, seq: ShowSequence, track: int, spare: int,
                         pad: tuple[float, float, float]) -> None:
        """Plan ``spare``'s way from its pad into ``track`` around everyone else, in a
        worker, leaving no sooner than the planning can be done (JOIN_LEAD_S of show time
        ahead; the worker's deadline is that much wall time)."""
        try:
            absent, static = self._not_on_plan(seq, spare)  # not itself (in the air)
            # The other spares stand on their pads: obstacles like any drone on the ground.
            others = seq.pads_taken(spare)
            static = np.concatenate([static, *(column(p) for p in others)]) if others \
                else static
            now = self.clock.now()
            picture = seq.picture()
            # Each time planning ran out of time, twice the lead (and the deadline): on a
            # busy machine the join goes to a later formation rather than to none.
            lead = self.config.join_lead_s * 2 ** seq.join_tries(track, spare)
            wall = self.config.return_deadline_s if seq.paused \
                else max(self.clock.wall_interval(lead - 0.5), 0.05)
            earliest = seq.show_time(now) + lead
            self._say(f"planning spare {spare}'s way into track {track + 1} (leaving no "
                      f"sooner than show time {earliest:.1f} s)", "spare_planning",
                      system_id=spare, track=track + 1)
            try:
                join = await self._planner().plan_join(
                    track, np.asarray(pad, dtype=float), earliest, wall, absent=absent,
                    leaves=seq.leaves, joins=seq.joins, static=static,
                    climb=seq.spare_climb, climb_s=seq.spare_climb_s(),
                    what=f"planning spare {spare}'s way into track {track + 1}",
                    replaced=seq.replaced_leaves)
            except PlanningTimeout as exc:
                self._perform(seq.join_failed(track, spare, str(exc), self.clock.now(),
                                              retry=True))
                return
            except GroundctlError as exc:
                self._perform(seq.join_failed(track, spare, str(exc), self.clock.now()))
                return
            if seq.picture() != picture:
                self._perform(seq.join_failed(
                    track, spare, "the fleet changed while it was planned (a drone left, "
                                  "fell or holds): planning it again", self.clock.now(),
                    retry=True))
                return
            actions = seq.set_join(track, spare, join, self.clock.now())
            if spare in seq.vehicles and seq.vehicles[spare].join is join:
                self._spare_sent(spare, track)
            self._perform(actions)
        finally:
            self._join_tasks.pop(track, None)

    def _spare_sent(self, spare: int, track: int) -> None:
        """``spare`` flies ``track`` from now on: its setpoints, LEDs and tracking are the
        track's."""
        if self._stream is not None:
            self._stream.retrack(spare, track)
        if self._leds.schedule is not None:
            self._leds.schedule = self._leds.schedule.retrack(spare, track)
        if self.monitor is not None:
            self.monitor.add(spare, track)

    def _not_on_plan(self, seq: ShowSequence, leaving: int | None
                     ) -> tuple[list[int], NDArray[np.float64]]:
        """Tracks nobody flies (excluded, down, descending, killed) and the columns where
        those drones really are, from telemetry (or their slot, for one never airborne).
        A spare on its way in is neither (it goes to the planners as a join), and a track
        a spare flies is flown whoever flew it before."""
        absent: list[int] = []
        flown: set[int] = set()
        columns: list[NDArray[np.float64]] = []
        for track in self._excluded_tracks():
            absent.append(track)
            columns.append(column(self.plan.home[track]))
        positions = show_positions(self.plan.origin, self.link.vehicles)
        now = self.clock.now()
        for sysid, v in seq.vehicles.items():
            phase = seq.streamed_as(v)  # a lost one is still streamed what it was
            if sysid == leaving:
                continue
            path = seq.path(sysid, now)
            if v.join is not None and ((path is not None and path.kind is PathKind.JOIN)
                                       or phase is VehiclePhase.PREFLIGHT):
                continue  # on its way in (seq.joins), or still on its pad
            if path is not None and path.kind is PathKind.HOLD:
                assert path.point is not None
                if v.track >= 0:  # a spare at its standby point has no track
                    absent.append(v.track)  # hovering where it was heard again, off its plan
                    columns.append(np.array([path.point]))
                else:  # it may go straight down onto its pad at any moment
                    columns.append(column(np.asarray(path.point)))
            elif phase not in (VehiclePhase.READY, VehiclePhase.SHOW, VehiclePhase.LEAVING,
                               VehiclePhase.RETURNING):
                if v.track >= 0:
                    absent.append(v.track)  # down, descending, killed, or never airborne
                pos = positions.get(sysid)
                home = self.plan.home[v.track] if v.pad is None or self.plan.spares is None \
                    else self.plan.spares.pads[v.pad]
                columns.append(column(home if pos is None else pos))
            elif v.track >= 0:
                flown.add(v.track)
        static = np.concatenate(columns) if columns else np.empty((0, 3))
        return [t for t in absent if t not in flown], static
