"""Sparse keyframes that reproduce a per-frame focus track, for Blender F-curves.

Interpolation semantics: **linear between keys**, the value of the first key before it and of
the last key after it (constant extrapolation) -- exactly what ``rvr render --track`` does
(``io.track.resolve_track``) and what a Blender F-curve does with every keyframe's
``interpolation = 'LINEAR'`` and ``extrapolation = 'CONSTANT'``. Keys sit on whole frames;
a Blender tool inserts key ``frame`` at scene frame ``strip.frame_start + frame`` (0-based clip
index here). Linear keys are used rather than Bezier ones because their value between keys
does not depend on handle placement, so the tolerance below is a guarantee.

The fit is greedy and exact: from each key, the next key is placed at the farthest frame whose
straight segment stays within ``tol`` of every frame in between (a feasible-slope cone, O(n)).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INTERPOLATION = "LINEAR"
EXTRAPOLATION = "CONSTANT"


@dataclass(frozen=True)
class Key:
    """frame: 0-based clip index; focus: disparity (DESIGN units); aperture: scale >= 0."""

    frame: int
    focus: float
    aperture: float


def _segment_end(values: list[np.ndarray], tols: list[float], i: int) -> int:
    """Farthest j > i such that the lines i->j of every channel stay within tol on i..j."""
    n = len(values[0])
    lo = [-np.inf] * len(values)
    hi = [np.inf] * len(values)
    best = i + 1
    for j in range(i + 1, n):
        ok = True
        for c, v in enumerate(values):
            slope = (v[j] - v[i]) / (j - i)
            if not lo[c] - 1e-12 <= slope <= hi[c] + 1e-12:
                ok = False
        if ok:
            best = j
        # frame j is an interior point of any longer segment: narrow the cones
        for c, v in enumerate(values):
            lo[c] = max(lo[c], (v[j] - tols[c] - v[i]) / (j - i))
            hi[c] = min(hi[c], (v[j] + tols[c] - v[i]) / (j - i))
            if lo[c] > hi[c]:
                return best
    return best


def keyframes(focus: np.ndarray, aperture: np.ndarray | None = None, tol: float = 0.05,
              aperture_tol: float = 0.005) -> list[Key]:
    """Fewest-greedy linear keys whose interpolation is within ``tol`` of ``focus`` (disparity
    units) and ``aperture_tol`` of ``aperture`` on every frame. focus, aperture: (n,) per frame.
    Raises ValueError for an empty or non-finite track or tol <= 0."""
    f = np.asarray(focus, dtype=np.float64).reshape(-1)
    n = len(f)
    if n == 0:
        raise ValueError("empty focus track")
    a = np.ones(n) if aperture is None else np.asarray(aperture, dtype=np.float64).reshape(-1)
    if len(a) != n:
        raise ValueError(f"focus has {n} frames but aperture {len(a)}")
    if not (np.isfinite(f).all() and np.isfinite(a).all()):
        raise ValueError("focus track holds NaN or infinite values")
    if tol <= 0 or aperture_tol <= 0:
        raise ValueError("tolerances must be > 0")
    # the stored keys are float32-rounded by JSON readers: keep a small margin
    tols = [tol * 0.98, aperture_tol * 0.98]
    keys = [0]
    while keys[-1] < n - 1:
        keys.append(_segment_end([f, a], tols, keys[-1]))
    return [Key(int(k), float(f[k]), float(a[k])) for k in keys]


def evaluate_keys(keys: list[Key], n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame (focus, aperture) of linear keys, constant outside (as a Blender F-curve)."""
    frames = np.array([k.frame for k in keys], dtype=np.float64)
    t = np.arange(n_frames, dtype=np.float64)
    return (np.interp(t, frames, [k.focus for k in keys]).astype(np.float32),
            np.interp(t, frames, [k.aperture for k in keys]).astype(np.float32))
