"""The built-in MAVLink vehicle simulator.

``SimFleet(SimConfig(count=..., flavour=...), clock)`` simulates a fleet of
ArduCopter- or PX4-like vehicles, each on its own UDP socket, whose physics
(:mod:`~groundctl.sim.physics`) is stepped together in numpy.  See
:mod:`groundctl.sim.fleet` for the lifecycle and :mod:`groundctl.sim.faults`
for the fault knobs.
"""

from groundctl.sim.config import Dynamics, SimConfig, grid_layout
from groundctl.sim.faults import FaultEvent, FaultKind, LinkFaults
from groundctl.sim.fleet import SimFleet
from groundctl.sim.state import VehicleState

__all__ = ["Dynamics", "FaultEvent", "FaultKind", "LinkFaults", "SimConfig", "SimFleet",
           "VehicleState", "grid_layout"]
