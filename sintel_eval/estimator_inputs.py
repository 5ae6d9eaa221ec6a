"""Inputs from the trained RGBD-HDR estimator for the ablation rows ``estimated_disparity`` and
``estimated_hdr`` (:mod:`.variants`).

The weights are the file given to ``python -m sintel_eval ablate ... --estimator-weights W``
(:func:`configure`), else the shipped ``rvr_addon/estimate/weights/estimator.pt`` if it exists.
Without usable weights both rows are reported unavailable with the reason, never faked.

The network runs on each frame's 8-bit input at its native size (as ``rvr estimate`` does). Its
disparity is used **as predicted**, in DESIGN units (px of blur at aperture 1 at the native
width): the network is trained in those units on harness clips, and no per-clip scale or shift
is fitted to the ground truth (a real clip has none to fit to). One frame's (D, E) is computed
once and shared by both rows and every focus track (a small cache keyed by the input's bytes).
"""
from __future__ import annotations

import hashlib
from collections import OrderedDict
from pathlib import Path

import numpy as np

from rvr_addon.color import srgb_to_linear, to_float01
from rvr_addon.errors import InputError
from rvr_addon.render.model import hdr_radiance

from .reader import GTFrame

_state: dict = {"weights": None, "loaded": None, "error": None}
_cache: "OrderedDict[str, tuple[np.ndarray, np.ndarray]]" = OrderedDict()
CACHE_FRAMES = 4


def configure(weights: str | Path | None) -> None:
    """Use these weights for the estimator rows (None: the shipped weights, if any)."""
    _state.update(weights=Path(weights) if weights is not None else None, loaded=None, error=None)
    _cache.clear()


def weights_path() -> Path | None:
    """The weights the rows would use: the configured file, else the shipped one if present."""
    if _state["weights"] is not None:
        return _state["weights"]
    from rvr_addon.estimate.infer import SHIPPED_WEIGHTS

    return SHIPPED_WEIGHTS if SHIPPED_WEIGHTS.is_file() else None


def _estimator():
    if _state["loaded"] is None:
        from rvr_addon.estimate.infer import Estimator, load_estimator

        path = weights_path()
        if path is None:
            raise InputError("no estimator weights")
        _state["loaded"] = Estimator(load_estimator(path))
    return _state["loaded"]


def unavailable() -> str | None:
    """Why the estimator rows cannot run (no weights, unreadable weights), or None."""
    path = weights_path()
    if path is None:
        return ("no trained estimator weights: pass --estimator-weights RUN_DIR/estimator.pt (from `rvr train`), "
                "or ship them as rvr_addon/estimate/weights/estimator.pt")
    if _state["error"] is None and _state["loaded"] is None:
        try:
            _estimator()
        except InputError as ex:
            _state["error"] = str(ex)
    return _state["error"]


def estimate(frame: GTFrame) -> tuple[np.ndarray, np.ndarray]:
    """(D (H, W) DESIGN units, E (H, W, 3)) of the network on the frame's 8-bit input."""
    key = hashlib.sha1(np.ascontiguousarray(frame.input_srgb).tobytes()).hexdigest()
    if key in _cache:
        _cache.move_to_end(key)
        return _cache[key]
    d, e = _estimator()(frame.input_srgb)
    _cache[key] = (d, e)
    while len(_cache) > CACHE_FRAMES:
        _cache.popitem(last=False)
    return d, e


def estimated_disparity(frame: GTFrame) -> np.ndarray:
    """The network's disparity as predicted (DESIGN units, no fit to the ground truth)."""
    return estimate(frame)[0]


def estimated_hdr_radiance(frame: GTFrame) -> np.ndarray:
    """``srgb_to_linear(input) * exp(50 E)`` with the network's E."""
    e = estimate(frame)[1]
    return np.asarray(hdr_radiance(srgb_to_linear(to_float01(frame.input_srgb)), e), dtype=np.float32)
