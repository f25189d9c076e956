"""The command line answers before it loads the flight: ``--help`` and a bad option need
the parser only, not scipy, OSQP, Textual, Rerun, the executor or the simulator.

Every ``groundctl`` run used to import all of them to build its parser (0.7 s of CPU
before it could say "--speed must be positive"); the heavy modules are now imported
where a command uses them, and the packages ``groundctl.link`` and ``groundctl.sim``
load their names on first use.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: Never loaded by building the parser.
HEAVY = ("scipy", "osqp", "textual", "rerun", "ray", "groundctl.flight.runner",
         "groundctl.flight.report", "groundctl.sim.fleet", "groundctl.link.fleet",
         "groundctl.skybrush.importing", "groundctl.plan.planner")


def _loaded_by(code: str) -> list[str]:
    """The modules a fresh interpreter has loaded after ``code``."""
    out = subprocess.run(
        [sys.executable, "-c", f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"],
        capture_output=True, text=True, check=True, timeout=60)
    return list(json.loads(out.stdout.splitlines()[-1]))


def test_building_the_parser_loads_nothing_heavy() -> None:
    loaded = _loaded_by("from groundctl.cli import build_parser\nbuild_parser()")
    heavy = sorted(m for m in loaded if any(m == h or m.startswith(h + ".") for h in HEAVY))
    assert heavy == [], heavy
    assert "groundctl.commands.dry_run" in loaded  # the parser was built, every verb


def test_a_bad_option_is_one_argparse_line_without_the_flight() -> None:
    run = subprocess.run([sys.executable, "-m", "groundctl.cli", "dry-run", "--speed", "-1"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines()[-1].endswith("must be positive, not '-1'")


@pytest.mark.parametrize(("package", "name", "home"), [
    ("groundctl.link", "FleetLink", "groundctl.link.fleet"),
    ("groundctl.link", "Flavour", "groundctl.link.flavours"),
    ("groundctl.sim", "SimFleet", "groundctl.sim.fleet"),
    ("groundctl.sim", "SimConfig", "groundctl.sim.config"),
    ("groundctl.show", "load_show", "groundctl.show.loader"),
])
def test_the_packages_public_names_load_on_first_use(package: str, name: str,
                                                      home: str) -> None:
    loaded = _loaded_by(f"import {package}\nassert {package}.{name}.__module__ == {home!r}")
    assert home in loaded
    assert "groundctl.sim.fleet" not in _loaded_by(f"import {package}")


@pytest.mark.parametrize("package", ["groundctl.link", "groundctl.sim", "groundctl.show"])
def test_an_unknown_name_is_an_attribute_error(package: str) -> None:
    import importlib

    module = importlib.import_module(package)
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        module.Nope  # noqa: B018
    assert all(hasattr(module, n) for n in module.__all__)
