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
   normalised so that the mattes of a pixel sum to 1: ``M_j = g_j / sum_k g_k``, a partition
   of the pixel between (at most 4) adjacent layers;
3. each layer's premultiplied radiance ``L * M_j`` and its matte ``M_j`` are spread by the
   aperture kernel of radius ``|s_j|`` (a scatter: a point spreads into the PSF; zero outside
   the frame) into ``C_j`` and ``W_j``. Nothing is counted twice: the layers of a pixel carry
   its radiance once, so a blurred object keeps its energy;
4. layers are composited FRONT to back; a layer is hidden by the visible coverage of the layers
   in front of it, by saturation within a surface and by "over" beyond. ``V_i = T_i W_i`` is the
   visible coverage of layer i; ``H_j = sum_{i <= j - S} V_i`` (``S = OCCLUSION_DELAY = 1``: every
   layer in front) and ``F_j = sum_{i < j - SURFACE_STEPS} V_i`` (those more than 3 steps in
   front). The visible fraction of layer j is ``T_j = min(1 - F_j, (1 - H_j) / W_j)`` (both
   clamped at 0; :func:`visible_fraction`), ``acc = sum_j T_j C_j`` and ``cov = sum_j V_j``.
   So layer j takes, up to its own coverage, what the layers up to 3 steps in front leave,
   ``V_j = min(W_j (1 - F_j), 1 - H_j)``, and the farther ones hide it by the "over" operator of
   eq. 4, ``T_j = 1 - F_j`` where nothing nearer is in front (with the matte blurred too, not the
   sharp ``(1 - M)`` of eq. 4, so background blur never bleeds over a foreground silhouette and a
   blurred one is semi-transparent over the sharp background behind it). ``cov <= 1``.
   Why saturation within 3 steps: "over" treats the coverage of the layers in front and that of
   layer j as independent, and on a depth gradient (every tile of an estimated depth map) they
   are not: neighbouring layers are neighbouring contour bands of one surface whose blurs overlap,
   ``W_i + W_j ~ 1``, and over hid ``W_i W_j`` of the farther band (a smooth surface has no
   disocclusion; on a straight edge between two surfaces on one side of the focal plane the lens
   points that see past the nearer one and those that see the farther one are nested half-planes
   of the aperture, so the farther one is seen on exactly ``min(W_j, 1 - W_i)``). Over (then
   with S = 2) left a 2-30 % coverage deficit on the real-depth frame of bench/render_bench.py,
   73 % of it from layers 2 steps in front, 19 % from 3, which the fill of step 5 laid over the
   frame as a grey veil. Saturation also lets the parts of one pixel (the soft matte of eq. 2
   splits it between <= 4 adjacent layers) sum without hiding one another, which is why "over"
   needed a delay of 2 steps (with S = 1 a surface hid ~10% of itself; the earlier ``alpha_j =
   M_j / P_j`` cure more than doubled the energy of a small blurred highlight). Beyond 3 steps
   the coverage in front is mostly a whole other surface or a sharp silhouette's soft matte (it
   hands ~5 % of its rim to the layers beside it), not a band beside layer j, and there "over"
   is kept: saturating it let the blurred background through a sharp silhouette's rim (1.7 ->
   3.3 % on the render tests' frame). Where layer j has nothing behind the layers in front in the
   input (the hole in the background around a blurred foreground's rim) ``W_j < 1 - H_j`` and the
   deficit stays, for the fill;
5. the result is resolved by the coverage:
   ``out = acc / max(cov, 1) + (1 - min(cov, 1)) * fill`` (a coverage within COVERAGE_SNAP of 1
   counts as 1: :func:`fill_weight`).
   ``cov < 1`` where light reaches the lens from behind every visible layer: the background
   occluded in the input, seen around a blurred foreground's rim (the layers behind it have a
   hole where the foreground was), beyond the frame border (a blur reaching outside the frame),
   and the small deficits of the discretisation. That light is unknown; ``fill`` estimates it
   from the input radiance L around the pixel: :func:`push_pull_fill`, a push-pull pyramid
   whose samples are the pixels weighted by their coverage ``min(cov, 1)`` (a pixel its own
   surface no longer covers is no evidence of what lies behind it), in which, within each 2x2
   block and between levels, a sample more than FILL_DEPTH_TOLERANCE steps in front of the
   farthest one fades by ``exp(-FILL_DEPTH_SHARPNESS)`` per step (an occluder is not the
   background it hides; the tolerance is 2 steps, what the compositing treated as one surface when
   it was "over" with a delay of 2: with 1 step an estimated depth map's small far outliers, the HDR lights it puts
   2-3 steps behind their surroundings, won every block up the pyramid and the fill, taken by the
   1-20 % coverage deficits of a depth gradient, turned half of the frame white), weights are averaged (not saturated) up the pyramid, and the fill is
   the half-resolution level upsampled. The pyramid averages ``sqrt(L)`` and the fill is the
   square of the result (a power mean of order FILL_POWER = 1/2, :func:`fill_encode` /
   :func:`fill_decode`): the hidden background is most often the dark surface around a small
   highlight, not the highlight, and a linear mean let one HDR emitter beside a blurred leaf
   turn the whole hidden area white (on the harness clips the power mean gains 0.3-0.9 dB
   against Cycles, most in the edge band; it also lifted occlusion-aware above the naive sum
   in the band on the one clip where it was behind). So a hole takes the colour of the
   covered background around it, the rim of a blurred foreground mixes its colour with that of the real
   neighbouring background (no dark or bright halo; normalising by the coverage instead gave
   the rim the foreground's full colour and filled a small highlight's hole with the highlight
   itself), and an HDR highlight keeps its energy. ``cov > 1`` only where surfaces less than S
   steps apart overlap after the blur; there the sum is normalised.

