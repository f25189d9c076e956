"""Imported first by the helpers' fork server (:mod:`groundctl.processes`), before numpy,
to settle it (:func:`~groundctl.processes.settle_helper`).  Only there: the server
starts with :data:`~groundctl.processes.SERVER_MARK` in its environment, and any
other importer is left as it is."""

from __future__ import annotations

import os

from groundctl.processes import SERVER_MARK, settle_helper

if os.environ.pop(SERVER_MARK, None) == "1":
    settle_helper()
