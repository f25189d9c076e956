"""The per-vehicle MPC with real OSQP: rejoin, neighbours in the way, fallbacks, warm starts.

Closed loops here fly the vehicle perfectly along each result for one tick (the
autopilot tracks p + v + a setpoints with little lag), so what is checked is what
the executor would stream: distances are measured on the flown trajectory finely
sampled, against the neighbours' true trajectories.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest

from groundctl.execute.mpc import (
    RECOVERY_MPS,
    MpcConfig,
    MpcController,
    MpcRequest,
    MpcResult,
    brake_trajectory,
    convex_fence,
    solve_in_priority,
    verify,
)
from groundctl.show.model import Limits

LIMITS = Limits()  # 5 m/s, 3 m/s^2, 1.5 m separation, 2-120 m altitude
#: The MPC as flown, without OSQP's per-pass wall-time cap: what these tests judge is
#: the geometry, which a busy machine must not change (the cap is the flight's).
CFG = MpcConfig(osqp_settings={k: v for k, v in MpcConfig().osqp_settings.items()
                               if k != "time_limit"})
N, DT = CFG.steps, CFG.dt
Path = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


def line(start: tuple[float, float, float], vel: tuple[float, float, float]) -> Path:
    """A straight path at constant velocity."""
    p0, v = np.asarray(start, dtype=float), np.asarray(vel, dtype=float)

    def at(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)[..., None]
        pos = p0 + v * t
        return pos, np.broadcast_to(v, pos.shape).copy(), np.zeros_like(pos)
    return at


def request(sysid: int, t0: float, p0, v0, path: Path, others: list[Path] | None = None,
            ids: list[int] | None = None, limits: Limits = LIMITS, **kw) -> MpcRequest:
    times = t0 + DT * np.arange(N + 1)
    rp, rv, ra = path(times)
    nb = np.stack([o(times)[0] for o in others]) if others else None
    if others and ids is None:
        ids = list(range(100, 100 + len(others)))
    return MpcRequest(sysid, t0, np.asarray(p0, float), np.asarray(v0, float), rp, rv, ra,
                      limits, nb, None if ids is None else np.asarray(ids), **kw)


def flown(result: MpcResult, t_from: float, t_to: float, per_step: int = 50) -> np.ndarray:
    """Positions the vehicle flies between two instants along ``result``."""
    ts = np.linspace(t_from, t_to, per_step + 1)
    return result.sample(ts)[0]


def check_limits(result: MpcResult, limits: Limits = LIMITS) -> None:
    speed_h = np.linalg.norm(result.vel[:, :2], axis=1)
    assert speed_h.max() <= limits.max_speed_h * 1.01
    assert np.linalg.norm(result.acc, axis=1).max() <= limits.max_accel * 1.01
    assert result.vel[:, 2].max() <= limits.max_speed_up * 1.01
    assert -result.vel[:, 2].min() <= limits.max_speed_down * 1.01


def test_rejoin_from_lateral_offset_on_a_moving_path() -> None:
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    ctrl = MpcController(1, CFG)
    r = ctrl.solve(request(1, 0.0, (0.0, 3.0, 10.0), (3.0, 0.0, 0.0), path))
    assert r.status == "solved", r.reason
    check_limits(r)
    ref_end, vel_end, _ = path(np.array(r.end))
    assert np.linalg.norm(r.pos[-1] - ref_end) < 0.1  # back on the path at the horizon end
    assert np.linalg.norm(r.vel[-1] - vel_end) < 0.1  # ... with the path's velocity
    # Closed loop: the vehicle converges onto its path, every tick within the limits.
    t, (p, v) = 0.0, (r.pos[0], r.vel[0])
    for _ in range(40):
        r = ctrl.solve(request(1, t, p, v, path))
        assert r.status == "solved", r.reason
        check_limits(r)
        t += DT
        p, v, _ = r.sample(t)
    assert np.linalg.norm(p - path(np.array(t))[0]) < 0.05


def closed_loop_separation(path: Path, others: list[Path], start, seconds: float
                           ) -> tuple[float, list[MpcResult]]:
    """Fly ``seconds`` of MPC ticks; the smallest distance to any neighbour while flying."""
    ctrl = MpcController(1, CFG)
    t = 0.0
    p, v = np.asarray(start, dtype=float), path(np.array(0.0))[1]
    worst = np.inf
    results = []
    for _ in range(round(seconds / DT)):
        r = ctrl.solve(request(1, t, p, v, path, others, list(range(2, 2 + len(others)))))
        results.append(r)
        if r.status == "solved":
            # A solved result keeps the limit over its whole horizon in continuous time.
            ts = np.linspace(t, r.end, 40 * N + 1)
            own = r.sample(ts)[0]
            d = min(np.linalg.norm(own - o(ts)[0], axis=1).min() for o in others)
            assert d >= LIMITS.min_separation - 1e-3
        ts = np.linspace(t, t + DT, 51)
        seg = flown(r, t, t + DT)
        worst = min(worst, *(np.linalg.norm(seg - o(ts)[0], axis=1).min() for o in others))
        t += DT
        p, v, _ = r.sample(t)
    return worst, results


def test_static_neighbour_in_the_way_is_never_violated() -> None:
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    blocker = line((6.0, 0.1, 10.0), (0.0, 0.0, 0.0))  # right on the path, 2 s ahead
    worst, results = closed_loop_separation(path, [blocker], (0.0, 0.0, 10.0), 5.0)
    assert worst >= LIMITS.min_separation - 1e-3
    assert sum(r.status == "solved" for r in results) >= 0.9 * len(results)
    # It went round and came back onto its path behind the blocker.
    last = results[-1]
    assert np.linalg.norm(last.pos[0] - path(np.array(last.t0))[0]) < 0.5


def test_moving_neighbour_crossing_the_path_is_never_violated() -> None:
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    crosser = line((6.0, -6.0, 10.0), (0.0, 3.0, 0.0))  # both at (6, 0, 10) at t = 2 s
    worst, results = closed_loop_separation(path, [crosser], (0.0, 0.0, 10.0), 4.0)
    assert worst >= LIMITS.min_separation - 1e-3
    assert sum(r.status == "solved" for r in results) >= 0.9 * len(results)


def test_start_inside_a_neighbours_separation_opens_the_gap() -> None:
    """Pushed to 1.0 m of a neighbour flying alongside on the path it would rejoin: the
    MPC does not give up (or stop there), it opens the gap at RECOVERY_MPS or better and
    keeps it, never closer than where it started."""
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    close = line((0.0, 1.0, 10.0), (3.0, 0.0, 0.0))
    r = MpcController(1, CFG).solve(request(1, 0.0, (0.0, 0.0, 10.0), (3.0, 0.0, 0.0), path,
                                       [close], [7]))
    assert r.status in ("solved", "fallback"), r.reason
    gap = np.linalg.norm(r.pos[:, :2] - close(r.times)[0][:, :2], axis=1)
    assert gap.min() >= 1.0 - 1e-3 and r.closest == 7
    assert gap[-1] >= min(1.5, 1.0 + RECOVERY_MPS * r.times[-1]) - 0.05


def test_a_start_above_its_speed_limits_is_flown_back_within_them_and_onto_its_path() -> None:
    """Carried by a gust to 6 m/s sideways-forward and 3 m/s up (limits 5 and 2.5): a
    state to recover from, not a reason to give up.  Each limit closes from the measured
    speed at half ``max_accel``; the correction keeps that envelope, every limit once it
    has closed, and ends on its path."""
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    r = MpcController(1, CFG).solve(request(1, 0.0, (0.0, 1.0, 10.0), (4.8, 3.6, 3.0), path))
    assert r.status == "solved", r.reason
    assert r.reason == ("start state: horizontal speed 6.00 m/s above max_speed_h 5.0 m/s; "
                        "climb rate 3.00 m/s above max_speed_up 2.5 m/s; flown back within "
                        "its limits")
    brake = CFG.envelope_brake * LIMITS.max_accel
    assert verify(r.pos, r.vel, r.acc, DT, LIMITS, brake=brake).ok
    ts = np.linspace(0.0, r.end, 3001)
    _, vel, _ = r.sample(ts)
    speed_h = np.linalg.norm(vel[:, :2], axis=1)
    # The envelope: never above the speed it started at less what braking at `brake`
    # takes off (8 % for the speed polygon's corners), within the limit once closed.
    assert np.all(speed_h <= np.maximum(5.0, 6.0 - brake * ts) * 1.09)
    closed = ts >= (6.0 - 5.0) / brake
    assert speed_h[closed].max() <= 5.0 * 1.09 and vel[ts >= 0.5 / brake, 2].max() <= 2.5 * 1.01
    assert np.linalg.norm(r.acc, axis=1).max() <= LIMITS.max_accel * 1.01
    # Flown tick after tick from where each result takes it: solved every tick, within
    # every limit once the envelope has closed, and back on its path.
    ctrl, cur, t = MpcController(1, CFG), r, 0.0
    ctrl.solve(request(1, 0.0, (0.0, 1.0, 10.0), (4.8, 3.6, 3.0), path))
    for _ in range(60):
        t = round(t + DT, 9)
        p, v, _ = cur.sample(t)
        cur = ctrl.solve(request(1, t, p, v, path))
        assert cur.status == "solved", (t, cur.reason)
        if t >= 1.0 / brake + DT:
            check_limits(cur)
    p, v, _ = cur.sample(t)
    assert np.linalg.norm(p - path(np.array([t]))[0][0]) < 0.1


def test_a_start_outside_the_altitude_band_is_not_the_mpcs_to_fix() -> None:
    # Above max_alt (a gust's updraft): the autopilot's fence is in charge; the MPC says
    # why it gives nothing and keeps the path, which is no worse than now.
    high = replace(LIMITS, max_alt=9.0)
    path = line((0.0, 0.0, 8.5), (3.0, 0.0, 0.0))
    r = MpcController(1, CFG).solve(request(1, 0.0, (0.0, 0.0, 9.5), (3.0, 0.0, 0.0), path,
                                       limits=high))
    assert r.status == "path"
    assert r.reason.startswith("start state: altitude 9.50 m outside [2.0, 9.0] m")


def test_a_neighbour_closing_too_fast_leaves_an_unsafe_stop() -> None:
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    # Head-on at 10 m/s closing, 4 m away: nothing within 3 m/s^2 can avoid it.
    ram = line((4.0, 0.0, 10.0), (-7.0, 0.0, 0.0))
    r = MpcController(1, CFG).solve(request(1, 0.0, (0.0, 0.0, 10.0), (3.0, 0.0, 0.0), path,
                                       [ram], [9]))
    assert r.status == "unsafe"
    assert "separation slack" in r.reason and "the stop is unsafe too" in r.reason
    assert "vehicle 9" in r.reason


def test_a_dodge_that_needs_a_little_more_speed_is_flown_as_an_escape() -> None:
    # Hovering, speed limit 1 m/s; a neighbour closes at 4 m/s from 5 m, 0.3 m off the
    # line.  Keeping 1.5 m needs about 1.2 m/s sideways: no correction keeps every
    # limit, the escape (speeds up to 20 % over) keeps the separation.
    from dataclasses import replace

    from groundctl.execute.mpc import ESCAPE_SPEED_MARGIN, MPC_OSQP_SETTINGS

    limits = replace(LIMITS, max_speed_h=1.0)
    hover = line((0.0, 0.0, 10.0), (0.0, 0.0, 0.0))
    ram = line((5.0, 0.3, 10.0), (-4.0, 0.0, 0.0))
    # Six QPs: without OSQP's per-pass wall-time cap, so that a busy machine cannot
    # turn the escape into a stop (the cap is the flight's, not the geometry's).
    untimed = MpcConfig(osqp_settings={k: v for k, v in MPC_OSQP_SETTINGS.items()
                                       if k != "time_limit"})
    ctrl = MpcController(1, untimed)
    r = ctrl.solve(request(1, 0.0, (0.0, 0.0, 10.0), (0.0, 0.0, 0.0), hover, [ram], [9],
                           limits=limits))
    assert r.status == "fallback", r.reason
    assert "best escape found keeps" in r.reason and "its path 0.30 m" in r.reason
    check_limits(r, replace(limits, max_speed_h=1.0 + ESCAPE_SPEED_MARGIN))
    speed = np.linalg.norm(r.vel[:, :2], axis=1).max()
    assert 1.01 < speed <= 1.2 * 1.01  # it did need the margin, and no more
    ts = np.linspace(0.0, r.end, 601)
    gap = np.linalg.norm(r.sample(ts)[0] - ram(ts)[0], axis=1)
    assert gap.min() >= 1.5 - 1e-3
    # Flown at its escape speed, the next tick goes on with the escape's raised limits
    # (not a "start state over max_speed_h" stop after one tick), and no higher.
    # Flown tick after tick from where it is told to be, it goes on at up to its escape
    # speed (never a "start state over max_speed_h" stop) until it is back within its
    # own limits, and keeps the neighbour at the limit all along.
    cur, t = r, 0.0
    for _ in range(12):
        t += 0.1
        p, v, _ = cur.sample(t)
        cur = ctrl.solve(request(1, t, p, v, hover, [ram], [9], limits=limits))
        assert "start state" not in cur.reason, (t, cur.reason)
        assert cur.status in ("solved", "fallback"), cur.reason
        check_limits(cur, replace(limits, max_speed_h=1.0 + ESCAPE_SPEED_MARGIN))
        ts = np.linspace(t, cur.end, 301)
        assert np.linalg.norm(cur.sample(ts)[0] - ram(ts)[0], axis=1).min() >= 1.5 - 1e-3


def test_warm_start_cuts_the_iterations() -> None:
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    others = [line((0.0, dy, 10.0 + dz), (3.0, 0.0, 0.0)) for dy, dz in
              ((4, 0), (-4, 0), (0, 4), (0, -4))]
    ctrl = MpcController(1, CFG)
    first = ctrl.solve(request(1, 0.0, (0.0, 2.0, 11.0), (3.0, 0.0, 0.0), path, others))
    p, v, _ = first.sample(DT)
    second = ctrl.solve(request(1, DT, p, v, path, others))
    assert first.status == second.status == "solved"
    assert second.iterations < 0.5 * first.iterations
    ctrl.reset()
    cold = ctrl.solve(request(1, DT, p, v, path, others))
    assert cold.iterations > second.iterations


def test_the_qp_is_built_once_whatever_the_neighbour_count() -> None:
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    ctrl = MpcController(1, CFG)
    solver, shape, nnz = ctrl.solver, ctrl._pattern.matrix.shape, ctrl._pattern.matrix.nnz
    t, p, v = 0.0, np.array([0.0, 1.0, 10.0]), np.array([3.0, 0.0, 0.0])
    rng = np.random.default_rng(3)
    for count in (0, 1, 8, 3, 12, 0, 5):  # 12 > 8 slots: the nearest 8 get rows
        angles = rng.uniform(0, 2 * np.pi, count)
        others = [line((3.0 * np.cos(a), 3.0 * np.sin(a), 10.0 + rng.uniform(-1, 1)),
                       (3.0, 0.0, 0.0)) for a in angles]
        r = ctrl.solve(request(1, t, p, v, path, others, list(range(10, 10 + count))))
        assert r.status == "solved", r.reason
        assert r.neighbours_used == min(count, CFG.max_neighbours)
        assert ctrl.solver is solver
        assert ctrl._pattern.matrix.shape == shape and ctrl._pattern.matrix.nnz == nnz
        t += DT
        p, v, _ = r.sample(t)


def test_head_on_replanning_in_priority_keeps_separation() -> None:
    # Paths pass 2 m apart; both vehicles have drifted 1 m towards each other, so
    # flying straight on they would meet head-on.
    paths = {1: line((-8.0, 1.0, 10.0), (3.0, 0.0, 0.0)),
             2: line((8.0, -1.0, 10.0), (-3.0, 0.0, 0.0))}
    state = {1: (np.array([-8.0, 0.0, 10.0]), np.array([3.0, 0.0, 0.0])),
             2: (np.array([8.0, 0.0, 10.0]), np.array([-3.0, 0.0, 0.0]))}
    ctrls = {s: MpcController(s, CFG) for s in paths}
    last: dict[int, MpcResult] = {}
    t, worst = 0.0, np.inf
    times_of = lambda t0: t0 + DT * np.arange(N + 1)  # noqa: E731
    for _ in range(45):
        reqs = []
        for s, other in ((1, 2), (2, 1)):
            if other in last:  # the other's own MPC output ...
                pred = last[other].sample(times_of(t))[0]
            else:  # ... or its path shifted by its current error
                err = state[other][0] - paths[other](np.array(t))[0]
                pred = paths[other](times_of(t))[0] + err
            rp, rv, ra = paths[s](times_of(t))
            reqs.append(MpcRequest(s, t, *state[s], rp, rv, ra, LIMITS, pred[None],
                                   np.array([other])))
        last = solve_in_priority(ctrls, reqs)
        # The later vehicle was verified against the earlier one's fresh result.
        assert last[2].status != "solved" or last[2].min_separation >= LIMITS.min_separation - 1e-3
        ts = np.linspace(t, t + DT, 51)
        worst = min(worst, np.linalg.norm(last[1].sample(ts)[0] - last[2].sample(ts)[0],
                                          axis=1).min())
        t += DT
        for s in paths:
            p, v, _ = last[s].sample(t)
            state[s] = (p, v)
    assert worst >= LIMITS.min_separation - 1e-3
    for s in paths:  # both back on their paths once past each other
        assert np.linalg.norm(state[s][0] - paths[s](np.array(t))[0]) < 0.3


def test_a_convex_geofence_is_kept() -> None:
    fence = ((-50.0, -50.0), (50.0, -50.0), (50.0, 1.5), (-50.0, 1.5))  # edge at y = 1.5
    limits = Limits(geofence=fence)
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    # 1 m from the fence edge and drifting towards it at 1.5 m/s.
    r = MpcController(1, CFG).solve(request(1, 0.0, (0.0, 0.5, 10.0), (3.0, 1.5, 0.0), path,
                                       limits=limits))
    assert r.status == "solved", r.reason
    ts = np.linspace(r.t0, r.end, 1001)
    assert r.sample(ts)[0][:, 1].max() < 1.5
    assert convex_fence(fence) is not None
    star = tuple((float(np.cos(a)), float(np.sin(a))) for a in np.arange(5) * 4 * np.pi / 5)
    assert convex_fence(star) is None  # a pentagram turns one way, but twice round
    notch = ((0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (2.0, 1.0), (0.0, 4.0))
    assert convex_fence(notch) is None


def test_sample_holds_the_final_velocity_past_the_horizon() -> None:
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    r = MpcController(1, CFG).solve(request(1, 5.0, path(np.array(5.0))[0], (3.0, 0.0, 0.0), path))
    p, v, a = r.sample(r.end + 1.0)
    assert np.allclose(v, r.vel[-1]) and np.allclose(a, 0.0)
    assert np.allclose(p, r.pos[-1] + r.vel[-1])
    p, v, a = r.sample(r.t0 - 1.0)
    assert np.allclose(p, r.pos[0]) and np.allclose(v, r.vel[0])
    pos, _, _ = r.sample(r.times)
    assert np.allclose(pos, r.pos)


def test_brake_trajectory_stops_within_the_limits() -> None:
    pos, vel, acc = brake_trajectory((0.0, 0.0, 10.0), (4.0, 0.0, -1.0), DT, N, 3.0)
    assert np.allclose(vel[-1], 0.0)
    assert np.linalg.norm(acc, axis=1).max() <= 3.0 + 1e-9
    speed = np.linalg.norm(vel, axis=1)
    assert np.all(np.diff(speed) <= 1e-12)
    check = verify(pos, vel, acc, DT, LIMITS)
    assert check.ok and check.min_separation == np.inf


@pytest.mark.parametrize(("change", "needle"), [
    ({"p0": (0.0, np.nan, 10.0)}, "`p0` must be finite"),
    ({"v0": (1.0, 2.0)}, "`v0` must have shape (3,), got (2,)"),
    ({"ref_pos": np.zeros((N + 1, 2))}, "`ref_pos` must have shape (*, 3)"),
    ({"ref_vel": np.zeros((N, 3))}, f"`ref_vel` must have shape ({N + 1}, 3)"),
    ({"neighbours": np.zeros((2, N, 3))}, f"`neighbours` must have shape (*, {N + 1}, 3)"),
    ({"neighbours": np.zeros((2, N + 1, 3)), "neighbour_ids": np.array([1])},
     "`neighbour_ids` must be (2,) integers"),
    ({"neighbours": np.zeros((2, N + 1, 3))}, "`neighbour_ids` must be given with"),
    ({"neighbours": np.zeros((2, N + 1, 3)), "neighbour_ids": np.array([4, 4])},
     "`neighbour_ids` must not repeat a vehicle"),
    ({"a0": (0.0, 0.0, np.inf)}, "`a0` must be finite"),
])
def test_bad_inputs_name_the_argument(change: dict, needle: str) -> None:
    t = DT * np.arange(N + 1)
    rp, rv, ra = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))(t)
    args = {"sysid": 1, "t0": 0.0, "p0": (0.0, 0.0, 10.0), "v0": (3.0, 0.0, 0.0),
            "ref_pos": rp, "ref_vel": rv, "ref_acc": ra, "limits": LIMITS}
    args.update(change)
    with pytest.raises(ValueError) as info:
        MpcRequest(**args)
    assert needle in str(info.value)


def test_a_request_that_does_not_fit_the_controller_is_refused() -> None:
    t = DT * np.arange(21)
    rp, rv, ra = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))(t)
    req = MpcRequest(1, 0.0, rp[0], rv[0], rp, rv, ra, LIMITS)
    with pytest.raises(ValueError, match="`ref_pos` holds 21 samples but the controller plans "
                                         "30 steps"):
        MpcController(1, CFG).solve(req)
    with pytest.raises(ValueError, match=r"`request.sysid` is 1"):
        MpcController(2, MpcConfig(steps=20)).solve(req)


def test_a_neighbour_without_a_slot_is_still_verified() -> None:
    # No slots at all: the QP flies straight through the neighbour, the verifier refuses.
    ctrl = MpcController(1, replace(CFG, max_neighbours=0, passes=1))
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    r = ctrl.solve(request(1, 0.0, (0.0, 0.0, 10.0), (3.0, 0.0, 0.0), path,
                           [line((6.0, 0.0, 10.0), (0.0, 0.0, 0.0))], [5]))
    assert r.status == "fallback"
    assert r.reason.startswith("verification after 1 passes: separation from vehicle 5 ")
    assert r.neighbours_used == 0 and r.min_separation >= LIMITS.min_separation


def test_fresh_neighbours_are_given_relative_to_the_requests_own_deviation() -> None:
    """A vehicle replanned from its reference flies it offset by its own deviation: the
    fresh result of an earlier vehicle replaces that one's prediction as its result
    plus its own deviation, minus this vehicle's, like every other neighbour."""
    from groundctl.execute.mpc import with_predictions

    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    other = line((0.0, 4.0, 10.0), (3.0, 0.0, 0.0))
    mine = np.tile([0.0, 0.3, 0.0], (N + 1, 1))
    theirs = np.tile([0.0, -0.2, 0.0], (N + 1, 1))
    ahead = MpcController(2, CFG).solve(request(2, 0.0, (0.0, 4.0, 10.0), (3.0, 0.0, 0.0), other))
    req = request(5, 0.0, (0.0, 0.0, 10.0), (3.0, 0.0, 0.0), path, [other], [2], own=mine)
    got = with_predictions(req, {2: ahead}, DT, {2: theirs, 5: mine})
    expect = ahead.sample(req.t0 + DT * np.arange(N + 1))[0] + theirs - mine
    assert np.allclose(got.others[0], expect)
    plain = with_predictions(request(5, 0.0, (0.0, 0.0, 10.0), (3.0, 0.0, 0.0), path,
                                     [other], [2]), {2: ahead}, DT)
    assert np.allclose(plain.others[0], ahead.sample(req.t0 + DT * np.arange(N + 1))[0])


