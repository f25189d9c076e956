"""The show-file loader: schema, defaults and every error message (pinned)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from groundctl.errors import EXIT_USAGE, ShowFileError
from groundctl.show.loader import assigned_goals, load_show, parse_show
from groundctl.show.model import QuadrotorModel, UnicycleModel

PATH = "shows/test.toml"


def base(**tables: Any) -> dict[str, Any]:
    """A valid 4-drone quadrotor show; keyword tables replace (or with None, drop) tables."""
    data: dict[str, Any] = {
        "show": {"name": "t", "drones": 4},
        "origin": {"lat": 47.0, "lon": 8.0, "alt": 400.0},
        "formation": [{"shape": "circle", "center": [0, 0, 10], "size": 10,
                       "transition": 20}],
    }
    for key, value in tables.items():
        if value is None:
            data.pop(key, None)
        else:
            data[key] = value
    return copy.deepcopy(data)


def formation(**keys: Any) -> dict[str, Any]:
    """``base()`` with the first formation's keys updated (None drops a key)."""
    data = base()
    f = data["formation"][0]
    for key, value in keys.items():
        if value is None:
            f.pop(key, None)
        else:
            f[key] = value
    return data


def error(data: dict[str, Any], base_dir: Path | str = ".") -> ShowFileError:
    with pytest.raises(ShowFileError) as info:
        parse_show(data, PATH, base_dir)
    return info.value


def unicycle(**extra: Any) -> dict[str, Any]:
    data = base(model={"kind": "unicycle"}, limits={"min_separation": 0.8},
                formation=[{"shape": "circle", "center": [0, 0], "size": 10,
                            "transition": 20}])
    data.update(copy.deepcopy(extra))
    return data


# --- what a valid show turns into -----------------------------------------------------


def test_defaults_fill_everything_not_given():
    show = parse_show(base(), PATH)
    assert show.name == "t" and show.drones == 4 and show.source == PATH
    assert show.takeoff_altitude == 3.0
    assert isinstance(show.model, QuadrotorModel)
    assert show.origin.heading_deg == 0.0
    assert show.limits.min_separation == 1.5 and show.limits.geofence is None
    assert show.planner.steps is None
    # Default takeoff: a grid 3 m apart, ceil(sqrt(4)) = 2 columns, centred at 0.
    np.testing.assert_allclose(show.home, [[-1.5, 1.5, 0], [1.5, 1.5, 0],
                                           [-1.5, -1.5, 0], [1.5, -1.5, 0]])
    np.testing.assert_allclose(show.start_positions[:, 2], 3.0)
    (f,) = show.formations
    assert (f.name, f.shape, f.index, f.transition_s, f.hold_s) == ("circle", "circle", 1, 20, 0)
    assert f.points.shape == (4, 3) and f.colors.shape == (4, 3)
    np.testing.assert_allclose(f.colors, 1.0)  # white
    np.testing.assert_allclose(f.points[:, 1], 0.0)  # vertical: drawn in the x-z plane
    assert show.start_headings is None


def test_every_table_is_read():
    data = base(
        show={"name": "full", "drones": 4, "takeoff_altitude": 4.0},
        origin={"lat": 47.0, "lon": 8.0, "alt": 400.0, "heading": 30.0},
        limits={"max_speed_h": 4, "max_speed_up": 2, "max_speed_down": 1, "max_accel": 2,
                "min_separation": 1.2, "min_altitude": 3, "max_altitude": 50,
                "geofence": [[-50, -50], [50, -50], [50, 50], [-50, 50]]},
        planner={"dt": 0.1, "steps": 50, "max_iterations": 10, "tolerance": 0.01,
                 "pattern_tolerance": 0.2, "alpha": 2.0, "beta": 0.5},
        takeoff={"layout": "grid", "spacing": 2.0, "columns": 4, "center": [5, 5]},
        landing={"transition": 30, "hold": 1.0},
    )
    show = parse_show(data, PATH)
    assert show.origin.heading_deg == 30.0
    assert show.limits.min_alt == 3 and show.limits.max_alt == 50
    assert show.limits.geofence == ((-50, -50), (50, -50), (50, 50), (-50, 50))
    assert show.planner.steps == 50 and show.planner.alpha == 2.0
    np.testing.assert_allclose(show.home[:, 1], 5.0)
    np.testing.assert_allclose(show.home[:, 0], [2, 4, 6, 8])
    landing = show.formations[-1]
    assert (landing.name, landing.shape, landing.index) == ("landing", "home", 2)
    assert (landing.transition_s, landing.hold_s) == (30, 1.0)
    np.testing.assert_allclose(landing.points, show.start_positions)
    np.testing.assert_allclose(landing.colors, 0.0)


