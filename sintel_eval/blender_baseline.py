"""Blender's own Compositor *Defocus* node as a baseline renderer (bench/blender_defocus.py).

The implementation lives in ``bench/blender_defocus.py`` (documented there: how the node maps
a per-pixel radius, its footprint versus our disk kernel). :func:`load_blender_defocus` is the
one loader of that file for the benchmarks and the harness: it executes it once under the
module name ``rvr_bench_blender_defocus`` registered in ``sys.modules`` (its dataclasses need
that) and returns the cached module afterwards. Loading imports bpy on first use.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np

from rvr_addon.errors import InputError

MODULE_NAME = "rvr_bench_blender_defocus"
SOURCE = Path(__file__).resolve().parents[1] / "bench" / "blender_defocus.py"


def load_blender_defocus() -> ModuleType:
    """The module of bench/blender_defocus.py (loaded once, then taken from sys.modules).

    Raises InputError if the file is missing (a partial checkout) and ImportError if bpy is
    not installed (run ./scripts/setup.sh).
    """
    mod = sys.modules.get(MODULE_NAME)
    if mod is not None:
        return mod
    if not SOURCE.is_file():
        raise InputError(f"'{SOURCE}' is missing; restore it from the repository (git checkout bench/).")
    import bpy  # noqa: F401  (fail here with the clear ImportError, not inside the module)

    spec = importlib.util.spec_from_file_location(MODULE_NAME, SOURCE)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[MODULE_NAME] = mod  # @dataclass resolves its module through sys.modules
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        del sys.modules[MODULE_NAME]
        raise
    return mod


def blender_defocus_linear(image_srgb: np.ndarray, radius_px: np.ndarray) -> np.ndarray:
    """Blur an 8-bit sRGB frame with Blender's Defocus node; returns linear RGB (H, W, 3) float32.

    image_srgb: (H, W, 3) uint8 sRGB (the node sees its linearisation, values <= 1).
    radius_px: (H, W) float blur radius in px per pixel (>= 0), e.g. ``a |D - f|``; the node's
    blur_max is set to the frame's largest radius (rounded up), so nothing is capped.
    """
    bd = load_blender_defocus()
    radius = np.asarray(radius_px, dtype=np.float32)
    blur_max = float(np.ceil(radius.max())) if radius.size else 0.0
    _, out = bd.blender_defocus(image_srgb, radius, max_radius_px=blur_max, repeats=1, measure=False)
    return np.asarray(out, dtype=np.float32)
