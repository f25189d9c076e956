"""Matching vehicles to plan tracks: automatic by nearest slot, or from the fleet file."""

from __future__ import annotations

import numpy as np
import pytest
from test_execute_support import HOME

from groundctl.execute.mapping import auto_assign, explicit_assign


def test_vehicles_are_matched_to_the_slot_they_stand_on() -> None:
    positions = {7: [6.2, 0.1, 0.4], 3: [0.3, -0.2, 0.0], 5: [2.9, 0.0, -1.5]}
    a = auto_assign(HOME, positions)
    assert a.tracks == {3: 0, 5: 1, 7: 2}
    assert a.distances[5] == pytest.approx(0.1)  # altitude ignored: GPS altitude wanders
    assert a.refused == {} and a.unassigned_tracks == () and a.extra_vehicles == ()
    assert a.problems() == []


def test_a_vehicle_off_every_slot_is_refused_with_its_distance() -> None:
    positions = {1: [0.0, 0.0, 0.0], 2: [3.0, 0.0, 0.0], 7: [6.0, 4.2, 0.0]}
    a = auto_assign(HOME, positions)
    assert a.tracks == {1: 0, 2: 1}
    assert a.refused == {
        7: "vehicle 7 is 4.2 m from the nearest takeoff slot (tolerance 3.0 m)"}
    assert a.unassigned_tracks == (2,)
    assert a.problems() == [
        "vehicle 7 is 4.2 m from the nearest takeoff slot (tolerance 3.0 m)",
        "no vehicle for track(s) 2"]


def test_extra_vehicles_and_missing_positions_are_reported() -> None:
    positions = {1: [0.1, 0.0, 0.0], 2: [0.0, 0.2, 0.0], 3: [3.0, 0.0, 0.0],
                 4: [6.0, 0.0, 0.0], 9: None}
    a = auto_assign(HOME, positions, tolerance_m=0.5)
    assert a.tracks == {1: 0, 3: 1, 4: 2}
    assert a.extra_vehicles == (2,)
    assert a.refused == {9: "vehicle 9 has no position estimate"}


def test_two_vehicles_on_one_slot_refuse_the_one_whose_free_slot_is_too_far() -> None:
    home = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    a = auto_assign(home, {1: [0.0, 0.0, 0.0], 2: [0.5, 0.0, 0.0]}, tolerance_m=3.0)
    assert a.tracks == {1: 0}
    assert a.extra_vehicles == ()
    assert a.refused == {2: "vehicle 2: its nearest takeoff slot is taken; the free one "
                            "(track 1) is 9.5 m away (tolerance 3.0 m)"}


def test_explicit_table_is_checked_against_positions() -> None:
    positions = {10: [0.0, 0.0, 0.0], 11: [3.0, 3.5, 0.0], 12: [6.0, 0.0, 0.0]}
    a = explicit_assign({10: 0, 11: 1, 13: 2}, HOME, positions)
    assert a.tracks == {10: 0}
    assert a.refused == {
        11: "vehicle 11 is 3.5 m from its takeoff slot (track 1, tolerance 3.0 m)",
        13: "vehicle 13 (track 2) has not been heard from"}
    assert a.extra_vehicles == (12,)
    assert a.unassigned_tracks == (1, 2)


def test_explicit_table_errors_name_the_parameter() -> None:
    with pytest.raises(ValueError, match=r"`assignments`: vehicle 4 -> track 5, but the plan "
                                         r"has tracks 0\.\.2"):
        explicit_assign({4: 5}, HOME, {})
    with pytest.raises(ValueError, match="track 1 is given to both vehicle 1 and vehicle 2"):
        explicit_assign({1: 1, 2: 1}, HOME, {})
    with pytest.raises(ValueError, match="`tolerance_m` must be positive"):
        auto_assign(HOME, {}, tolerance_m=0.0)