The naive variant (Srinivasan et al. 2018) sums the blurred layers (``T_j = 1``, no
occlusion) and resolves the same way, so an ablation isolates occlusion handling.
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
"""Layers a pixel at layer coordinate u can touch: floor(u) + MATTE_OFFSETS."""
OCCLUSION_DELAY = 1
"""S of step 4: a layer is hidden by the layers at least this many steps in front of it (2 while
the compositing was "over" only, so that a pixel split between adjacent layers did not hide itself)."""
SURFACE_STEPS = 3
"""Step 4: the layers at most this many steps in front of a layer hide it by saturation (one
surface's neighbouring contour bands), those farther in front by "over"."""
FILL_DEPTH_SHARPNESS = 2.0
"""kappa of step 5, per layer step: a sample more than FILL_DEPTH_TOLERANCE steps nearer than
the farthest one around it weighs exp(-kappa * excess) as much (e^-2 per step)."""
FILL_DEPTH_TOLERANCE = 2.0
"""Depth difference in layer steps within which the fill treats samples as one background (the
delay of the "over"-only compositing, which treated layers 2 steps apart as one surface; was 1,
see step 5)."""
COVERAGE_SNAP = 1e-6
"""A pixel's coverage within this of 1 counts as 1 in the resolve (step 5, :func:`fill_weight`). The
fill treats a coverage of 1 and of 1 - 1e-13 differently beside a much farther background: the push
takes the coarse (farther) fill instead of the pixel's own sample wherever ``1 - w`` outweighs the
sample's depth factor (e^-2 a step: e^-42 at 23 steps), and that fill spreads to the neighbours the
level-1 fill serves. A fully covered pixel's coverage sums to 1 only up to rounding, in float32
(fast path: 1 - 1.2e-7 or 1 depending on the order of the sums) and in float64 (the reference's
saturated layers, ``H + (1 - H)``: 1 - 2.5e-13 on the bench scene, which flipped a pixel's fill from
0.98 to 0.30), so every path snaps it (before: only the fast path, against a float64 reference
that then summed to 1 within 1e-15; on the render tests' frame 6e-5 -> 1e-7 of the peak)."""
EXP_FLOOR = -60.0
"""Lower clamp of the fill's exponents (relative weights below e^-60 are treated as e^-60),
which keeps every weight sum positive in float32."""
WEIGHT_EPS = 1e-12
"""Weight sums below this count as empty (colour 0)."""
FILL_POWER = 0.5
"""Order of the power mean the fill takes of the radiance (step 5): it averages L**FILL_POWER."""


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


def max_blur_radius(height: int, width: int) -> float:
    """The largest blur radius the renderers plan layers for: twice the frame diagonal (+16 px).
    A larger disk covers the whole frame from every pixel; without a bound a huge disparity value
    (1e30), focus or aperture (1e6) asked for billions of layers (a MemoryError, an OOM kill)."""
    return 2.0 * math.hypot(height, width) + 16.0


def signed_radius(disparity: Any, focus: float, aperture: float) -> Any:
    """Signed blur radius in px: ``aperture * (disparity - focus)`` (numpy or torch); a numpy map is
    clipped to +-:func:`max_blur_radius` of its frame (NaN stays NaN)."""
    s = (disparity - focus) * aperture
    if isinstance(s, np.ndarray) and s.ndim >= 2:
        bound = np.float32(max_blur_radius(*s.shape[:2]))
        with np.errstate(invalid="ignore"):
            s = np.clip(s, -bound, bound, out=s if s is not disparity else None)
    return s


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


