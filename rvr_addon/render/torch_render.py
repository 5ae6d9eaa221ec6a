"""Differentiable torch implementation of the RVR forward model (for training).

Same model as :mod:`.model` (and the fast path): soft layer mattes of the signed radius,
per-layer aperture blur, front-to-back compositing with delayed, saturating occlusion, resolved by the
coverage with a depth-aware push-pull fill (avg-pool / bilinear-interpolate pyramid).
Gradients flow to the radiance (hence to E) and, through the mattes, to the disparity.
Layer radii are fixed per call (the plan is taken from the detached radius range), as in the
paper.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from .aperture import ApertureSpec, make_kernel, zone_edges, zone_offset
from .model import (
    OCCLUSION_DELAY,
    SURFACE_STEPS,
    WEIGHT_EPS,
    LayerPlan,
    depth_factor,
    fill_decode,
    fill_weight,
    fill_encode,
    matte_unnormalised,
    plan_layers,
    visible_fraction,
)

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
    norm = sum(matte_unnormalised(u, float(j)) for j in plan.indices)
    shape = (radiance.shape[0], 1, *radiance.shape[2:])
    zeros = lambda c: torch.zeros(shape[0], c, *shape[2:], dtype=radiance.dtype, device=radiance.device)  # noqa: E731
    acc, cov, hidden, far = zeros(3), zeros(1), zeros(1), zeros(1)  # hidden: H_j, far: F_j (model step 4)
    visible: dict[int, torch.Tensor] = {}  # V_i of layers not yet in `hidden`
    near: dict[int, torch.Tensor] = {}  # V_i of layers in `hidden`, not yet in `far`
    for j in plan.indices[::-1].tolist():  # front to back (model step 4)
        m = matte_unnormalised(u, float(j)) / norm
        if not bool((m > 0).any()):
            continue
        blurred = spread(torch.cat([radiance * m, m], dim=1), spec, abs(float(j) * plan.step))
        c, wj = blurred[:, :3], blurred[:, 3:4]
        for i in sorted(k for k in visible if k <= j - OCCLUSION_DELAY):
            near[i] = visible.pop(i)
            hidden = hidden + near[i]
        for i in sorted(k for k in near if k < j - SURFACE_STEPS):
            far = far + near.pop(i)
        if naive:
            acc, cov = acc + c, cov + wj
        else:
            t = visible_fraction((1.0 - hidden).clamp(min=0.0), (1.0 - far).clamp(min=0.0), wj)
            v = t * wj
            acc, cov = acc + t * c, cov + v
            visible[j] = v
    weight = fill_weight(cov)
    fill = push_pull_fill_torch(radiance, weight, u)
    return acc / cov.clamp(min=1.0) + (1.0 - weight) * fill


def _pull(c: torch.Tensor, w: torch.Tensor, z: torch.Tensor):
    """One depth-aware pull step of :func:`.model.push_pull_fill`."""
    h, wd = w.shape[-2:]
    pad = (0, wd % 2, 0, h % 2)
    if any(pad):
        c, w, z = F.pad(c, pad), F.pad(w, pad), F.pad(z, pad)
    zmax = F.max_pool2d(torch.where(w > 0, z, torch.full_like(z, -torch.inf)), 2)
    zmax = torch.where(torch.isinf(zmax), torch.zeros_like(zmax), zmax)
    e = w * depth_factor(z - zmax.repeat_interleave(2, dim=-2).repeat_interleave(2, dim=-1))
    se = F.avg_pool2d(e, 2)
    inv = torch.where(se > WEIGHT_EPS / 4, 1.0 / se.clamp(min=WEIGHT_EPS / 4), torch.zeros_like(se))
    return F.avg_pool2d(c * e, 2) * inv, F.avg_pool2d(w, 2), F.avg_pool2d(z * e, 2) * inv


def _up(x: torch.Tensor, h: int, w: int) -> torch.Tensor:
    return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)[..., :h, :w]


def push_pull_fill_torch(colour: torch.Tensor, weight: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """The fill of model step 5 (:func:`.model.push_pull_fill`), differentiable (avg-pool /
    bilinear-interpolate pyramid).

    colour: (B, C, H, W) straight colour; weight: (B, 1, H, W) in [0, 1]; depth: (B, 1, H, W)
    layer coordinate. Returns (B, C, H, W).
    """
    levels = [(fill_encode(colour), weight, depth)]
    while len(levels) < 2 or levels[-1][1].shape[-2:] != (1, 1):
        levels.append(_pull(*levels[-1]))
    f, g = levels[-1][0], levels[-1][2]
    for c, w, z in reversed(levels[1:-1]):  # push down to level 1
        h, wd = w.shape[-2:]
        up = _up(torch.cat([f, g], dim=1), h, wd)
        fu, gu = up[:, :-1], up[:, -1:]
        m = torch.where(w > 0, torch.maximum(z, gu), gu)
        a = w * depth_factor(z - m)
        b = (1.0 - w) * depth_factor(gu - m)
        inv = 1.0 / (a + b)
        f, g = (a * c + b * fu) * inv, (a * z + b * gu) * inv
    return fill_decode(_up(f, *weight.shape[-2:]))
