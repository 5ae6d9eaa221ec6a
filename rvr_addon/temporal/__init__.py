"""Temporal stabilization of disparity and HDR (paper section 4.2): optical flow
(:mod:`.flow`), the occlusion-aware, outlier-robust moving average (:mod:`.filter`), the
cache job behind ``rvr stabilize`` (:mod:`.job`), and SIMULATED inputs for tests and
benchmarks (:mod:`.simulate`)."""
from __future__ import annotations

from .settings import TemporalSettings

__all__ = ["TemporalFilter", "TemporalSettings", "stabilize_stream"]

_LAZY = {"TemporalFilter": ".filter", "stabilize_stream": ".filter"}
"""Exports imported on first use (:mod:`.filter` loads OpenCV; ``rvr --help`` must not)."""


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    globals()[name] = value
    return value
