"""Temporal stabilization of disparity and HDR (paper section 4.2): optical flow
(:mod:`.flow`), the occlusion-aware, outlier-robust moving average (:mod:`.filter`), the
cache job behind ``rvr stabilize`` (:mod:`.job`), and SIMULATED inputs for tests and
benchmarks (:mod:`.simulate`)."""
from __future__ import annotations

from ..lazy_exports import lazy_getattr
from .settings import TemporalSettings

__all__ = ["TemporalFilter", "TemporalSettings", "stabilize_stream"]

_LAZY = {"TemporalFilter": ".filter", "stabilize_stream": ".filter"}
"""Exports imported on first use (:mod:`.filter` loads OpenCV; ``rvr --help`` must not)."""

__getattr__ = lazy_getattr(__name__, _LAZY, globals())
