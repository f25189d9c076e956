"""groundctl's exceptions: one root, subclasses that keep their data.

The tree::

    GroundctlError                      every error groundctl raises on purpose
    ├── ShowFileError                   a show file that cannot be used (path, where, message)
    ├── InfeasibleTransition            a transition the limits cannot fly (index, needed_time)
    ├── PlanningError                   the optimiser failed (transition, status)
    ├── PlanFileError                   a plan file that cannot be read (path, message)
    │   └── UntrustedPlan               a plan not tied to the show it is flown with (path, show)
    ├── ImportedShowError               a Skybrush .skyc or CSV show that cannot be used
    ├── SkybrushExportError             a plan Skybrush could not load or upload (path, drone)
    ├── WrongFileKind                   a file of another kind than the command reads
    ├── UnsafePlan                      verification found violations (violations)
    ├── LinkError                       MAVLink transport and protocol
    │   ├── CommandRefused              a vehicle answered a command with a refusal
    │   ├── CommandTimeout              no answer after every retry
    │   └── VehicleLost                 a vehicle stopped talking
    ├── PreflightFailed                 pre-flight checks did not pass (failures)
    ├── FlightError                     the flight could not go on (reason)
    │   ├── PlanningTimeout             a plan not ready by its deadline (what, deadline_s)
    │   ├── LifecycleError              a phase change its table does not list (phase, event)
    │   └── NoGo                        the operator did not give the go (the console)
    ├── SimulatorError                  the built-in simulator was misused
    ├── UsageError                      arguments that cannot be used together
    ├── ConsoleUnavailable              --console without a terminal (or with --json)
    ├── ClusterError                    --ray: no ray extra, or the cluster unreachable (address)
    └── RecordingError                  a recording that cannot be read (path, message)
        └── DamagedTlog                 a tlog readable only up to a point (path, offset, ...)

Third-party errors (OSError from sockets, ValueError from TOML, OSQP statuses)
are translated at the boundary with ``raise Ours(...) from exc``.  The CLI
turns any :class:`GroundctlError` into one line on stderr and ``exit_code``.

Every one of them pickles with its message and its data (they cross from the
planning worker process to the flight executor), although their ``__init__``
takes other arguments than the message: see :meth:`GroundctlError.__reduce__`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: Exit codes the CLI uses.  Stable: scripts rely on them.
EXIT_OK = 0
EXIT_UNSAFE = 1  # the command ran but the result is not safe
EXIT_USAGE = 2  # bad input: show file, plan file, arguments
EXIT_INFEASIBLE = 3  # the show cannot be planned within its limits
EXIT_LINK = 4  # the vehicles could not be reached or controlled
EXIT_ABORTED = 5  # the operator (or Ctrl-C) stopped the command


class GroundctlError(Exception):
    """Root of every error groundctl raises on purpose."""

    exit_code: int = EXIT_UNSAFE

    def __reduce__(self) -> tuple[Any, ...]:
        # Exception's own pickling calls ``type(self)(*self.args)``, but ``args`` holds
        # the message while ``__init__`` takes the data (InfeasibleTransition(index,
        # name, ...)): unpickling would fail, or build a wrong message.  Rebuild without
        # ``__init__`` instead: the message from ``args``, the data from ``__dict__``.
        return _rebuild, (type(self), self.args), self.__dict__


def _rebuild(cls: type[GroundctlError], args: tuple[Any, ...]) -> GroundctlError:
    """An instance of ``cls`` with ``args`` but without running its ``__init__``."""
    return cls.__new__(cls, *args)  # BaseException.__new__ sets ``args``


class ShowFileError(GroundctlError):
    """A show file that cannot be used.

    ``where`` names the place inside the file (``formation 3 'star': size``);
    the message says the rule, the value and, where there is one, the fix.
    """

    exit_code = EXIT_USAGE

    def __init__(self, path: str | Path, where: str, message: str) -> None:
        self.path = str(path)
        self.where = where
        self.message = message
        super().__init__(f"{self.path}: {where}: {message}" if where else f"{self.path}: {message}")


class InfeasibleTransition(GroundctlError):
    """A transition that the show's limits cannot fly in the time given."""

    exit_code = EXIT_INFEASIBLE

    def __init__(self, index: int, name: str, needed_time: float, given_time: float,
                 reason: str) -> None:
        self.index = index
        self.name = name
        self.needed_time = needed_time
        self.given_time = given_time
        self.reason = reason
        super().__init__(
            f"transition {index} into '{name}': {reason}; it needs at least "
            f"{needed_time:.1f} s but has {given_time:.1f} s"
        )


