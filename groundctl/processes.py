"""Where the ground station's helper processes come from: a fork server with the
numerical libraries already loaded.

Every helper (the planning worker, the MPC worker, the dry-run's simulator) is a
clean process -- no thread, socket or event loop of the ground station leaks
into it -- but a fresh interpreter (``spawn``) pays about a second of CPU
importing numpy, scipy, OSQP and pymavlink before it can work, once per helper
and per flight.  On Linux the helpers are forked instead from one *fork
server*: a process started once (the first time a helper is needed) from a
clean interpreter, which imports those libraries and then only forks.  Its
children start in milliseconds, as clean as spawned ones (the server runs no
thread of ours), and the import is paid once per ground-station process
(measured on the whole test suite, mostly dry-runs: 477 s of machine CPU, against
at least 603 s with every helper spawned).

Each helper watches the ground station's own process and leaves once it is gone
(:func:`groundctl.flight.workers.settle_worker`; the simulator when its pipe
closes), also after a SIGKILL; the server, which every process it forked keeps
alive, leaves after the last of them.  Elsewhere (no ``forkserver`` start
method) helpers are spawned as before.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
import time
from multiprocessing.context import ForkServerContext, SpawnContext

#: Imported by the fork server before it forks anything; the first one settles it
#: (:func:`settle_helper`) before numpy loads.
PRELOAD = ("groundctl.helperenv", "numpy", "scipy.sparse", "scipy.linalg", "osqp",
           "pymavlink.dialects.v20.ardupilotmega", "groundctl.flight.returning",
           "groundctl.execute.mpc", "groundctl.sim.fleet")

#: Thread-pool sizes of the numerical libraries, pinned in every helper: their matrices
#: are small, and the control loop's process needs a core of its own.
SINGLE_THREADED = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                   "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")

def settle_helper() -> None:
    """What every helper process does first, and the fork server before it forks:

    * ignore the stop signals -- they reach the whole process group (Ctrl-C, a closed
      terminal, a service manager); the ground station decides what they mean (land
      the fleet, which needs its helpers) and stops them itself.  A fork server killed
      by one would take its children with it (their sentinels close: broken pools in
      the middle of that landing);
    * pin the numerical libraries to one thread (OpenBLAS, MKL and OpenMP read it when
      they load, with numpy: a helper forked from the server has it already).
    """
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    for variable in SINGLE_THREADED:
        os.environ[variable] = "1"


#: In the environment the fork server starts with, and only there: the sign for
#: :mod:`groundctl.helperenv` that it runs in the server (anybody else may import it --
#: a test importing every module did -- and a ground station settled as a helper would
#: ignore Ctrl-C, and so would every program it starts).
SERVER_MARK = "GROUNDCTL_HELPER_SERVER"

_context: ForkServerContext | SpawnContext | None = None


def helper_context() -> ForkServerContext | SpawnContext:
    """The multiprocessing context every helper process is started from (its fork
    server running, and settled)."""
    global _context
    if _context is None:
        if "forkserver" in mp.get_all_start_methods():
            ctx = mp.get_context("forkserver")
            ctx.set_forkserver_preload(list(PRELOAD))
            _context = ctx
        else:
            _context = mp.get_context("spawn")
    if _context.get_start_method() == "forkserver":
        from multiprocessing import forkserver

        # The server inherits the environment it starts with: the mark only for it.
        os.environ[SERVER_MARK] = "1"
        try:
            forkserver.ensure_running()
        finally:
            os.environ.pop(SERVER_MARK, None)
    return _context


#: Wall seconds between a helper's looks at whether the process it serves is still there.
PARENT_POLL_S = 0.5


def process_gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (a zombie, dead but not yet reaped, has)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            # "pid (comm) state ...": comm may hold spaces and parentheses.
            return f.read().rsplit(b")", 1)[1].split()[0] in (b"Z", b"X")
    except FileNotFoundError:
        return True
    except OSError:  # no /proc: ask the kernel
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False
        return False


def leave_with(pid: int) -> None:
    """Make this helper leave (``os._exit(0)``) once process ``pid`` -- the one it
    serves -- is gone, also after a SIGKILL that left it no time to say so: a daemon
    thread looks every :data:`PARENT_POLL_S`.  Not "once its parent is gone": a helper's
    parent is the fork server, which lives as long as any process it forked."""
    def watch() -> None:
        while not process_gone(pid):
            time.sleep(PARENT_POLL_S)
        os._exit(0)
    threading.Thread(target=watch, daemon=True, name="parent-watch").start()
