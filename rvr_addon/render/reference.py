"""Brute-force reference of the RVR forward model, for tests and benchmarks only.

Every layer is evaluated on every pixel with the full matte formula, and blurred by an
explicit scatter: each source pixel adds ``value * kernel`` to the pixels its PSF covers
(vectorised over pixels, one kernel offset at a time). Compositing and the fill follow
model.py's steps 4-5 literally (the plain-numpy :func:`.model.push_pull_fill`). No tiles, no
FFT, float64. Slow: minutes at 1080p; use small images.
"""
from __future__ import annotations

import numpy as np

from .aperture import ApertureSpec, make_kernel, zone_edges, zone_offset
from .model import (
    OCCLUSION_DELAY,
    SURFACE_STEPS,
    LayerPlan,
    fill_weight,
    matte_unnormalised,
    plan_for_radius_map,
    push_pull_fill,
    resolve,
    signed_radius,
    visible_fraction,
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
    rad = radiance.astype(np.float64)
    h, w = rad.shape[:2]
    acc = np.zeros((h, w, 3))
    cov = np.zeros((h, w))
    far = np.zeros((h, w))  # F_j: sum of V_i over layers i < j - SURFACE_STEPS
    visible: dict[int, np.ndarray] = {}  # V_i of the layers not yet in `far`
    for j, m in reversed(list(zip(plan.indices.tolist(), mattes))):  # front to back
        blurred = spread(np.concatenate([rad * m[..., None], m[..., None]], axis=2), spec, abs(float(j) * plan.step))
        c, wj = blurred[..., :3], blurred[..., 3]
        for i in sorted(k for k in visible if k < j - SURFACE_STEPS):
            far = far + visible.pop(i)
        hidden = sum((v for i, v in visible.items() if i <= j - OCCLUSION_DELAY), far)  # H_j (step 4)
        if naive:
            t = np.ones((h, w))
        else:
            t = visible_fraction(np.maximum(1.0 - hidden, 0.0), np.maximum(1.0 - far, 0.0), wj)
        acc += t[..., None] * c
        cov += t * wj
        visible[j] = t * wj
    fill = push_pull_fill(rad, fill_weight(cov), u.astype(np.float64))
    return resolve(acc, cov, fill).astype(np.float32)
