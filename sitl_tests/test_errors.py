"""Every GroundctlError crosses a process boundary intact, and the CLI prints it as one line.

Planning workers and the flight's MPC worker send errors back through pickle:
an error class that does not survive the round trip turns one clear line into
a ``BrokenProcessPool`` traceback.  The classes are found, not listed: a new
one is covered the day it is written.
"""

from __future__ import annotations

import importlib
import inspect
import pickle
import pkgutil
import subprocess
import sys
import typing
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

import groundctl
from groundctl.cli import one_line
from groundctl.errors import EXIT_INFEASIBLE, GroundctlError, PlanningError, ShowFileError


def _all_subclasses(cls: type[GroundctlError]) -> Iterator[type[GroundctlError]]:
    for sub in cls.__subclasses__():
        yield sub
        yield from _all_subclasses(sub)


def _error_classes() -> list[type[GroundctlError]]:
    """GroundctlError and every subclass defined anywhere in groundctl."""
    for info in pkgutil.walk_packages(groundctl.__path__, "groundctl."):
        if not info.name.endswith("__main__"):  # that one runs the CLI
            importlib.import_module(info.name)
    found = {GroundctlError, *_all_subclasses(GroundctlError)}
    return sorted(found, key=lambda c: (c.__module__, c.__qualname__))


_SAMPLES: dict[Any, Any] = {
    int: 7, float: 2.5, str: "text", bool: True, str | Path: "shows/x.toml",
    Sequence[str]: ["first", "second"], dict[int, list[str]]: {3: ["gps", "battery"]},
    float | None: 1.5, int | None: 2, Sequence[tuple[int, int, float, float]]: [(3, 9, 1.2, 4.5)],
}


def _instance(cls: type[GroundctlError]) -> GroundctlError:
    """``cls`` built with a sample value for each argument its ``__init__`` takes."""
    init = next((c.__dict__["__init__"] for c in cls.__mro__ if "__init__" in c.__dict__
                 and inspect.isfunction(c.__dict__["__init__"])), None)
    if init is None:  # Exception's own __init__: the message
        return cls("a message")
    hints = typing.get_type_hints(init)
    args = []
    for name, param in list(inspect.signature(init).parameters.items())[1:]:
        if param.default is not inspect.Parameter.empty and name not in hints:
            continue
        hint = hints[name]
        assert hint in _SAMPLES, f"{cls.__name__}({name}: {hint}): add a sample for {hint}"
        args.append(_SAMPLES[hint])
    return cls(*args)


ERROR_CLASSES = _error_classes()


def test_the_whole_tree_is_found() -> None:
    names = {c.__name__ for c in ERROR_CLASSES}
    assert {"ShowFileError", "InfeasibleTransition", "PlanningError", "PlanFileError",
            "UntrustedPlan", "UnsafePlan", "LinkError", "CommandRefused", "CommandTimeout",
            "VehicleLost", "PreflightFailed", "FlightError", "PlanningTimeout",
            "SimulatorError"} <= names


@pytest.mark.parametrize("cls", ERROR_CLASSES, ids=lambda c: c.__qualname__)
def test_every_error_survives_pickle_with_its_message_and_data(
        cls: type[GroundctlError]) -> None:
    error = _instance(cls)
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is cls
    assert str(again) == str(error)
    assert again.args == error.args
    assert vars(again) == vars(error)
    assert again.exit_code == error.exit_code


def test_an_error_with_line_breaks_is_printed_as_one_line() -> None:
    error = ShowFileError("shows/x.toml", "formation 1 'a\nb'", "bad\r\x1b[31mred\u202e")
    text = one_line(str(error))
    assert "\n" not in text and "\r" not in text and "\x1b" not in text
    assert text == ("shows/x.toml: formation 1 'a\\nb': bad\\r\\x1b[31mred\\u202e")
    assert len(one_line("x" * 100_000)) == 2000


#: Two drones side by side that must turn through each other in the least time the
#: limits allow (no room to go round): the SCP ends with slack, a PlanningError.
CROSSING_SHOW = """
[show]
name = "crossing"
drones = 2
takeoff_altitude = 3.0
[origin]
lat = 47.0
lon = 8.0
alt = 400.0
[limits]
min_separation = 1.5
[planner]
max_iterations = 3
[takeoff]
layout = "points"
points = [[0.0, 0.0], [1.5, 0.0]]
[[formation]]
name = "turned"
shape = "points"
points = [[0.75, -0.75, 3.0], [0.75, 0.75, 3.0]]
transition = 1.3
[[formation]]
name = "back"
shape = "points"
points = [[0.0, 0.0, 3.0], [1.5, 0.0, 3.0]]
transition = 1.3
"""


def test_a_planner_failure_in_a_worker_process_is_one_line_and_exit_3(tmp_path: Path) -> None:
    show = tmp_path / "crossing.toml"
    show.write_text(CROSSING_SHOW)
    # Two transitions and --workers 2: planned in a process pool, the error pickled back.
    proc = subprocess.run([sys.executable, "-m", "groundctl", "plan", str(show), "--workers",
                           "2", "-o", str(tmp_path / "x.plan.npz")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == EXIT_INFEASIBLE, proc.stderr
    assert "BrokenProcessPool" not in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stderr.splitlines() == [proc.stderr.strip()]
    assert proc.stderr.startswith("groundctl plan: error: transition 1: planner failed: "
                                  "no separation-feasible solution")
    assert not (tmp_path / "x.plan.npz").exists()


def test_planning_error_pickles_with_its_status() -> None:
    error = PlanningError(3, "no separation-feasible solution", "slack 0.1 m")
    again = pickle.loads(pickle.dumps(error))
    assert (again.transition, again.status, again.detail) == (3, error.status, "slack 0.1 m")
    assert str(again) == str(error)
