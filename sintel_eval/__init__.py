"""Ground-truth harness: procedural scenes rendered with Cycles through bpy (``python -m sintel_eval``).

Importing the package does not import bpy; ``render_demo_scene`` and ``generate`` do, on first use.

Generator modules: camera_math (lens constants, units; no bpy), scene_plan (seeded scene
description; no bpy), scripts_events (scripts, events, focus tracks; no bpy), speech
(espeak-ng, voice activity, mouths; no bpy), look (seeded style, lighting, figures and photo
texture choices; no bpy), textures (real-image texture library and crops; no bpy), bpy_util /
materials / photo_materials / figures / scene_builder (Blender objects), passes (Cycles
renders), dataset (the clip folder, resume), generate_cli (CLI), cli_args (argparse value types).
"""
from __future__ import annotations

__all__ = ["render_demo_scene", "generate", "GenerateConfig"]


def __getattr__(name: str):
    if name == "render_demo_scene":
        from .demo_scene import render_demo_scene

        return render_demo_scene
    if name in ("generate", "GenerateConfig"):
        from . import dataset

        return getattr(dataset, name)
    raise AttributeError(f"module 'sintel_eval' has no attribute {name!r}")
