"""Blender UI of RVR-LAAF: panels only (they draw what operators/ defines)."""
from __future__ import annotations

from . import vse

_modules = (vse,)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
