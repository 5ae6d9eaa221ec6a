"""Temporal stabilization of disparity and HDR (paper section 4.2): optical flow
(:mod:`.flow`), the occlusion-aware, outlier-robust moving average (:mod:`.filter`), the
cache job behind ``rvr stabilize`` (:mod:`.job`), and SIMULATED inputs for tests and
benchmarks (:mod:`.simulate`)."""
from __future__ import annotations

from .filter import TemporalFilter, TemporalSettings, stabilize_stream

__all__ = ["TemporalFilter", "TemporalSettings", "stabilize_stream"]
