"""Imported first by the helpers' fork server (:mod:`groundctl.processes`), before numpy:
OpenBLAS, MKL and OpenMP read their thread counts when they load.  Nothing else imports
this module (its import is its effect)."""

from __future__ import annotations

import os

from groundctl.processes import SINGLE_THREADED

for _variable in SINGLE_THREADED:
    os.environ[_variable] = "1"
