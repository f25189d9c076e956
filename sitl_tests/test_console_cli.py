"""``groundctl dry-run`` with and without a terminal: the console opens on a terminal and
closes on its own when the show is done; without one (or with ``--json``) nothing
changes; ``--console`` where it cannot be drawn is one line and exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from console_fixtures import Terminal

from groundctl.errors import EXIT_OK, EXIT_USAGE

REPO = Path(__file__).resolve().parents[1]
QUICK = REPO / "shows" / "quick.toml"
GROUNDCTL = [sys.executable, "-m", "groundctl"]
ENV = {**os.environ, "PYTHONPATH": str(REPO), "TERM": "xterm-256color", "COLUMNS": "160",
       "LINES": "48"}


def test_dry_run_on_a_terminal_opens_the_console_and_exits_on_its_own(tmp_path: Path) -> None:
    """The README's main job on a terminal: the console comes up, the show flies (``--go``:
    no key pressed), the console closes and the report follows, exit 0."""
    term = Terminal(tmp_path / "rec", "--go", speed=8.0)
    rc = term.finish(timeout=150.0)
    text = term.out.decode(errors="replace")
    assert rc == EXIT_OK, text[-3000:]
    assert "\x1b[?1049h" in text  # the console took the screen (alternate screen) ...
    assert "PRE-FLIGHT" in text or "SHOW" in text
    after = text.rsplit("\x1b[?1049l", 1)[-1]  # ... gave it back, and the report follows
    assert "show quick: SAFE" in after
    assert (tmp_path / "rec" / "events.jsonl").exists()


@pytest.mark.parametrize("extra, message", [
    (["--console"], "--console needs stdin, stdout and stderr to be a terminal"),
    (["--console", "--json"], "--console and --json cannot go together"),
])
def test_console_where_it_cannot_be_drawn_is_one_line(extra: list[str], message: str) -> None:
    out = subprocess.run([*GROUNDCTL, "dry-run", str(QUICK), *extra], capture_output=True,
                         text=True, env=ENV, cwd=REPO, timeout=60, stdin=subprocess.DEVNULL)
    assert out.returncode == EXIT_USAGE
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], out.stderr
