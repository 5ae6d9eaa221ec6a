"""The one definition of the RVR forward model (paper eq. 2-4), shared by every renderer.

Units (DESIGN.md): disparity ``D`` is signed, in px of blur radius at aperture scale 1 at
the frame's native width, ``+`` = behind the focal plane. A frame focused at disparity ``f``
with aperture scale ``a`` blurs pixel x with the signed radius ``s = a * (D(x) - f)``; the
kernel radius is ``|s|``.

The model, for every renderer (fast tiles, torch, brute-force reference):

1. linear HDR radiance ``L = srgb_to_linear(I) * exp(K_HDR * E)`` (eq. 3);
2. the signed radius is discretised into layers ``s_j = j * step`` (``j`` integer, so the focal
   plane ``s = 0`` is always a layer and stays perfectly sharp); the soft matte of layer j is
   ``g_j = exp(-LAMBDA * ((s - s_j) / step) ** 2)`` (eq. 2), lowered by its value at
   ``MATTE_CUTOFF`` steps (1.4e-5) and clamped at 0 so it has compact support, then
   normalised so that the mattes of a pixel sum to 1 (a partition of the pixel, so no dark
   seams between layers);
3. a pixel's mattes are turned into "over" alphas, back (largest ``s``) to front:
   ``alpha_j = M_j / P_j`` with ``P_j = sum_{k >= j} M_k`` the pixel's coverage from the back
   up to layer j. Over-compositing the unblurred layers with these alphas returns the pixel
   exactly; crucially, a surface split between adjacent layers is opaque to what lies behind
   it (with ``alpha_j = M_j``, eq. 4 read literally, a surface at a fractional layer lets
   about 5% of the background show through it). The normalisation of the mattes cancels:
   ``alpha_j = g_j / sum_{k=j}^{j+3} g_k``;
4. each layer's premultiplied radiance ``L * alpha_j`` and its alpha ``alpha_j`` are spread by
   the aperture kernel of radius ``|s_j|`` (a scatter: a point spreads into the PSF; zero
   outside the frame) into ``C_j`` and ``A_j``;
5. layers are composited back to front with the "over" operator, accumulating colour and
   coverage alike: ``acc = acc * (1 - A_j) + [C_j, A_j]`` (eq. 4 with the matte blurred too,
   so background blur never bleeds over a foreground silhouette);
6. the result is normalised by the accumulated coverage, ``out = acc_rgb / acc_alpha``, which
   fills partial coverage (occluded background behind a blurred foreground rim, frame
   borders) without dark halos.

The naive variant (Srinivasan et al. 2018) uses ``M_j`` itself in step 4 and sums the
blurred layers instead of step 5, normalising the same way, so an ablation isolates
occlusion handling.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

LAMBDA = 2.8
"""Matte falloff of eq. 2, for layers one ``step`` apart."""
K_HDR = 50.0
"""HDR exponent scale k of eq. 3: radiance = I_lin * exp(K_HDR * E)."""
MATTE_CUTOFF = 2.0
"""Matte support in layer steps; the weight cut there is exp(-2.8 * 2**2) = 1.4e-5."""
MATTE_FLOOR = math.exp(-LAMBDA * MATTE_CUTOFF**2)
"""Value subtracted from the Gaussian so the matte reaches 0 continuously at the cutoff."""
MATTE_OFFSETS = range(-1, 3)
ALPHA_SPAN = 4
"""Layers j .. j + ALPHA_SPAN - 1 hold every non-zero matte at or behind j of a pixel with
g_j > 0 (support of 2 steps each side)."""
"""Layers a pixel at layer coordinate u can touch: floor(u) + MATTE_OFFSETS."""
ALPHA_EPS = 1e-8
"""Coverage below which a pixel is treated as empty when normalising."""


@dataclass(frozen=True)
class LayerPlan:
    """Disparity layers of one frame.

    indices: integer layer indices j, ordered back to front (descending).
    step: signed-radius spacing of layers in px; layer j sits at ``j * step``.
    """

    indices: np.ndarray
    step: float

    @property
    def radii(self) -> np.ndarray:
        """Kernel radius of each layer in px (same order as ``indices``)."""
        return np.abs(self.indices.astype(np.float64) * self.step)

    def __len__(self) -> int:
        return int(self.indices.size)


def signed_radius(disparity: Any, focus: float, aperture: float) -> Any:
    """Signed blur radius in px: ``aperture * (disparity - focus)`` (numpy or torch)."""
    return (disparity - focus) * aperture


def hdr_radiance(linear_rgb: Any, hdr_exponent: Any | None) -> Any:
    """Linear HDR radiance ``I_lin * exp(K_HDR * E)`` (eq. 3).

    linear_rgb: (..., H, W, 3) numpy or (B, 3, H, W) torch, linear light.
    hdr_exponent: E in log space, broadcastable to linear_rgb, or None for E = 0.
    """
    if hdr_exponent is None:
        return linear_rgb
    if isinstance(linear_rgb, np.ndarray):
        return linear_rgb * np.exp(K_HDR * np.asarray(hdr_exponent, dtype=np.float32))
    return linear_rgb * (K_HDR * hdr_exponent).exp()


def plan_layers(
    s_min: float, s_max: float, *, max_step: float = 1.0, min_layers: int = 1
) -> LayerPlan:
    """Choose layers covering signed radii [s_min, s_max] px.

    The spacing is ``max_step`` px of radius (1 px, the paper's integer levels) unless more
    layers are needed to reach ``min_layers`` across the range. Layer 0 (in focus) is
    always on the grid.
    """
    if not (math.isfinite(s_min) and math.isfinite(s_max)):
        raise ValueError(f"signed radius range must be finite, got [{s_min}, {s_max}]")
    if max_step <= 0:
        raise ValueError(f"max_step must be > 0 px, got {max_step}")
    span = max(s_max - s_min, 0.0)
    step = float(max_step)
    if min_layers > 1 and span > 0:
        step = min(step, span / (min_layers - 1))
    step = max(step, 1e-3)
    j_hi = math.ceil(s_max / step - 1e-9)
    j_lo = math.floor(s_min / step + 1e-9)
    return LayerPlan(indices=np.arange(j_hi, j_lo - 1, -1, dtype=np.int64), step=step)


def plan_for_radius_map(s: np.ndarray, *, max_step: float = 1.0, min_layers: int = 1) -> LayerPlan:
    """``plan_layers`` over the finite range of a signed-radius map."""
    return plan_layers(float(np.min(s)), float(np.max(s)), max_step=max_step, min_layers=min_layers)


def matte_unnormalised(u: Any, j: Any) -> Any:
    """Un-normalised matte of layer j at layer coordinate ``u = s / step`` (numpy or torch).

    ``max(exp(-LAMBDA d^2) - MATTE_FLOOR, 0)`` with ``d = u - j``: the Gaussian of eq. 2
    lowered by its value at the cutoff, so it is continuous with compact support.
    """
    d = u - j
    if isinstance(d, np.ndarray) or np.isscalar(d):
        d = np.asarray(d, dtype=np.float32)
        return np.maximum(np.exp(-LAMBDA * d * d) - MATTE_FLOOR, 0.0).astype(np.float32)
    return ((-LAMBDA * d * d).exp() - MATTE_FLOOR).clamp(min=0.0)


def matte_normaliser(u: np.ndarray, plan: LayerPlan) -> np.ndarray:
    """Per-pixel sum of the un-normalised mattes over the plan's layers, (H, W) float32.

    Only the <= 4 layers within the cutoff are visited, so this costs O(pixels).
    """
    j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
    base = np.floor(u)
    total = np.zeros(u.shape, dtype=np.float32)
    for off in MATTE_OFFSETS:
        j = base + off
        w = matte_unnormalised(u, j)
        w[(j < j_lo) | (j > j_hi)] = 0.0
        total += w
    return total


def layer_alpha(u: Any, j: float, j_hi: float) -> Any:
    """Over-compositing alpha of layer j, ``g_j / sum_{k=j}^{min(j+3, j_hi)} g_k`` (step 3).

    u: layer coordinate s / step (numpy or torch, clamped to the plan's range); 0 where the
    pixel has no matte at layer j.
    """
    g = matte_unnormalised(u, j)
    total = g
    for k in range(1, ALPHA_SPAN):
        if j + k > j_hi:
            break
        total = total + matte_unnormalised(u, j + k)
    if isinstance(g, np.ndarray):
        return np.divide(g, total, out=np.zeros_like(g), where=total > 0)
    return g / total.clamp(min=1e-30)
