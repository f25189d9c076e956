"""Spare drones in the plan (issue 29): ``[spares]`` read, their waiting places laid out
or checked against the show in continuous time, written into and read back from the plan
file, refused in one line where they would meet a show drone."""

from __future__ import annotations

import json
import re
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from groundctl.cli import main
from groundctl.errors import EXIT_INFEASIBLE, PlanFileError, ShowFileError, SpareError
from groundctl.plan.plan import Plan, SparePlan
from groundctl.plan.planner import plan_show
from groundctl.plan.spares import LAYOUT_MARGIN_M, clearance, closest_to_point, place_spares
from groundctl.plan.verify import verify
from groundctl.show.loader import parse_show
from groundctl.show.model import SpareSettings

SHOW = """
[show]
name = "spares"
drones = 4
takeoff_altitude = 5.0
[origin]
lat = 47.0
lon = 8.0
alt = 400.0
[limits]
min_separation = 1.5
{limits}
[takeoff]
layout = "grid"
spacing = 3.0
columns = 2
[[formation]]
name = "line"
shape = "line"
center = [0.0, 0.0, 10.0]
size = 9.0
transition = 10.0
hold = 2.0
color = "#ff0000"
{spares}
"""


def _parse(spares: str, limits: str = "") -> object:
    import tomllib

    return parse_show(tomllib.loads(SHOW.format(spares=spares, limits=limits)), "s.toml")


@pytest.fixture(scope="module")
def plan() -> Plan:
    show = _parse("")
    return plan_show(show, workers=1).plan


_DENSE: dict[int, np.ndarray] = {}


def _dense_min(plan: Plan, q: np.ndarray) -> float:
    """The closest any drone comes to ``q`` on a 1 ms grid (an upper bound of the truth)."""
    tr = plan.trajectories
    if id(tr) not in _DENSE:
        _DENSE[id(tr)] = tr.evaluate(np.arange(tr.start, tr.end, 0.001))[0]  # (T, n, 3)
    return float(np.linalg.norm(_DENSE[id(tr)] - q, axis=2).min())


# -- the show file ----------------------------------------------------------------------

def test_spares_table_is_read() -> None:
    show = _parse('[spares]\ncount = 3\nstandby = "air"\naltitude = 6.0')
    assert show.spares == SpareSettings(count=3, standby="air", altitude=6.0)
    show = _parse("[spares]\ncount = 2\npads = [[12.0, 0.0], [12.0, 3.0]]")
    assert show.spares is not None and show.spares.standby == "ground"
    assert show.spares.pads is not None and show.spares.pads.tolist() == [[12, 0], [12, 3]]


@pytest.mark.parametrize("table, fragment", [
    ("count = 0", "'count' must be at least 1"),
    ("count = 1001", "'count' must be at most 1000"),
    ('count = 2\nstandby = "water"', "'standby'"),
    ("count = 2\nspare = 1", "unknown key 'spare'"),
    ('count = 2\nstandby = "air"\npads = [[9, 0], [9, 3]]', "'pads' is for spares waiting on"),
    ("count = 2\npoints = [[9, 0, 5], [9, 3, 5]]", "'points' is for spares waiting in"),
    ("count = 2\naltitude = 5", "'altitude' is for spares waiting in"),
    ('count = 2\nstandby = "air"\naltitude = 5\npoints = [[9, 0, 5], [9, 3, 5]]',
     "either 'points' or 'altitude'"),
    ("count = 2\npads = [[9, 0]]", "'pads' must be an array of at least 2 points"),
    ("count = 2\npads = [[9, 0], [9, 3], [9, 6]]", "'pads' must have at most 2 points"),
    ("count = 2\npads = [[9, 0], [9, 1]]", "'pads': pads 1 and 2 are 1.0 m apart"),
    ('count = 1\nstandby = "air"\npoints = [[9, 0, 500]]', "outside min_altitude"),
    ('count = 1\nstandby = "air"\naltitude = 1', "'altitude' must be at least 2"),
    ("count = 2\npads = [[9, 0], [90, 3]]", "outside the geofence"),
    ('count = "two"', "'count' must be an integer"),
])
def test_malformed_spares_are_one_line(table: str, fragment: str) -> None:
    limits = "geofence = [[-50, -50], [50, -50], [50, 50], [-50, 50]]"
    with pytest.raises(ShowFileError) as exc:
        _parse(f"[spares]\n{table}", limits)
    assert "[spares]" in str(exc.value)
    assert fragment in str(exc.value)
    assert "\n" not in str(exc.value)