class PlanningError(GroundctlError):
    """The optimiser could not produce a plan (OSQP status, no convergence)."""

    exit_code = EXIT_INFEASIBLE

    def __init__(self, transition: int, status: str, detail: str = "") -> None:
        self.transition = transition
        self.status = status
        self.detail = detail
        msg = f"transition {transition}: planner failed: {status}"
        super().__init__(f"{msg} ({detail})" if detail else msg)


class SeparationConflict(PlanningError):
    """The optimiser found no plan that keeps every pair apart within its budget.

    Keeps the drones still in conflict (1-based, worst first, with how close and
    when, on the last iterate) and the formations' spacing that straight lines are
    guaranteed to clear."""

    def __init__(self, transition: int, name: str, reason: str,
                 pairs: Sequence[tuple[int, int, float, float]], conflicts: int,
                 spacing: float, safe_spacing: float) -> None:
        self.name = name
        self.reason = reason
        self.pairs = [tuple(p) for p in pairs]
        self.conflicts = conflicts
        self.spacing = spacing
        self.safe_spacing = safe_spacing
        shown = ", ".join(f"drones {i} and {j} {d:.2f} m apart at t = {t:.1f} s"
                          for i, j, d, t in self.pairs)
        more = conflicts - len(self.pairs)
        if more > 0:
            shown += f" (+{more} more pair{'s' if more > 1 else ''})"
        if spacing < safe_spacing:
            way = (f"its formations' closest slots are {spacing:.2f} m apart: space them at "
                   f"least {safe_spacing:.2f} m (sqrt 2 x min_separation: the straight lines "
                   f"are then conflict-free) or give the transition into '{name}' more time")
        else:
            way = (f"its slots are {spacing:.2f} m apart, so the straight lines of the "
                   "planner's own assignment would be conflict-free: plan the show with "
                   f"groundctl's assignment, or give the transition into '{name}' more time")
        detail = f"{reason}: {shown or 'no pair named'}; {way}"
        super().__init__(transition, "no separation-feasible solution", detail)


class SpareError(GroundctlError):
    """Spare drones that cannot wait where the show file puts them, or nowhere beside the
    show (``[spares]``).  Keeps the spare (0-based) and how close it came, when known."""

    exit_code = EXIT_INFEASIBLE

    def __init__(self, message: str, spare: int | None = None,
                 distance: float | None = None) -> None:
        self.message = message
        self.spare = spare
        self.distance = distance
        super().__init__(message)


class PlanFileError(GroundctlError):
    """A plan file that cannot be read or is not a groundctl plan."""

    exit_code = EXIT_USAGE

    def __init__(self, path: str | Path, message: str) -> None:
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


class UntrustedPlan(PlanFileError):
    """A plan whose limits cannot be trusted: no show to take them from, a show it was
    not planned from, or a plan that disagrees with its own show.

    ``show`` is the show file it was checked against ("" if none was found).
    """

    def __init__(self, path: str | Path, message: str, show: str | Path = "") -> None:
        self.show = str(show)
        super().__init__(path, message)


class ImportedShowError(GroundctlError):
    """A Skybrush show (``.skyc``, or a CSV export) that cannot be read or used."""

    exit_code = EXIT_USAGE

    def __init__(self, path: str | Path, message: str) -> None:
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


class SkybrushExportError(GroundctlError):
    """A plan that cannot be written as a ``.skyc`` Skybrush loads and uploads: too many
    drones for Skybrush, or a drone whose trajectory is past the size Skybrush's server
    sends to a drone (``drone``: its 1-based number, None for the show as a whole)."""

    exit_code = EXIT_USAGE

    def __init__(self, path: str | Path, message: str, drone: int | None = None) -> None:
        self.path = str(path)
        self.message = message
        self.drone = drone
        super().__init__(f"{self.path}: not written: {message}")


class WrongFileKind(GroundctlError):
    """A file that is something else than what the command reads (a show given to
    ``check``, a plan given to ``plan``): says what it is and what is expected."""

    exit_code = EXIT_USAGE

    def __init__(self, path: str | Path, kind: str, expected: str, hint: str = "") -> None:
        self.path = str(path)
        self.kind = kind
        self.expected = expected
        self.hint = hint
        msg = f"{self.path}: is {kind}, not {expected}"
        super().__init__(f"{msg}; {hint}" if hint else msg)


class UnsafePlan(GroundctlError):
    """Verification found at least one violated limit."""

    exit_code = EXIT_UNSAFE

    def __init__(self, violations: Sequence[str]) -> None:
        self.violations = list(violations)
        first = self.violations[0] if self.violations else "unknown violation"
        more = f" (and {len(self.violations) - 1} more)" if len(self.violations) > 1 else ""
        super().__init__(f"plan is unsafe: {first}{more}")


class LinkError(GroundctlError):
    """MAVLink transport or protocol failure."""

    exit_code = EXIT_LINK


