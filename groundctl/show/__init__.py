"""Show model, show-file loader and formation shapes.

``load_show`` and ``parse_show`` are imported lazily: the planner imports
:mod:`groundctl.show.model`, and the loader imports the planner's assignment.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from groundctl.lazy import lazy_names

if TYPE_CHECKING:
    from groundctl.show.loader import load_show, parse_show

__all__ = ["load_show", "parse_show"]

__getattr__ = lazy_names(__name__, {"load_show": "loader", "parse_show": "loader"})
