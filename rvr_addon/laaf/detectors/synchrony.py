"""Face-free speaker localisation by audio-visual synchrony (Hershey & Movellan 2000, "Audio
Vision": the pixels whose change follows the sound are where the sound comes from).

Per analysis frame: the previous grey frame's camera motion is removed with the action
detector's camera-motion model (DIS flow at ``flow_width`` px, homography or, with a disparity
map, plane + parallax: ``ActionDetector.camera_flow``), the current frame is warped back onto
the previous one and the absolute difference, minus its median over the frame (global flicker
and residual misalignment), is the motion energy. It is averaged over a grid of square blocks
(``blocks`` across the width, e.g. 8 px blocks at 320 px): a (rows, cols) map per frame, the
only per-frame state (a few kB).

At frame t the map of Pearson correlations between each block's energy and the audio feature
over a window (``SynchronyLocaliser.correlate``) is taken; the feature is the *change* of the
audio envelope ``|env(t) - env(t-1)|``, because a frame difference measures how much the mouth
opening changed, not how open it is. Only positive correlation counts; the map is smoothed
with a Gaussian of ``sigma_blocks`` and the outermost ring of blocks is dropped (flow and
warping are unreliable at the border). The speaker is at the peak if it reaches ``min_corr``.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from .action import ActionDetector


def pearson_map(series: np.ndarray, feature: np.ndarray) -> np.ndarray:
    """Pearson correlation of each cell's series with ``feature``: series (n, ...) and feature
    (n,) -> (...) float32; cells (or a feature) without variance give 0."""
    s = series.astype(np.float64) - series.mean(axis=0)
    f = feature.astype(np.float64) - feature.mean()
    num = np.tensordot(f, s, axes=(0, 0))
    den = np.sqrt((s * s).sum(axis=0) * float((f * f).sum()))
    out = np.zeros_like(num)
    ok = den > 1e-12
    out[ok] = num[ok] / den[ok]
    return out.astype(np.float32)


class SynchronyLocaliser:
    """Motion-energy block series and their correlation with the audio (module docstring).

    blocks: grid columns across the analysis width (rows follow the aspect). flow_width: px
    width of the camera-motion estimate. keep_frames: frames of block energy kept.
    sigma_blocks: spatial smoothing of the correlation map, in blocks.
    """

    def __init__(self, blocks: int = 40, flow_width: int = 160, keep_frames: int = 96,
                 sigma_blocks: float = 1.0) -> None:
        self.blocks = blocks
        self.keep_frames = keep_frames
        self.sigma_blocks = sigma_blocks
        self.camera = ActionDetector(flow_width=flow_width)
        self._prev: np.ndarray | None = None  # push only
        self._energy: OrderedDict[int, np.ndarray] = OrderedDict()
        self.grid: tuple[int, int] = (0, 0)
        self.shape: tuple[int, int] = (0, 0)

    def _grid(self, shape: tuple[int, int]) -> tuple[int, int]:
        """(rows, cols) of the block grid of frames of this (h, w)."""
        h, w = shape
        cols = max(4, min(self.blocks, w // 2))
        return max(3, int(round(h * cols / w))), cols

    def _small(self, gray: np.ndarray) -> np.ndarray:
        import cv2

        h, w = gray.shape
        fw = min(self.camera.flow_width, w)
        return cv2.resize(gray, (fw, max(int(round(h * fw / w)), 8)), interpolation=cv2.INTER_AREA)

    def measure(self, prev: np.ndarray | None, gray: np.ndarray,
                disparity: np.ndarray | None = None) -> np.ndarray | None:
        """Block motion energy (rows, cols) float32 of (h, w) uint8 grey ``gray`` against the frame
        before (``prev``; None at the first frame: None), the camera's motion removed."""
        import cv2

        if prev is None or prev.shape != gray.shape:
            return None
        h, w = gray.shape
        rows, cols = self._grid(gray.shape)
        small = self._small(gray)
        fh, fw = small.shape
        disp = None
        if disparity is not None and self.camera.use_disparity:
            disp = cv2.resize(disparity, (fw, fh), interpolation=cv2.INTER_AREA)
        _, cam, _ = self.camera.camera_motion(self._small(prev), small, disp)
        cam = cv2.resize(cam, (w, h), interpolation=cv2.INTER_LINEAR) * (w / fw)
        gy, gx = np.mgrid[0:h, 0:w].astype(np.float32)
        back = cv2.remap(gray, gx + cam[..., 0], gy + cam[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        energy = np.abs(back.astype(np.float32) - prev.astype(np.float32))
        energy = np.maximum(energy - float(np.median(energy)), 0.0)
        return cv2.resize(energy, (cols, rows), interpolation=cv2.INTER_AREA)

    def add(self, t: int, shape: tuple[int, int], energy: np.ndarray | None) -> None:
        """Keep frame t's block energy (from :meth:`measure`) for frames of this (h, w)."""
        self.shape = shape
        self.grid = self._grid(shape)
        if energy is not None:
            self._energy[t] = energy
            while len(self._energy) > self.keep_frames:
                self._energy.popitem(last=False)

    def push(self, t: int, gray: np.ndarray, disparity: np.ndarray | None = None) -> None:
        """Ingest frame t (in order): (h, w) uint8 grey and optional disparity of the same size."""
        self.add(t, gray.shape, self.measure(self._prev, gray, disparity))
        self._prev = gray

    def correlate(self, frames: list[int], feature: np.ndarray) -> tuple[np.ndarray | None, int]:
        """Smoothed positive correlation map (rows, cols) of the block energy over ``frames``
        with ``feature`` (one value per frame), border ring zeroed, and the number of frames
        used; (None, n) when fewer than 6 frames have energy or the feature is flat."""
        import cv2

        idx = [i for i, k in enumerate(frames) if k in self._energy]
        if len(idx) < 6 or float(np.ptp(feature[idx])) <= 0:
            return None, len(idx)
        series = np.stack([self._energy[frames[i]] for i in idx])
        if series.shape[1:] != self.grid:
            return None, 0
        corr = np.maximum(pearson_map(series, feature[idx]), 0.0)
        corr = cv2.GaussianBlur(corr, (0, 0), self.sigma_blocks)
        corr[0, :], corr[-1, :], corr[:, 0], corr[:, -1] = 0, 0, 0, 0
        return corr, len(idx)

    def peak(self, corr: np.ndarray) -> tuple[float, float, float]:
        """(value, x, y) of the map's maximum; x, y at the block centre in analysis px."""
        i, j = np.unravel_index(int(np.argmax(corr)), corr.shape)
        rows, cols = corr.shape
        h, w = self.shape
        return float(corr[i, j]), (j + 0.5) * w / cols, (i + 0.5) * h / rows
