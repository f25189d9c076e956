"""ShowRunner: the async driver that flies a plan through a FleetLink.

The decisions live in the pure executor core (:mod:`groundctl.execute`);
this module only times them and carries them out:

1. :meth:`ShowRunner.connect` waits for the fleet's HEARTBEATs;
2. :meth:`ShowRunner.preflight` asks for the telemetry streams and the EKF
   origins, maps vehicles to tracks and repeats the pre-flight checks until
   every vehicle passes (or a check fails that waiting cannot fix: a low
   battery, a vehicle off its slot);
3. :meth:`ShowRunner.fly` runs one loop at ``rate_hz`` of the clock,
   scheduled on absolute deadlines so it never drifts: the sequence's
   actions become link commands (each in its own task, so a slow ACK never
   delays a setpoint), then every streamed vehicle gets its setpoint and,
   when due, its LED colour, then the monitor measures the tick.

Operator commands (:meth:`hold`, :meth:`resume`, :meth:`land_all`,
:meth:`land_one`, :meth:`land_here`, :meth:`kill`) may be called at any time
from the event loop (console, signal handler, test).  Everything notable is
sent to the event sink and to ``notify`` (the operator's screen).

The runner is a package: :mod:`~groundctl.flight.runner.config` holds
:class:`RunnerConfig`, :class:`VehicleRecord`, :class:`FlightBudget`, the constants
and small helpers; :class:`ShowRunner` is one class built in layers, one module
each (each layer derives from the one before it)::

    state      RunnerState: the fields, saying and notifying, records, spawning a task
    preflight  the ground part: connect, the checks, the go gate, settings, the sequence
    commands   actions carried out, the operator's commands, the status line
    planning   the planning workers; returns and ways out planned as tasks
    timing     each vehicle's lead, late vehicles
    stream     the tick's stream, the MPC replan, the guard
    core       ShowRunner: run, and fly (the loop that composes the stages)

The stages themselves are units with their own state and tests, which the layers
feed and carry out: :class:`~groundctl.flight.runner.slots.SendSlots` (a tick's
setpoints over its period), :class:`~groundctl.flight.runner.leds.LedSends` (LED
colours sent ahead of their instant), :class:`~groundctl.execute.lead.LeadEstimator`
and :class:`~groundctl.execute.lead.LateWatch`,
:class:`~groundctl.flight.replanning.Replanner` (MPC) and
:class:`~groundctl.execute.guard.FlightGuard`.
"""

from __future__ import annotations

# Every public name the module had before it became a package stays importable from here.
from groundctl.flight.runner.config import (
    FOLD_AFTER,
    PERMANENT_CHECKS,
    FlightBudget,
    RunnerConfig,
    VehicleRecord,
)
from groundctl.flight.runner.core import ShowRunner

__all__ = [
    "FOLD_AFTER",
    "PERMANENT_CHECKS",
    "FlightBudget",
    "RunnerConfig",
    "ShowRunner",
    "VehicleRecord",
]