def test_formation_keys_place_and_colour_the_shape():
    data = formation(name="ring", plane="horizontal", rotation=90, hold=3,
                     gradient=["#ff0000", "#0000ff"], gradient_axis="v")
    f = parse_show(data, PATH).formations[0]
    assert f.name == "ring" and f.hold_s == 3
    np.testing.assert_allclose(f.points[:, 2], 10.0)
    # The circle's first slot (top, +v) turned 90 degrees ends at -u = -x.
    np.testing.assert_allclose(f.points[0], [-5.0, 0.0, 10.0], atol=1e-9)
    # Colours follow the shape's own axes: the top slot (+v) is the last stop, wherever
    # the rotation took it.
    np.testing.assert_allclose(f.colors[0], [0, 0, 1])


def test_per_point_colours():
    f = parse_show(formation(colors=["red", "#00ff00", [0, 0, 255], "#fff"]), PATH)
    np.testing.assert_allclose(f.formations[0].colors[1], [0, 1, 0])


def test_fixed_count_shapes_may_have_spare_slots():
    show = parse_show(formation(shape="text", text="HI", dot_spacing=1.5, size=None,
                                center=[0, 0, 10]), PATH)
    assert show.formations[0].points.shape == (28, 3)
    assert assigned_goals(show)[0].shape == (4, 3)


def test_grid_shape_variants():
    show = parse_show(formation(shape="grid", rows=2, columns=3, spacing=2, size=None), PATH)
    assert show.formations[0].points.shape == (6, 3)
    show = parse_show(formation(shape="grid", size=6), PATH)  # 2 x 2, size / 1
    assert np.ptp(show.formations[0].points[:, 0]) == pytest.approx(6)


def test_inline_points_2d_and_3d():
    show = parse_show(formation(shape="points", size=None, center=None,
                                points=[[0, 0, 5], [2, 0, 5], [4, 0, 5], [6, 0, 5]]), PATH)
    np.testing.assert_allclose(show.formations[0].points[:, 2], 5)
    show = parse_show(formation(shape="points", size=None, center=[0, 0, 10],
                                points=[[0, 0], [2, 0], [4, 0], [6, 0]]), PATH)
    np.testing.assert_allclose(show.formations[0].points[3], [6, 0, 10])


def test_points_from_a_csv_next_to_the_show(tmp_path):
    (tmp_path / "logo.csv").write_text("x,y,z\n0,0,5\n2,0,5\n4,0,5\n6,0,7\n")
    data = formation(shape="points", size=None, center=None, file="logo.csv")
    show = parse_show(data, str(tmp_path / "s.toml"), tmp_path)
    np.testing.assert_allclose(show.formations[0].points[3], [6, 0, 7])


def test_load_show_reads_a_file(tmp_path):
    path = tmp_path / "mini.toml"
    path.write_text(
        '[show]\ndrones = 4\n[origin]\nlat = 1\nlon = 2\nalt = 3\n'
        '[[formation]]\nshape = "line"\nsize = 9\ncenter = [0, 0, 10]\ntransition = 20\n')
    show = load_show(path)
    assert show.name == "mini" and show.source == str(path)


