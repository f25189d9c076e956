"""A flight with the console: the Textual app and the flight in one event loop.

:class:`ConsoleSession` wires the pieces to a runner once it exists
(:meth:`ConsoleSession.attach`, the dry-run's ``on_runner`` hook): its event
sink and the link's go through the feed to the recording, its ``notify``
lines go to the log pane, its go gate is the operator's.
:func:`run_with_console` runs the flight beside the app; the flight never
waits on the app, and if the app ends before the flight (it crashed), the
flight goes on with its lines on stderr, as in the plain mode.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from typing import TypeVar

from groundctl.console.app import ConsoleApp
from groundctl.console.commands import Controller, GoGate
from groundctl.console.feed import EventFeed
from groundctl.console.model import ConsoleModel
from groundctl.console.terminal import stderr_lines
from groundctl.flight.runner import ShowRunner

T = TypeVar("T")


class ConsoleSession:
    """The console's objects for one flight.

    ``stop(label)`` stops the flight the way Ctrl-C does; ``go_gate`` False
    arms without asking (``--go``).
    """

    def __init__(self, stop: Callable[[str], None], *, show: str = "",
                 duration_s: float = 0.0, separation_limit_m: float = 0.0,
                 go_gate: bool = True, linger_s: float = 2.0,
                 hangup: Callable[[str], None] | None = None) -> None:
        self.feed = EventFeed()
        self.model = ConsoleModel(show, duration_s, separation_limit_m)
        self.gate = GoGate() if go_gate else None
        self.controller = Controller(self.feed, stop, self.gate)
        self.app = ConsoleApp(self.model, self.controller, self.feed, linger_s=linger_s)
        self.app.on_terminal_lost = self._terminal_lost
        self._hangup = hangup or stop
        self.alive = True
        """False once the app has ended: lines go to stderr again (unless the terminal is
        gone: ``app.terminal_gone``)."""
        _start_resource_tracker()

    def notify(self, text: str) -> None:
        """The runner's ``notify``: the log pane while the console is up; stderr after
        it closed, never waited for; nowhere once the terminal is gone (every line the
        runner says is in the recording's events.jsonl too)."""
        if self.alive:
            self.feed.notice(text)
            return
        if self.app.terminal_gone is None:
            stderr_lines().line(text)

    def _terminal_lost(self, why: str) -> None:
        """The terminal went away under the console: as SIGHUP (it may come too, and
        counts once) -- a no-go before the show, a landing along a planned return in it."""
        self.alive = False
        inner = self.feed.inner
        if inner is not None:
            with contextlib.suppress(Exception):
                inner.emit("terminal_lost", text=f"the operator's terminal is gone: {why}")
        self._hangup(f"terminal closed ({why})")

    def attach(self, runner: ShowRunner) -> None:
        """Wire the console to ``runner`` (before it runs)."""
        inner = runner.events
        self.feed.inner = inner
        runner.events = self.feed
        if runner.link.events is inner:
            runner.link.events = self.feed  # link events (losses, STATUSTEXT) too
        self.feed.now = runner.clock.now
        runner.notify = self.notify
        runner.confirm_go = self.gate
        inner_tick = runner.on_tick  # the dry-run's truth probe: chained, not replaced

        def on_tick(now: float, show_time: float) -> None:
            if inner_tick is not None:
                inner_tick(now, show_time)
            if self.alive:
                try:
                    self.app.tick()
                except Exception:  # the console must never stop the control loop
                    self.alive = False

        runner.on_tick = on_tick
        self.controller.target = runner
        self.model.attach(runner)


def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker now, while ``sys.stderr`` is the real one.

    The flight starts processes (the simulator, the planner and MPC workers) while the
    app runs, and the tracker's first start passes ``sys.stderr.fileno()`` to its
    child: under Textual, whose stand-in stderr has no usable descriptor, that fails
    ("bad value(s) in fds_to_keep").
    """
    from multiprocessing import resource_tracker
    with contextlib.suppress(OSError, ValueError):
        resource_tracker.ensure_running()


async def run_with_console(session: ConsoleSession, flight: Awaitable[T],
                           outcome: Callable[[T], str], *, headless: bool = False,
                           size: tuple[int, int] | None = None) -> T:
    """Run ``flight`` with ``session``'s app beside it; returns what the flight returns.

    The app closes on its own once the flight is over (after showing
    ``outcome(result)`` for its ``linger_s``).
    """
    app = session.app
    flight_task = asyncio.ensure_future(flight)
    app.remember_task_factory()
    app_task = asyncio.ensure_future(app.run_async(headless=headless, size=size))
    text = "the flight ended with an error"
    try:
        await asyncio.wait({flight_task, app_task}, return_when=asyncio.FIRST_COMPLETED)
        if not flight_task.done():
            session.alive = False
            why = "closed" if app_task.exception() is None else \
                f"failed ({app_task.exception()!r})"
            session.notify(f"console {why}: the flight goes on; its lines follow here")
        result = await flight_task
        text = outcome(result)
        return result
    finally:
        if not app_task.done():
            app.call_later(app.flight_over, text)  # in the app's context
            try:
                await asyncio.wait_for(asyncio.shield(app_task), app.linger_s + 10.0)
            except TimeoutError:
                app.exit()
        session.alive = False
        if app_task.done() and not app_task.cancelled():
            app_task.exception()  # retrieved: a crash of the console is not re-raised
