"""Blender UI of RVR-LAAF: panels, the target list and the preview overlay (they draw what
operators/ defines)."""
from __future__ import annotations

from . import overlay, vse

_modules = (vse, overlay)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
