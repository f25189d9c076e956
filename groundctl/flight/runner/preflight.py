"""The ground part, before anything flies: the link up, the pre-flight checks
until every vehicle passes, the operator's go gate and exclusions, the
vehicles' settings and parameters, and the sequence built from the
assignment.

A plan's spares (:attr:`Plan.spares <groundctl.plan.plan.Plan.spares>`) are checked
with the rest but never waited for: when the show's vehicles pass, the spares that
passed too are :attr:`~groundctl.flight.runner.state.RunnerState.spares`, and each
one not ready is said in one line (the show starts with fewer spares, not later)."""

from __future__ import annotations

import asyncio
import math
from dataclasses import replace
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.errors import FlightError, LinkError, NoGo, PreflightFailed
from groundctl.execute.frames import show_positions
from groundctl.execute.lead import LeadEstimator
from groundctl.execute.leds import LedSchedule
from groundctl.execute.mapping import Assignment, auto_assign, explicit_assign
from groundctl.execute.preflight import PreflightReport, remaining_plan_conflicts, run_preflight
from groundctl.execute.sequence import ShowSequence
from groundctl.execute.setpoints import SetpointStream, StreamTarget
from groundctl.flight.monitor import FlightMonitor
from groundctl.flight.runner.config import PERMANENT_CHECKS, _ids, log
from groundctl.flight.runner.state import RunnerState
from groundctl.link.flavours import Flavour
from groundctl.link.window import per_network
from groundctl.record.logstreams import request_log_extras
from groundctl.vehicleid import spell