def test_spares_need_a_hovering_model() -> None:
    import tomllib

    text = SHOW.format(spares="[spares]\ncount = 1", limits="").replace(
        "[takeoff]", '[model]\nkind = "unicycle"\n[takeoff]').replace("hold = 2.0", "").replace(
        "[0.0, 0.0, 10.0]", "[0.0, 0.0]").replace("transition = 10.0", "transition = 30.0")
    with pytest.raises(ShowFileError, match="spares need a vehicle that can hover"):
        parse_show(tomllib.loads(text), "s.toml")


# -- the exact distance of a point from the fleet's paths -------------------------------

def test_closest_to_point_is_exact_against_dense_sampling(plan: Plan) -> None:
    rng = np.random.default_rng(7)
    for q in rng.uniform([-8, -4, 3], [8, 4, 12], size=(6, 3)):
        d, drone, t = closest_to_point(plan.trajectories, q)
        dense = _dense_min(plan, q)
        # Exact: never above the sampled minimum, and the 1 ms grid is within 3 mm of it.
        assert d <= dense + 1e-6
        assert dense - d < 3e-3
        pos = plan.trajectories.evaluate(t)[0][drone]
        assert np.linalg.norm(pos - q) == pytest.approx(d, abs=1e-4)


# -- laid out, given, refused -----------------------------------------------------------

@pytest.mark.parametrize("standby", ["ground", "air"])
def test_laid_out_spares_clear_the_show(plan: Plan, standby: str) -> None:
    sp = place_spares(SpareSettings(count=5, standby=standby), plan)  # type: ignore[arg-type]
    limit = plan.limits.min_separation
    assert sp.count == 5 and not sp.given and sp.standby == standby
    assert sp.clearance_m >= limit + LAYOUT_MARGIN_M - 1e-3
    # Beside the ground footprint (homes and landing spots), not among it.
    footprint = np.vstack([plan.home, plan.landing])
    gap = np.linalg.norm(sp.pads[:, None, :2] - footprint[None, :, :2], axis=2).min()
    assert gap >= limit + LAYOUT_MARGIN_M - 1e-9
    height = 0.0 if standby == "ground" else plan.takeoff_altitude
    assert np.allclose(sp.points - sp.pads, [0.0, 0.0, height])
    for q in sp.points:  # against sampling, not only the planner's own sum
        assert _dense_min(plan, q) >= sp.clearance_m - 1e-9


def test_laid_out_spares_stay_inside_the_geofence() -> None:
    # A fence that ends 3 m past the grid's +x side: only the -x side has room.
    show = _parse("[spares]\ncount = 2", "geofence = [[-40, -20], [6.5, -20], [6.5, 20], "
                                         "[-40, 20]]")
    sp = plan_show(show, workers=1).plan.spares
    assert sp is not None
    assert (sp.pads[:, 0] < 0).all()


def test_no_room_for_spares_is_one_line() -> None:
    show = _parse("[spares]\ncount = 3", "geofence = [[-6, -6], [6, -6], [6, 6], [-6, 6]]")
    with pytest.raises(SpareError, match=r"no room for 3 spares beside the takeoff grid"):
        plan_show(show, workers=1)


