"""Show model, show-file loader and formation shapes.

``load_show`` and ``parse_show`` are imported lazily: the planner imports
:mod:`groundctl.show.model`, and the loader imports the planner's assignment.
"""

from __future__ import annotations

from typing import Any

__all__ = ["load_show", "parse_show"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from groundctl.show import loader

        return getattr(loader, name)
    raise AttributeError(f"module 'groundctl.show' has no attribute {name!r}")