class CommandRefused(LinkError):
    """A vehicle answered a command with a refusal (COMMAND_ACK result != ACCEPTED)."""

    def __init__(self, system_id: int, command: str, result: str, reason: str = "") -> None:
        self.system_id = system_id
        self.command = command
        self.result = result
        self.reason = reason
        why = f": {reason}" if reason else ""
        super().__init__(f"vehicle {system_id}: {command} refused ({result}){why}")


class CommandTimeout(LinkError):
    """A command got no answer after every retry."""

    def __init__(self, system_id: int, command: str, attempts: int, timeout_s: float) -> None:
        self.system_id = system_id
        self.command = command
        self.attempts = attempts
        self.timeout_s = timeout_s
        super().__init__(
            f"vehicle {system_id}: no answer to {command} after {attempts} attempts "
            f"({timeout_s:.1f} s each)"
        )


class VehicleLost(LinkError):
    """A vehicle stopped talking for longer than the link timeout."""

    def __init__(self, system_id: int, silent_for_s: float) -> None:
        self.system_id = system_id
        self.silent_for_s = silent_for_s
        super().__init__(f"vehicle {system_id}: lost (silent for {silent_for_s:.1f} s)")


class PreflightFailed(GroundctlError):
    """Pre-flight checks failed; ``failures`` maps system id to the failed checks."""

    exit_code = EXIT_UNSAFE

    def __init__(self, failures: dict[int, list[str]]) -> None:
        self.failures = failures
        parts = [f"vehicle {sid}: {', '.join(why)}" for sid, why in sorted(failures.items())]
        super().__init__("pre-flight checks failed: " + "; ".join(parts))


class FlightError(GroundctlError):
    """The flight could not go on."""

    exit_code = EXIT_UNSAFE

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


class PlanningTimeout(FlightError):
    """A plan (a land-all return, a vehicle's way out) was not ready by its deadline."""

    def __init__(self, what: str, deadline_s: float) -> None:
        self.what = what
        self.deadline_s = deadline_s
        shown = f"{deadline_s:.1f}" if deadline_s >= 0.1 else f"{deadline_s:.1g}"
        super().__init__(f"{what} took longer than its {shown} s deadline")


class LifecycleError(FlightError):
    """A vehicle was moved in a way its lifecycle table does not list: a bug in the
    sequence, stopped where it happens (:mod:`groundctl.execute.sequence.lifecycle`)."""

    def __init__(self, phase: str, event: str, detail: str = "") -> None:
        self.phase = phase
        self.event = event
        super().__init__(f"internal error: a vehicle in phase {phase} cannot take event "
                         f"{event}" + (f" ({detail})" if detail else ""))


class NoGo(FlightError):
    """The operator answered the pre-flight go / no-go with no-go: nothing was armed."""

    exit_code = EXIT_ABORTED

    def __init__(self, reason: str = "no-go: the operator did not give the go; "
                                     "nothing was armed") -> None:
        super().__init__(reason)


class SimulatorError(GroundctlError):
    """The built-in simulator was given something it cannot do."""

    exit_code = EXIT_USAGE


class UsageError(GroundctlError):
    """Command-line arguments that cannot be used together (two --connect the same)."""

    exit_code = EXIT_USAGE


class ConsoleUnavailable(GroundctlError):
    """``--console`` asked for where it cannot be drawn (no terminal, or ``--json``)."""

    exit_code = EXIT_USAGE


class ClusterError(GroundctlError):
    """``--ray``: the ray extra is not installed, or the cluster cannot be reached."""

    exit_code = EXIT_USAGE

    def __init__(self, address: str, message: str) -> None:
        self.address = address
        self.message = message
        super().__init__(message)


class RecordingError(GroundctlError):
    """A flight recording (directory, tlog, event log, show clock) that cannot be read."""

    exit_code = EXIT_USAGE

    def __init__(self, path: str | Path, message: str) -> None:
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


class DamagedTlog(RecordingError):
    """A tlog readable only up to byte ``offset``: cut short or damaged there.

    ``packets`` were read before it; ``stopped_at_unix_s`` is the last good
    record's stamp (None if there was none) and ``show_time_s`` the show time
    it stands for, where known.  What could be read is still replayed.
    """

    def __init__(self, path: str | Path, offset: int, size: int, packets: int, reason: str,
                 stopped_at_unix_s: float | None = None,
                 show_time_s: float | None = None) -> None:
        self.offset = offset
        self.size = size
        self.packets = packets
        self.reason = reason
        self.stopped_at_unix_s = stopped_at_unix_s
        self.show_time_s = show_time_s
        when = f", show time {show_time_s:.2f} s" if show_time_s is not None else ""
        super().__init__(path, f"{reason} at byte {offset} of {size}: replayed the "
                               f"{packets} packets before it{when}")
