"""Blender operators, properties and F-curve helpers of RVR-LAAF (Blender state only).

Registered in order by :func:`register` (properties first: the operators read them) and
unregistered in reverse.
"""
from __future__ import annotations

from . import fcurves, ops_analyze, ops_focus, ops_render, prefs, preview, props  # noqa: F401 (preview: no classes)

_modules = (props, prefs, fcurves, ops_render, ops_analyze, ops_focus)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    from . import notes

    for module in reversed(_modules):
        module.unregister()
    notes.stop()
