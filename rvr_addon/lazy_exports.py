"""Package exports imported on first use (PEP 562), so that importing a light submodule (or
building the ``rvr`` parser) loads no NumPy, OpenCV or torch. Standard library only."""
from __future__ import annotations

import importlib
from typing import Any, Callable


def lazy_getattr(package: str, table: dict[str, str], namespace: dict[str, Any]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: ``table`` maps an exported name to the relative
    module defining it (``".maps"``); the first access imports it and caches the value in
    ``namespace`` (the package's ``globals()``); other names raise AttributeError."""

    def __getattr__(name: str) -> Any:
        if name not in table:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(table[name], package), name)
        namespace[name] = value
        return value

    return __getattr__
