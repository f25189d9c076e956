"""Operator commands typed on stdin: what they call, and what bad input says.

The runner is stood in for by a small peer that records the calls it gets
(the seam is :class:`groundctl.commands.flying.OperatorTarget`).
"""

from __future__ import annotations

import pytest

from groundctl.commands.flying import OPERATOR_HELP, operator_line
from groundctl.errors import FlightError


class RecordingRunner:
    """Records every operator call; ``status_line`` answers a fixed line."""

    def __init__(self, fail_with: Exception | None = None) -> None:
        self.calls: list[tuple[object, ...]] = []
        self.fail_with = fail_with

    def _got(self, *call: object) -> None:
        self.calls.append(call)
        if self.fail_with is not None:
            raise self.fail_with

    def hold(self) -> None:
        self._got("hold")

    def resume(self) -> None:
        self._got("resume")

    def land_all(self) -> None:
        self._got("land_all")

    def land_one(self, sysid: int) -> None:
        self._got("land_one", sysid)

    def land_here(self, sysid: int) -> None:
        self._got("land_here", sysid)

    def replace(self, sysid: int) -> None:
        self._got("replace", sysid)

    def kill(self, sysid: int, confirm: bool = False) -> None:
        self._got("kill", sysid, confirm)

    def status_line(self) -> str:
        self._got("status_line")
        return "show t=3.0/33 s [show:9]"


def run(line: str, runner: RecordingRunner | None = None
        ) -> tuple[list[tuple[object, ...]], list[str]]:
    runner = runner or RecordingRunner()
    said: list[str] = []
    operator_line(runner, line, said.append)
    return runner.calls, said


@pytest.mark.parametrize(("line", "call"), [
    ("hold", ("hold",)),
    ("resume\n", ("resume",)),
    ("land", ("land_all",)),
    ("LAND 4", ("land_one", 4)),
    ("  land-here   7 ", ("land_here", 7)),
    ("replace 4", ("replace", 4)),
    ("kill 3 confirm", ("kill", 3, True)),
    ("kill 3", ("kill", 3, False)),  # the runner itself says it needs confirming
])
def test_commands_call_the_runner(line: str, call: tuple[object, ...]) -> None:
    calls, said = run(line)
    assert calls == [call] and said == []


def test_status_and_help_are_said() -> None:
    assert run("status") == ([("status_line",)], ["show t=3.0/33 s [show:9]"])
    assert run("help") == ([], [OPERATOR_HELP])
    assert OPERATOR_HELP.startswith("commands: hold | resume | land")


def test_blank_lines_do_nothing() -> None:
    assert run("") == ([], [])
    assert run("   \n") == ([], [])


def test_an_unknown_verb_is_named_with_the_commands() -> None:
    calls, said = run("lnd")
    assert calls == []
    assert said == [f"unknown command 'lnd'; {OPERATOR_HELP}"]


@pytest.mark.parametrize(("line", "message"), [
    ("land-here", "land-here needs a system id: land-here SYSID"),
    ("kill", "kill needs a system id: kill SYSID confirm"),
    ("land-here x", "land-here: 'x' is not a system id (1-255): land-here SYSID"),
    ("land 0", "land: '0' is not a system id (1-255): land | land SYSID"),
    ("land 256", "land: '256' is not a system id (1-255): land | land SYSID"),
    ("land 3 4", "land takes at most 1 argument, got '4': land | land SYSID"),
    ("land-here 3 now", "land-here takes at most 1 argument, got 'now': land-here SYSID"),
    ("replace", "replace needs a system id: replace SYSID"),
    ("replace 3 now", "replace takes at most 1 argument, got 'now': replace SYSID"),
    ("hold 5", "hold takes no arguments, got '5': hold"),
    ("resume now please", "resume takes no arguments, got 'now please': resume"),
    ("status x", "status takes no arguments, got 'x': status"),
    ("kill 3 yes", "kill: expected the word 'confirm' after the system id, got 'yes': "
                   "kill SYSID confirm"),
    ("kill 3 confirm now", "kill takes at most 2 arguments, got 'now': kill SYSID confirm"),
])
def test_wrong_arguments_say_what_is_wrong_and_call_nothing(line: str, message: str) -> None:
    calls, said = run(line)
    assert calls == []
    assert said == [message]


def test_a_refusal_by_the_runner_is_said_not_raised() -> None:
    runner = RecordingRunner(fail_with=FlightError("the flight has not started"))
    calls, said = run("land 2", runner)
    assert calls == [("land_one", 2)]
    assert said == ["land: the flight has not started"]


def test_stdin_kinds_that_can_carry_operator_lines(tmp_path: pytest.TempPathFactory) -> None:
    import os

    from groundctl.commands.flying import stdin_is_interactive

    read_fd, write_fd = os.pipe()
    with os.fdopen(read_fd) as pipe, open(os.devnull) as devnull:
        assert stdin_is_interactive(pipe)
        assert not stdin_is_interactive(devnull)  # a character device, not a terminal
    os.close(write_fd)
    regular = tmp_path / "commands.txt"  # type: ignore[operator]
    regular.write_text("hold\n")
    with open(regular) as f:
        assert not stdin_is_interactive(f)
    closed = open(os.devnull)  # noqa: SIM115
    closed.close()
    assert not stdin_is_interactive(closed)
    assert not stdin_is_interactive(None)


def test_no_operator_input_from_dev_null_and_no_traceback(monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    """`fly </dev/null` (a service manager): no operator commands, nothing raised in the loop."""
    import asyncio
    import os

    from groundctl.commands.flying import read_operator_commands

    errors: list[dict[str, object]] = []

    async def main() -> None:
        asyncio.get_running_loop().set_exception_handler(lambda _loop, ctx: errors.append(ctx))
        await asyncio.wait_for(read_operator_commands(RecordingRunner(), print),  # type: ignore[arg-type]
                               timeout=5.0)
        await asyncio.sleep(0.05)  # callbacks the reader may have scheduled run now

    with open(os.devnull) as devnull:
        monkeypatch.setattr("sys.stdin", devnull)
        asyncio.run(main())
    assert errors == []