class Preflight(RunnerState):
    """The ground part (a layer of :class:`ShowRunner`)."""

    # -- phase 1: connect -----------------------------------------------------------
    async def connect(self) -> None:
        """Wait until every expected vehicle (or as many as the plan has) sent a HEARTBEAT;
        not the fleet file's spares (``spare_ids``): one that stays silent is a spare
        fewer, not a show that cannot start."""
        want: list[int] | int = [s for s in self.expected_ids if s not in
                                 self.config.spare_ids] if self.expected_ids is not None \
            else self.plan.drones
        self._say(f"waiting for {want if isinstance(want, int) else len(want)} vehicle(s)",
                  "connecting")
        await self.link.wait_for_vehicles(want, timeout=self.config.connect_timeout_s)
        self._say(f"{len(self.link.vehicles)} vehicle(s) heard", "connected",
                  system_ids=sorted(self.link.vehicles))

    # -- phase 2: pre-flight --------------------------------------------------------
    def _fleet(self) -> dict[int, Any]:
        ids = self.expected_ids if self.expected_ids is not None else sorted(self.link.vehicles)
        return {s: self.link.vehicles[s] for s in ids if s in self.link.vehicles}

    def _assign(self) -> Assignment:
        positions = show_positions(self.plan.origin, self._fleet())
        tol = self.config.thresholds.slot_tolerance_m
        pads = self.plan.spares.pads if self.plan.spares is not None else None
        marked = self.config.spare_ids
        if self.config.tracks is not None:
            return explicit_assign(self.config.tracks, self.plan.home, positions, tol,
                                   pads, marked)
        return auto_assign(self.plan.home, positions, tol, pads, marked)

    async def _ask(self, sysid: int, what: str, call: Any) -> None:
        try:
            await call
        except LinkError as exc:
            log.debug("vehicle %s: %s not answered yet: %s", sysid, what, exc)

    async def preflight(self) -> PreflightReport:
        """Streams, EKF origins, assignment and checks; raises PreflightFailed or FlightError."""
        cfg = self.config
        start = self.clock.now()
        streams_ok: set[int] = set()
        asked: dict[tuple[int, str], float] = {}
        failing_since: dict[tuple[int, str], float] = {}
        last_lines: list[str] = []
        show_ready: float | None = None  # since when the show's own vehicles all pass
        next_progress = start + cfg.progress_every_s
        while True:
            cfg = self.config  # the operator may exclude a vehicle meanwhile (the console)
            now = self.clock.now()
            fleet = self._fleet()
            def due(sysid: int, what: str, every: float, now: float = now) -> bool:
                key = (sysid, what)
                if now - asked.get(key, -math.inf) < every:
                    return False
                asked[key] = now
                return True

            for sysid, state in fleet.items():
                if sysid not in streams_ok and due(sysid, "streams", 3.0):
                    self._spawn(self._request_streams(sysid, streams_ok))
                if state.ekf_origin is None and due(sysid, "origin", 2.0):
                    self._spawn(self._ask(sysid, "GPS_GLOBAL_ORIGIN", self.link.request_message(
                        sysid, mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, retries=0, poll=True)))
                if state.home is None and due(sysid, "home", 2.0):
                    self._spawn(self._ask(sysid, "HOME_POSITION", self.link.request_message(
                        sysid, mavlink.MAVLINK_MSG_ID_HOME_POSITION, retries=0, poll=True)))
            self.assignment = self._assign()
            report = run_preflight(fleet, self.assignment, now, cfg.thresholds)
            self.preflight_report = report
            failures = report.failures(cfg.excluded)
            lines = report.lines(cfg.excluded) + self.assignment.problems()
            if lines != last_lines:
                if self.events is not None:
                    self.events.emit("preflight", lines=lines)
                last_lines = lines
            missing = [t for t in self.assignment.unassigned_tracks
                       if t not in self._excluded_tracks()]
            if not failures and not missing:
                # The show could start: spares still settling (streams, battery, EKF
                # origin come a few seconds after the show's vehicles' on a busy link)
                # are given a little longer, then left on their pads, said.
                show_ready = show_ready if show_ready is not None else now
                if not report.spare_failures(cfg.excluded) \
                        or now - show_ready >= cfg.spare_settle_s:
                    break
            else:
                show_ready = None
            # Give up early on what waiting cannot fix: once one check has failed that
            # long, naming every vehicle failing such a check now (on a busy link the
            # others' answers came a little later, the same fault).
            permanent: dict[int, list[str]] = {}
            settled = False
            for sysid, results in report.results.items():
                if sysid in cfg.excluded or sysid in report.spares:
                    continue
                for r in results:
                    key = (sysid, r.name)
                    if r.ok or r.name not in PERMANENT_CHECKS or not self._known(sysid, r.name):
                        failing_since.pop(key, None)
                        continue
                    since = failing_since.setdefault(key, now)
                    settled = settled or now - since >= cfg.settle_s
                    permanent.setdefault(sysid, []).append(str(r))
            if settled:
                self._say("pre-flight refused: " + report.summary(cfg.excluded) + "\n"
                          + "\n".join(report.failing_by_check(cfg.excluded)), "preflight_failed",
                          failures=permanent)
                raise PreflightFailed(permanent)
            if now - start >= cfg.preflight_timeout_s:
                if failures:
                    self._say("pre-flight timed out: " + report.summary(cfg.excluded) + "\n"
                              + "\n".join(report.failing_by_check(cfg.excluded)),
                              "preflight_failed", failures=failures)
                    raise PreflightFailed(failures)
                raise FlightError(f"pre-flight: no vehicle for track(s) {missing} after "
                                  f"{cfg.preflight_timeout_s:.0f} s; exclude or add vehicles")
            if now >= next_progress:
                next_progress = now + cfg.progress_every_s
                self._say("pre-flight: " + report.summary(cfg.excluded), "progress")
            await asyncio.sleep(max(self.clock.wall_interval(0.5), 0.001))
        grounded = self._excluded_tracks()
        conflicts = remaining_plan_conflicts(self.plan, grounded) if grounded else []
        if conflicts:
            raise FlightError(f"excluding vehicle(s) {sorted(cfg.excluded)} leaves the show "
                              f"unsafe: {conflicts[0]}")
        self._say("pre-flight passed: " + report.summary(cfg.excluded), "preflight_passed",
                  tracks={str(k): v for k, v in self._tracks().items()},
                  lines=report.lines(cfg.excluded))
        self._spares_ready(report)
        return report

    def _spares_ready(self, report: PreflightReport) -> None:
        """:attr:`spares` from the report the show passed with, one line for each spare
        not ready (why), and the count ready against the plan's."""
        plan = self.plan.spares
        if plan is None:
            self.spares = {}
            return
        excluded = self.config.excluded
        self.spares = report.ready_spares(excluded)
        failed = report.spare_failures(excluded)
        standing = {pad: sysid for sysid, pad in report.spares.items()}
        for pad in range(plan.count):
            if pad in self.spares.values():
                continue
            sysid = standing.get(pad)
            name = f"spare {pad + 1}"
            if sysid is None:
                x, y = plan.pads[pad, :2]
                text = (f"{name}: no vehicle located on its pad at ({x:.1f}, {y:.1f}) "
                        "(not heard, or no position yet); the show starts without this "
                        "spare")
            elif sysid in excluded:
                text = (f"vehicle {spell(sysid)} ({name}) excluded by the operator: it "
                        "stays on its pad")
            else:
                text = (f"vehicle {spell(sysid)} ({name}) not ready: "
                        + "; ".join(failed.get(sysid, []))
                        + "; the show starts without this spare")
            self._say(text, "spare_not_ready", spare=pad, system_id=sysid)
        self._say(f"spares: {len(self.spares)} of {plan.count} ready", "spares_ready",
                  ready=sorted(self.spares), asked=plan.count,
                  pads={str(s): k for s, k in self.spares.items()})

    def _known(self, sysid: int, check: str) -> bool:
        state = self.link.vehicles.get(sysid)
        if state is None:
            return False
        if check == "battery":
            return state.battery_remaining_pct is not None
        return state.ekf_origin is not None and state.position_ned is not None

    async def _request_streams(self, sysid: int, done: set[int]) -> None:
        try:
            await self.link.request_streams(sysid)
        except LinkError as exc:
            log.debug("vehicle %s: streams not set yet: %s", sysid, exc)
        else:
            done.add(sysid)
            self._spawn(request_log_extras(self.link, sysid))  # the tlog's extras, once

    def _tracks(self) -> dict[int, int]:
        assert self.assignment is not None
        return {s: t for s, t in self.assignment.tracks.items() if s not in self.config.excluded}

    def _excluded_tracks(self) -> set[int]:
        if self.assignment is None:
            return set()
        excluded = {t for s, t in self.assignment.tracks.items() if s in self.config.excluded}
        if self.config.tracks is not None:
            excluded |= {t for s, t in self.config.tracks.items() if s in self.config.excluded}
        return excluded

    # -- phase 3: fly ---------------------------------------------------------------
    def _build(self) -> ShowSequence:
        tracks = self._tracks()
        states = self.link.vehicles
        flavours: dict[int, Flavour] = {}
        targets = []
        for sysid, track in sorted(tracks.items()):
            state = states[sysid]
            assert state.flavour is not None and state.ekf_origin is not None  # pre-flight
            flavours[sysid] = state.flavour
            targets.append(StreamTarget(sysid, track, state.ekf_origin))
            self._record(sysid)
        spares = {s: pad for s, pad in self.spares.items()
                  if states.get(s) is not None and states[s].flavour is not None
                  and states[s].ekf_origin is not None}
        for sysid in sorted(spares):
            state = states[sysid]
            assert state.flavour is not None and state.ekf_origin is not None
            flavours[sysid] = state.flavour
            # Streamed (and lit) only once it takes over a track, which it is then given
            # (_spare_sent); until then its row stands for track 0 and is never sent.
            targets.append(StreamTarget(sysid, 0, state.ekf_origin))
            self._record(sysid)
        self._stream = SetpointStream(self.plan, targets, self.config.initial_lead_s)
        self.leads = LeadEstimator([t.sysid for t in targets], self.config.lead) \
            if self.config.lead_s is None else None
        self._leds.schedule = LedSchedule.from_targets(self.plan, targets)
        self.monitor = FlightMonitor(self.plan, tracks)
        self.sequence = ShowSequence(self.plan, tracks, flavours, self.config.sequence,
                                     grounded_tracks=self._excluded_tracks(),
                                     spares=spares, use_spares=self.config.use_spares)
        return self.sequence

    async def _vehicle_settings(self) -> None:
        """The show's ``[vehicle]`` table on every vehicle, before arming; PreflightFailed
        with each refused vehicle's reasons."""
        if self.config.vehicle is None:
            return
        from groundctl.execute.vehset import enforce
        flavours: dict[int, Flavour] = {}
        # The spares too: one sent in flies the show, and one in the air waits in it.
        for sysid in [*self._tracks(), *sorted(self.spares)]:
            flavour = self.link.vehicles[sysid].flavour
            assert flavour is not None  # the pre-flight's autopilot check
            flavours[sysid] = flavour
        self._say(f"vehicle settings: checking {len(flavours)} vehicle(s)", "vehicle_settings")
        outcomes = await enforce(self.link, self.clock, flavours, self.config.vehicle,
                                 self.plan.origin, self.plan.limits)
        # Which name each renamed setting went by (ArduCopter 4.8's RTL_ALT_M, or RTL_ALT
        # in cm before it): said once per name, with the vehicles that answered to it.
        used: dict[str, list[int]] = {}
        for sysid, out in sorted(outcomes.items()):
            for name in out.names.values():
                used.setdefault(name, []).append(sysid)
        if used:
            self._say("vehicle settings: parameter names as the vehicles know them: " +
                      ", ".join(f"{name} on vehicle(s) {_ids(ids)}"
                                for name, ids in sorted(used.items())),
                      "vehicle_settings_names", names=used)
        for sysid, out in sorted(outcomes.items()):
            if out.changed or out.fence:
                self._say(f"vehicle {spell(sysid)}: " + ", ".join(
                    [*(["fence uploaded"] if out.fence else []), *out.changed]),
                    "vehicle_settings_set", system_id=sysid, changed=out.changed,
                    fence=out.fence)
        refused = {s: o.problems for s, o in outcomes.items() if o.problems and s in self.spares}
        for sysid, why in sorted(refused.items()):
            # A spare whose own settings cannot be made the show's stays on its pad.
            del self.spares[sysid]
            self._say(f"vehicle {spell(sysid)} (spare): its settings were refused ("
                      + "; ".join(why) + "): it stays on its pad", "spare_not_ready",
                      system_id=sysid)
        failures = {s: o.problems for s, o in outcomes.items()
                    if o.problems and s not in refused}
        if failures:
            self._say("pre-flight refused: vehicle settings\n" + "\n".join(
                f"vehicle {spell(s)}: " + "; ".join(why) for s, why in sorted(failures.items())),
                "preflight_failed", failures=failures)
            raise PreflightFailed(failures)

    async def _configure(self, seq: ShowSequence) -> None:
        """Parameters the show relies on, set before arming (ArduPilot GUID_TIMEOUT)."""
        timeout = self.config.guided_timeout_s
        if timeout is None:
            return
        ardu = [s for s, v in seq.vehicles.items() if v.flavour is Flavour.ARDUPILOT]
        if not ardu:
            return
        async def confirmed(vid: int) -> bool:
            try:
                return await self.link.set_param(vid, "GUID_TIMEOUT", timeout) is True
            except Exception:  # whatever went wrong: not confirmed, said below, not fatal
                return False

        done = await per_network(ardu, confirmed)
        failed = [s for s, ok in zip(ardu, done, strict=True) if not ok]
        if failed:
            self._say(f"GUID_TIMEOUT {timeout:g} s not confirmed by vehicle(s) {_ids(failed)}: "
                      "through a link drop they fly on along their last setpoint for up to "
                      "their own GUID_TIMEOUT (3 s by default)", "param_not_set",
                      system_ids=failed, name="GUID_TIMEOUT")

    # -- the operator's go gate and pre-flight exclusion (the console) -----------------
    async def _go_gate(self) -> None:
        """Wait for the operator's go (:attr:`confirm_go`), keeping the pre-flight report
        fresh meanwhile; then the checks once more, as they stand now, before arming."""
        assert self.confirm_go is not None and self.preflight_report is not None
        self._say("pre-flight passed: waiting for the operator's go", "go_waiting")
        decision = asyncio.ensure_future(self.confirm_go(self.preflight_report))
        self.awaiting_go = True
        try:
            while not decision.done():
                await asyncio.wait([decision], timeout=max(self.clock.wall_interval(0.5),
                                                           0.001))
                if not decision.done() and self.assignment is not None:
                    self.assignment = self._assign()
                    self.preflight_report = run_preflight(self._fleet(), self.assignment,
                                                          self.clock.now(),
                                                          self.config.thresholds)
        finally:
            self.awaiting_go = False
            if not decision.done():
                decision.cancel()
        if not decision.result():
            if self.events is not None:
                self.events.emit("operator", command="no-go")
            raise NoGo()
        if self.events is not None:
            self.events.emit("operator", command="go")
        # What was shown may be a moment old, and exclusions may have changed: the checks
        # (and the exclusion safety check) once more, as they stand now.
        await self.preflight()

    def exclude(self, sysid: int) -> None:
        """Keep ``sysid`` on the ground (before arming only).  Refused with a FlightError
        when the show is already flying, the vehicle is not in it, or the others would
        pass too close to it on its slot (:func:`remaining_plan_conflicts`)."""
        if self.sequence is not None:
            raise FlightError(f"exclude {sysid}: the show is already armed; land it instead")
        if self.assignment is not None and sysid in self.assignment.spares:
            if sysid in self.config.excluded:
                raise FlightError(f"exclude {sysid}: already excluded")
            # A spare's pad is verified clear of the show: keeping it there needs no check.
            self.config = replace(self.config, excluded=self.config.excluded | {sysid})
            self._say(f"vehicle {sysid} (spare {self.assignment.spares[sysid] + 1}) excluded "
                      "by the operator: it stays on its pad", "operator",
                      command=f"exclude {sysid}", system_id=sysid)
            return
        if self.assignment is None or sysid not in self.assignment.tracks:
            heard = sysid in self.link.vehicles
            raise FlightError(f"exclude {sysid}: " + (
                "no track assigned to it yet (it is not known on a takeoff slot); wait for "
                "its position" if heard else "not a vehicle of this show"))
        if sysid in self.config.excluded:
            raise FlightError(f"exclude {sysid}: already excluded")
        excluded = self.config.excluded | {sysid}
        tracks = {t for s, t in self.assignment.tracks.items() if s in excluded}
        conflicts = remaining_plan_conflicts(self.plan, tracks)
        if conflicts:
            raise FlightError(f"exclude {sysid}: the rest of the show would be unsafe: "
                              f"{conflicts[0]}")
        self.config = replace(self.config, excluded=frozenset(excluded))
        self._say(f"vehicle {sysid} excluded by the operator: it stays on the ground",
                  "operator", command=f"exclude {sysid}", system_id=sysid)
