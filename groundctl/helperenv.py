"""Imported first by the helpers' fork server (:mod:`groundctl.processes`), before numpy.
Nothing else imports this module (its import is its effect):

* OpenBLAS, MKL and OpenMP read their thread counts when they load;
* the server ignores SIGTERM and SIGHUP (it ignores SIGINT by itself): they reach the
  whole process group, and the ground station lands the fleet on them, with its helpers
  -- which a server killed by the signal would take with it (their sentinels close:
  broken pools in the middle of that landing).  Its children ignore them too, as every
  helper does; the ground station stops them itself.
"""

from __future__ import annotations

import os
import signal

from groundctl.processes import SINGLE_THREADED

for _variable in SINGLE_THREADED:
    os.environ[_variable] = "1"
for _name in ("SIGTERM", "SIGHUP"):
    if hasattr(signal, _name):
        signal.signal(getattr(signal, _name), signal.SIG_IGN)
