"""MAVLink link layer: one UDP endpoint for the fleet, per-vehicle state, commands.

Pure protocol modules (no I/O): :mod:`.messages` (what we send),
:mod:`.state` (what we know), :mod:`.trust` (what we believe: reports checked
against the vehicle's own stream), :mod:`.command` (COMMAND_LONG/ACK exchange),
:mod:`.timesync`, :mod:`.quality`, :mod:`.codec`, :mod:`.signing`,
:mod:`.flavours`.  I/O: :mod:`.transport` (socket) and :mod:`.fleet`
(:class:`FleetLink`, the asyncio API).

The names below are imported on first use: a command line that only needs
:mod:`.flavours` (``--autopilot``'s choices) does not load the whole link.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from groundctl.lazy import lazy_names

if TYPE_CHECKING:
    from groundctl.link.command import CommandExchange
    from groundctl.link.flavours import Flavour
    from groundctl.link.fleet import DEFAULT_STREAMS, FleetLink, LinkStats
    from groundctl.link.fleetfile import Endpoint, FleetFileError, load_fleet
    from groundctl.link.signing import SigningConfig
    from groundctl.link.state import VehicleState, apply

#: Each public name and the module it lives in.
_HOMES = {
    "CommandExchange": "command",
    "Flavour": "flavours",
    "DEFAULT_STREAMS": "fleet",
    "FleetLink": "fleet",
    "LinkStats": "fleet",
    "Endpoint": "fleetfile",
    "FleetFileError": "fleetfile",
    "load_fleet": "fleetfile",
    "SigningConfig": "signing",
    "VehicleState": "state",
    "apply": "state",
}

__all__ = ["DEFAULT_STREAMS", "CommandExchange", "Endpoint", "Flavour", "FleetFileError",
           "FleetLink", "LinkStats", "SigningConfig", "VehicleState", "apply", "load_fleet"]


__getattr__ = lazy_names(__name__, _HOMES)
