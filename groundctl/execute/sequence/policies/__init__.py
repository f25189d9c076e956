"""Policies: the judgements that decide a vehicle's next move, each in a module of its
own, taking the vehicle's view (its :class:`~groundctl.execute.sequence.types.VehicleRun`,
its telemetry, the fleet-wide facts it needs) and returning a decision; the sequence
(:class:`~groundctl.execute.sequence.ShowSequence`) only carries the decision out (phase
changes, commands, notices) and arbitrates between policies by the order it asks them.

Pure functions of plain data: each is tested without a fleet, a plan or a clock
(``sitl_tests/test_execute_policies.py``).

* :mod:`.battery` -- a low battery: leave the show, land where it is, or land everyone;
* :mod:`.modes` -- the vehicle left its flight mode by itself: take it back (a link-loss
  failsafe of ours to undo) or respect it (a pilot, a fence, a battery failsafe);
* :mod:`.refusals` -- a command refused or without effect: stale, done already (judged
  by its effect: a climb, a land mode), judged later by the climb, retried, or given up;
* :mod:`.rejoin` -- a lost vehicle heard again: stands down, stranded off its plan, or
  back in the sequence; one that was landing judged by what it does now;
* :mod:`.waysout` -- a way out handed over: taken, too late (the next instant, a bounded
  number of times) or overtaken; without one, on with the show or down where it holds;
* :mod:`.homing` -- the land-all return when none can be planned: the show flies on to
  its end, every drone lands in columns, or each goes straight to its landing point;
* :mod:`.stranded` -- a vehicle given up as disarmed that flies after all (back, stranded,
  or down where it is), the fleet landed when too many are stranded at once, and where
  a vehicle given up goes;
* :mod:`.lastresort` -- landing in columns: whether a drone's column is clear, and when
  to say that one still waits;
* :mod:`.operator` -- what `land SYSID`, `land-here SYSID` and `kill SYSID` do to the
  vehicle as it is;
* :mod:`.spares` -- which spare takes over a track whose drone left the show, and in
  what order the others try (not yet asked by the sequence: spares are planned, not
  flown; ``docs/architecture.md``, "Still to build").

Holds are the guard's (:mod:`groundctl.execute.guard`, a unit of its own).  The layers
of the sequence carry the decisions out through its own state (see
``docs/architecture.md``, "Still to reshape").
"""