def test_given_standby_point_in_the_show_is_refused_naming_the_drone(plan: Plan) -> None:
    settings = SpareSettings(count=2, standby="air",
                             points=np.array([[20.0, 0.0, 8.0], [1.0, 0.2, 10.0]]))
    with pytest.raises(SpareError) as exc:
        place_spares(settings, plan)
    err = exc.value
    assert err.spare == 1
    assert err.distance == pytest.approx(_dense_min(plan, np.array([1.0, 0.2, 10.0])),
                                         abs=3e-3)
    assert err.exit_code == EXIT_INFEASIBLE
    msg = str(err)
    assert msg.startswith("[spares] standby point 2 at (1, 0.2, 10) comes within 0.54 m "
                          "of drone ")
    assert "at show time" in msg and "\n" not in msg


def test_given_pad_under_a_landing_column_is_refused(plan: Plan) -> None:
    lands = plan.landing[0, :2]
    settings = SpareSettings(count=1, pads=(lands + np.array([0.5, 0.0]))[None, :])
    with pytest.raises(SpareError, match=r"pad 1 at .* comes within 0\.50 m of drone 1's "
                                         r"landing column"):
        place_spares(settings, plan)


def test_given_spares_clear_of_the_show_are_kept(plan: Plan) -> None:
    pads = np.array([[12.0, -2.0], [12.0, 2.0]])
    sp = place_spares(SpareSettings(count=2, pads=pads), plan)
    assert sp.given and sp.pads[:, :2].tolist() == pads.tolist()
    assert sp.clearance_m == pytest.approx(4.0)  # each other: 4 m apart


def test_spares_too_close_to_each_other_count(plan: Plan) -> None:
    pads = np.array([[20.0, 0.0, 0.0], [20.0, 1.0, 0.0]])
    found = clearance(plan, pads, pads)
    assert found.distance == pytest.approx(1.0) and found.what == "spare 2"


# -- the plan file and the verifier -----------------------------------------------------

def test_spares_round_trip_through_the_plan_file(plan: Plan, tmp_path: Path) -> None:
    sp = place_spares(SpareSettings(count=3, standby="air"), plan)
    path = replace(plan, spares=sp).save(tmp_path / "p.plan.npz")
    back = Plan.load(path).spares
    assert back is not None
    assert back.standby == "air" and not back.given
    assert np.array_equal(back.pads, sp.pads) and np.array_equal(back.points, sp.points)
    assert back.clearance_m == sp.clearance_m
    assert Plan.load(plan.save(tmp_path / "none.plan.npz")).spares is None


def _rewrite(src: Path, dst: Path, *, meta: dict | None = None,
             arrays: dict[str, np.ndarray] | None = None, drop: tuple[str, ...] = ()) -> Path:
    with np.load(src) as z:
        members = {k: z[k] for k in z.files if k not in drop}
    if meta is not None:
        doc = json.loads(str(members["meta"]))
        doc.update(meta)
        members["meta"] = np.array(json.dumps(doc))
    members.update(arrays or {})
    with dst.open("wb") as fh:
        np.savez_compressed(fh, **members)
    return dst


@pytest.mark.parametrize("change, fragment", [
    ({"drop": ("spare_points",)}, "'spare_pads' without its companion array"),
    ({"drop": ("spare_pads", "spare_points")}, "come together"),
    ({"arrays": {"spare_points": np.zeros((2, 3))}}, "declare the shapes"),
    ({"arrays": {"spare_pads": np.full((3, 3), np.nan)}}, "NaN or infinite"),
    ({"arrays": {"spare_pads": np.full((3, 3), 2e4)}}, "'spare_pads' lies more than"),
    ({"meta": {"spares": {"standby": "sea", "given": False, "clearance_m": 3.0}}},
     "'spares.standby'"),
    ({"meta": {"spares": {"standby": "air", "given": 1, "clearance_m": 3.0}}},
     "'spares.given'"),
    ({"meta": {"spares": {"standby": "air", "given": False}}}, "'spares.clearance_m' is missing"),
])
def test_hostile_spares_in_a_plan_file_are_one_line(plan: Plan, tmp_path: Path,
                                                    change: dict, fragment: str) -> None:
    sp = place_spares(SpareSettings(count=3, standby="air"), plan)
    good = replace(plan, spares=sp).save(tmp_path / "good.plan.npz")
    bad = _rewrite(good, tmp_path / "bad.plan.npz", **change)
    with pytest.raises(PlanFileError) as exc:
        Plan.load(bad)
    assert fragment in str(exc.value) and "\n" not in str(exc.value)


