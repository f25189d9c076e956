"""One vehicle's tick (package docstring, "Linearisation passes" to "Weak vehicles"): the
QP solved pass after pass, the rollout accepted only once verified, else the escape or
a checked fallback (the stop, or the path), and a weak vehicle's re-timed reference."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from groundctl.execute.mpc.checks import (
    _TINY,
    DIST_TOL,
    _only_separation,
    brake_trajectory,
    escape_limits,
    position_violations,
    rollout,
    start_violations,
    verify,
)
from groundctl.execute.mpc.qp import MpcQp, _Plan
from groundctl.execute.mpc.types import FloatArray, MpcRequest, MpcResult, Status, TrajectoryCheck
from groundctl.execute.retime import Retimer
from groundctl.vehicleid import spell

#: OSQP's status when a pass hits ``time_limit``.
_TIME_LIMIT = "run time limit reached"
#: Times at most a pass that hit ``time_limit`` is resumed from its last iterate (a busy
#: machine preempts the worker mid-pass; the batch's own budget still bounds the whole)...
_TIME_LIMIT_RESUMES = 20
#: ... and only while the solve (all its passes) has taken less than this on the
#: controller's clock, s: the worker's batch budget is 60 % of its 0.2 s deadline,
#: shared by every vehicle.
_RESUME_WITHIN_S = 0.05
#: OSQP outcomes whose iterate is worth verifying.
_ACCEPTED_OSQP = ("solved", "solved inaccurate")
#: How fast an autopilot streamed the path takes a vehicle back onto it (its offset
#: fades as exp(-t / PATH_SETTLE_S)), s: the "keep its path" escape candidate.
PATH_SETTLE_S = 1.0
#: A weak vehicle's re-timed reference is solved again after this long, s.
RETIME_EVERY_S = 1.0
#: ... or at once when its path ahead has moved by more than this from the one it was
#: re-timed from (the show clock held, a return or a way out replaced the path), m.
RETIME_PATH_TOL_M = 0.05


class MpcController(MpcQp):
    """One vehicle's MPC: the QP built once, updated and warm-started every tick."""

    def solve(self, request: MpcRequest) -> MpcResult:
        """One tick: the verified correction, or a stop with the reason why not."""
        self._continuing = False
        result = self._solve(request)
        if self._continuing and result.status in ("solved", "fallback"):
            # Solved with the escape's raised limits from a start above its own: it may
            # still be above them next tick, and the escape goes on until it is not.
            self._escaped = True
        return result

    def _solve(self, request: MpcRequest) -> MpcResult:
        self._check(request)
        # The path the executor streams when the MPC gives nothing: a weak vehicle's
        # is its plan, not the re-timed reference the QP tracks.
        self._streamed = request
        if request.lookahead is not None:
            request = self._retimed_request(request)
        start = self._clock()
        # Already inside a neighbour's separation (pushed there): not a reason to give
        # up, a reason to get out.  Anything else already broken is.
        bad_start = start_violations(replace(request, neighbours=None, neighbour_ids=None),
                                     self.config.limit_tol)
        escape_at = escape_limits(request.limits)  # never raised twice
        if bad_start and self._escaped:
            # Flying an escape, up to ESCAPE_SPEED_MARGIN over its speed limits: it goes on
            # with those raised limits until its speed is back within its own, instead of
            # ending after one tick on a start state it was told to fly.
            continued = replace(request, limits=escape_at)
            if not start_violations(replace(continued, neighbours=None, neighbour_ids=None),
                                    self.config.limit_tol):
                request, bad_start = continued, []
                self._continuing = True
        self._escaped = False
        # A start above a speed limit is a state to recover from, within the envelope that
        # closes from it (package docstring, "Envelope"); a position outside the altitude
        # band or the geofence is not the MPC's to fix (the autopilot's fence is in charge).
        if bad_start and position_violations(request, with_neighbours=False):
            return self._fallback(request, "start state: " + "; ".join(bad_start), start)
        recovered = ("start state: " + "; ".join(bad_start) + "; flown back within its "
                     "limits") if bad_start else ""
        d0 = np.linalg.norm(request.others[:, 0] - request.p0[None], axis=1)
        inside = d0 < request.limits.min_separation - DIST_TOL
        self._start_distance = d0 if inside.any() else None
        recovering = bool(inside.any())
        cfg = self.config
        gp, gv, ga = self._guess(request)
        self._update_cost(request)
        iterations = 0
        req, cause = request, ""
        for npass in range(1, 2 * cfg.passes + 1):
            escaping = npass > cfg.passes  # the escape passes (module docstring, "Escape")
            slots = self._assign_slots(req, gp)
            self._cuts(npass - cfg.passes if escaping else npass, req, gv, ga)
            self._linearise(req, gp, gv, ga, slots)
            if npass == 1:
                # After the update: warm_start sets OSQP's z = A x with the A it holds
                # (measured: half the iterations of a cold tick).  Later passes start
                # from OSQP's own last iterate.
                self._warm(request, gp, gv, ga)
            res = self.solver.solve(raise_error=False)
            iterations += int(res.info.iter)
            status = str(res.info.status)
            for _ in range(_TIME_LIMIT_RESUMES):
                if status != _TIME_LIMIT or self._clock() - start > _RESUME_WITHIN_S:
                    break
                # The pass ran out of (wall) time, usually because this process was not
                # scheduled: go on from OSQP's own last iterate rather than fall back
                # (while the whole solve is young: the batch has a deadline too).
                res = self.solver.solve(raise_error=False)
                iterations += int(res.info.iter)
                status = str(res.info.status)
            if status not in _ACCEPTED_OSQP:
                if escaping:  # the escape's QP failed: the last pass's cause stands
                    return self._fallback(request, cause, start, iterations, npass)
                return self._fallback(request, f"OSQP {status} after {res.info.iter} "
                                      f"iterations (pass {npass})", start, iterations, npass)
            x = np.asarray(res.x)
            acc = x[self.oA: self.oSs].reshape(self.N, 3).copy()
            # The norm limit is met through tangent-plane cuts, which a solution can still
            # overshoot at a corner (measured: 2.59 m/s^2 for 2.5 on a dodge): project each
            # step's acceleration onto the ball, then roll out and verify what is flown.
            a_max = req.limits.max_accel * (1.0 - cfg.limit_tol / 2)
            norm = np.linalg.norm(acc, axis=1, keepdims=True)
            acc *= np.minimum(1.0, a_max / np.maximum(norm, _TINY))
            pos, vel = rollout(request.p0, request.v0, acc, self.dt)
            self._lin = _Plan(request.t0, pos, vel, acc, np.array(res.y))
            slack = x[self.oSs:]
            max_slack = float(max(slack.max(), 0.0))
            used = int((slots >= 0).sum())
            if escaping:
                escape = verify(pos, vel, acc, self.dt, req.limits, req.others,
                                req.other_ids, substeps=cfg.substeps,
                                limit_tol=cfg.limit_tol, baseline=recovering,
                                brake=self._brake(req))
                if npass < 2 * cfg.passes and (max_slack > cfg.slack_tol or not escape.ok):
                    gp, gv, ga = pos, vel, acc
                    continue
                last = verify(pos, vel, acc, self.dt, request.limits, request.others,
                              request.other_ids, substeps=cfg.substeps,
                              limit_tol=cfg.limit_tol, baseline=recovering,
                              brake=self._brake(request))
                return self._escape(request, pos, vel, acc, last, escape, cause, start,
                                    iterations, npass, max_slack, used)
            check = verify(pos, vel, acc, self.dt, request.limits, request.others,
                           request.other_ids, substeps=cfg.substeps, limit_tol=cfg.limit_tol,
                           baseline=recovering, brake=self._brake(request))
            # The envelope's slack (speed, altitude, fence) is judged on what is flown: the
            # rollout, by the verifier, within ``limit_tol``.  The QP's own velocities meet
            # the dynamics only to ADMM's tolerance, and a weak vehicle re-timed at 60 % of
            # its limits was stopped mid-climb for 10 mm/s of slack on a rollout that kept
            # them.  The separation's slack is never accepted.
            sep_slack = float(np.max(slack[: self.oSe - self.oSs], initial=0.0))
            if sep_slack <= cfg.slack_tol and check.ok:
                result = MpcResult(
                    sysid=self.sysid, status="solved", reason=recovered, t0=request.t0,
                    dt=self.dt,
                    pos=pos, vel=vel, acc=acc, solve_ms=1e3 * (self._clock() - start),
                    iterations=iterations, passes=npass, max_slack=max_slack,
                    min_separation=check.min_separation, closest=check.closest,
                    neighbours_used=used, recovering=bool(bad_start))
                self._last = result
                return result
            if npass < cfg.passes:
                # Relinearise around this solution, slack and all (OSQP warm-starts from
                # it by itself): a guess through a neighbour gives half-spaces that no
                # trajectory can meet at once; the solution's own normals can be.
                gp, gv, ga = pos, vel, acc
                continue
            if max_slack > cfg.slack_tol:
                n_sep = self.oSe - self.oSs
                sep_slack = float(np.max(slack[:n_sep], initial=0.0))
                what = "separation" if sep_slack >= np.max(slack[n_sep:], initial=0.0) \
                    else "speed, altitude or geofence"
                detail = f": {check.violations[0]}" if check.violations else ""
                cause = (f"no correction keeps the limits after {npass} passes ({what} "
                         f"slack {max_slack:.3f}){detail}")
            else:
                sep_slack = 0.0
                cause = f"verification after {npass} passes: " + "; ".join(check.violations)
            if recovering or sep_slack > cfg.slack_tol or \
                    any(v.startswith("separation") for v in check.violations):
                # The separation is what cannot be kept: one more pass with the speeds
                # allowed ESCAPE_SPEED_MARGIN over their limits, from this solution.
                req, gp, gv, ga = (replace(request, limits=escape_at), pos, vel, acc)
                continue
            return self._fallback(request, cause, start, iterations, npass, max_slack, used)
        raise AssertionError("unreachable")  # pragma: no cover

    def _escape(self, req: MpcRequest, pos: FloatArray, vel: FloatArray, acc: FloatArray,
                check: TrajectoryCheck, escape: TrajectoryCheck, cause: str, start: float,
                iterations: int, passes: int, max_slack: float, used: int) -> MpcResult:
        recovering = self._start_distance is not None
        where = f"inside a neighbour's separation: {cause}" if recovering else cause
        stop, stop_check, on_path = self._judged_fallback(req, where, start, iterations,
                                                          passes, max_slack, used)
        if stop.status in ("fallback", "path") and not recovering:
            return stop  # a fallback that keeps every limit beats an escape that breaks one
        best_other = max(stop_check.min_separation, on_path.min_separation)
        usable = not escape.violations or _only_separation(escape)
        if usable and check.min_separation > best_other + DIST_TOL:
            result = MpcResult(
                sysid=self.sysid, status="fallback",
                reason=f"{where}: the best escape found keeps {check.min_separation:.2f} m "
                       f"(its path {on_path.min_separation:.2f} m, the stop "
                       f"{stop.min_separation:.2f} m)", t0=req.t0, dt=self.dt, pos=pos,
                vel=vel, acc=acc, solve_ms=1e3 * (self._clock() - start),
                iterations=iterations, passes=passes, max_slack=max_slack,
                min_separation=check.min_separation, closest=check.closest,
                neighbours_used=used)
            self._last = result
            self._escaped = True
            return result
        if stop.status == "fallback" and \
                on_path.min_separation > stop_check.min_separation + DIST_TOL:
            # The stop breaks nothing new but the path keeps farther away: the path.
            stop = replace(stop, status="unsafe",
                           reason=f"{stop.reason}; the stop keeps "
                                  f"{stop_check.min_separation:.2f} m, its path "
                                  f"{on_path.min_separation:.2f} m")
            self._last = None
        return stop

    def _retimed_request(self, req: MpcRequest) -> MpcRequest:
        """``req`` with its reference replaced by the path re-timed to its limits (solved
        again every ``RETIME_EVERY_S``, or when the last one no longer covers the
        horizon); as it is if the re-timing QP fails."""
        assert req.lookahead is not None
        steps = len(req.lookahead) - 1
        rt = self._retimed
        moved = rt is not None and self._path_moved(req.t0, req.lookahead, req.lookahead_dt)
        if moved or (rt is not None and rt.end < req.t0 + self.config.horizon_s):
            rt = self._retimed = None  # no reference to keep if the new one fails
        stale = rt is None or not (rt.t0 <= req.t0 < rt.t0 + RETIME_EVERY_S)
        if stale:
            self._retimed_from = (req.t0, req.lookahead_dt, req.lookahead)
            if self._retimer is None or self._retimer.steps != steps or \
                    self._retimer.dt != req.lookahead_dt:
                self._retimer = Retimer(steps=steps, dt=req.lookahead_dt)
            fresh = self._retimer.solve(req.t0, req.lookahead, req.p0, req.v0, req.limits)
            rt = self._retimed = fresh if fresh is not None else rt
        if rt is None:
            return replace(req, lookahead=None)
        rp, rv, ra = rt.sample(req.t0 + self.dt * np.arange(self.N + 1))
        return replace(req, ref_pos=rp, ref_vel=rv, ref_acc=ra, lookahead=None)

    def _path_moved(self, t0: float, lookahead: FloatArray, dt: float) -> bool:
        """Whether the path ahead (``lookahead`` from ``t0``) is no longer the one the
        reference was re-timed from, where the two overlap.

        The re-timed reference sets off before its path does; when the show clock holds
        (or a return replaces the path) the path's future stands still, and a reference
        kept for ``RETIME_EVERY_S`` would still lead the vehicle off towards where its
        path would have gone: under load, with the solves late, for seconds, into a
        neighbour hovering below (1.18 m, seen)."""
        if self._retimed_from is None:
            return True
        t_old, dt_old, old = self._retimed_from
        times = t0 + dt * np.arange(len(lookahead))
        u = (times - t_old) / dt_old
        inside = u <= len(old) - 1
        if not inside.any():
            return True
        u = u[inside]
        k = np.clip(u.astype(np.intp), 0, len(old) - 2)
        frac = (u - k)[:, None]
        then = old[k] * (1.0 - frac) + old[k + 1] * frac
        return bool(np.abs(then - lookahead[inside]).max() > RETIME_PATH_TOL_M)

    def _path_back(self, req: MpcRequest) -> TrajectoryCheck:
        """The path checked as the executor would fly it if the MPC gave nothing: the
        autopilot takes the vehicle back onto it, its offset decaying critically damped
        with time constant ``PATH_SETTLE_S`` (position and velocity consistent)."""
        tau = PATH_SETTLE_S
        t = (self.dt * np.arange(len(req.ref_pos)))[:, None]
        e0, de0 = req.p0 - req.ref_pos[0], req.v0 - req.ref_vel[0]
        c = de0 + e0 / tau  # critically damped: e = (e0 + c t) exp(-t / tau)
        fade = np.exp(-t / tau)
        back_pos = req.ref_pos + (e0 + c * t) * fade
        back_vel = req.ref_vel + (c - (e0 + c * t) / tau) * fade
        # The autopilot brings it back within its own acceleration limit: what is judged
        # here is where the path takes it (separation, speeds, altitude, fence).
        check = verify(back_pos, back_vel, np.diff(back_vel, axis=0) / self.dt, self.dt,
                       replace(req.limits, max_accel=math.inf), req.others, req.other_ids,
                       substeps=self.config.substeps, limit_tol=self.config.limit_tol,
                       baseline=True)
        if check.min_separation < req.limits.min_separation - DIST_TOL and check.ok:
            # "No worse than now" is for the envelope (a gust's 2.6 m/s climb is not the
            # path's doing); the separation it must keep outright.
            check = replace(check, violations=(
                f"separation from vehicle {spell(check.closest or 0)} {check.min_separation:.2f} m "
                f"(min_separation {req.limits.min_separation} m)",))
        return check

    def _fallback(self, req: MpcRequest, cause: str, start: float, iterations: int = 0,
                  passes: int = 0, max_slack: float = 0.0, used: int = 0) -> MpcResult:
        return self._judged_fallback(req, cause, start, iterations, passes, max_slack,
                                     used)[0]

    def _judged_fallback(self, req: MpcRequest, cause: str, start: float, iterations: int,
                         passes: int, max_slack: float, used: int
                         ) -> tuple[MpcResult, TrajectoryCheck, TrajectoryCheck]:
        """The fallback (the checked stop, or the path if it keeps every limit), with the
        checks of both candidates: the stop's and the path's (the escape weighs them)."""
        pos, vel, acc = brake_trajectory(req.p0, req.v0, self.dt, self.N, req.limits.max_accel)
        check = verify(pos, vel, acc, self.dt, req.limits, req.others, req.other_ids,
                       substeps=self.config.substeps, limit_tol=self.config.limit_tol,
                       baseline=True)
        streamed = req if self._streamed is None else self._streamed
        on_path = self._path_back(replace(streamed, p0=req.p0, v0=req.v0, lookahead=None))
        status: Status = "fallback" if check.ok else "unsafe"
        reason = cause if check.ok else f"{cause}; the stop is unsafe too: " + \
            "; ".join(check.violations)
        if on_path.ok:
            # A stop in a moving formation is where the others are about to be: a path
            # that keeps every limit (the plan kept the fleet apart) is kept instead.
            status = "path"
            reason = f"{cause}; its path keeps every limit" + (
                f" ({on_path.min_separation:.2f} m from vehicle {spell(on_path.closest or 0)})"
                if on_path.closest is not None else "")
        result = MpcResult(
            sysid=self.sysid, status=status, reason=reason, t0=req.t0, dt=self.dt, pos=pos,
            vel=vel, acc=acc, solve_ms=1e3 * (self._clock() - start), iterations=iterations,
            passes=passes, max_slack=max_slack, min_separation=check.min_separation,
            closest=check.closest, neighbours_used=used)
        # Only what is flown is the vehicle's last trajectory (its acceleration smooths
        # the next solve's first step).
        self._last = result if status == "fallback" else None
        return result, check, on_path
