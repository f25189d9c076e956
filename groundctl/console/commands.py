"""What the console's keys and command line do: pure, no Textual.

:class:`Controller` turns a key or a typed line into a call on the runner,
asking first where a mistake cannot be undone: land all and quit ask ``y``,
kill asks the operator to type the vehicle's system id, go asks ``y``.  Bad
input and the runner's refusals become a line in the console's log, never an
exception.  Every step (asked, confirmed, cancelled, refused, bad input) is an
event (``console``) in ``events.jsonl``; the commands themselves are logged by
the runner (``operator``).

:class:`GoGate` is the runner's ``confirm_go``: it waits for the operator's go.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from groundctl.commands.flying import OperatorTarget
from groundctl.console.feed import EventFeed
from groundctl.errors import GroundctlError
from groundctl.execute.preflight import PreflightReport
from groundctl.vehicleid import parse_vehicle


class ConsoleTarget(OperatorTarget, Protocol):
    """What the console acts on: the typed commands' target, and exclusion before arming
    (a :class:`~groundctl.flight.runner.ShowRunner`)."""

    def exclude(self, sysid: int) -> None: ...


class GoGate:
    """The runner's ``confirm_go``: awaited once the pre-flight passed, answered by the
    operator (:meth:`decide`)."""

    def __init__(self) -> None:
        self._future: asyncio.Future[bool] | None = None
        self.report: PreflightReport | None = None
        """The report the question was asked with."""

    async def __call__(self, report: PreflightReport) -> bool:
        self.report = report
        self._future = asyncio.get_running_loop().create_future()
        try:
            return await self._future
        finally:
            self._future = None

    @property
    def waiting(self) -> bool:
        """The runner waits for the answer now."""
        return self._future is not None and not self._future.done()

    def decide(self, go: bool) -> bool:
        """Answer; False if nobody was waiting."""
        if not self.waiting:
            return False
        assert self._future is not None
        self._future.set_result(go)
        return True


@dataclass(frozen=True)
class Question:
    """A confirmation the console waits for."""

    action: str
    """``land-all``, ``kill``, ``go``, ``quit``."""
    prompt: str
    """What the operator is asked."""
    sysid: int | None = None
    """The vehicle (kill)."""


HELP = ("keys: h hold, r resume, a land all, l land selected, d land-here selected, "
        "e replace selected (a spare takes its track), k kill selected, x exclude selected "
        "(pre-flight), g go, q quit, p problems only, s sort, f log of selected, "
        "v pre-flight/fleet view, : command line.  commands: hold | resume | land [SYSID] | "
        "land-here SYSID | replace SYSID | kill SYSID | exclude SYSID | go | no-go | quit | "
        "status | log [SYSID|all] | help")

_ARGS = {"hold": 0, "resume": 0, "land": 1, "land-here": 1, "replace": 1, "kill": 1,
         "exclude": 1, "go": 0,
         "no-go": 0, "quit": 0, "status": 0, "help": 0, "log": 1}


class Controller:
    """Keys and command lines to runner calls (see the module docstring).

    ``stop(label)`` stops the flight the way Ctrl-C does (the first time lands
    everyone, the second abandons); ``log_filter`` is set by ``log SYSID``.
    """

    def __init__(self, feed: EventFeed, stop: Callable[[str], None],
                 gate: GoGate | None = None) -> None:
        self.feed = feed
        self.stop = stop
        self.gate = gate
        self.target: ConsoleTarget | None = None
        self.question: Question | None = None
        """The confirmation asked for now (None: none)."""
        self.log_filter: int | None = None
        self.stopping = 0
        """How many times the operator confirmed quit."""

    # -- saying and logging ----------------------------------------------------------
    def say(self, text: str, sysid: int | None = None, **fields: object) -> None:
        """A line in the console's log and a ``console`` event."""
        self.feed.console(text, sysid)
        inner = self.feed.inner
        if inner is not None:
            inner.emit("console", text=text, system_id=sysid, **fields)

    def _ask(self, q: Question) -> None:
        self.question = q
        self.say(q.prompt, q.sysid, step="asked", action=q.action)

    def _call(self, what: str, call: Callable[[ConsoleTarget], None],
              sysid: int | None = None) -> None:
        if self.target is None:
            self.say(f"{what}: no flight yet (the vehicles are still being connected)",
                     sysid, step="refused", action=what)
            return
        try:
            call(self.target)
        except GroundctlError as exc:  # the runner refused: said, never raised
            text = str(exc)
            self.say(text if text.startswith(what) else f"{what}: {text}", sysid,
                     step="refused", action=what)
            return
        self.say(f"{what}: sent", sysid, step="done", action=what)

    # -- keys -------------------------------------------------------------------------
    def hold(self) -> None:
        self._call("hold", lambda t: t.hold())

    def resume(self) -> None:
        self._call("resume", lambda t: t.resume())

    def land_all(self) -> None:
        self._ask(Question("land-all", "land ALL vehicles and end the show? y / n"))

    def land_one(self, sysid: int | None) -> None:
        if self._need(sysid, "land"):
            assert sysid is not None
            self._call(f"land {sysid}", lambda t: t.land_one(sysid), sysid)

    def land_here(self, sysid: int | None) -> None:
        if self._need(sysid, "land-here"):
            assert sysid is not None
            self._call(f"land-here {sysid}", lambda t: t.land_here(sysid), sysid)

    def replace(self, sysid: int | None) -> None:
        if self._need(sysid, "replace"):
            assert sysid is not None
            self._call(f"replace {sysid}", lambda t: t.replace(sysid), sysid)

    def kill(self, sysid: int | None) -> None:
        if self._need(sysid, "kill"):
            assert sysid is not None
            self._ask(Question("kill", f"KILL vehicle {sysid}: its motors stop and it falls. "
                                       f"Type {sysid} and Enter to confirm, anything else "
                                       "cancels", sysid))

    def exclude(self, sysid: int | None) -> None:
        if self._need(sysid, "exclude"):
            assert sysid is not None
            self._call(f"exclude {sysid}", lambda t: t.exclude(sysid), sysid)

    def go(self) -> None:
        if self.gate is None:
            self.say("go: no go gate in this run (--go): the show arms once the pre-flight "
                     "passes", step="refused", action="go")
        elif not self.gate.waiting:
            self.say("go: not yet: the pre-flight checks have not all passed (see the "
                     "pre-flight view)" if self.target is not None and not self._armed()
                     else "go: not waiting for a go", step="refused", action="go")
        else:
            self._ask(Question("go", "GO: arm and fly the show? y / n"))

    def no_go(self) -> None:
        if self.gate is None or not self.gate.waiting:
            self.say("no-go: not waiting for a go (quit stops the flight)", step="refused",
                     action="no-go")
            return
        self.gate.decide(False)
        self.say("no-go: nothing is armed; the flight ends", step="done", action="no-go")

    def quit(self) -> None:
        if self.stopping:
            self._ask(Question("quit", "quit again: ABANDON the flight to the vehicles' own "
                                       "failsafes? y / n"))
        elif self._armed():
            self._ask(Question("quit", "quit: land every vehicle first (as Ctrl-C does)? "
                                       "y / n"))
        else:
            self._ask(Question("quit", "quit: nothing is armed; end the flight? y / n"))

    def _armed(self) -> bool:
        return getattr(self.target, "sequence", None) is not None

    def _need(self, sysid: int | None, verb: str) -> bool:
        if sysid is None:
            self.say(f"{verb}: select a vehicle in the table first (or type {verb} SYSID)",
                     step="bad_input", action=verb)
            return False
        return True

    # -- answers ----------------------------------------------------------------------
    def answer(self, text: str) -> None:
        """The operator's answer to :attr:`question`."""
        q, self.question = self.question, None
        if q is None:
            return
        word = text.strip().lower()
        if q.action == "kill":
            if word == str(q.sysid):
                self.say(f"kill {q.sysid}: confirmed", q.sysid, step="confirmed",
                         action="kill")
                sysid = q.sysid
                assert sysid is not None
                self._call(f"kill {sysid}", lambda t: t.kill(sysid, confirm=True), sysid)
            else:
                self.say(f"kill {q.sysid}: cancelled (typed {text.strip()!r}, not "
                         f"{q.sysid})", q.sysid, step="cancelled", action="kill")
            return
        if word not in ("y", "yes"):
            self.say(f"{q.action}: cancelled", step="cancelled", action=q.action)
            return
        self.say(f"{q.action}: confirmed", step="confirmed", action=q.action)
        if q.action == "land-all":
            self._call("land all", lambda t: t.land_all())
        elif q.action == "go":
            if self.gate is None or not self.gate.decide(True):
                self.say("go: the runner no longer waits for a go", step="refused",
                         action="go")
        elif q.action == "quit":
            self.stopping += 1
            if self.gate is not None and self.gate.waiting:
                self.gate.decide(False)  # a no-go: nothing was armed
                return
            self.stop("quit (console)")

    def cancel(self) -> None:
        """Escape: the question asked is dropped."""
        if self.question is not None:
            q, self.question = self.question, None
            self.say(f"{q.action}: cancelled", q.sysid, step="cancelled", action=q.action)

    # -- the command line -------------------------------------------------------------
    def line(self, text: str) -> None:
        """One typed line: the answer to the question asked, or a command."""
        if self.question is not None:
            self.answer(text)
            return
        words = text.split()
        if not words:
            return
        verb, rest = words[0].lower(), words[1:]
        if verb not in _ARGS:
            self.say(f"unknown command {words[0]!r}; {HELP}", step="bad_input",
                     action=words[0][:40])
            return
        if len(rest) > _ARGS[verb]:
            self.say(f"{verb}: too many arguments {' '.join(rest)!r}; {HELP}",
                     step="bad_input", action=verb)
            return
        sysid: int | None = None
        if rest and not (verb == "log" and rest[0].lower() == "all"):
            try:
                sysid = parse_vehicle(rest[0])
            except ValueError:
                sysid = -1
            if sysid < 1:
                self.say(f"{verb}: {rest[0]!r} is not a system id (1-255)", step="bad_input",
                         action=verb)
                return
        if verb in ("land-here", "replace", "kill", "exclude") and sysid is None:
            self.say(f"{verb} needs a system id: {verb} SYSID", step="bad_input", action=verb)
            return
        self._verb(verb, sysid, rest)

    def _verb(self, verb: str, sysid: int | None, rest: list[str]) -> None:
        if verb == "hold":
            self.hold()
        elif verb == "resume":
            self.resume()
        elif verb == "land":
            if sysid is None:
                self.land_all()
            else:
                self.land_one(sysid)
        elif verb == "land-here":
            self.land_here(sysid)
        elif verb == "replace":
            self.replace(sysid)
        elif verb == "kill":
            self.kill(sysid)
        elif verb == "exclude":
            self.exclude(sysid)
        elif verb == "go":
            self.go()
        elif verb == "no-go":
            self.no_go()
        elif verb == "quit":
            self.quit()
        elif verb == "status":
            self.say(self.target.status_line() if self.target is not None
                     else "no flight yet")
        elif verb == "log":
            self.log_filter = sysid
            self.feed.console("log: " + (f"vehicle {sysid} only" if sysid is not None
                                         else "fleet-wide"))
        else:
            self.feed.console(HELP)
