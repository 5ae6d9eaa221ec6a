"""AF-Net: learned look-ahead focus for any video (paper section 5.3, Fig. 8, Table 2). No bpy.

Modules (one job each): ``model`` (the network: CNN-1 focus-region maps per temporal unit,
CNN-2 NFT probability of the centre frame; input encoding), ``annotations`` (the focus
annotation file: editor exports and weak labels), ``data`` (training clips from harness
ground truth and annotation files; sample drawing), ``train`` (``rvr train-afnet``:
resumable, loss log and plot, exported weights), ``infer`` (weights, streaming inference,
NFT peaks and regions), ``weak`` (weak labels from the AI-assist presets on real clips),
``commands`` (CLI). The LAAF engine uses it through preset ``learned``
(``rvr_addon/laaf/detectors/afnet.py``); ``rvr eval-focus --presets ... learned`` compares it
with the presets.
"""
from __future__ import annotations

from ..lazy_exports import lazy_getattr

from .config import AFNetConfig

__all__ = ["AFNet", "AFNetConfig", "ANNOTATION_FORMAT", "AnnotatedClip", "Annotation", "read_annotations",
           "write_annotations", "DEFAULT_WEIGHTS", "load_afnet", "predict_clip"]

_LAZY = {"ANNOTATION_FORMAT": ".annotations", "AnnotatedClip": ".annotations", "Annotation": ".annotations",
         "read_annotations": ".annotations", "write_annotations": ".annotations", "DEFAULT_WEIGHTS": ".infer",
         "load_afnet": ".infer", "predict_clip": ".infer", "AFNet": ".model"}
"""Exports imported on first use (:mod:`.model` and :mod:`.infer` load torch; ``rvr --help`` must not)."""

__getattr__ = lazy_getattr(__name__, _LAZY, globals())
