"""Hostile show and plan files through the real CLI: one clear line each, never a crash.

The corpus is :mod:`hostile_corpus` (also run by ``benchmarks/hostile_files.py``).
Every case must be refused before any real work: the whole parametrised test
takes seconds.
"""

from __future__ import annotations

import os
import tomllib
import zipfile
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest
from hostile_corpus import (
    BASE_SHOW,
    SECRET,
    Case,
    base_arrays,
    base_members,
    corpus,
    long_show,
    npy_member,
    points_file_show,
    prepare,
    random_layout_show,
    run_case,
    show_with,
    tamper_separation,
    write_plan,
    write_show,
)

from groundctl.cli import main
from groundctl.commands.flying import load_or_plan
from groundctl.errors import (
    EXIT_OK,
    EXIT_UNSAFE,
    EXIT_USAGE,
    PlanFileError,
    ShowFileError,
    UntrustedPlan,
)
from groundctl.plan.plan import Plan
from groundctl.record.recording import Recording, default_directory, safe_name
from groundctl.show.loader import load_show, parse_show
from groundctl.show.takeoff import _TRIES_PER_DRONE, random_layout

CASES = corpus()


def test_the_corpus_is_big_enough() -> None:
    assert len(CASES) >= 60
    assert len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_a_hostile_file_is_one_clear_line(case: Case, tmp_path: Path) -> None:
    directory, argv = prepare(case, tmp_path)
    out = run_case(argv, directory, timeout=20.0)
    assert not out.crashed, f"killed (signal {out.signal}, timed out {out.timed_out})"
    assert not out.traceback, out.stderr[-2000:]
    assert out.exit_code not in (None, 0), (out.stdout[-500:], out.stderr[-500:])
    assert len(out.lines) == 1, out.stderr[-2000:]
    assert out.lines[0].startswith(f"groundctl {argv[0]}: error: "), out.lines[0]
    for text in case.forbidden:
        assert text not in out.stderr, f"the error echoes file contents: {out.lines[0]}"
    assert out.seconds < 10, f"took {out.seconds:.1f} s: the checks must fire before any work"


# -- 5. NaN and inf in plan files ---------------------------------------------------------