def test_unicycle_show_is_flat_at_takeoff_altitude_with_headings():
    data = unicycle(takeoff={"layout": "random", "area": [60, 60], "seed": 3,
                             "annulus": [20, 25], "headings": "toward_center"},
                    show={"drones": 4, "takeoff_altitude": 5})
    show = parse_show(data, PATH)
    assert isinstance(show.model, UnicycleModel)
    np.testing.assert_allclose(show.formations[0].points[:, 2], 5.0)
    r = np.linalg.norm(show.home[:, :2], axis=1)
    assert np.all((r >= 20) & (r <= 25))
    # toward_center: each heading points from its home at the formation's centre.
    to_centre = -show.home[:, :2]
    np.testing.assert_allclose(show.start_headings,
                               np.arctan2(to_centre[:, 1], to_centre[:, 0]))
    again = parse_show(data, PATH)
    np.testing.assert_array_equal(again.home, show.home)  # seeded


def test_random_and_listed_headings():
    data = unicycle(takeoff={"layout": "random", "area": [60, 60], "seed": 3,
                             "headings": "random"})
    a = parse_show(data, PATH).start_headings
    assert a is not None and np.all(np.abs(a) <= np.pi)
    np.testing.assert_array_equal(a, parse_show(data, PATH).start_headings)
    data["takeoff"]["headings"] = [0, 90, 180, -90]
    np.testing.assert_allclose(parse_show(data, PATH).start_headings,
                               np.radians([0, 90, 180, -90]))


# --- errors ------------------------------------------------------------------------------


