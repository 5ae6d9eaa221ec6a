"""Ground-truth harness: procedural scenes rendered with Cycles through bpy (``python -m sintel_eval``).

Importing the package does not import bpy; ``render_demo_scene`` does, on first use.
"""
from __future__ import annotations

__all__ = ["render_demo_scene"]


def __getattr__(name: str):
    if name == "render_demo_scene":
        from .demo_scene import render_demo_scene

        return render_demo_scene
    raise AttributeError(f"module 'sintel_eval' has no attribute {name!r}")
