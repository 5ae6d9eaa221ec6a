"""Brute-force reference of the RVR forward model, for tests and benchmarks only.

Every layer is evaluated on every pixel with the full matte formula, and blurred by an
explicit scatter: each source pixel adds ``value * kernel`` to the pixels its PSF covers
(vectorised over pixels, one kernel offset at a time). No tiles, no FFT, float64.
Slow: minutes at 1080p; use small images.
"""
from __future__ import annotations

import numpy as np

from .aperture import ApertureSpec, make_kernel, zone_edges, zone_offset
from .model import (
    ALPHA_EPS,
    LayerPlan,
    matte_unnormalised,
    plan_for_radius_map,
    signed_radius,
)


def scatter(src: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Spread every pixel of src (H, W, C) into the kernel's footprint; zero outside frame."""
    h, w = src.shape[:2]
    half = kernel.shape[0] // 2
    out = np.zeros_like(src)
    for ky, kx in zip(*np.nonzero(kernel)):
        dy, dx = ky - half, kx - half
        # target (y + dy, x + dx) receives src(y, x) * k
        ty0, ty1 = max(dy, 0), min(h + dy, h)
        tx0, tx1 = max(dx, 0), min(w + dx, w)
        if ty0 >= ty1 or tx0 >= tx1:
            continue
        out[ty0:ty1, tx0:tx1] += kernel[ky, kx] * src[ty0 - dy:ty1 - dy, tx0 - dx:tx1 - dx]
    return out


def spread(src: np.ndarray, spec: ApertureSpec, radius: float) -> np.ndarray:
    """Scatter src (H, W, C) with the aperture of ``radius``; with cat's-eye vignetting each
    source pixel uses the kernel of its zone."""
    if not spec.varies:
        return scatter(src, make_kernel(spec, radius).astype(np.float64))
    h, w = src.shape[:2]
    ys, xs = zone_edges(h, spec.zones), zone_edges(w, spec.zones)
    out = np.zeros_like(src)
    for zy in range(spec.zones):
        for zx in range(spec.zones):
            part = np.zeros_like(src)
            part[ys[zy]:ys[zy + 1], xs[zx]:xs[zx + 1]] = src[ys[zy]:ys[zy + 1], xs[zx]:xs[zx + 1]]
            out += scatter(part, make_kernel(spec, radius, zone_offset(spec, zy, zx)).astype(np.float64))
    return out


def layer_mattes(u: np.ndarray, plan: LayerPlan) -> np.ndarray:
    """Normalised mattes of all layers, (L, H, W) float64, in plan order."""
    g = np.stack([matte_unnormalised(u, np.float32(j)).astype(np.float64) for j in plan.indices])
    return g / g.sum(axis=0, keepdims=True)


def render_reference(
    radiance: np.ndarray,
    disparity: np.ndarray,
    focus: float,
    aperture: float,
    spec: ApertureSpec | None = None,
    plan: LayerPlan | None = None,
    naive: bool = False,
    max_step: float = 1.0,
    min_layers: int = 1,
) -> np.ndarray:
    """Reference shallow-DOF linear radiance (H, W, 3) float32; see model.py for the model."""
    spec = spec or ApertureSpec()
    if aperture == 0:
        return radiance.astype(np.float32, copy=True)
    s = signed_radius(disparity.astype(np.float32), np.float32(focus), np.float32(aperture))
    if plan is None:
        plan = plan_for_radius_map(s, max_step=max_step, min_layers=min_layers)
    u = np.clip(s / np.float32(plan.step), plan.indices.min(), plan.indices.max()).astype(np.float32)
    mattes = layer_mattes(u, plan)
    if not naive:
        # over-compositing alphas: matte over the pixel's coverage from the back up to j
        covered = np.cumsum(mattes, axis=0)
        mattes = np.divide(mattes, covered, out=np.zeros_like(mattes), where=covered > 1e-12)
    rad = radiance.astype(np.float64)
    acc = np.zeros(rad.shape[:2] + (4,), dtype=np.float64)
    for j, m in zip(plan.indices, mattes):
        src = np.concatenate([rad * m[..., None], m[..., None]], axis=2)
        blurred = spread(src, spec, abs(float(j) * plan.step))
        if not naive:
            acc *= 1.0 - blurred[..., 3:4]
        acc += blurred
    return (acc[..., :3] / np.maximum(acc[..., 3:4], ALPHA_EPS)).astype(np.float32)
