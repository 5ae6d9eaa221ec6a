"""Saliency detector H_sal: OpenCV contrib's static saliency (fine-grained centre-surround,
Montabone & Soto 2010, by default; or spectral residual, Hou & Zhang 2007), standing in for
the paper's deep saliency network (no weights can be downloaded here).

The raw map (computed at 160 px width, smoothed) is normalised per frame: heat = 0.5 * s /
(mean(s) + k_std * std(s)), clipped to [0, 1], so a pixel is "salient" (heat >= 0.5) when it
stands ``k_std`` deviations above the frame's mean saliency. The default k_std = 0 keeps the
more salient ~40% of the frame: a classical saliency map is a weak cue, so in the action
preset it only removes the flattest background from the moving regions.
"""
from __future__ import annotations

import time

import numpy as np

from .base import AnalysisFrame, DetectorOutput, FocusDetector


class SaliencyDetector(FocusDetector):
    """H_sal; method: 'fine_grained' (default: object-sized blobs) or 'spectral_residual'
    (faster, but it marks small bright spots, not people); computed at ``width`` px."""

    name = "saliency"

    def __init__(self, method: str = "fine_grained", k_std: float = 0.0, blur_frac: float = 0.03,
                 width: int = 160) -> None:
        import cv2

        if method == "spectral_residual":
            self._sal = cv2.saliency.StaticSaliencySpectralResidual_create()
        elif method == "fine_grained":
            self._sal = cv2.saliency.StaticSaliencyFineGrained_create()
        else:
            raise ValueError(f"saliency method {method!r}: use 'spectral_residual' or 'fine_grained'")
        self.method = method
        self.width = width
        self.k_std = k_std
        self.blur_frac = blur_frac
        self._heat: dict[int, np.ndarray] = {}
        self._seconds = 0.0
        self._n = 0

    def compute(self, rgb: np.ndarray) -> np.ndarray:
        """Heat (h, w) float32 0..1 of one (h, w, 3) uint8 frame (see the module docstring)."""
        import cv2

        small = rgb
        if rgb.shape[1] > self.width:
            h = max(int(round(rgb.shape[0] * self.width / rgb.shape[1])), 8)
            small = cv2.resize(rgb, (self.width, h), interpolation=cv2.INTER_AREA)
        ok, sal = self._sal.computeSaliency(cv2.cvtColor(small, cv2.COLOR_RGB2BGR))
        if not ok:
            return np.zeros(rgb.shape[:2], np.float32)
        sal = sal.astype(np.float32)
        if sal.shape != rgb.shape[:2]:
            sal = cv2.resize(sal, (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_LINEAR)
        sigma = self.blur_frac * max(sal.shape)
        if sigma > 0.5:
            sal = cv2.GaussianBlur(sal, (0, 0), sigma)
        thr = float(sal.mean() + self.k_std * sal.std())
        return np.clip(0.5 * sal / max(thr, 1e-6), 0.0, 1.0)

    measures = True

    def measure(self, frame: AnalysisFrame, prev: AnalysisFrame | None, faces: list) -> np.ndarray:
        """The frame's heat map (``compute``)."""
        return self.compute(frame.rgb)

    def process(self, t: int, frame: AnalysisFrame) -> None:
        start = time.perf_counter()
        heat = self.measure(frame, None, [])
        self._seconds += time.perf_counter() - start
        self.ingest(t, frame, heat)

    def ingest(self, t: int, frame: AnalysisFrame, heat: np.ndarray) -> None:
        self._heat = {t: heat}
        self._n += 1

    def output(self, t: int) -> DetectorOutput:
        return DetectorOutput(self._heat.get(t))

    def metrics(self) -> dict:
        return {"method": self.method, "s_per_frame": self._seconds / max(self._n, 1)}
