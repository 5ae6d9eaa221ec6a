"""A photometric check of the parallax cue's depth: a multi-view plane sweep.

The parallax cue triangulates each pixel from dense optical flow. Flow is smooth by design, so
where the frame has little texture, or across a depth edge, it interpolates, and the depth it
gives can be wrong while the flow still passes its own checks (forward-backward agreement,
distance to the epipolar line). The plane sweep asks the pictures themselves instead: for
``planes`` inverse depths q (fronto-parallel planes in the reference view, uniform in q, so
uniform in parallax), every neighbour is warped into the reference view by the plane's
homography ``K (R + T [0 0 q]) K^-1``, the warp is scored by zero-mean normalised
cross-correlation over ``window`` x ``window`` patches, the neighbours' costs are averaged, and each
pixel takes the best plane (refined by a parabola through its neighbours). The sweep needs no
flow and sees all the neighbours at once.

The check keeps the flow's depth (it is finer) and lowers its confidence where the sweep's
best depth disagrees with it by more than ``tolerance`` in log inverse depth: there the
fusion falls back on the other cues. Measured on the HoloLens office walk (real, measured depth;
``rvr eval-estimator --real-video``, docs/depth.md): the whole depth's per-frame error
0.366 -> 0.345 at half the parallax cue's analysis size and 32 planes (full size, 48 planes:
0.344 at about 8x the time; a third of the size: 0.347; 0.347 as shipped: 24 planes, the cue's
sparser pair flow and cheaper memory flow); the sweep's own depth in place of the
flow's was worse (0.375), and so was a two-view sweep per pair (0.350-0.352).

Units: q in the caller's inverse-depth unit (the translations ``T`` given in the same unit's
inverse, i.e. ``x_v = R x_ref + T`` with depth 1/q); images uint8 or float gray of one size; K
in px of that size.
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from .cues import scale_K

SWEEP_SHRINK = 2
"""The sweep runs at the analysis size divided by this (its result is upsampled): at full size
the HoloLens figure was the same (0.3441 against 0.3442) at about 5 times the cost."""
SWEEP_PLANES = 24
"""Planes between 0 and ``q_max`` (uniform in inverse depth; the best is refined by a parabola).
HoloLens office, with the pairs' flow of FLOW_PATCH_STRIDE 4: 0.3467 / 0.3464 / 0.3481 at 16 /
24 / 32 planes (with the flow of stride 3: 0.3451 at 32, 0.3439 at 48)."""
SWEEP_WINDOW = 7
"""Side (px at the sweep's size) of the normalised cross-correlation's patch: the cost's only
aggregation (a guided filter of each cost slice on the frame, radius 5 over 5 px patches,
scored 0.3442 against 0.3439 at about 1.4 times the time)."""
CHECK_TOLERANCE = 0.1
"""|log(q_flow / q_sweep)| above which the flow's depth counts as contradicted."""
CHECK_PENALTY = 0.3
"""Factor on the confidence of a contradicted pixel (not 0: the sweep is wrong too, on
repeated texture and where no neighbour sees the pixel)."""
MIN_TRUSTED = 100
"""Fewer trusted pixels than this: nothing to check (the confidence is returned as is)."""


def plane_sweep(ref: np.ndarray, views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
                K: np.ndarray, q_max: float, planes: int = SWEEP_PLANES,
                window: int = SWEEP_WINDOW) -> np.ndarray:
    """Inverse depth (h, w) float32 of every pixel of ``ref`` by a plane sweep over ``views``.

    ref: (h, w) gray (0..255). views: (gray of the same size, R (3, 3), T (3,)) per neighbour,
    ``x_view = R x_ref + T`` with T in the unit whose inverse q is. K: (3, 3) px at this size.
    q_max: the nearest plane's inverse depth (planes at q_max/planes .. q_max).
    """
    if not views:
        raise ValueError("plane_sweep: no neighbouring view to sweep")
    if planes < 3 or not q_max > 0:
        raise ValueError(f"plane_sweep: need >= 3 planes and q_max > 0, got {planes}, {q_max}")
    ref = np.ascontiguousarray(ref, np.float32)
    h, w = ref.shape
    ks = (int(window), int(window))
    K = np.asarray(K, np.float64)
    Ki = np.linalg.inv(K)
    ref_mean = cv2.boxFilter(ref, -1, ks)
    ref_var = cv2.boxFilter(ref * ref, -1, ks) - ref_mean * ref_mean
    imgs = [(np.ascontiguousarray(g, np.float32), np.asarray(R, np.float64), np.asarray(T, np.float64))
            for g, R, T in views]
    qs = np.linspace(q_max / planes, q_max, planes)
    vol = np.zeros((planes, h, w), np.float32)
    weight = np.float32(1.0 / len(imgs))
    for k, q in enumerate(qs):
        for img, R, T in imgs:
            # outside the neighbour its border is repeated: such pixels score noise there, as
            # their flow does (the cue does not trust a pixel whose flow leaves the frame)
            H = K @ (R + np.outer(T, [0.0, 0.0, q])) @ Ki
            warped = cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                         borderMode=cv2.BORDER_REPLICATE)
            sums = cv2.boxFilter(cv2.merge([warped, warped * warped, ref * warped]), -1, ks)
            m = sums[..., 0]
            var = sums[..., 1] - m * m
            cov = sums[..., 2] - ref_mean * m
            var *= ref_var
            np.maximum(var, 0.0, out=var)
            var += np.float32(4.0)
            cov /= np.sqrt(var)
            vol[k] -= cov  # minus the ZNCC: -1 (equal) .. 1
        vol[k] *= weight
    best = vol.argmin(0)
    b0 = np.clip(best, 1, planes - 2)[None]
    c_lo = np.take_along_axis(vol, b0 - 1, 0)[0]
    c_0 = np.take_along_axis(vol, b0, 0)[0]
    c_hi = np.take_along_axis(vol, b0 + 1, 0)[0]
    den = c_lo - 2.0 * c_0 + c_hi
    off = np.where(den > 1e-6, 0.5 * (c_lo - c_hi) / np.maximum(den, 1e-6), 0.0)
    pos = b0[0] + np.clip(off, -1.0, 1.0)
    return np.interp(pos, np.arange(planes), qs).astype(np.float32)