# -- step 5: the fill (plain numpy; the definition the fast and torch paths reproduce) ----------

def _pad_even(x: np.ndarray) -> np.ndarray:
    """Zero-pad the first two axes to even lengths (padding has zero weight)."""
    h, w = x.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return x
    return np.pad(x, ((0, h % 2), (0, w % 2)) + ((0, 0),) * (x.ndim - 2))


def _blocks(x: np.ndarray) -> np.ndarray:
    """(2h, 2w, ...) -> (h, w, 4, ...): the 2x2 blocks of an even-sized array."""
    h, w = x.shape[0] // 2, x.shape[1] // 2
    b = x.reshape(h, 2, w, 2, *x.shape[2:])
    return np.moveaxis(b, 2, 1).reshape(h, w, 4, *x.shape[2:])


def upsample2(x: np.ndarray) -> np.ndarray:
    """Bilinear 2x upsampling with half-pixel centres and edge clamping (as ``cv2.resize``
    INTER_LINEAR and torch's ``interpolate(..., align_corners=False)``): output pixel 2i
    is ``0.75 x[i] + 0.25 x[i - 1]``, 2i + 1 is ``0.75 x[i] + 0.25 x[i + 1]``, per axis."""
    for axis in (0, 1):
        n = x.shape[axis]
        idx = np.arange(n)
        prev = np.take(x, np.maximum(idx - 1, 0), axis=axis)
        nxt = np.take(x, np.minimum(idx + 1, n - 1), axis=axis)
        even = 0.75 * x + 0.25 * prev
        odd = 0.75 * x + 0.25 * nxt
        x = np.stack([even, odd], axis=axis + 1)
        shape = list(x.shape)
        shape[axis:axis + 2] = [2 * n]
        x = x.reshape(shape)
    return x


def depth_factor(dz: Any, kappa: float = FILL_DEPTH_SHARPNESS, tolerance: float = FILL_DEPTH_TOLERANCE) -> Any:
    """Preference of a sample ``dz = z - z_ref <= 0`` layer steps nearer than the reference:
    ``exp(max(-kappa * max(0, -dz - tolerance), EXP_FLOOR))`` (numpy or torch)."""
    if isinstance(dz, np.ndarray) or np.isscalar(dz):
        return np.exp(np.maximum(kappa * np.minimum(dz + tolerance, 0.0), EXP_FLOOR))
    return (kappa * (dz + tolerance).clamp(max=0.0)).clamp(min=EXP_FLOOR).exp()


def fill_encode(colour: Any) -> Any:
    """Radiance -> the domain the fill averages in: ``max(L, 0) ** FILL_POWER`` (numpy or torch;
    torch clamps at 1e-10 so the gradient stays finite)."""
    if isinstance(colour, np.ndarray):
        return np.sqrt(np.maximum(colour, 0.0))
    return colour.clamp(min=1e-10).sqrt()


def fill_decode(encoded: Any) -> Any:
    """Inverse of :func:`fill_encode` on the averaged values: ``f ** (1 / FILL_POWER)``."""
    return encoded * encoded


def push_pull_fill(colour: np.ndarray, weight: np.ndarray, depth: np.ndarray,
                   kappa: float = FILL_DEPTH_SHARPNESS, tolerance: float = FILL_DEPTH_TOLERANCE) -> np.ndarray:
    """The fill of model step 5, plain numpy: a depth-aware push-pull estimate at half
    resolution, bilinearly upsampled.

    colour: (H, W, C) straight colour (the input radiance); weight: (H, W) confidence in
    [0, 1] (the pixel's coverage ``min(cov, 1)``); depth: (H, W) layer coordinate ``u``
    (larger = farther). Returns (H, W, C) in the dtype of ``colour``.

    Pull: level l + 1 has one sample per 2x2 block of level l (odd sizes padded with zero
    weight), until 1x1. The block's samples are weighted by ``e_i = w_i depth_factor(z_i -
    z_max)`` (z_max: the block's largest depth with w > 0): samples more than ``tolerance``
    steps in front of the farthest are occluders, not background, and fade by ``kappa`` per
    step. The block's colour and depth are the e-weighted means, its weight the MEAN of its
    four weights (an occluder's poorly covered pixels stay uncertain up the pyramid).
    Push, from the 1x1 level down to level 1: a level's fill mixes its own sample and the
    bilinearly 2x-upsampled (:func:`upsample2`) coarser fill by ``a = w depth_factor(z - m)``
    and ``b = (1 - w) depth_factor(z_up - m)``, ``m = max(z, z_up)`` (z_up alone where w = 0).
    The fill is level 1's fill upsampled to full size: a pixel's own sample enters only
    through its 2x2 block, so a hole takes the colour of the covered background around it.
    Colours are averaged as ``fill_encode(colour)`` and the upsampled result is decoded by
    :func:`fill_decode` (a power mean, see the module's step 5).
    """
    f, _ = push_pull_levels(fill_encode(colour), weight, depth, kappa, tolerance, down_to=1)
    h, w = weight.shape
    return fill_decode(upsample2(f)[:h, :w]).astype(colour.dtype, copy=False)


