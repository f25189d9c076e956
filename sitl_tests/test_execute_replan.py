"""Who is replanned with MPC: triggers, confirmation, release, predicted conflicts."""

from __future__ import annotations

import numpy as np
import pytest

from groundctl.execute.replan import (
    BRUTE_FORCE_VEHICLES,
    ReplanSupervisor,
    predicted_conflicts,
)
from groundctl.show.model import MpcSettings

SETTINGS = MpcSettings(trigger_error_m=0.4, release_error_m=0.15, release_after_s=2.0)


def test_a_deviation_confirmed_on_two_ticks_starts_mpc_and_a_calm_spell_ends_it() -> None:
    sup = ReplanSupervisor(SETTINGS)
    assert sup.tick(0.0, {1: 0.1, 2: 0.9}) == ([], [])  # one late sample is not a deviation
    started, _ = sup.tick(0.1, {1: 0.1, 2: 0.8})
    assert [(a.sysid, a.why) for a in started] == [(2, "0.80 m off its path (trigger 0.40 m)")]
    assert sup.tick(0.2, {1: 0.1, 2: 0.3}) == ([], [])  # better but not back yet
    assert sup.tick(1.0, {1: 0.1, 2: 0.1}) == ([], [])  # calm from here...
    assert sup.tick(2.9, {1: 0.1, 2: 0.12}) == ([], [])
    _, ended = sup.tick(3.0, {1: 0.1, 2: 0.1})  # ... for 2 s: handed back
    assert [(r.sysid, r.after_s) for r in ended] == [(2, pytest.approx(2.9))]
    assert sup.active == {} and sup.activations == 1 and sup.vehicles == {2}


def test_a_calm_flight_activates_nothing() -> None:
    sup = ReplanSupervisor(SETTINGS)
    rng = np.random.default_rng(3)
    for k in range(600):  # a minute at 10 Hz of errors like real ArduCopter's (RMS ~0.1 m)
        errors = {s: float(abs(rng.normal(0.0, 0.1))) for s in range(1, 10)}
        errors = {s: min(e, 0.35) for s, e in errors.items()}
        assert sup.tick(k / 10, errors) == ([], [])
    assert sup.activations == 0


def test_a_predicted_conflict_starts_both_and_losing_eligibility_ends_it() -> None:
    # Two drones 3 m apart on parallel paths; one is 1 m off towards the other, the
    # other 0.8 m off towards it: predicted 1.2 m apart, under the 1.5 m limit.
    t = np.linspace(0.0, 3.0, 7)
    a = np.stack([t, np.zeros_like(t), np.full_like(t, 10.0)], axis=1)
    paths = np.stack([a, a + np.array([0.0, 3.0, 0.0]), a + np.array([0.0, 9.0, 0.0])])
    errors = np.array([[0.0, 1.0, 0.0], [0.0, -0.8, 0.0], [0.0, 0.0, 0.0]])
    conflicts = predicted_conflicts([1, 2, 3], paths, errors, 1.5)
    assert set(conflicts) == {1, 2} and conflicts[1][0] == 2
    assert conflicts[1][1] == pytest.approx(1.2)
    sup = ReplanSupervisor(SETTINGS)
    started, _ = sup.tick(0.0, {1: 1.0, 2: 0.8, 3: 0.0}, conflicts)
    assert [a.sysid for a in started] == [1, 2]
    assert started[0].why == "predicted within 1.20 m of vehicle 2"
    _, ended = sup.tick(0.5, {2: 0.5}, {}, eligible={2})  # 1 landed meanwhile
    assert [r.sysid for r in ended] == [1]
    assert predicted_conflicts([1], paths[:1], errors[:1], 1.5) == {}
    with pytest.raises(ValueError, match="`confirm_ticks`"):
        ReplanSupervisor(SETTINGS, confirm_ticks=0)


@pytest.mark.parametrize("n", [2, 9, BRUTE_FORCE_VEHICLES, BRUTE_FORCE_VEHICLES + 1, 120])
def test_predicted_conflicts_name_each_vehicles_closest_on_either_side_of_the_kd_tree(
        n: int) -> None:
    """Every pair compared on a small fleet, a KD-tree per instant on a large one: each
    vehicle within the limit at some instant, with the other it comes closest to."""
    rng = np.random.default_rng(n)
    paths = rng.uniform(0.0, 1.5 * n ** (1 / 3), (n, 7, 3))
    errors = rng.normal(0.0, 0.3, (n, 7, 3))
    ids = [int(s) for s in rng.permutation(254)[:n] + 1]
    pred = paths + errors
    d = np.linalg.norm(pred[:, None] - pred[None], axis=-1).min(axis=2)
    d[np.diag_indices(n)] = np.inf
    want = {ids[a]: (ids[int(np.argmin(d[a]))], float(d[a].min()))
            for a in range(n) if d[a].min() <= 1.5}
    got = predicted_conflicts(ids, paths, errors, 1.5)
    assert want, "the case should hold some conflicts"
    assert got.keys() == want.keys()
    for s, (other, dist) in want.items():
        assert got[s][0] == other and got[s][1] == pytest.approx(dist, rel=1e-12)