def checked_confidence(ref: np.ndarray, views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
                       K: np.ndarray, q: np.ndarray, conf: np.ndarray, shrink: int = SWEEP_SHRINK,
                       planes: int = SWEEP_PLANES, tolerance: float = CHECK_TOLERANCE,
                       penalty: float = CHECK_PENALTY) -> tuple[np.ndarray, float | None]:
    """``conf`` times ``penalty`` where the plane sweep of ``views`` contradicts ``q``.

    ref, views, K as :func:`plane_sweep` at q's size (the sweep itself runs ``shrink`` times
    smaller). q: (h, w) inverse depth (NaN unknown); conf: (h, w) 0..1. Returns the new
    confidence and the share of the trusted pixels (conf > 0.5) that were contradicted (None
    when there were too few to check).
    """
    trusted = (conf > 0.5) & np.isfinite(q)
    if trusted.sum() < MIN_TRUSTED or not views:
        return conf, None
    h, w = q.shape
    q_max = 1.3 * float(np.percentile(q[trusted], 99))
    if not q_max > 0:
        return conf, None
    s = int(shrink) if min(h, w) // max(int(shrink), 1) >= 4 * SWEEP_WINDOW else 1
    size = (max(w // s, 1), max(h // s, 1))

    def small(g: np.ndarray) -> np.ndarray:
        return cv2.resize(g, size, interpolation=cv2.INTER_AREA) if s > 1 else g

    Ks = scale_K(K, (w, h), size)
    q_sweep = plane_sweep(small(ref), [(small(g), R, T) for g, R, T in views], Ks, q_max, planes)
    if s > 1:
        q_sweep = cv2.resize(q_sweep, (w, h), interpolation=cv2.INTER_LINEAR)
    with np.errstate(divide="ignore", invalid="ignore"):
        contradicted = ~(np.abs(np.log(q_sweep / q)) < tolerance)
    out = np.where(contradicted, conf * np.float32(penalty), conf).astype(np.float32)
    return out, float((contradicted & trusted).sum() / trusted.sum())
