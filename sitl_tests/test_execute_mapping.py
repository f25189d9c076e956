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


# -- spares: the vehicles on the plan's spare pads (issue 29) ---------------------------
#: Two spare pads: one a takeoff spacing beside the grid's end (within the slot tolerance
#: of slot 2, as laid-out pads are), one behind the grid.
PADS = np.array([[9.0, 0.0, 0.0], [3.0, 6.0, 0.0]])


def test_vehicles_on_spare_pads_stand_by_as_spares() -> None:
    positions = {1: HOME[0], 2: HOME[1], 3: HOME[2], 8: [9.1, 0.0, 0.3], 7: [3.0, 5.8, 0.0]}
    a = auto_assign(HOME, positions, pads=PADS)
    assert a.tracks == {1: 0, 2: 1, 3: 2}
    assert a.spares == {8: 0, 7: 1}
    assert a.distances[8] == pytest.approx(0.1) and a.distances[7] == pytest.approx(0.2)
    assert a.heights[8] == pytest.approx(0.3)
    assert a.refused == {} and a.extra_vehicles == () and a.problems() == []


def test_a_spare_never_takes_the_free_slot_of_a_show_drone_not_yet_located() -> None:
    positions = {1: HOME[0], 2: HOME[1], 3: None, 8: [8.9, 0.0, 0.0]}
    # Without pads, vehicle 8 stands 2.9 m from slot 2: within the tolerance, it is given
    # track 2 (and would fly it from the pad) ...
    assert auto_assign(HOME, positions).tracks == {1: 0, 2: 1, 8: 2}
    # ... with them it is the pad's spare, nearer it than every slot: track 2 waits for
    # vehicle 3's position.
    a = auto_assign(HOME, positions, pads=PADS)
    assert a.tracks == {1: 0, 2: 1} and a.spares == {8: 0}
    assert a.unassigned_tracks == (2,)
    assert a.refused == {3: "vehicle 3 has no position estimate"}


def test_a_vehicle_off_every_slot_and_pad_is_still_refused() -> None:
    positions = {1: HOME[0], 2: HOME[1], 3: HOME[2], 9: [3.0, -9.0, 0.0],
                 7: [3.0, 6.0, 0.0], 8: [3.2, 6.0, 0.0]}
    a = auto_assign(HOME, positions, pads=PADS)
    assert a.tracks == {1: 0, 2: 1, 3: 2} and a.spares == {7: 1}
    assert a.refused == {
        8: "vehicle 8: its nearest spare pad is taken",
        9: "vehicle 9 is 9.0 m from the nearest takeoff slot and 10.8 m from the nearest "
           "spare pad (tolerance 3.0 m)"}


def test_a_vehicle_left_over_on_the_grid_stands_by_on_a_pad_within_the_tolerance() -> None:
    # Vehicle 4 stands between slot 2 and pad 0, nearer the slot: a candidate for it, left
    # over once vehicle 3 has it, and within the tolerance of the pad.
    positions = {1: HOME[0], 2: HOME[1], 3: HOME[2], 4: [7.4, 0.0, 0.0]}
    a = auto_assign(HOME, positions, pads=PADS)
    assert a.tracks == {1: 0, 2: 1, 3: 2} and a.spares == {4: 0}
    assert a.extra_vehicles == () and a.refused == {}
    assert auto_assign(HOME, positions).extra_vehicles == (4,)  # no pads: extra


def test_marked_spares_are_matched_to_the_nearest_free_pads() -> None:
    positions = {10: HOME[0], 11: HOME[1], 12: HOME[2], 20: [3.0, 6.1, 0.0],
                 21: [13.0, 0.0, 0.0], 23: None, 30: [0.0, 9.0, 0.0]}
    a = explicit_assign({10: 0, 11: 1, 12: 2}, HOME, positions, pads=PADS,
                        spares={20, 21, 22, 23})
    assert a.tracks == {10: 0, 11: 1, 12: 2}
    # Vehicle 21 is off its pad: a spare all the same, its slot check says how far.
    assert a.spares == {20: 1, 21: 0}
    assert a.distances[21] == pytest.approx(4.0)
    # 22 was not heard: a spare fewer, no failure; 30 is not in the fleet file's table.
    assert a.refused == {23: "vehicle 23 (a spare) has no position estimate"}
    assert a.extra_vehicles == (30,)
    # A marked spare never takes a slot, not even one it stands on.
    b = auto_assign(HOME, {1: HOME[0], 2: HOME[1], 8: HOME[2]}, pads=PADS, spares={8})
    assert b.tracks == {1: 0, 2: 1} and b.spares == {8: 0} and b.unassigned_tracks == (2,)
    # Without pads in the plan, marked spares are extra: they stay on the ground.
    c = explicit_assign({10: 0}, HOME, {10: HOME[0], 20: HOME[1]}, spares={20})
    assert c.spares == {} and c.extra_vehicles == (20,)
    with pytest.raises(ValueError, match="`spares`: vehicle 11 is marked a spare but also "
                                         "given track 1"):
        explicit_assign({10: 0, 11: 1}, HOME, {}, pads=PADS, spares={11})
    with pytest.raises(ValueError, match=r"`pads` must have shape \(k, 3\)"):
        auto_assign(HOME, {}, pads=[[0.0, 1.0]])