def test_toml_syntax_error_has_line_and_column(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('[show]\ndrones = 4\nname = "x\n')
    with pytest.raises(ShowFileError) as info:
        load_show(path)
    assert info.value.where == "line 3, column 10"
    assert str(info.value).startswith(f"{path}: line 3, column 10: TOML syntax error: ")
    assert info.value.exit_code == EXIT_USAGE


def test_missing_file(tmp_path):
    with pytest.raises(ShowFileError, match="no such file"):
        load_show(tmp_path / "nope.toml")


def test_unknown_key_suggests_the_closest():
    e = error(formation(transtion=20))
    assert str(e) == ("shows/test.toml: formation 1 'circle': unknown key 'transtion'; "
                      "did you mean 'transition'?")


def test_unknown_key_in_limits_and_unknown_table():
    assert str(error(base(limits={"min_seperation": 2}))) == (
        "shows/test.toml: [limits]: unknown key 'min_seperation'; did you mean 'min_separation'?")
    assert str(error(base(formations=[{}]))) == (
        "shows/test.toml: unknown table or key 'formations'; did you mean [[formation]]?")


def test_key_of_another_shape_says_so():
    assert error(formation(arms=5)).message == (
        "'arms' does not apply here: it is a key of shape star")


def test_wrong_type():
    e = error(formation(size="big"))
    assert str(e) == ("shows/test.toml: formation 1 'circle': "
                      "'size' must be a number, got string 'big'")
    assert error(base(show={"drones": 4.5})).message == (
        "'drones' must be an integer, got number 4.5")
    assert error(formation(center=[0, 0])).message == (
        "'center' must be an array of 3 numbers, got array [0, 0]")
    assert error(base(formation={"shape": "circle"})).message == (
        "must be an array of tables: write [[formation]] (double brackets) before each formation")


def test_missing_required_keys():
    assert str(error(formation(transition=None))) == (
        "shows/test.toml: formation 1 'circle': missing required key 'transition'")
    assert error(base(show={"name": "x"})).message == "missing required key 'drones'"
    assert error(formation(size=None)).message == "missing required key 'size'"
    assert error(base(origin=None)).message == "missing required table [origin]"
    assert error(base(formation=None)).message == (
        "no formations; add at least one [[formation]] table")


def test_unknown_shape_suggests_the_closest():
    e = error(formation(shape="cirle"))
    assert e.where == "formation 1"
    assert e.message == ("'shape' must be one of 'grid', 'line', 'circle', 'square', 'star', "
                         "'spiral', 'sphere', 'text', 'points', got 'cirle'; "
                         "did you mean 'circle'?")
    assert error(formation(shape="sqare", name="box")).where == "formation 1 'box'"


def test_fewer_shape_points_than_drones():
    data = formation(shape="text", text="I", size=None)
    data["show"]["drones"] = 12
    data["takeoff"] = {"columns": 4}
    assert str(error(data)) == (
        "shows/test.toml: formation 1 'text': 12 drones but the shape has 11 points")
    assert error(formation(count=3)).message == (
        "'count' 3 is fewer than the 4 drones; remove 'count' or set it to at least 4")


def test_points_closer_than_min_separation_say_how_big_to_make_it():
    # 4 slots on a 1.5 m circle: sqrt(2) * 0.75 = 1.06 m apart.
    e = error(formation(size=1.5))
    assert e.message == ("points are 1.06 m apart but min_separation is 1.5 m; "
                         "increase 'size' to at least 2.2")
    ok = parse_show(formation(size=2.2), PATH)
    assert ok.formations[0].points.shape == (4, 3)
    assert error(formation(shape="text", text="HI", size=None, dot_spacing=1.2)).message == (
        "points are 1.2 m apart but min_separation is 1.5 m; "
        "increase 'dot_spacing' to at least 1.5")
    assert error(formation(shape="points", size=None, points=[[0, 0], [1, 0], [5, 0], [9, 0]])
                 ).message == ("points 1 and 2 are 1.0 m apart but min_separation is 1.5 m; "
                               "move them apart")


def test_formation_outside_the_geofence():
    data = formation(size=30)
    data["limits"] = {"geofence": [[-10, -10], [10, -10], [10, 10], [-10, 10]]}
    assert error(data).message == (
        "point 2 at (15.0, 0.0, 10.0) is outside the geofence (2 of 4 outside)")


def test_formation_outside_the_altitude_limits():
    parse_show(formation(size=16), PATH)  # lowest slot exactly on min_altitude: allowed
    assert error(formation(size=18)).message == (
        "lowest point is at z = 1.0 m, below min_altitude 2.0 m; raise 'center' by at least 1.0 m")
    data = formation(center=[0, 0, 118])
    assert error(data).message == (
        "highest point is at z = 123.0 m, above max_altitude 120.0 m; "
        "lower 'center' by at least 3.0 m")


def test_transition_too_short_names_distance_speed_and_need():
    e = error(formation(center=[20, 0, 10], transition=4))
    assert e.where == "formation 1 'circle'"
    # The slowest drone climbs as it flies across: along its line the horizontal
    # 5 m/s allows 5.14 m/s.
    assert e.message == ("'transition' 4.0 s is too short: a drone must fly 24.7 m "
                         "at <= 5.14 m/s; it needs at least 6.6 s")


def test_transition_too_short_unicycle_and_landing():
    data = unicycle(formation=[{"shape": "circle", "center": [100, 0], "size": 10,
                                "transition": 20}])
    e = error(data)
    assert "at 2.0 m/s (the unicycle's constant speed)" in e.message
    data = base(landing={"transition": 1})
    e = error(data)
    assert e.where == "[landing]"
    assert e.message.startswith("'transition' 1.0 s is too short: a drone must fly ")


def test_transition_time_pinned_example():
    data = base(show={"drones": 1}, formation=[{"shape": "points", "points": [[40, 0, 3]],
                                                "transition": 4}])
    # 40 m at 5 m/s with 3 m/s^2: 40 / 5 + 5 / 3 = 9.67 s -> "at least 9.7 s".
    assert error(data).message == ("'transition' 4.0 s is too short: a drone must fly 40.0 m "
                                   "at <= 5.0 m/s; it needs at least 9.7 s")


@pytest.mark.parametrize(("keys", "message"), [
    ({"color": "#ff88"}, "'color': '#ff88' is not a colour; write '#rrggbb', '#rgb', [r, g, b]"),
    ({"color": [255, 0]}, "'color': [255, 0] is not a colour; [r, g, b] needs three integers"),
    ({"gradient": ["#ff0000"]}, "'gradient' needs at least 2 colours, got 1"),
    ({"gradient": ["#ff0000", "nope"]}, "'gradient': 'nope' is not a colour"),
    ({"colors": ["red"]}, "'colors' has 1 colours but the shape has 4 points"),
    ({"color": "red", "colors": ["red"] * 4}, "give only one of 'color', 'gradient' and"),
    ({"gradient_axis": "u"}, "'gradient_axis' needs 'gradient'"),
    ({"gradient": ["red", "blue"], "gradient_axis": "w"}, "'gradient_axis' must be one of"),
])
def test_bad_colours(keys, message):
    assert error(formation(**keys)).message.startswith(message)


def test_csv_missing_or_malformed(tmp_path):
    data = formation(shape="points", size=None, center=None, file="logo.csv")
    e = error(data, tmp_path)
    assert e.message == f"'file' 'logo.csv' not found (looked for {tmp_path / 'logo.csv'})"
    (tmp_path / "logo.csv").write_text("x,y,z\n0,0,5\n2,zz,5\n")
    # Line and column, never the file's text: the file may not be what it claims to be.
    assert error(data, tmp_path).message == "'file' logo.csv line 3: 'y' is not a number"
    (tmp_path / "logo.csv").write_text("x;y;z\n0;0;5\n")
    assert error(data, tmp_path).message == (
        "'file' logo.csv line 1: the header (the first line) has no column 'x', 'y', 'z'; "
        "it needs 'x,y,z'")


def test_unicycle_rejects_3d_things():
    flat = "the unicycle model flies flat at 'takeoff_altitude' 3.0 m"
    data = unicycle()
    data["formation"][0]["plane"] = "vertical"
    assert error(data).message == (f"'plane' \"vertical\" is not possible: {flat}; "
                                   "use plane = \"horizontal\" (the default for this model)")
    data = unicycle()
    data["formation"][0]["shape"] = "sphere"
    assert error(data).message == f"shape 'sphere' is 3D but {flat}; use a 2D shape"
    data = unicycle()
    data["formation"][0]["center"] = [0, 0, 10]
    assert error(data).message == (f"'center' z 10.0 m is not possible: {flat}; "
                                   "give 'center' as [x, y]")
    data = unicycle()
    data["formation"][0]["hold"] = 2
    assert error(data).message == ("'hold' must be 0 for the unicycle model, got 2.0: "
                                   "it flies at constant speed and cannot hover")


def test_unicycle_points_are_flat_too():
    data = unicycle()
    data["formation"][0] = {"shape": "points", "points": [[0, 0], [2, 0], [4, 0], [6, 0]],
                            "transition": 20}
    np.testing.assert_allclose(parse_show(data, PATH).formations[0].points[:, 2], 3.0)
    data["formation"][0]["points"] = [[0, 0, 3], [2, 0, 3], [4, 0, 3], [6, 0, 9]]
    assert error(data).message == ("point 4 is at z = 9.0 m but the unicycle model flies flat "
                                   "at 'takeoff_altitude' 3.0 m; give points as [x, y]")


def test_model_and_takeoff_errors():
    assert error(base(model={"kind": "quadrotor", "speed": 2})).message == (
        "'speed' does not apply here: it is a key of kind \"unicycle\"")
    assert error(base(model={"kind": "plane"})).message == (
        "'kind' must be one of 'quadrotor', 'unicycle', got 'plane'")
    assert error(base(takeoff={"headings": "random"})).message == (
        "'headings' only applies to [model] kind = \"unicycle\"")
    assert error(base(takeoff={"spacing": 1.0})).message == (
        "homes are 1.0 m apart but min_separation is 1.5 m; increase 'spacing' to at least 1.5")
    assert error(base(takeoff={"layout": "points", "points": [[0, 0], [1, 0], [5, 0], [9, 0]]})
                 ).message == ("homes 1 and 2 are 1.0 m apart but min_separation is 1.5 m; "
                               "move them apart")
    fenced = base(takeoff={"center": [30, 0]},
                  limits={"geofence": [[-20, -20], [20, -20], [20, 20], [-20, 20]]})
    assert error(fenced).message == (
        "home 2 at (31.5, 1.5, 0.0) is outside the geofence (4 of 4 outside)")
    assert error(base(takeoff={"layout": "points", "points": [[0, 0]]})).message == (
        "'points' has 1 points but the show has 4 drones")
    assert error(base(takeoff={"layout": "random", "area": [2, 2]})).message == (
        "could not place 4 drones 1.5 m apart in the 'area'; enlarge them or lower 'min_spacing'")
    assert error(base(takeoff={"layout": "grid", "seed": 3})).message == (
        "'seed' does not apply here: it is a key of layout 'random'")
    e = error(base(show={"drones": 4, "takeoff_altitude": 1}))
    assert e.where == "[show]"
    assert e.message == ("'takeoff_altitude' 1.0 m is outside [limits] min_altitude 2.0 m .. "
                         "max_altitude 120.0 m")
    assert error(base(limits={"min_altitude": 50, "max_altitude": 40})).message == (
        "'max_altitude' 40.0 m must be above 'min_altitude' 50.0 m")
    assert error(base(limits={"geofence": [[0, 0], [1, 1], [2, 2]]})).message.startswith(
        "'geofence' encloses no area")
    assert error(base(limits={"land_battery_pct": 100})).message.startswith(
        "'land_battery_pct' 100.0 must be below 100")
    assert "'max_wind' must be greater than 0" in error(base(limits={"max_wind": 0})).message


def test_the_wind_limit_defaults_to_ten_metres_per_second_and_can_be_set():
    assert parse_show(base(), PATH, ".").limits.max_wind == 10.0
    assert parse_show(base(limits={"max_wind": 7.5}), PATH, ".").limits.max_wind == 7.5


def test_planner_tolerance_above_what_keeps_the_scp_safe_is_refused():
    err = error(base(planner={"tolerance": 0.2}))
    assert str(err) == f"{PATH}: [planner]: 'tolerance' must be at most 0.09, got 0.2"


def test_the_mpc_table_is_read_and_checked(tmp_path: Path) -> None:
    from groundctl.show.model import MpcSettings

    assert parse_show(base(), PATH).mpc == MpcSettings()
    show = parse_show(base(mpc={"enabled": False, "horizon": 2.5, "trigger_error": 0.8,
                                "release_error": 0.3, "release_after": 1}), PATH)
    assert show.mpc == MpcSettings(False, 2.5, 0.8, 0.3, 1.0)
    assert str(error(base(mpc={"trigger_eror": 1}))) == (
        "shows/test.toml: [mpc]: unknown key 'trigger_eror'; did you mean 'trigger_error'?")
    assert error(base(mpc={"trigger_error": 0.2, "release_error": 0.3})).message == (
        "'release_error' 0.3 m must be below 'trigger_error' 0.2 m")
    assert error(base(mpc={"enabled": "yes"})).message == (
        "'enabled' must be true or false, got string 'yes'")
    assert error(base(mpc={"horizon": 30})).message == "'horizon' must be at most 10, got 30"


def _fleet_show(drones: int, slots: int) -> str:
    return f"""
[show]
name = "fleet"
drones = {drones}
takeoff_altitude = 3.0

[origin]
lat = 47.3977
lon = 8.5456
alt = 488.0

[limits]
max_altitude = 400.0

[planner]
dt = 2.0

[takeoff]
layout = "grid"
spacing = 2.2

[[formation]]
name = "sphere"
shape = "sphere"
count = {slots}
size = 120.0
center = [0.0, 0.0, 70.0]
transition = 60.0
hold = 2.0
color = "#ffffff"

[landing]
transition = 100.0
"""


def test_ten_thousand_drones_load_and_one_more_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text(_fleet_show(10_000, 10_000))
    show = load_show(path)
    assert show.drones == 10_000 and len(show.formations[0].points) == 10_000
    path.write_text(_fleet_show(10_001, 10_001))
    with pytest.raises(ShowFileError, match="'drones' must be at most 10000"):
        load_show(path)


def test_spare_slots_beyond_the_exact_assignments_size_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text(_fleet_show(2000, 3000))
    with pytest.raises(ShowFileError, match=r"2000 drones x 3000 slots is 6000000 assignment "
                                            r"costs, more than 5000000 .* give it exactly "
                                            r"2000 slots"):
        load_show(path)
    path.write_text(_fleet_show(1000, 5000))  # 5,000,000: the largest that is assigned
    assert len(load_show(path).formations[0].points) == 5000
