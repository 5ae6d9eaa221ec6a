"""Differentiable torch implementation of the RVR forward model (for training).

Same model as :mod:`.model` (and the fast path): soft layer mattes of the signed radius,
per-layer aperture blur, back-to-front "over" compositing with blurred mattes, normalised
by accumulated coverage. Gradients flow to the radiance (hence to E) and, through the
mattes, to the disparity. Layer radii are fixed per call (the plan is taken from the
detached radius range), as in the paper.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from .aperture import ApertureSpec, make_kernel, zone_edges, zone_offset
from .model import ALPHA_EPS, LayerPlan, layer_alpha, matte_unnormalised, plan_layers

DIRECT_MAX_SIDE = 11
"""Kernels up to this side are applied by direct (grouped) convolution, larger via FFT."""


def _as_batch(value, batch: int, like: torch.Tensor) -> torch.Tensor:
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        t = t.expand(batch)
    return t.reshape(batch, 1, 1, 1)


def scatter_blur(x: torch.Tensor, kernel: np.ndarray) -> torch.Tensor:
    """Spread each pixel of x (B, C, H, W) by the PSF ``kernel`` (2R+1)^2; zero outside.

    A scatter equals a true convolution with the PSF (correlation with the flipped PSF).
    """
    side = kernel.shape[0]
    if side == 1:
        return x * float(kernel[0, 0])
    half = side // 2
    b, c, h, w = x.shape
    if side <= DIRECT_MAX_SIDE:
        k = torch.as_tensor(np.ascontiguousarray(kernel[::-1, ::-1]), dtype=x.dtype, device=x.device)
        k = k.expand(c, 1, side, side)
        return F.conv2d(x, k, padding=half, groups=c)
    fh, fw = h + side - 1, w + side - 1
    k = torch.as_tensor(kernel, dtype=x.dtype, device=x.device)
    spec = torch.fft.rfft2(x, s=(fh, fw)) * torch.fft.rfft2(k, s=(fh, fw))
    full = torch.fft.irfft2(spec, s=(fh, fw))
    return full[..., half:half + h, half:half + w]


def spread(x: torch.Tensor, spec: ApertureSpec, radius: float) -> torch.Tensor:
    """Scatter x (B, C, H, W) with the aperture of ``radius``; with cat's-eye vignetting each
    source pixel uses the kernel of its zone (same model as the other paths)."""
    if not spec.varies:
        return scatter_blur(x, make_kernel(spec, radius))
    h, w = x.shape[-2:]
    ys, xs = zone_edges(h, spec.zones), zone_edges(w, spec.zones)
    out = torch.zeros_like(x)
    for zy in range(spec.zones):
        for zx in range(spec.zones):
            mask = torch.zeros(1, 1, h, w, dtype=x.dtype, device=x.device)
            mask[..., ys[zy]:ys[zy + 1], xs[zx]:xs[zx + 1]] = 1.0
            out = out + scatter_blur(x * mask, make_kernel(spec, radius, zone_offset(spec, zy, zx)))
    return out


def render_torch(
    radiance: torch.Tensor,
    disparity: torch.Tensor,
    focus,
    aperture,
    spec: ApertureSpec | None = None,
    plan: LayerPlan | None = None,
    naive: bool = False,
    max_step: float = 1.0,
    min_layers: int = 1,
) -> torch.Tensor:
    """Shallow-DOF linear radiance (B, 3, H, W).

    radiance: (B, 3, H, W) linear HDR radiance (eq. 3 applied).
    disparity: (B, 1, H, W) or (B, H, W), px of blur radius at aperture 1, + = behind focus.
    focus, aperture: floats or (B,) tensors (disparity units; aperture scale >= 0).
    """
    spec = spec or ApertureSpec()
    if disparity.ndim == 3:
        disparity = disparity[:, None]
    b = radiance.shape[0]
    f = _as_batch(focus, b, radiance)
    a = _as_batch(aperture, b, radiance)
    s = (disparity - f) * a
    if plan is None:
        sd = s.detach()
        plan = plan_layers(float(sd.min()), float(sd.max()), max_step=max_step, min_layers=min_layers)
    u = (s / plan.step).clamp(float(plan.indices.min()), float(plan.indices.max()))
    j_hi = float(plan.indices.max())
    norm = sum(matte_unnormalised(u, float(j)) for j in plan.indices) if naive else None
    acc = torch.zeros(radiance.shape[0], 4, *radiance.shape[2:], dtype=radiance.dtype, device=radiance.device)
    for j in plan.indices:  # back to front
        m = matte_unnormalised(u, float(j)) / norm if naive else layer_alpha(u, float(j), j_hi)
        if not bool((m > 0).any()):
            continue
        layer = torch.cat([radiance * m, m], dim=1)
        blurred = spread(layer, spec, abs(float(j) * plan.step))
        acc = acc + blurred if naive else acc * (1.0 - blurred[:, 3:4]) + blurred
    return acc[:, :3] / acc[:, 3:4].clamp(min=ALPHA_EPS)