def _pull(c: np.ndarray, w: np.ndarray, z: np.ndarray, kappa: float,
          tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One depth-aware pull step (see :func:`push_pull_fill`): the next coarser level."""
    cb, wb, zb = _blocks(_pad_even(c)), _blocks(_pad_even(w)), _blocks(_pad_even(z))
    zmax = np.where(wb > 0, zb, -np.inf).max(axis=2, keepdims=True)
    zmax = np.where(np.isfinite(zmax), zmax, 0.0)
    e = wb * depth_factor(zb - zmax, kappa, tolerance)
    se = e.sum(axis=2)
    inv = np.where(se > WEIGHT_EPS, 1.0 / np.maximum(se, WEIGHT_EPS), 0.0)
    return (cb * e[..., None]).sum(axis=2) * inv[..., None], wb.mean(axis=2), (zb * e).sum(axis=2) * inv


def push_pull_levels(c: np.ndarray, w: np.ndarray, z: np.ndarray, kappa: float = FILL_DEPTH_SHARPNESS,
                     tolerance: float = FILL_DEPTH_TOLERANCE, down_to: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(fill colour, fill depth) at level ``down_to`` of the push-pull of :func:`push_pull_fill`
    (level 0 = the arrays given); at least ``down_to`` pull steps are made."""
    levels = [(c, w, z)]
    while len(levels) <= down_to or levels[-1][1].shape != (1, 1):
        levels.append(_pull(*levels[-1], kappa, tolerance))
    f, g = levels[-1][0], levels[-1][2]
    for c, w, z in reversed(levels[down_to:-1]):
        h, wd = w.shape
        fu, gu = upsample2(f)[:h, :wd], upsample2(g)[:h, :wd]
        m = np.where(w > 0, np.maximum(z, gu), gu)
        a = w * depth_factor(z - m, kappa, tolerance)
        b = (1.0 - w) * depth_factor(gu - m, kappa, tolerance)
        inv = 1.0 / (a + b)
        f = (a[..., None] * c + b[..., None] * fu) * inv[..., None]
        g = (a * z + b * gu) * inv
    return f, g


def visible_fraction(remaining: Any, remaining_far: Any, coverage: Any) -> Any:
    """``T_j`` of step 4: ``min(remaining_far, remaining / max(coverage, WEIGHT_EPS))``.

    remaining: ``max(0, 1 - H_j)``, the coverage every layer at least OCCLUSION_DELAY steps in
    front leaves; remaining_far: ``max(0, 1 - F_j)``, what those more than SURFACE_STEPS in front
    leave; coverage: ``W_j``, the layer's blurred matte. Numpy or torch, elementwise."""
    if isinstance(remaining, np.ndarray) or np.isscalar(remaining):
        return np.minimum(remaining_far, remaining / np.maximum(coverage, WEIGHT_EPS))
    return remaining_far.minimum(remaining / coverage.clamp(min=WEIGHT_EPS))


def fill_weight(cov: Any) -> Any:
    """Step 5's ``min(cov, 1)``, 1 within COVERAGE_SNAP of 1 (numpy or torch): the fill's sample
    weights and the share of the fill, ``1 - fill_weight(cov)``."""
    if isinstance(cov, np.ndarray):
        w = np.minimum(cov, 1.0)
        return np.where(w >= 1.0 - COVERAGE_SNAP, 1.0, w).astype(cov.dtype, copy=False)
    w = cov.clamp(max=1.0)
    return w.masked_fill(w >= 1.0 - COVERAGE_SNAP, 1.0)


def resolve(acc: np.ndarray, cov: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """Step 5: ``acc / max(cov, 1) + (1 - fill_weight(cov)) * fill`` ((H, W, 3), (H, W), (H, W, 3))."""
    return acc / np.maximum(cov, 1.0)[..., None] + (1.0 - fill_weight(cov))[..., None] * fill
