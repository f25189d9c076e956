"""A weak vehicle seen by its hover throttle, and its path re-timed to what it can fly.

The authority estimator is fed VFR_HUD throttles as a fleet of one airframe
reports them; the re-timing QP runs on real OSQP, flown perfectly along its
result (re-solved every second, as the MPC does) against a path that is faster
than the vehicle for ten seconds.
"""

from __future__ import annotations

import numpy as np
import pytest

from groundctl.execute.authority import AuthorityEstimator, beyond, scaled_limits
from groundctl.execute.retime import RETIME_OSQP, Retimer
from groundctl.show.model import Limits

HOVER = {1: 35.0, 2: 36.0, 3: 34.0, 4: 35.0}


def feed(est: AuthorityEstimator, throttles: dict[int, float], seconds: float = 5.0,
         acc: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
    for k in range(int(seconds * 4)):  # VFR_HUD at 4 Hz
        for sysid, thr in throttles.items():
            est.sample(k * 0.25, sysid, thr, np.array(acc))


def test_a_vehicle_hovering_at_a_higher_throttle_than_its_fleet_is_weak() -> None:
    est = AuthorityEstimator()
    feed(est, {**HOVER, 5: 58.0})
    auth = est.authority()
    assert auth[5] == pytest.approx(35.0 / 58.0, rel=1e-3)
    assert all(auth[s] == 1.0 for s in HOVER)  # a healthy fleet's spread is no weakness


def test_nothing_is_said_before_enough_samples_or_with_too_small_a_fleet() -> None:
    est = AuthorityEstimator()
    feed(est, {1: 35.0, 5: 58.0}, seconds=1.0)
    assert est.authority() == {}  # two vehicles and 4 samples each
    feed(est, {1: 35.0, 2: 35.0, 5: 58.0}, seconds=5.0)
    assert est.authority()[5] < 0.65


def test_throttle_while_the_path_accelerates_is_not_weakness() -> None:
    est = AuthorityEstimator()
    feed(est, {**HOVER, 5: 35.0})
    feed(est, {5: 70.0}, acc=(0.0, 0.0, 2.0))  # a hard climb: ignored
    assert est.authority()[5] == 1.0
    # A gentle climb's extra throttle is scaled by the thrust it needs.
    est2 = AuthorityEstimator()
    feed(est2, {**HOVER, 5: 35.0 * (9.80665 + 0.4) / 9.80665}, acc=(0.0, 0.0, 0.4))
    assert est2.authority()[5] == 1.0


def test_scaled_limits_and_what_a_path_asks_beyond_them() -> None:
    lim = scaled_limits(Limits(max_speed_h=4.0, max_speed_up=2.5, max_speed_down=1.5,
                               max_accel=2.5), 0.6)
    assert (lim.max_speed_h, lim.max_speed_up, lim.max_speed_down, lim.max_accel) == \
        pytest.approx((2.4, 1.5, 0.9, 1.5))
    vel = np.array([[0.0, 0.0, -1.1], [0.0, 0.0, -0.5]])
    assert beyond(lim, vel, np.zeros((2, 3))) == "descent 1.10 m/s (it manages 0.90)"
    assert beyond(lim, vel * 0.5, np.zeros((2, 3))) is None


def _descent(t: np.ndarray) -> np.ndarray:
    """A path that holds, descends at 1.2 m/s for about 10 s (smooth ramps), holds."""
    rate = 1.2 * np.clip(np.minimum((t - 8.0) / 1.0, (19.0 - t) / 1.0), 0.0, 1.0)
    z = 20.0 - np.cumsum(rate) * (t[1] - t[0])
    return np.stack([np.zeros_like(t), np.zeros_like(t), z], axis=1)


def test_retiming_sets_off_early_and_halves_the_largest_error_of_following() -> None:
    lim = Limits(max_speed_h=4.0, max_speed_up=1.5, max_speed_down=0.9, max_accel=1.5)
    fine = np.arange(0.0, 40.0, 0.01)
    path = _descent(fine)

    def at(ts: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(ts, fine, path[:, a]) for a in range(3)], axis=1)

    # Following: chase the path at up to 0.9 m/s down (the best a causal tracker does).
    z, follow = 20.0, []
    for p in path[:, 2]:
        z += max(-0.9 * 0.01, min(1.5 * 0.01, p - z))
        follow.append(abs(p - z))
    # Re-timed: solved every second from where the last one put it, flown perfectly; a
    # solve OSQP does not finish keeps the last reference, as the MPC does.
    # (No wall-time cap in a test: a busy machine must not change the result.)
    untimed = {k: v for k, v in RETIME_OSQP.items() if k != "time_limit"}
    rt, t, p0, v0, errors = Retimer(osqp_settings=untimed), 0.0, at(np.array([0.0]))[0], \
        np.zeros(3), []
    ref, failed = None, 0
    while t < 30.0:
        new = rt.solve(t, at(t + rt.dt * np.arange(rt.steps + 1)), p0, v0, lim)
        failed += new is None
        ref = new or ref
        assert ref is not None
        ts = t + np.arange(0.0, 1.0, 0.05)
        errors += list(np.linalg.norm(ref.sample(ts)[0] - at(ts), axis=1))
        assert -ref.vel[:, 2].min() <= 0.9 + 1e-2  # what it can fly
        p, v, _ = ref.sample(np.array([t + 1.0]))
        t, p0, v0 = t + 1.0, p[0], v[0]
    assert max(errors) <= 0.55 * max(follow)
    assert errors[0] < 1e-6  # starts where it is
    assert failed <= 3


def test_a_path_it_can_fly_is_not_retimed() -> None:
    lim = Limits(max_speed_h=4.0, max_speed_up=1.5, max_speed_down=1.5, max_accel=1.5)
    path = _descent(np.arange(0.0, 20.25, 0.01))[::25][:81]
    ref = Retimer().solve(0.0, path, path[0], np.zeros(3), lim)
    assert ref is not None and np.abs(ref.pos - path).max() < 0.1
