"""``groundctl plan --ray``: the same plan through a Ray cluster as locally.

One local Ray cluster (2 CPUs) for the whole module: Ray starts slowly on a busy
2-core machine.  Its temp dir is Ray's default under /tmp, never the repo.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import zipfile
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from plan_fixtures import points_show

from groundctl.errors import EXIT_USAGE, PlanningError
from groundctl.plan.distribute import LocalExecutor, RayExecutor
from groundctl.plan.groupsolve import GroupSolvers, Solved
from groundctl.plan.planner import plan_show
from groundctl.plan.report import report_dict
from groundctl.show.loader import load_show
from groundctl.show.model import Show
from sitl_tests.test_errors import CROSSING_SHOW
from sitl_tests.test_plan_groupsolve import LIM as WALL_LIMITS
from sitl_tests.test_plan_groupsolve import _specs, grid_to_wall

ray = pytest.importorskip("ray")
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parents[1]
QUICK = ROOT / "shows" / "quick.toml"  # three quadrotor transitions


@pytest.fixture(scope="module")
def cluster() -> Iterator[RayExecutor]:
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield RayExecutor("auto")  # uses the connection above, leaves it open
    finally:
        ray.shutdown()


#: The planner's wall-time budget per transition in these comparisons, s (the most a show
#: may give).  A plan is the same on Ray and locally while the budget does not run out;
#: past it the search stops on the iterate it has (a plan, not the same one), and on a
#: machine with two busy processes beside the suite a 16-drone transition on Ray took
#: 42.8 s against the default budget of 40 s (local: 1.6 s).
UNBOUNDED_S = 3600.0


def _unbounded(show: Show) -> Show:
    return replace(show, planner=replace(show.planner, budget_s=UNBOUNDED_S))


def _figures(report: dict) -> dict:  # type: ignore[type-arg]
    """The report without its wall times (keys naming ``seconds``)."""
    out = {k: v for k, v in report.items() if "seconds" not in k}
    out["transitions"] = [{k: v for k, v in t.items() if "seconds" not in k}
                          for t in report["transitions"]]
    return out


def test_ray_and_local_plans_are_identical(cluster: RayExecutor) -> None:
    show = _unbounded(load_show(QUICK))
    local = plan_show(show, executor=LocalExecutor(2))
    remote = plan_show(show, executor=cluster)
    assert np.array_equal(local.plan.trajectories.pos, remote.plan.trajectories.pos)
    assert np.array_equal(local.plan.trajectories.vel, remote.plan.trajectories.vel)
    assert np.array_equal(local.plan.trajectories.times, remote.plan.trajectories.times)
    assert _figures(report_dict(local)) == _figures(report_dict(remote))


def test_one_transition_on_the_cluster_solves_its_groups_on_actors_as_locally(
        cluster: RayExecutor) -> None:
    # One transition, two CPUs: the spare one goes to the conflict groups (a Ray actor
    # beside the transition's task); the plan is the one planned in one process.
    start, goal, duration = grid_to_wall(side=4)
    home = start.copy()
    home[:, 2] = 0.0
    show = _unbounded(points_show(home, [goal], transition=duration, limits=WALL_LIMITS,
                                  takeoff_altitude=3.0))
    assert cluster.cpus == 2
    local = plan_show(show, executor=LocalExecutor(1))
    remote = plan_show(show, executor=cluster)
    assert local.transitions[0].qp_drones > 0
    assert np.array_equal(local.plan.trajectories.pos, remote.plan.trajectories.pos)


def test_groups_on_ray_actors_solve_as_here_and_a_killed_actor_loses_only_time(
        cluster: RayExecutor, caplog: pytest.LogCaptureFixture) -> None:
    cases = _specs(4)
    with GroupSolvers(1) as here:
        for spec, job in cases:
            here.build(job.group, spec)
        alone = here.solve([job for _, job in cases])
    with GroupSolvers(1, workers=2, ray=True) as spread:
        for spec, job in cases:
            spread.build(job.group, spec)
        assert sorted(spread._where.values()) == [-1, -1, 0, 0]
        together = spread.solve([job for _, job in cases])
        ray.kill(spread._slots[0].actor)  # type: ignore[union-attr]
        with caplog.at_level(logging.WARNING):
            again = spread.solve([job for _, job in cases])
        assert "a group solver Ray actor died" in caplog.text
    assert all(isinstance(o, Solved) for o in again)
    assert all(np.array_equal(a.P, b.P) for a, b in zip(alone, together, strict=True))


def test_a_planning_error_comes_back_as_itself(cluster: RayExecutor, tmp_path: Path) -> None:
    path = tmp_path / "crossing.toml"
    path.write_text(CROSSING_SHOW)
    show = load_show(path)
    with pytest.raises(PlanningError) as local:
        plan_show(show, workers=1)
    with pytest.raises(PlanningError) as remote:
        plan_show(show, executor=cluster)
    assert type(remote.value) is type(local.value)
    assert str(remote.value) == str(local.value)
    assert vars(remote.value) == vars(local.value)


def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


def test_cli_ray_local_writes_the_same_plan(tmp_path: Path) -> None:
    """The zip members are compared, not the file bytes: NumPy's zip records each
    member's write time (2 s resolution), so two writes of one plan may differ there."""
    quick = tmp_path / "quick.toml"  # the bundled show with the budget out of reach
    text = QUICK.read_text()
    assert text.count("[planner]\n") == 1
    quick.write_text(text.replace("[planner]\n", f"[planner]\nbudget = {UNBOUNDED_S:g}\n"))
    base = [sys.executable, "-m", "groundctl", "plan", str(quick)]
    plain = subprocess.run([*base, "-o", str(tmp_path / "a.plan.npz")],
                           capture_output=True, text=True, timeout=120)
    assert plain.returncode == 0, plain.stderr
    # A cluster of its own in the child process (this module's is in this process).
    viaray = subprocess.run([*base, "--ray", "local", "-o", str(tmp_path / "b.plan.npz")],
                            capture_output=True, text=True, timeout=300)
    assert viaray.returncode == 0, viaray.stderr
    assert _members(tmp_path / "a.plan.npz") == _members(tmp_path / "b.plan.npz")


def test_without_the_extra_one_line_and_exit_2(tmp_path: Path) -> None:
    code = ("import sys; sys.modules['ray'] = None; from groundctl.cli import main; "
            f"sys.exit(main(['plan', {str(QUICK)!r}, '--ray', 'auto', '-o', "
            f"{str(tmp_path / 'x.plan.npz')!r}]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == EXIT_USAGE
    assert proc.stderr == ("groundctl plan: error: --ray needs the ray extra: "
                           "pip install 'groundctl[ray]'\n")
    assert not (tmp_path / "x.plan.npz").exists()


def test_an_unreachable_cluster_is_one_line_and_exit_2(tmp_path: Path) -> None:
    import socket
    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for address in (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}"):
        proc = subprocess.run([sys.executable, "-m", "groundctl", "plan", str(QUICK), "--ray",
                               address, "-o", str(tmp_path / "x.plan.npz")],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == EXIT_USAGE, proc.stderr
        assert proc.stderr.startswith("groundctl plan: error: cannot connect to the Ray "
                                      f"cluster: nothing answers at 127.0.0.1:{port}")
        assert proc.stderr.count("\n") == 1
    proc = subprocess.run([sys.executable, "-m", "groundctl", "plan", str(QUICK), "--ray",
                           "nonsense", "-o", str(tmp_path / "x.plan.npz")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == EXIT_USAGE and "not a Ray address" in proc.stderr
    assert not (tmp_path / "x.plan.npz").exists()
