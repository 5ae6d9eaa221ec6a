"""Extension preferences: cache location, worker threads, estimator and AF-Net weights.

Keyed by the extension's package name (``__package__`` of the root, e.g.
``bl_ext.user_default.rvr_laaf``), never by a hard-coded name. :func:`get` returns the
preferences, or the defaults when the extension is registered without being enabled as an
add-on (tests that call ``register()`` directly, scripts).
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty

from . import compat
from ..rvr_addon.errors import InputError

ROOT_PACKAGE = __package__.rpartition(".")[0]


class RVR_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ROOT_PACKAGE

    cache_dir: StringProperty(
        name="Cache Location",
        description="Where Analyze writes each clip's cache (one folder per clip under it); // = next to the "
                    ".blend file",
        subtype="DIR_PATH", default="//rvr_cache/", options=compat.PATH_OPTIONS)
    threads: IntProperty(
        name="Threads", description="CPU threads for estimation, flow and rendering (0 = all cores)",
        default=0, min=0, max=256)
    weights_path: StringProperty(
        name="Estimator Weights",
        description="Trained estimator weights (estimator.pt written by `rvr train`); empty = the weights shipped "
                    "with the extension",
        subtype="FILE_PATH", default="", options=compat.PATH_OPTIONS)
    afnet_weights_path: StringProperty(
        name="AF-Net Weights",
        description="Trained AF-Net weights (afnet.pt written by `rvr train-afnet`) for the Learned autofocus "
                    "preset; empty = the weights shipped with the extension",
        subtype="FILE_PATH", default="", options=compat.PATH_OPTIONS)
    afnet_region: EnumProperty(
        name="Learned Focus Region",
        description="Where an NFT of the Learned preset focuses",
        items=(("SPEAKER", "Speaker", "Where a voice starts, the speaker the speech detector localises (faces, mouths, "
                                      "audio-visual synchrony); elsewhere AF-Net's map"),
               ("MAP", "AF-Net Map", "Always AF-Net's own focus-region map (the paper's; about 2.5x faster)")),
        default="SPEAKER")

    def draw(self, context) -> None:
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "cache_dir")
        layout.prop(self, "threads")
        layout.prop(self, "weights_path")
        layout.prop(self, "afnet_weights_path")
        layout.prop(self, "afnet_region")
        try:
            path = weights_file(self)
            layout.label(text=f"Using weights: {path}", icon="CHECKMARK")
        except InputError:
            layout.label(text="No trained weights yet: Analyze needs Disparity maps on the strip", icon="INFO")


@dataclass
class Defaults:
    """The preferences' defaults, used when the extension is not enabled as an add-on."""

    cache_dir: str = "//rvr_cache/"
    threads: int = 0
    weights_path: str = ""
    afnet_weights_path: str = ""
    afnet_region: str = "SPEAKER"


_override: dict = {}


def get(context=None):
    """The extension's preferences (or :class:`Defaults`), with any :func:`override` applied."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ROOT_PACKAGE) if context.preferences is not None else None
    found = addon.preferences if addon is not None and addon.preferences is not None else None
    if not _override and found is not None:
        return found
    base = Defaults() if found is None else Defaults(found.cache_dir, found.threads, found.weights_path,
                                                     found.afnet_weights_path, found.afnet_region)
    return Defaults(**{**base.__dict__, **_override})


@contextmanager
def override(**values):
    """Use other preference values for a while (the command line's --cache-dir, --weights),
    without touching the user's saved preferences."""
    global _override
    old = _override
    _override = {**old, **values}
    try:
        yield
    finally:
        _override = old


def weights_file(prefs) -> Path:
    """The estimator weights to use: the preference if set (it must exist), else the shipped file.

    Raises InputError naming the missing file and the fix.
    """
    from ..rvr_addon.estimate.infer import NO_WEIGHTS_HELP, SHIPPED_ONNX, SHIPPED_WEIGHTS

    if prefs.weights_path:
        path = Path(bpy.path.abspath(prefs.weights_path))
        if not path.is_file():
            raise InputError(f"the estimator weights '{path}' set in Preferences > Add-ons > RVR-LAAF Refocus were "
                             "not found; fix the path or clear it to use the shipped weights")
        return path
    if SHIPPED_WEIGHTS.is_file():
        return SHIPPED_WEIGHTS
    if SHIPPED_ONNX.is_file():  # the extension zip ships the ONNX export only
        return SHIPPED_ONNX
    raise InputError(f"no estimator weights: '{SHIPPED_WEIGHTS}' does not exist yet. Fix: set Preferences > "
                     "Add-ons > RVR-LAAF Refocus > Estimator Weights to a trained estimator.pt, or set the strip's "
                     f"Disparity maps (depth from elsewhere) and Analyze again. ({NO_WEIGHTS_HELP})")


def afnet_weights_file(prefs) -> Path | None:
    """AF-Net weights for the Learned preset: the preference if set (it must exist), else None
    (the engine then uses the shipped file and names the fix when it is missing)."""
    if not prefs.afnet_weights_path:
        return None
    path = Path(bpy.path.abspath(prefs.afnet_weights_path))
    if not path.is_file():
        raise InputError(f"the AF-Net weights '{path}' set in Preferences > Add-ons > RVR-LAAF Refocus were not "
                         "found; fix the path or clear it to use the shipped weights")
    return path


def apply_threads(prefs) -> None:
    """Limit torch, ONNX Runtime and OpenCV to the preferred number of threads (0 = leave the defaults)."""
    n = int(prefs.threads)
    if n <= 0:
        return
    import os

    import cv2

    os.environ["RVR_ONNX_THREADS"] = str(n)  # read when an ONNX network is loaded (rvr_addon.onnxrun.threads)

    cv2.setNumThreads(n)
    try:
        import torch

        torch.set_num_threads(n)
    except ImportError:  # pragma: no cover - torch is a dependency of the estimator only
        pass


classes = (RVR_AP_preferences,)
register, unregister = bpy.utils.register_classes_factory(classes)
