"""The helpers' fork server (groundctl/processes.py): settled itself, and nobody else."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from groundctl.processes import SINGLE_THREADED, helper_context


def _thread_limits() -> dict[str, str | None]:
    return {v: os.environ.get(v) for v in SINGLE_THREADED}


def test_a_stop_signal_to_the_process_group_leaves_the_helpers_fork_server_alive() -> None:
    from multiprocessing import forkserver

    from groundctl.processes import helper_context

    ctx = helper_context()
    if ctx.get_start_method() != "forkserver":
        pytest.skip("no fork server on this platform")
    probe = ctx.Process(target=time.sleep, args=(0.0,))
    probe.start()  # makes sure the server runs
    probe.join(60.0)
    server = forkserver._forkserver._forkserver_pid  # type: ignore[attr-defined]
    assert server is not None
    for sig in (signal.SIGTERM, signal.SIGHUP):
        os.kill(server, sig)  # as a Ctrl-C-like stop to the whole group would
    time.sleep(0.3)
    os.kill(server, 0)  # still there: the ground station lands the fleet with its helpers
    again = ctx.Process(target=time.sleep, args=(0.0,))
    again.start()
    again.join(60.0)
    assert again.exitcode == 0
    assert forkserver._forkserver._forkserver_pid == server  # type: ignore[attr-defined]


def test_helpers_from_the_fork_server_are_single_threaded() -> None:
    ctx = helper_context()
    if ctx.get_start_method() != "forkserver":
        pytest.skip("no fork server on this platform")
    # Not ``with Pool``: its exit is terminate(), a SIGTERM that helpers ignore (by design,
    # see settle_helper), and it hung when the worker had not yet read its sentinel.
    pool = ctx.Pool(1)
    try:
        limits = pool.apply(_thread_limits)
    finally:
        pool.close()
        pool.join()
    assert set(limits.values()) == {"1"}


def test_importing_the_servers_settling_module_leaves_the_importer_as_it_is() -> None:
    """A test importing every module imported it into pytest's own worker, which then
    ignored Ctrl-C, and so did every `groundctl sim` it started (killed by its tests)."""
    code = ("import signal, os, groundctl.helperenv\n"
            "assert signal.getsignal(signal.SIGINT) is signal.default_int_handler\n"
            "assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL\n"
            "assert 'OMP_NUM_THREADS' not in os.environ\n")
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
