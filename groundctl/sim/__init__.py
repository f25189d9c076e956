"""The built-in MAVLink vehicle simulator.

``SimFleet(SimConfig(count=..., flavour=...), clock)`` simulates a fleet of
ArduCopter- or PX4-like vehicles, each on its own UDP socket, whose physics
(:mod:`~groundctl.sim.physics`) is stepped together in numpy.  See
:mod:`groundctl.sim.fleet` for the lifecycle and :mod:`groundctl.sim.faults`
for the fault knobs.

The names below are imported on first use: a command line that only needs
:mod:`.config` (the profiles' names, a wind's direction) does not load the vehicles.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from groundctl.lazy import lazy_names

if TYPE_CHECKING:
    from groundctl.sim.config import Dynamics, SimConfig, grid_layout
    from groundctl.sim.faults import FaultEvent, FaultKind, LinkFaults
    from groundctl.sim.fleet import SimFleet
    from groundctl.sim.state import VehicleState

#: Each public name and the module it lives in.
_HOMES = {
    "Dynamics": "config",
    "SimConfig": "config",
    "grid_layout": "config",
    "FaultEvent": "faults",
    "FaultKind": "faults",
    "LinkFaults": "faults",
    "SimFleet": "fleet",
    "VehicleState": "state",
}

__all__ = ["Dynamics", "FaultEvent", "FaultKind", "LinkFaults", "SimConfig", "SimFleet",
           "VehicleState", "grid_layout"]


__getattr__ = lazy_names(__name__, _HOMES)
