"""The bound of ANY temporal filter on a clip's per-frame estimates (ablation row
``temporal_ideal_est``).

A temporal filter can only average what the per-frame estimates say about the same scene point
in different frames. The best it could do, given perfect correspondences, unlimited look-ahead
and look-back and no outliers to reject, is to replace every frame's error by the mean error
over every frame that sees the point. This module builds exactly that from the harness's ground
truth:

    X_ideal,t(p) = X_gt,t(p) + mean_{k visible} (X_est,k - X_gt,k)(c_{t->k}(p))     (X = D or E)

with ``c_{t->k}`` the exact correspondence of pixel p of frame t in frame k: back-projected
with the ground-truth planar depth ``Z`` and frame t's camera, projected with frame k's
(``manifest.json`` -> ``camera_per_frame``, the DATASET.md pinhole convention, pixel centres at
``col + 0.5``). Frame k *sees* the point when the projection lands inside it and k's own depth
there agrees within ``DEPTH_TOLERANCE`` (else the point is occluded in k). Pixels no other
frame sees keep their own error. Frames k within ``half_window`` of t take part (the whole of a
harness clip by default).

What it leaves is the part of the estimator's error attached to the scene, which no temporal
filter can remove. So the flicker of this row is the floor of the ``temporal_*_est`` rows:
``(off - filtered) / (off - ideal)`` is the share of the *attainable* flicker reduction a
filter achieves (``bench/temporal_bench.py --dataset``: ``..._attainable_share``).
Correspondences assume a static scene: points on a moving person fail the depth test in most
other frames or land on the wrong part of the person, so the bound is loose there.
"""
from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Iterator

import cv2
import numpy as np

from rvr_addon.errors import InputError

from .reader import GTFrame
from .temporal_inputs import Estimates, estimate_radiance

if TYPE_CHECKING:
    from .variants import InputStage

DEPTH_TOLERANCE = 0.02
"""A point is visible in another frame when that frame's depth there is within this fraction of
the point's own depth in that frame."""
HALF_WINDOW = 36
"""Frames on each side of t whose errors are averaged (the cost grows with its square)."""


def back_project(depth: np.ndarray, f_px: float) -> np.ndarray:
    """(H, W, 4) homogeneous camera-space points (m) of every pixel centre of a frame with planar
    depth ``depth`` (H, W) in m (Blender camera, looking along -Z; DATASET.md pixel convention)."""
    h, w = depth.shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float64) + 0.5, np.arange(h, dtype=np.float64) + 0.5)
    s = depth.astype(np.float64)
    return np.stack([(xs - w / 2.0) * s / f_px, -(ys - h / 2.0) * s / f_px, -s, np.ones_like(s)], axis=-1)