def test_verifier_refuses_a_spare_moved_into_the_show(plan: Plan) -> None:
    assert verify(plan).safe
    q = np.array([[1.0, 0.2, 10.0]])
    bad = replace(plan, spares=SparePlan("air", q - [0, 0, 10], q, 3.0))
    ver = verify(bad)
    assert not ver.safe
    assert any(v.startswith("spare 1 comes 0.53") for v in ver.violations), \
        ver.violations


def test_zip_has_the_spare_members(plan: Plan, tmp_path: Path) -> None:
    sp = place_spares(SpareSettings(count=1), plan)
    with zipfile.ZipFile(replace(plan, spares=sp).save(tmp_path / "p.plan.npz")) as z:
        assert {"spare_pads.npy", "spare_points.npy"} <= set(z.namelist())


# -- the commands -----------------------------------------------------------------------

def test_plan_command_prints_and_writes_the_spares(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    show = tmp_path / "s.toml"
    show.write_text(SHOW.format(spares='[spares]\ncount = 2\nstandby = "air"', limits=""))
    out = tmp_path / "s.plan.npz"
    assert main(["plan", str(show), "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["spares"]["count"] == 2 and report["spares"]["standby"] == "air"
    assert report["spares"]["clearance_m"] >= 2.5 - 1e-3
    assert len(report["spares"]["points"]) == 2
    assert Plan.load(out).spares is not None
    assert main(["plan", str(show), "-o", str(out)]) == 0
    assert "spares: 2 waiting in the air over their pads, laid out beside the takeoff grid" \
        in capsys.readouterr().out


def test_plan_command_refuses_a_standby_point_in_the_show(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    show = tmp_path / "s.toml"
    show.write_text(SHOW.format(
        spares='[spares]\ncount = 1\nstandby = "air"\npoints = [[1.0, 0.2, 10.0]]', limits=""))
    out = tmp_path / "s.plan.npz"
    assert main(["plan", str(show), "-o", str(out)]) == EXIT_INFEASIBLE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "standby point 1 at (1, 0.2, 10) comes within 0.54 m of drone" in err[0]
    assert not out.exists()


def test_flying_a_plan_with_spares_says_where_they_wait(
        plan: Plan, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from groundctl.commands.flying import load_or_plan

    path = replace(plan, spares=place_spares(SpareSettings(count=2), plan)).save(
        tmp_path / "p.plan.npz")
    got = load_or_plan(path, quiet=False, accept_plan_limits=True)
    assert got.spares is not None
    assert "spares: 2 waiting on their pads; one takes over the track of a drone that " \
        "leaves the show" in capsys.readouterr().err


def test_a_plan_whose_spares_were_edited_is_not_trusted(tmp_path: Path) -> None:
    from groundctl.errors import UntrustedPlan
    from groundctl.plan.provenance import check_against_show
    from groundctl.show.loader import load_show

    show_path = tmp_path / "s.toml"
    show_path.write_text(SHOW.format(spares="[spares]\ncount = 2", limits=""))
    show = load_show(show_path)
    plan = plan_show(show, workers=1).plan
    check_against_show(plan, show, "p.npz")  # as planned: trusted
    assert plan.spares is not None
    for edited, fragment in [
        (replace(plan, spares=None), "spares differ from the show's"),
        (replace(plan, spares=replace(plan.spares, standby="air")), "(2 waiting on the air)"),
        (replace(plan, spares=replace(plan.spares, given=True)), "lets the planner lay"),
    ]:
        with pytest.raises(UntrustedPlan, match=re.escape(fragment)):
            check_against_show(edited, show, "p.npz")


def test_a_drone_at_rest_the_whole_show_is_measured(plan: Plan) -> None:
    """A segment at rest has a hull of radius 0 that only touches the upper bound: it
    is measured, not pruned (it was: a drone hovering 2 m away went unseen)."""
    tr = plan.trajectories
    pos = np.concatenate([tr.pos, np.repeat([[[30.0, 0.0, 10.0]]], len(tr.times), axis=1)])
    still = replace(tr, pos=pos, vel=np.concatenate([tr.vel, np.zeros((1, len(tr.times), 3))]))
    d, drone, _ = closest_to_point(still, np.array([32.0, 0.0, 10.0]))
    assert d == pytest.approx(2.0) and drone == plan.drones


@pytest.mark.parametrize("points, fragment", [
    (lambda sp: sp.points + np.array([0.5, 0.0, 0.0]), "not straight above their 'spare_pads'"),
    (lambda sp: sp.pads.copy(), "is not above its pad's"),
])
def test_spare_points_edited_off_their_pads_are_refused(plan: Plan, tmp_path: Path,
                                                        points: object, fragment: str) -> None:
    sp = place_spares(SpareSettings(count=2, standby="air"), plan)
    good = replace(plan, spares=sp).save(tmp_path / "good.plan.npz")
    bad = _rewrite(good, tmp_path / "bad.plan.npz",
                   arrays={"spare_points": points(sp)})  # type: ignore[operator]
    with pytest.raises(PlanFileError, match=re.escape(fragment)):
        Plan.load(bad)


def test_verifier_refuses_a_spare_waiting_above_the_ceiling(plan: Plan) -> None:
    sp = place_spares(SpareSettings(count=1, standby="air"), plan)
    high = replace(sp, points=sp.points + np.array([0.0, 0.0, 500.0]))
    ver = verify(replace(plan, spares=high))
    assert any("a spare waits at" in v and "max_altitude" in v for v in ver.violations)


def test_laid_out_spares_moved_in_the_plan_are_not_trusted(tmp_path: Path) -> None:
    from groundctl.errors import UntrustedPlan
    from groundctl.plan.provenance import check_against_show
    from groundctl.show.loader import load_show

    show_path = tmp_path / "s.toml"
    show_path.write_text(SHOW.format(spares='[spares]\ncount = 2\nstandby = "air"', limits=""))
    show = load_show(show_path)
    plan = plan_show(show, workers=1).plan
    assert plan.spares is not None
    moved = replace(plan.spares, pads=plan.spares.pads + np.array([3.0, 0.0, 0.0]),
                    points=plan.spares.points + np.array([3.0, 0.0, 0.0]))
    with pytest.raises(UntrustedPlan, match="differ from where the planner lays them out"):
        check_against_show(replace(plan, spares=moved), show, "p.npz")


def test_a_fleet_entirely_at_rest_is_measured(plan: Plan) -> None:
    """Every hull of radius 0: the ball query's reach is the nearest centre exactly, and
    rounding could leave it out (it did, 549 times in 2,000 random cases)."""
    rng = np.random.default_rng(11)
    tr = plan.trajectories
    for _ in range(50):
        points = rng.uniform(-20, 20, (plan.drones, 3))
        pos = np.repeat(points[:, None, :], len(tr.times), axis=1)
        still = replace(tr, pos=pos, vel=np.zeros_like(pos))
        q = rng.uniform(-20, 20, 3)
        d, drone, _ = closest_to_point(still, q)
        gaps = np.linalg.norm(points - q, axis=1)
        assert d == pytest.approx(float(gaps.min())) and drone == int(np.argmin(gaps))


def test_an_air_spare_must_hover_above_the_ground(plan: Plan) -> None:
    with pytest.raises(SpareError, match=r"standby point 1 is at z = 0 m, not above the ground"):
        place_spares(SpareSettings(count=1, standby="air",
                                   points=np.array([[30.0, 0.0, 0.0]])), plan)
