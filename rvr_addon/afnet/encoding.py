"""AF-Net's input encoding, without torch: a frame as the network's input bytes
(:func:`encode_frame`, shared by training data and inference) and those bytes as the network's
float input (:func:`decode_frames_np`; :func:`.model.decode_frames` is the torch twin)."""
from __future__ import annotations

import numpy as np

from .config import AFNetConfig


def normalise_disparity(d: np.ndarray) -> np.ndarray:
    """Per-frame normalised disparity for the network.

    d: (h, w) float disparity in any unit and offset (DESIGN units, an estimate, ...).
    Returns (h, w) float32: (d - median) / (p90 - p10), clipped to [-3, 3]; 0 for a flat or
    non-finite frame.
    """
    d = np.asarray(d, np.float32)
    ok = np.isfinite(d)
    if not ok.any():
        return np.zeros(d.shape, np.float32)
    lo, med, hi = np.percentile(d[ok], (10, 50, 90))
    spread = float(hi - lo)
    if not np.isfinite(spread) or spread < 1e-6:
        return np.zeros(d.shape, np.float32)
    out = np.where(ok, (d - med) / spread, 0.0)
    return np.clip(out, -3.0, 3.0).astype(np.float32)


DISPARITY_CODE_SCALE = 40.0
"""Normalised disparity d is stored as the byte ``round(40 d) + 128`` (steps of 0.025)."""


def encode_frame(rgb: np.ndarray, disparity: np.ndarray | None, config: AFNetConfig) -> np.ndarray:
    """One frame as the network's input channels, as bytes (training data and inference share it).

    rgb: (H, W, 3) uint8 sRGB, any size. disparity: (H', W') float (any size, any unit) or None
    (a zero channel). Returns (C, height, width) uint8 (C = config.channels): the image (RGB or
    gray) and, with ``config.disparity``, :func:`normalise_disparity` coded as
    ``round(40 d) + 128``. :func:`decode_frames` turns it into the network's float input.
    """
    import cv2

    size = (config.width, config.height)
    interp = cv2.INTER_AREA if rgb.shape[1] >= config.width else cv2.INTER_LINEAR
    small = cv2.resize(np.ascontiguousarray(rgb), size, interpolation=interp)
    img = small.transpose(2, 0, 1) if config.rgb else cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)[None]
    if not config.disparity:
        return np.ascontiguousarray(img, dtype=np.uint8)
    if disparity is None:
        code = np.full((1, config.height, config.width), 128, np.uint8)
    else:
        d = np.asarray(disparity, np.float32)
        if (d.shape[1], d.shape[0]) != size:
            d = cv2.resize(d, size, interpolation=cv2.INTER_AREA if d.shape[1] >= config.width else cv2.INTER_LINEAR)
        code = (np.round(normalise_disparity(d) * DISPARITY_CODE_SCALE) + 128).astype(np.uint8)[None]
    return np.ascontiguousarray(np.concatenate([img, code], 0), dtype=np.uint8)


def decode_frames_np(codes: np.ndarray, config: AFNetConfig) -> np.ndarray:
    """Bytes of :func:`encode_frame`, shape (..., C, H, W), -> float32 network input: image in
    [-0.5, 0.5], disparity channel in [-3, 3] (as :func:`.model.decode_frames`)."""
    x = np.asarray(codes).astype(np.float32)
    n_img = 3 if config.rgb else 1
    img = x[..., :n_img, :, :] / np.float32(255.0) - np.float32(0.5)
    if not config.disparity:
        return img
    return np.concatenate([img, (x[..., n_img:, :, :] - np.float32(128.0)) / np.float32(DISPARITY_CODE_SCALE)],
                          axis=-3)