def project_into(points_t: np.ndarray, t_to_k: np.ndarray, f_px: float, depth_k: np.ndarray,
                 tolerance: float = DEPTH_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """Where frame t's camera-space points (:func:`back_project`) land in frame k, and whether k
    sees them. t_to_k: (4, 4) ``world_to_camera_k @ inv(world_to_camera_t)``; depth_k: (H, W)
    planar depth of frame k in m. Returns (maps (H, W, 2) float32 of frame-k pixel-array
    coordinates for ``cv2.remap``, visible (H, W) bool)."""
    h, w = points_t.shape[:2]
    cam_k = points_t @ np.asarray(t_to_k, np.float64).T
    s_k = -cam_k[..., 2]
    ahead = np.isfinite(s_k) & (s_k > 1e-6)
    safe = np.where(ahead, s_k, 1.0)
    maps = np.stack([w / 2.0 + f_px * cam_k[..., 0] / safe - 0.5, h / 2.0 - f_px * cam_k[..., 1] / safe - 0.5],
                    axis=-1).astype(np.float32)
    maps[~ahead] = -1e4
    seen = cv2.remap(depth_k.astype(np.float32), maps, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=np.nan)
    visible = ahead & np.isfinite(seen) & (np.abs(seen - s_k) <= tolerance * safe)
    return maps, visible


def correspondence(depth_t: np.ndarray, world_to_camera_t: np.ndarray, world_to_camera_k: np.ndarray,
                   f_px: float, depth_k: np.ndarray, tolerance: float = DEPTH_TOLERANCE
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where every pixel of frame t lands in frame k, and whether k sees it (:func:`project_into`
    of :func:`back_project`). depth_t, depth_k: (H, W) planar depth in m; world_to_camera_*:
    (4, 4); f_px: focal length in px."""
    t_to_k = np.asarray(world_to_camera_k, np.float64) @ np.linalg.inv(np.asarray(world_to_camera_t, np.float64))
    return project_into(back_project(depth_t, f_px), t_to_k, f_px, depth_k, tolerance)


def ideal_estimates(frames: list[GTFrame], estimates: Estimates, half_window: int = HALF_WINDOW
                    ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(D, E) of the ideal filter for every frame of a clip (see the module docstring).

    Every frame needs ``depth_m`` and ``world_to_camera`` (harness clips written with them);
    InputError otherwise. E stays >= 0 (E_gt >= 0 and the mean error is added only where
    some frame saw the point)."""
    missing = [fr.frame for fr in frames if fr.depth_m is None or fr.world_to_camera is None or fr.f_px is None]
    if missing:
        raise InputError(f"the ideal-filter row needs each frame's depth (channel Z of gt/disparity) and camera "
                         f"(manifest.json camera_per_frame); frame(s) {missing[:5]} lack them: regenerate the clip "
                         "with `python -m sintel_eval generate`")
    errors = []
    for fr in frames:
        d, e = estimates(fr)
        errors.append(np.concatenate([(d - fr.disparity)[..., None], e - fr.exponent], axis=-1).astype(np.float32))
    out = []
    for i, fr in enumerate(frames):
        acc = np.zeros(errors[i].shape, np.float64)
        count = np.zeros(fr.disparity.shape, np.float64)
        points = back_project(fr.depth_m, fr.f_px)  # once per target frame, for every k
        camera_to_world = np.linalg.inv(np.asarray(fr.world_to_camera, np.float64))
        for k in range(max(0, i - half_window), min(len(frames), i + half_window + 1)):
            other = frames[k]
            maps, visible = project_into(points, np.asarray(other.world_to_camera, np.float64) @ camera_to_world,
                                         fr.f_px, other.depth_m)
            carried = cv2.remap(errors[k], maps, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
            visible &= np.isfinite(carried).all(axis=-1)
            acc += np.where(visible[..., None], carried, 0.0)
            count += visible
        mean = np.where(count[..., None] > 0, acc / np.maximum(count, 1.0)[..., None], errors[i])
        d = (fr.disparity + mean[..., 0]).astype(np.float32)
        e = np.maximum(fr.exponent + mean[..., 1:], 0.0).astype(np.float32)
        out.append((d, e))
    return out


def ideal_stage(estimates: Estimates) -> "InputStage":
    """An input stage rendering :func:`ideal_estimates` (buffers the clip; the result is kept for
    the clip's other focus tracks)."""
    from .variants import RenderInputs

    memo: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}  # the last clip's result

    def stage(frames: Iterator[GTFrame]) -> Iterator[tuple[GTFrame, RenderInputs]]:
        clip = list(frames)
        if not clip:
            return
        digest = hashlib.sha1()
        for fr in clip:
            digest.update(np.ascontiguousarray(fr.input_srgb).tobytes())
        digest.update(np.ascontiguousarray(estimates(clip[0])[0]).tobytes())  # other weights: other result
        key = digest.hexdigest()
        if key not in memo:
            memo.clear()  # one clip at a time: its tracks follow each other
            memo[key] = ideal_estimates(clip, estimates)
        for fr, (d, e) in zip(clip, memo[key]):
            yield fr, RenderInputs(fr.input_srgb, estimate_radiance(fr.input_srgb, e), d)

    return stage
