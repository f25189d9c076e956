"""Public names of a package imported on first use (PEP 562): a package whose
``__init__`` imported every module made a command line that only needed one of them
load them all (scipy, the simulator, the whole link)."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_names(package: str, homes: Mapping[str, str]) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package`` whose public names live in its submodules:
    ``homes`` maps each name to the submodule (relative to ``package``) it comes from."""

    def __getattr__(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{home}"), name)

    return __getattr__