def test_a_weak_vehicle_measured_above_its_limits_is_flown_back_within_them() -> None:
    """A weak vehicle's QP tracks its re-timed path; measured faster than its own
    (smaller) limits, it is flown back within them, never given its plan (3 m/s: more
    than it can fly)."""
    from dataclasses import replace

    weak = replace(LIMITS, max_speed_h=2.0)
    path = line((0.0, 0.0, 10.0), (3.0, 0.0, 0.0))
    ahead = path(0.25 * np.arange(81))[0]
    r = MpcController(1, CFG).solve(request(1, 0.0, (0.0, 0.0, 10.0), (2.5, 0.0, 0.0), path,
                                       limits=weak, lookahead=ahead))
    assert r.status == "solved", r.reason
    assert r.reason.startswith("start state: horizontal speed 2.50 m/s")
    assert verify(r.pos, r.vel, r.acc, DT, weak, brake=CFG.envelope_brake * weak.max_accel).ok
    brake = CFG.envelope_brake * weak.max_accel
    closed = r.times >= 0.5 / brake + DT
    assert np.linalg.norm(r.vel[closed, :2], axis=1).max() <= 2.0 * 1.01


def test_a_weak_vehicle_stops_leading_its_path_when_the_path_ahead_stands_still(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The re-timed reference sets off before the path does; when the path's future
    changes (the show clock holds, a return replaces the path) it is re-timed at once,
    not flown on for ``RETIME_EVERY_S`` towards where the path would have gone."""
    from groundctl.execute import retime

    # Its 50 ms wall-clock limit is for the flight's tick; here the first re-timing must
    # be solved on a busy machine too, or there is no lead to stop.
    monkeypatch.setitem(retime.RETIME_OSQP, "time_limit", 10.0)
    weak = replace(LIMITS, max_speed_down=0.9)

    def descends_at_5(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        z = 10.0 - 1.5 * np.clip(t - 5.0, 0.0, 6.0)  # 1.5 m/s from t = 5 s: too fast
        vz = np.where((t > 5.0) & (t < 11.0), -1.5, 0.0)
        pos = np.stack([np.zeros_like(t), np.zeros_like(t), z], axis=-1)
        vel = np.stack([np.zeros_like(t), np.zeros_like(t), vz], axis=-1)
        return pos, vel, np.zeros_like(pos)

    def hover(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pos = np.broadcast_to((0.0, 0.0, 10.0), (*np.shape(t), 3)).copy()
        return pos, np.zeros_like(pos), np.zeros_like(pos)

    ctrl = MpcController(1, CFG)
    ahead = descends_at_5(0.25 * np.arange(81))[0]
    first = ctrl.solve(request(1, 0.0, (0.0, 0.0, 10.0), (0.0, 0.0, 0.0), descends_at_5,
                               limits=weak, lookahead=ahead))
    assert first.status == "solved", first.reason
    assert first.sample(np.array([3.0]))[0][0, 2] < 9.95  # it sets off early
    # 0.9 s on (within RETIME_EVERY_S) the show holds: the path ahead stands still.
    p, v, _ = first.sample(np.array([0.9]))
    held = ctrl.solve(request(1, 0.9, p[0], v[0], hover, limits=weak,
                              lookahead=hover(0.9 + 0.25 * np.arange(81))[0]))
    assert held.status == "solved", held.reason
    z = held.sample(np.linspace(2.4, 3.9, 7))[0][:, 2]
    # Back to its path, no longer leading down (the old reference: 9.2 m at 3.9 s).
    assert np.all(z > 9.9), z


def test_the_verifier_holds_an_over_speed_start_to_its_envelope_even_when_recovering() -> None:
    """``baseline`` ("no worse than now", a vehicle inside a neighbour's separation) does
    not let a start above a speed limit fly on at that speed: the envelope closes."""
    acc = np.zeros((N, 3))
    pos, vel = (np.stack([6.0 * DT * np.arange(N + 1), np.zeros(N + 1),
                          np.full(N + 1, 10.0)], axis=1),
                np.tile([6.0, 0.0, 0.0], (N + 1, 1)))
    brake = CFG.envelope_brake * LIMITS.max_accel
    assert verify(pos, vel, acc, DT, LIMITS, baseline=True).ok  # the old reading
    check = verify(pos, vel, acc, DT, LIMITS, baseline=True, brake=brake)
    assert not check.ok
    assert "closing from 6.00 m/s" in check.violations[0]
