"""The per-vehicle lead: a simulated vehicle with a known response delay, on a float clock.

The vehicle is where the setpoint it received ``delay`` seconds ago put it:
``p(t) = plan(t - delay + L(t - delay))``, plus a steady offset (wind, GPS
bias) and seeded noise.  The estimator only sees what the runner sees:
measured minus planned position at the show clock, and the planned velocity.
"""

from __future__ import annotations

import numpy as np
import pytest

from groundctl.execute.lead import LateWatch, LeadConfig, LeadEstimator, late_vehicles

RATE = 10.0


def plan_pos(t: np.ndarray | float) -> np.ndarray:
    """A show-like path: 4 m sweeps east-west, 2 m north-south, speeds up to ~2.5 m/s."""
    t = np.asarray(t, dtype=float)
    return np.stack([4.0 * np.sin(0.6 * t), 2.0 * np.sin(0.35 * t + 1.0),
                     10.0 + 0.5 * np.sin(0.2 * t)], axis=-1)


def plan_vel(t: np.ndarray | float) -> np.ndarray:
    t = np.asarray(t, dtype=float)
    return np.stack([2.4 * np.cos(0.6 * t), 0.7 * np.cos(0.35 * t + 1.0),
                     0.1 * np.cos(0.2 * t)], axis=-1)


def fly(delays: list[float], seconds: float, seed: int = 0, offset=(0.3, -0.2, 0.05),
        noise_m: float = 0.02, config: LeadConfig | None = None
        ) -> tuple[LeadEstimator, list[np.ndarray]]:
    """Fly vehicles with the given response delays; returns the estimator and lead history."""
    rng = np.random.default_rng(seed)
    ids = list(range(1, len(delays) + 1))
    est = LeadEstimator(ids, config)
    history: list[np.ndarray] = []  # leads in use at each tick (what each setpoint used)
    d = np.array(delays)
    for k in range(int(seconds * RATE)):
        t = k / RATE
        history.append(est.leads.copy())
        # The lead in use when the setpoint now being flown was sent.
        lead_then = np.array([history[max(0, k - round(x * RATE))][i]
                              for i, x in enumerate(d)]) if k else est.leads.copy()
        here = np.array([plan_pos(t - x + lead_then[i]) for i, x in enumerate(d)])
        here += np.asarray(offset) + rng.normal(0.0, noise_m, here.shape)
        est.observe(t, ids, here - plan_pos(t)[None, :], np.repeat(plan_vel(t)[None], len(d), 0))
        est.update(1.0 / RATE, {})
    return est, history


@pytest.mark.parametrize("delay", [0.01, 0.05, 0.2, 0.35])
def test_the_lead_converges_on_the_vehicles_own_delay(delay: float) -> None:
    """From the initial lead: early vehicles (delay below it) and late ones (above)."""
    est, _ = fly([delay], 40.0)
    e = est.estimate(1)
    assert e.response_s == pytest.approx(delay, abs=0.01)
    assert est.lead(1) == pytest.approx(delay, abs=0.01)


def test_each_vehicle_gets_its_own_lead_and_the_offset_is_not_mistaken_for_timing() -> None:
    est, _ = fly([0.02, 0.15, 0.3], 40.0, offset=(1.0, 0.5, 0.0))
    assert est.leads == pytest.approx([0.02, 0.15, 0.3], abs=0.012)


def test_the_lead_moves_at_a_bounded_rate_and_stays_within_its_limits() -> None:
    cfg = LeadConfig(max_s=0.25)
    est, history = fly([0.5], 30.0, config=cfg)
    steps = np.abs(np.diff(np.array(history)[:, 0]))
    assert steps.max() <= cfg.slew_s_per_s / RATE + 1e-12
    assert est.lead(1) == pytest.approx(0.25)  # capped: this vehicle is too slow


def test_no_motion_no_change_and_the_link_delay_is_a_floor() -> None:
    est = LeadEstimator([1, 2])
    for k in range(50):  # hovering: nothing to learn from
        est.observe(k / RATE, [1, 2], np.zeros((2, 3)), np.zeros((2, 3)))
        est.update(1.0 / RATE, {1: None, 2: 0.3})
    assert est.estimate(1).response_s is None
    assert est.lead(1) == pytest.approx(LeadConfig().initial_s)
    assert est.lead(2) == pytest.approx(0.3)  # a setpoint cannot act before it arrives


def test_bad_samples_are_ignored_and_bad_arguments_refused() -> None:
    est = LeadEstimator([1])
    est.observe(0.0, [1, 9], [[5.0, 0, 0], [0, 0, 0]], [[2.0, 0, 0], [2.0, 0, 0]])
    est.observe(0.1, [1], [[np.nan, 0, 0]], [[2.0, 0, 0]])
    assert est.estimate(1).samples == 0  # too far off, unknown vehicle, not finite
    with pytest.raises(ValueError, match="one row per system id"):
        est.observe(0.2, [1], np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="`initial_s`"):
        LeadConfig(initial_s=1.0, max_s=0.5)


def test_late_is_judged_on_the_lead_in_use_and_clears() -> None:
    late: set[int] = set()
    newly, cleared = late_vehicles({1: 0.1, 2: 0.1}, {1: 0.2, 2: 0.05}, late)
    assert newly == {1} and cleared == set()
    late |= newly
    newly, cleared = late_vehicles({1: 0.25, 2: 0.1}, {1: 0.2, 2: None}, late)
    assert newly == set() and cleared == {1}


def test_a_vehicle_is_flagged_late_only_when_late_on_two_checks_in_a_row() -> None:
    watch = LateWatch()
    leads = {1: 0.1, 2: 0.1}
    late: set[int] = set()
    assert watch.check(leads, {1: 0.2, 2: 0.05}, late) == (set(), set())  # suspected
    assert watch.check(leads, {1: 0.05, 2: 0.2}, late) == (set(), set())  # 1 forgiven
    assert watch.check(leads, {1: 0.2, 2: 0.2}, late) == ({2}, set())  # 2 twice running
    late = {2}
    assert watch.check(leads, {1: 0.2, 2: 0.1}, late) == ({1}, {2})  # 1 twice running


def test_gusting_wind_does_not_move_the_lead() -> None:
    """Errors of 0.3 m that wander for seconds (a gusting wind, not timing): the estimate's
    standard error stays large, and the lead stays where it was."""
    rng = np.random.default_rng(7)
    est = LeadEstimator([1])
    gust = np.zeros(3)
    for k in range(600):
        t = k / RATE
        gust += -gust * 0.05 + 0.3 * np.sqrt(0.1) * rng.standard_normal(3)  # OU, tau 2 s
        here = plan_pos(t - 0.05 + est.lead(1)) + gust
        est.observe(t, [1], (here - plan_pos(t))[None], plan_vel(t)[None])
        est.update(1.0 / RATE, {})
        assert abs(est.lead(1) - LeadConfig().initial_s) < 0.02
    se = est.estimate(1).stderr_s
    assert se is not None and se > LeadConfig().max_stderr_s