def _check(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize(("edit", "message"), [
    (lambda a: a["vel"].fill(np.nan), "'vel' holds NaN or infinite values"),
    (lambda a: a["times"].__setitem__(3, np.nan), "'times' holds NaN or infinite values"),
    (lambda a: a["colors"].__setitem__((0, 1, 0), np.nan),
     "'colors' holds NaN or infinite values"),
    (lambda a: a["home"].__setitem__((1, 0), np.inf), "'home' holds NaN or infinite values"),
    (lambda a: a["meta"]["origin"].__setitem__("lat", float("nan")),
     "meta 'origin.lat' must be finite, got nan"),
    (lambda a: a["meta"]["formations"][0].__setitem__("arrive", float("inf")),
     "meta 'formations.0.arrive' must be finite, got inf"),
    (lambda a: a.__setitem__("times", a["times"][::-1].copy()), "'times' starts at "),
    (lambda a: a["times"].__setitem__(2, a["times"][1]), "'times' is not strictly increasing"),
])
def test_nan_inf_and_disorder_in_a_plan_are_one_line_exit_2(
        edit: Any, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arrays = base_arrays()
    edit(arrays)
    path = write_plan(tmp_path, arrays)
    with pytest.raises(PlanFileError) as info:
        Plan.load(path)
    assert info.value.exit_code == EXIT_USAGE
    assert str(info.value).startswith(f"{path}: not a groundctl plan: {message}")
    code, out, err = _check(["check", str(path)], capsys)
    assert (code, out) == (EXIT_USAGE, "")
    assert err == f"groundctl check: error: {info.value}\n"


# -- 6. a plan is checked against its show's limits -------------------------------------


def test_a_plan_next_to_its_show_is_checked_against_the_show(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_plan(tmp_path)
    code, out, err = _check(["check", str(path)], capsys)
    assert (code, err) == (EXIT_OK, "")
    assert out.startswith(f"SAFE: {path}: 4 drones") and \
        out.rstrip().endswith(f"limits from {tmp_path / 'show.toml'}")
    assert _check(["check", str(path), "--json"], capsys)[1].count('"limits_from"') == 1


def test_the_issues_edited_plan_is_never_safe(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """min_separation edited down and two drones just beyond it: SAFE before."""
    arrays = base_arrays()
    tamper_separation(arrays)
    path = write_plan(tmp_path, arrays)
    code, out, err = _check(["check", str(path)], capsys)
    assert (code, out) == (EXIT_USAGE, "")
    assert err.splitlines() == [
        f"groundctl check: error: {path}: its limits differ from the show's (min_separation "
        f"0.6 in the plan, 1.5 in the show): the plan was edited after it was planned from "
        f"{tmp_path / 'show.toml'}; re-plan it with 'groundctl plan {tmp_path / 'show.toml'}'"]
    # The same refusal before a dry-run starts a simulator.
    code, out, err = _check(["dry-run", str(path), "--no-record", "-q"], capsys)
    assert code == EXIT_USAGE and len(err.splitlines()) == 1 and "limits differ" in err
    # Without its show: refused, saying how to go on.
    (tmp_path / "show.toml").unlink()
    code, out, err = _check(["check", str(path)], capsys)
    assert code == EXIT_USAGE
    assert "no show file to check its limits against" in err
    assert "--show SHOW.toml" in err and "--accept-plan-limits" in err
    # The operator's explicit override: the limits it carries.
    code, out, err = _check(["check", str(path), "--accept-plan-limits"], capsys)
    assert (code, err) == (EXIT_OK, "")
    assert "limits from the plan file itself (--accept-plan-limits)" in out


def test_a_plan_moved_closer_than_its_shows_limit_is_unsafe(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arrays = base_arrays()
    tamper_separation(arrays)
    arrays["meta"]["limits"]["min_separation"] = 1.5  # the trajectories alone edited
    arrays["home"] = base_arrays()["home"]
    arrays["pos"][1, 0] = base_arrays()["pos"][1, 0]
    path = write_plan(tmp_path, arrays)
    code, out, _ = _check(["check", str(path)], capsys)
    assert code == EXIT_UNSAFE
    assert out.startswith("UNSAFE") and "(min_separation 1.5 m)" in out


def test_an_unsafe_plan_checked_against_a_show_it_is_not_tied_to_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Unsafe by its own limits: UNSAFE whatever the show; the line says the show was given
    # but could not be used (it said "no show to check it against").
    arrays = base_arrays()
    tamper_separation(arrays)
    arrays["meta"]["limits"]["min_separation"] = 1.5
    path = write_plan(tmp_path, arrays, sibling=False)
    other = write_show(tmp_path, BASE_SHOW.replace('"#ff0000"', '"#00ff00"'), "other.toml")
    code, out, _ = _check(["check", str(path), "--show", str(other)], capsys)
    assert code == EXIT_UNSAFE and out.startswith("UNSAFE")
    assert "limits from the plan file itself (not tied to the show given:" in out
    assert "no show to check it against" not in out


def test_a_plan_is_refused_with_another_show_or_without_a_hash(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_plan(tmp_path, sibling=False)
    other = write_show(tmp_path, BASE_SHOW.replace('"#ff0000"', '"#00ff00"'), "other.toml")
    code, _, err = _check(["check", str(path), "--show", str(other)], capsys)
    assert code == EXIT_USAGE
    assert f"was not planned from {other} (the show's hash differs" in err
    assert f"re-plan it with 'groundctl plan {other}', or pass --accept-plan-limits" in err
    arrays = base_arrays()
    del arrays["meta"]["show_digest"]
    old = write_plan(tmp_path, arrays, name="old.plan.npz")
    code, _, err = _check(["check", str(old)], capsys)
    assert code == EXIT_USAGE
    assert "records no show hash (saved before plans recorded their show" in err
    assert "re-plan it with 'groundctl plan" in err and "--accept-plan-limits" in err
    assert _check(["check", str(old), "--accept-plan-limits"], capsys)[0] == EXIT_OK
    # --show and --accept-plan-limits contradict each other.
    with pytest.raises(SystemExit) as info:
        main(["check", str(old), "--show", str(other), "--accept-plan-limits"])
    assert info.value.code == EXIT_USAGE


def test_the_show_hash_covers_the_show_file_and_its_point_files(tmp_path: Path) -> None:
    text = show_with(shape='shape = "points"', size='file = "p.csv"',
                     center="center = [0.0, 0.0, 0.0]")
    (tmp_path / "p.csv").write_text("x,y,z\n0,0,10\n3,0,10\n6,0,10\n9,0,10\n")
    show = write_show(tmp_path, text)
    first = load_show(show).digest
    assert len(first) == 64 and load_show(show).digest == first
    (tmp_path / "p.csv").write_text("x,y,z\n0,0,11\n3,0,11\n6,0,11\n9,0,11\n")
    assert load_show(show).digest != first
    show.write_text(text + "# a comment\n")
    assert load_show(show).digest not in ("", first)
    assert parse_show(tomllib.loads(text), str(show), tmp_path).digest == ""  # no bytes given


@pytest.mark.parametrize("command", ["check", "dry-run", "fly"])
def test_help_names_the_plan_source_flags(command: str,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    assert "--show SHOW" in text and "--accept-plan-limits" in text and "--points-dir" in text


# -- 7. sizes are checked before anything is allocated ---------------------------------


def test_a_16_mb_file_declaring_8_6_gb_is_refused_without_allocating(tmp_path: Path) -> None:
    members = base_members(skip=("pos",))
    # Stored, not compressed: the file really is 16 MB, its header declares 8.6 GB.
    declared = npy_member("{'descr': '<f8', 'fortran_order': False, "
                          "'shape': (1000000, 360, 3), }", bytes(16 << 20))
    path = tmp_path / "show.plan.npz"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, data in {**members, "pos.npy": declared}.items():
            zf.writestr(name, data)
    write_show(tmp_path)
    assert path.stat().st_size > 16 << 20
    out = run_case(["check", str(path)], tmp_path, memory=256 << 20)  # 256 MiB to spare
    assert out.exit_code == EXIT_USAGE, out.stderr
    assert out.lines == [f"groundctl check: error: {path}: not a groundctl plan: 'pos' "
                         f"declares the shape (1000000, 360, 3), not (drones, 52, 3) with 1 "
                         f"to 10000 drones"]


@pytest.mark.parametrize(("content", "message"), [
    (b"", "not a NumPy .npz archive (a zip of .npy arrays)"),
    (bytes(range(256)) * 8, "not a NumPy .npz archive (a zip of .npy arrays)"),
])
def test_empty_or_random_bytes_are_not_called_pickled_data(content: bytes, message: str,
                                                           tmp_path: Path) -> None:
    path = tmp_path / "x.plan.npz"
    path.write_bytes(content)
    with pytest.raises(PlanFileError) as info:
        Plan.load(path)
    assert str(info.value) == f"{path}: not a groundctl plan: {message}"
    assert "pickled" not in str(info.value)


def test_wrong_types_in_the_metadata_name_the_key(tmp_path: Path) -> None:
    arrays = base_arrays()
    arrays["meta"]["takeoff_altitude"] = "high"
    with pytest.raises(PlanFileError, match=r"meta 'takeoff_altitude' must be a number, "
                                            r"got str"):
        Plan.load(write_plan(tmp_path, arrays))


def test_a_plan_round_trips_with_its_show_hash(tmp_path: Path) -> None:
    path = write_plan(tmp_path)
    plan = Plan.load(path)
    assert plan.show_digest == load_show(tmp_path / "show.toml").digest
    again = Plan.load(plan.save(tmp_path / "again.plan.npz"))
    assert again.show_digest == plan.show_digest
    np.testing.assert_array_equal(again.trajectories.pos, plan.trajectories.pos)


# -- 8. point files stay where the operator put them ----------------------------------


def test_a_point_file_outside_the_show_directory_is_refused_unread(tmp_path: Path) -> None:
    show = write_show(tmp_path, points_file_show("../../../../../../etc/passwd")(tmp_path))
    with pytest.raises(ShowFileError) as info:
        load_show(show)
    assert info.value.message == (
        f"'file' '../../../../../../etc/passwd' is outside the show file's directory: point "
        f"files must be under {tmp_path} (allow another directory with --points-dir)")


def test_a_point_file_error_never_quotes_the_file(tmp_path: Path) -> None:
    (tmp_path / "p.csv").write_text(f"x,y,z\n0,0,10\n{SECRET},0,10\n")
    show = write_show(tmp_path, points_file_show("p.csv")(tmp_path))
    with pytest.raises(ShowFileError) as info:
        load_show(show)
    assert info.value.message == "'file' p.csv line 3: 'x' is not a number"


def test_points_dir_allows_another_directory(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "line.csv").write_text("x,y,z\n0,0,10\n3,0,10\n6,0,10\n9,0,10\n")
    here = tmp_path / "show"
    here.mkdir()
    show = write_show(here, points_file_show(str(shared / "line.csv"))(here))
    with pytest.raises(ShowFileError, match="outside the show file's directory"):
        load_show(show)
    assert load_show(show, [shared]).formations[0].points.shape == (4, 3)
    code = main(["plan", str(show), "--points-dir", str(shared), "-o",
                 str(here / "show.plan.npz"), "--json"])
    capsys.readouterr()
    assert code == EXIT_OK
    # The plan's check reads the same show and needs the same permission.
    code, _, err = _check(["check", str(here / "show.plan.npz")], capsys)
    assert code == EXIT_USAGE and "outside the show file's directory" in err
    assert _check(["check", str(here / "show.plan.npz"), "--points-dir", str(shared)],
                  capsys)[0] == EXIT_OK


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "symlink-out", "too-big"])
def test_special_point_files_are_refused_at_once(kind: str, tmp_path: Path) -> None:
    name = {"fifo": "pipe.csv", "dev-zero": "zero.csv", "symlink-out": "link.csv",
            "too-big": "big.csv"}[kind]
    if kind == "fifo":
        os.mkfifo(tmp_path / name)
    elif kind == "dev-zero":
        (tmp_path / name).symlink_to("/dev/zero")
    elif kind == "symlink-out":
        (tmp_path / name).symlink_to("/etc/passwd")
    else:
        (tmp_path / name).write_text("x,y,z\n" + "0,0,0\n" * 200_000)
    show = write_show(tmp_path, points_file_show(name)(tmp_path))
    # Refused before it is opened or read: opening the FIFO would block, reading
    # /dev/zero would not end (pytest's timeout would say so).
    with pytest.raises(ShowFileError) as info:
        load_show(show)
    expect = {"fifo": "not a regular file (a FIFO)",
              "dev-zero": "outside the show file's directory",
              "symlink-out": "outside the show file's directory",
              "too-big": "is 1.1 MiB, more than the 1.0 MiB allowed"}[kind]
    assert expect in info.value.message


# -- 9. recordings stay under recordings/ ----------------------------------------------


@pytest.mark.parametrize(("name", "part"), [
    ("../../../../elsewhere/quick", "_.._.._.._elsewhere_quick"),
    ("/etc/cron.d/x", "_etc_cron.d_x"),
    ("..", "show"),
    ("", "show"),
    ("quick", "quick"),
    ("a" * 300, "a" * 64),
])
def test_a_show_name_is_one_safe_path_component(name: str, part: str, tmp_path: Path) -> None:
    assert safe_name(name) == part
    root = tmp_path / "recordings"
    directory = default_directory(name, "dry-run", root)
    assert directory.parent == root
    assert directory.name.startswith(f"{part}-dry-run-")
    Recording(directory, lambda: 0.0).finish({"safe": True})
    assert directory.resolve().is_relative_to(root.resolve())
    assert [p.name for p in tmp_path.iterdir()] == ["recordings"]


def test_a_plans_show_name_cannot_leave_recordings(tmp_path: Path) -> None:
    arrays = base_arrays()
    arrays["meta"]["show_name"] = "../../../../elsewhere/quick"
    plan = Plan.load(write_plan(tmp_path, arrays, sibling=False))
    directory = default_directory(plan.show_name, "fly", tmp_path / "recordings")
    assert directory.parent == tmp_path / "recordings"


# -- 10. every number has a range, checked before any work -----------------------------


@pytest.mark.parametrize(("text", "where", "message"), [
    (show_with(drones="drones = 9223372036854775807"), "[show]",
     "'drones' must be at most 10000, got 9223372036854775807"),
    (show_with(size="size = 1e308"), "formation 1 'line'",
     "'size' must be at most 10000, got 1e+308"),
    (show_with(transition="transition = 1e9"), "formation 1 'line'",
     "'transition' must be at most 900, got 1e+09"),
    (show_with(formation__count="count = 1000000000"), "formation 1 'line'",
     "'count' must be at most 10000, got 1000000000"),
    (show_with(planner__dt="dt = 1e-9"), "[planner]", "'dt' must be at least 0.01, got 1e-09"),
    (show_with(planner__steps="steps = 1000000000"), "[planner]",
     "'steps' must be at most 2000, got 1000000000"),
    (show_with(hold="hold = 1e12"), "formation 1 'line'", "'hold' must be at most 900, got 1e+12"),
    (show_with(origin__heading="heading = 1e300"), "[origin]",
     "'heading' must be at most 360, got 1e+300"),
    # Below what physical drones can keep (issue 35: planned SAFE, flown 0.002 m apart).
    (show_with(min_separation="min_separation = 1e-6"), "[limits]",
     "'min_separation' must be at least 0.5, got 1e-06"),
    (show_with(alt="alt = -1e30"), "[origin]", "'alt' must be at least -500, got -1e+30"),
    (show_with(transition="transition = 500.0"), "formation 1 'line'",
     "'transition' 500.0 s at [planner] dt 0.2 s is 2500 QP steps, more than 2000; raise 'dt' "
     "to at least 0.25 s or shorten the transition"),
    (long_show(12, 80.0), "[limits]",
     "the show keeps drones airborne 974.2 s (climb, every transition and hold, descent) but "
     "'max_flight_time' is 900.0 s; shorten the show, or raise 'max_flight_time' if the "
     "batteries last longer"),
    (random_layout_show(1000, 10.0), "[takeoff]",
     "could not place 1000 drones 1.5 m apart in the 'area': it holds at most 65 points that "
     "far apart; enlarge it or lower 'min_spacing'"),
    ("a = " + "[" * 5000 + "]" * 5000, "",
     "TOML syntax error: arrays or inline tables nested too deeply"),
    (BASE_SHOW + "x." + ".".join(["a"] * 100_000) + " = 1\n", "line 28",
     "a dotted key or table name has more than 32 parts"),
])
def test_out_of_range_numbers_are_one_show_file_error(text: str, where: str, message: str,
                                                      tmp_path: Path) -> None:
    show = write_show(tmp_path, text)
    with pytest.raises(ShowFileError) as info:
        load_show(show)
    # The range checks' own messages: refused before any work (no layout, no formation).
    assert (info.value.path, info.value.where, info.value.message) == (str(show), where, message)


def test_a_longer_battery_allows_a_longer_show(tmp_path: Path) -> None:
    text = long_show(12, 80.0).replace("max_altitude = 40.0",
                                        "max_altitude = 40.0\nmax_flight_time = 1200")
    show = load_show(write_show(tmp_path, text))
    assert show.limits.max_flight_time == 1200


def _old_random_layout(n: int, area: tuple[float, float], center: tuple[float, float],
                       min_spacing: float, rng: np.random.Generator,
                       annulus: tuple[float, float] | None = None,
                       around: tuple[float, float] | None = None) -> np.ndarray | None:
    """The layout as it was before it was vectorised: every candidate against every pick."""
    half = np.array(area, dtype=float) / 2
    c = np.array(center, dtype=float)
    ring_c = np.array(around if around is not None else center, dtype=float)
    chosen = np.empty((0, 2))
    budget = 2000 * n
    while len(chosen) < n and budget > 0:
        batch = min(budget, 256)
        budget -= batch
        if annulus is None:
            cand = c + rng.uniform(-1.0, 1.0, size=(batch, 2)) * half
        else:
            r = np.sqrt(rng.uniform(annulus[0] ** 2, annulus[1] ** 2, size=batch))
            a = rng.uniform(0.0, 2 * np.pi, size=batch)
            cand = ring_c + np.column_stack([r * np.cos(a), r * np.sin(a)])
            cand = cand[np.all(np.abs(cand - c) <= half, axis=1)]
        for p in cand:
            if len(chosen) == n:
                break
            if len(chosen) == 0 or np.min(np.hypot(*(chosen - p).T)) >= min_spacing:
                chosen = np.vstack([chosen, p])
    return chosen if len(chosen) == n else None


@pytest.mark.parametrize(("n", "area", "spacing", "annulus"), [
    (25, (100.0, 100.0), 3.0, None), (200, (40.0, 40.0), 1.5, None),
    (4, (60.0, 60.0), 1.5, (20.0, 25.0)), (30, (4.0, 4.0), 1.5, None),
])
def test_the_faster_random_layout_places_the_same_drones(
        n: int, area: tuple[float, float], spacing: float,
        annulus: tuple[float, float] | None) -> None:
    for seed in range(3):
        new = random_layout(n, area, (1.0, 2.0), spacing, np.random.default_rng(seed), annulus)
        old = _old_random_layout(n, area, (1.0, 2.0), spacing, np.random.default_rng(seed),
                                 annulus)
        assert (new is None and old is None) or np.array_equal(new, old)


class _CountingRng:
    """A real generator that counts the candidate points drawn from it."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.points = 0

    def uniform(self, low: float, high: float, size: tuple[int, int] | int) -> np.ndarray:
        out = self.rng.uniform(low, high, size=size)
        self.points += out.shape[0]
        return out


def test_a_crowded_but_possible_random_layout_gives_up_after_a_bounded_number_of_tries(
        ) -> None:
    # 1000 drones in 45 m x 45 m at 1.5 m: within the packing bound, beyond dart throwing.
    # The work is bounded, not the wall time (a busy machine stretches that): at most
    # _TRIES_PER_DRONE candidates per drone are drawn before it gives up.  How long that
    # takes is benchmarks/bench_layout.py's figure.
    rng = _CountingRng(0)
    assert random_layout(1000, (45.0, 45.0), (0.0, 0.0), 1.5, cast(Any, rng)) is None
    assert 0 < rng.points <= _TRIES_PER_DRONE * 1000


def test_the_flying_commands_load_a_plan_file_through_its_show(tmp_path: Path) -> None:
    path = write_plan(tmp_path)
    plan = load_or_plan(path, quiet=True)  # what dry-run PLAN.npz and fly PLAN.npz fly
    assert plan.show_digest == load_show(tmp_path / "show.toml").digest
    (tmp_path / "show.toml").rename(tmp_path / "elsewhere.toml")
    with pytest.raises(UntrustedPlan, match="no show file to check its limits against"):
        load_or_plan(path, quiet=True)
    assert load_or_plan(path, quiet=True, show_file=tmp_path / "elsewhere.toml").drones == 4
    assert load_or_plan(path, quiet=True, accept_plan_limits=True).drones == 4


@pytest.mark.parametrize("workers", ["0", "-1", "1000000000", "two"])
def test_the_worker_count_is_bounded(workers: str, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    show = write_show(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(["plan", str(show), "--workers", workers])
    assert info.value.code == EXIT_USAGE
    assert "--workers must be" in capsys.readouterr().err
