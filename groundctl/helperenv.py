"""Imported first by the helpers' fork server (:mod:`groundctl.processes`), before numpy,
to settle it (:func:`~groundctl.processes.settle_helper`).  Nothing else imports this
module: its import is its effect."""

from __future__ import annotations

from groundctl.processes import settle_helper

settle_helper()
