"""Training losses of the RGBD-HDR estimator (paper section 4.1, eq. 5-7).

All image losses compare **display-referred sRGB in [0, 1]**: the renderer's linear output is
clipped to [0, 1] and encoded (:func:`to_display`), exactly as a camera writes the 8-bit
large-aperture target. Clipping is what lets the targets teach HDR: a saturated light in the
deep-DOF input is spread over many unsaturated pixels in the target.

* ``L_pix``: mean absolute difference (the paper's L1, averaged over pixels and channels).
* ``L_feat``: the paper uses VGG-19 features (conv1_2 .. conv5_2). No pretrained weights can
  be downloaded here, so the default feature term needs none: ``w_ssim * (1 - MS-SSIM) +
  w_grad * L1(image gradients)``. With a local VGG-19 state dict (``--vgg19 PATH``, torchvision's
  key layout) the paper's perceptual term ``sum_i lambda_i |Phi_i(target) - Phi_i(render)|_1``
  is added, lambda_i = 1/2.6, 1/4.8, 1/3.7, 1/5.6, 10/1.5 (the weights of Zhang et al. 2018,
  whose layer choice the paper cites).
* ``L_rend = L_feat + L_pix`` (eq. 5); ``L_adjust_rend`` is the same on the third image of a
  triplet, rendered with the disparity ``alpha * D + beta`` (:func:`render_member`).
* ``L_smooth = mean(|dD/dx| exp(-|dI/dx|)) + mean(|dD/dy| exp(-|dI/dy|))``, I the sRGB input
  (channel-mean absolute difference) and D **as a fraction of the frame width** (``D_px / W``,
  W the width of the whole frame the crop comes from). The paper gives w1 = 10 but not the unit
  of D. In px, the smoothness of a plausible disparity map (mean |dD| ~ 0.05 px/px) times 10
  outweighed the rendering loss several times and froze D: on a 64-px test scene D stayed
  within 1.3..2.8 px (truth -2..4, RMS error 2.1 px after 300 steps), against 0.97 px with
  this unit and 0.79 px with no smoothness at all. As a fraction of the width the term is a few
  per cent of the rendering loss at 320-1024 px frames.
* ``L_total = L_rend + L_adjust_rend + w1 L_smooth`` (eq. 7, w1 = 10); for a pair (no third
  image) ``L_total = 2 L_rend + w1 L_smooth``.

**Supervised auxiliary terms (ours, not the paper's).** The paper trains through the renderer
alone: it had 2,000 real brackets and 150k GPU iterations, and no ground truth. We have exact
ground truth on the harness's synthetic frames and a 2-core CPU; through the renderer alone,
3000 iterations on two small clips gave a disparity that correlated 0.14 with the truth. So,
where a sample has ground truth (harness frames; never photos, whose terms drop out),
``L_total`` gains ``w_sup * L_sup`` (``--supervised-weight``, 0 = the paper's loss) with

* ``L_D``: mean |D - D_gt| over pixels with a finite D_gt, D in **percent of the frame width**
  (the network's unit D_rel; resolution-free, ~1 for a typical error at initialisation). With
  ``disparity_invariant`` the prediction is first aligned to D_gt by the least-squares scale and
  shift of that sample (MiDaS, Ranftl et al. 2020): it then only teaches the shape of D, and the
  renderer alone fixes its scale and offset. Procedural frames (``scale_free``: no lens, D known
  up to a positive scale and a shift) are aligned instead by matching the median and the mean
  absolute deviation (:func:`align_median_scale`), whose scale is always positive;
* ``L_Dgrad``: multi-scale gradient matching of the residual ``R = D - D_gt`` (MiDaS): mean
  |dR/dx| + |dR/dy| at 4 scales (every 2^k-th pixel), same unit; it sharpens depth edges;
* ``L_E``: mean ``50 |E - E_gt|`` (natural-log radiance gain) over the saturated input pixels
  (brightest channel >= 254/255) and channels, ``E_gt = max(ln(L_hdr / L_lin), 0) / 50``
  clamped to the network's range [0, E_max];
* ``L_E0``: mean ``50 E`` over unsaturated pixels whose true gain is below 1.25 (a small pull to
  E = 0 where nothing was clipped; pixels mixing a light with its surround are left out).

``L_sup = w_D L_D + w_Dgrad L_Dgrad + w_E L_E + w_E0 L_E0`` (1, 0.5, 1, 0.1 by default).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..color import linear_to_srgb
from ..errors import InputError
from ..render.aperture import ApertureSpec
from ..render.model import K_HDR
from ..render.torch_render import render_torch
from .loss_weights import LossWeights  # noqa: F401 - re-exported: rvr_addon.estimate.losses.LossWeights

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
"""Per-scale exponents of Wang et al. 2003 (finest first)."""
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2
VGG_LAYERS = ("conv1_2", "conv2_2", "conv3_2", "conv4_2", "conv5_2")
VGG_LAMBDAS = (1 / 2.6, 1 / 4.8, 1 / 3.7, 1 / 5.6, 10 / 1.5)
_VGG19_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M", 512, 512, 512, 512, "M", 512, 512, 512, 512)
_VGG_TAPS = {"conv1_2": 3, "conv2_2": 8, "conv3_2": 13, "conv4_2": 22, "conv5_2": 31}
"""Index in ``features`` of the ReLU after each tapped convolution (torchvision's layout)."""
_IMAGENET_MEAN = (0.485, 0.456, 0.406)
_IMAGENET_STD = (0.229, 0.224, 0.225)


# ------------------------------------------------------------------------------ rendering


MAX_TRAIN_LAYERS = 64
"""Most depth layers one training render uses (see :func:`render_member`)."""


def render_member(
    radiance: torch.Tensor, disparity_px: torch.Tensor, alpha: float, beta: float,
    spec: ApertureSpec | None = None, max_layers: int | None = MAX_TRAIN_LAYERS,
) -> torch.Tensor:
    """Render the shallow-DOF image of one member of a pair/triplet through our forward model.

    radiance: (B, 3, H, W) linear HDR radiance (``srgb_to_linear(I) * exp(50 E)``).
    disparity_px: (B, 1, H, W) D in px of blur radius at aperture 1 at this resolution.
    alpha, beta: the member's affine factors: its signed blur radius is ``alpha * D + beta`` px
        (``alpha`` = aperture scale a, ``beta = -a * focus``; a triplet's scale/shift).
    max_layers: when the signed radii span more than this many px, the layers are spaced
        ``span / (max_layers - 1)`` px apart instead of 1 px (None: never). The autograd graph
        holds every layer's blurred copy, so memory and time grow with the span: one 128 px
        render+backward spanning +-8 / +-32 / +-80 px took 75 / 205 / 615 MB and 0.4 / 2.5 /
        15.5 s; a network whose D runs away on large frames reached many GB. Real spans on
        harness frames are ~10-40 px, so this only bounds the pathological cases.
    Returns (B, 3, H, W) linear radiance, identical to ``render_torch(radiance, D, focus=-beta/alpha,
    aperture=alpha)`` while the span is below ``max_layers``.
    """
    signed = alpha * disparity_px + beta
    max_step = 1.0
    if max_layers is not None and max_layers > 1:
        sd = signed.detach()
        span = float(sd.max() - sd.min())
        if span > max_layers - 1:
            max_step = span / (max_layers - 1)
    return render_torch(radiance, signed, 0.0, 1.0, spec=spec, max_step=max_step)


SRGB_SLOPE_AT_WHITE = 1.055 / 2.4
"""d sRGB / d linear at linear = 1."""


def to_display(linear: torch.Tensor, leak: bool = True) -> torch.Tensor:
    """Linear radiance -> sRGB in [0, 1], clipped like an 8-bit camera.

    The value is exactly ``linear_to_srgb(linear)``. With ``leak`` the gradient does not stop
    at the white clip: above 1 it is that of ``1 + s ln(x)``, s the sRGB curve's slope at white
    (a straight-through estimator that continues the curve logarithmically). With a hard clip
    an over-bright render of a light (too large E) has no gradient wherever it saturates, so
    only the rims of a blurred light pushed E, always upwards: on the test scenes E ran to its
    bound (gain 1000 for lights of gain 8-20). With the leak a saturated render pixel over an
    unsaturated target pixel pulls E down, and over a saturated target pixel (|1 - 1| = 0) it
    does nothing. The gradient is logarithmic because radiance is exp(50 E): a linear leak
    gave gradients of 1e3 and wrecked training.
    """
    out = linear_to_srgb(linear)
    if leak and linear.requires_grad:
        over = linear.detach() > 1.0
        log_x = torch.log(torch.where(over, linear, torch.ones_like(linear)))
        out = out + (log_x - log_x.detach()) * SRGB_SLOPE_AT_WHITE
    return out


# ------------------------------------------------------------------------------ pixel terms


def pixel_l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean |a - b| over all elements (scalar)."""
    return (a - b).abs().mean()


def image_gradients(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward differences of (B, C, H, W): (dx (B, C, H, W-1), dy (B, C, H-1, W))."""
    return x[..., :, 1:] - x[..., :, :-1], x[..., 1:, :] - x[..., :-1, :]


def gradient_l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """mean |dx a - dx b| + mean |dy a - dy b| (0 for a 1-px-wide/high axis)."""
    ax, ay = image_gradients(a)
    bx, by = image_gradients(b)
    total = a.new_zeros(())
    if ax.numel():
        total = total + (ax - bx).abs().mean()
    if ay.numel():
        total = total + (ay - by).abs().mean()
    return total


# ------------------------------------------------------------------------------ SSIM


def _gaussian_window(size: int, sigma: float, like: torch.Tensor) -> torch.Tensor:
    coords = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2.0
    g = torch.exp(-(coords**2) / (2.0 * sigma**2))
    return g / g.sum()


def _filter(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Separable 'valid' Gaussian filtering of (B, C, H, W), per channel."""
    c = x.shape[1]
    k = g.numel()
    x = F.conv2d(x, g.view(1, 1, 1, k).expand(c, 1, 1, k), groups=c)
    return F.conv2d(x, g.view(1, 1, k, 1).expand(c, 1, k, 1), groups=c)


def ssim_terms(a: torch.Tensor, b: torch.Tensor, window: int = SSIM_WINDOW) -> tuple[torch.Tensor, torch.Tensor]:
    """(mean SSIM, mean contrast-structure) per image and channel, (B, C) each.

    a, b: (B, C, H, W) in [0, 1]. Gaussian window ``window`` (shrunk to the image's smaller
    side, kept odd), sigma 1.5, 'valid' filtering; C1 = 0.01^2, C2 = 0.03^2 (data range 1).
    """
    size = min(window, a.shape[-1], a.shape[-2])
    size = size if size % 2 else size - 1
    g = _gaussian_window(max(size, 1), SSIM_SIGMA, a)
    mu_a, mu_b = _filter(a, g), _filter(b, g)
    var_a = _filter(a * a, g) - mu_a**2
    var_b = _filter(b * b, g) - mu_b**2
    cov = _filter(a * b, g) - mu_a * mu_b
    cs = (2.0 * cov + SSIM_C2) / (var_a + var_b + SSIM_C2)
    lum = (2.0 * mu_a * mu_b + SSIM_C1) / (mu_a**2 + mu_b**2 + SSIM_C1)
    return (lum * cs).mean(dim=(-2, -1)), cs.mean(dim=(-2, -1))


def ms_ssim_scales(height: int, width: int, window: int = SSIM_WINDOW) -> int:
    """Scales used for an image of this size: up to 5, the coarsest still >= ``window`` px."""
    side = min(height, width)
    if side < window:
        return 1
    return max(1, min(len(MS_SSIM_WEIGHTS), 1 + int(math.floor(math.log2(side / window)))))


def ms_ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Multi-scale SSIM (Wang et al. 2003) of (B, C, H, W) images in [0, 1] -> scalar mean.

    ``prod_{j < M} cs_j^{w_j} * ssim_M^{w_M}`` over M scales (2x2 average pooling between
    them); M from :func:`ms_ssim_scales`, the first M weights of ``MS_SSIM_WEIGHTS`` renormalised
    to sum 1. Terms are clamped at 1e-6 before the power (no NaN gradients).
    """
    m = ms_ssim_scales(a.shape[-2], a.shape[-1])
    w = torch.tensor(MS_SSIM_WEIGHTS[:m], dtype=a.dtype, device=a.device)
    w = w / w.sum()
    value = a.new_ones(a.shape[:2])
    for j in range(m):
        ssim, cs = ssim_terms(a, b)
        term = ssim if j == m - 1 else cs
        value = value * term.clamp(min=1e-6) ** w[j]
        if j < m - 1:
            a, b = F.avg_pool2d(a, 2), F.avg_pool2d(b, 2)
    return value.mean()


# ------------------------------------------------------------------------------ VGG-19


class VGG19Features(nn.Module):
    """The convolutional part of VGG-19 (Simonyan & Zisserman 2015) up to relu5_2.

    The module layout and parameter names are torchvision's (``features.<i>.weight``), so its
    ``vgg19`` state dicts load directly. Input: (B, 3, H, W) sRGB in [0, 1] (normalised inside
    with the ImageNet mean/std). Output: the ReLU outputs after conv1_2, conv2_2, conv3_2,
    conv4_2, conv5_2.
    """

    def __init__(self) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        cin = 3
        for item in _VGG19_CFG:
            if item == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(cin, int(item), 3, padding=1), nn.ReLU(inplace=False)]
                cin = int(item)
        self.features = nn.Sequential(*layers[: _VGG_TAPS["conv5_2"] + 1])
        self.register_buffer("mean", torch.tensor(_IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(_IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, srgb: torch.Tensor) -> list[torch.Tensor]:
        x = (srgb - self.mean) / self.std
        taps = sorted(_VGG_TAPS.values())
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in taps:
                out.append(x)
        return out


def load_vgg19(path: str | Path) -> VGG19Features:
    """VGG19Features with weights from a local state dict (torchvision's ``vgg19`` layout).

    The file is loaded with ``torch.load(weights_only=True)``; ``classifier.*`` entries are
    ignored. The network is frozen (eval mode, no gradients for its parameters).
    Raises InputError naming the file when it is missing, corrupt or not a VGG-19 state dict.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"VGG-19 weights '{path}' not found; pass the path of a local torchvision vgg19 "
                         "state dict (e.g. vgg19-dcbb9e9d.pth) or leave --vgg19 out (the default loss needs none).")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as ex:
        raise InputError(f"VGG-19 weights '{path}' cannot be read ({type(ex).__name__}: {ex}); the file is corrupt "
                         "or not a torch state dict. Re-download or re-save it with torch.save(model.state_dict()).") from ex
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise InputError(f"VGG-19 weights '{path}' hold a {type(state).__name__}, not a state dict.")
    net = VGG19Features()
    wanted = net.state_dict()
    picked = {k: v for k, v in state.items() if k in wanted}
    missing = sorted(set(wanted) - set(picked))
    if missing:
        raise InputError(f"VGG-19 weights '{path}' lack {len(missing)} tensors of torchvision's vgg19 layout "
                         f"(e.g. {missing[0]}); is it a VGG-19 (not VGG-16 or a batch-norm variant) state dict?")
    bad = [k for k, v in picked.items() if tuple(v.shape) != tuple(wanted[k].shape)]
    if bad:
        raise InputError(f"VGG-19 weights '{path}': tensor {bad[0]} has shape {tuple(picked[bad[0]].shape)}, "
                         f"expected {tuple(wanted[bad[0]].shape)}; not a VGG-19 state dict.")
    net.load_state_dict(picked)
    net.eval()
    for p in net.parameters():
        p.requires_grad_(False)
    return net


def vgg_loss(vgg: VGG19Features, rendered: torch.Tensor, target: torch.Tensor,
             lambdas: Sequence[float] = VGG_LAMBDAS) -> torch.Tensor:
    """sum_i lambda_i * mean |Phi_i(target) - Phi_i(rendered)| over conv1_2 .. conv5_2."""
    fr, ft = vgg(rendered), vgg(target)
    return sum(lam * (a - b).abs().mean() for lam, a, b in zip(lambdas, fr, ft))


# ------------------------------------------------------------------------------ eq. 5-7


def rendering_loss(rendered: torch.Tensor, target: torch.Tensor, weights: LossWeights = LossWeights(),
                   vgg: VGG19Features | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """L_rend = L_feat + L_pix (eq. 5) of display-referred images.

    rendered, target: (B, 3, H, W) sRGB in [0, 1]. Returns (scalar loss, float parts
    ``pix``, ``ssim`` (1 - MS-SSIM), ``grad`` and ``vgg`` when used) for logging.
    """
    pix = pixel_l1(rendered, target)
    dssim = 1.0 - ms_ssim(rendered, target)
    grad = gradient_l1(rendered, target)
    loss = weights.pix * pix + weights.ssim * dssim + weights.grad * grad
    parts = {"pix": pix.item(), "ssim": dssim.item(), "grad": grad.item()}
    if vgg is not None:
        v = vgg_loss(vgg, rendered, target)
        loss = loss + weights.vgg * v
        parts["vgg"] = v.item()
    return loss, parts


def smoothness_loss(disparity: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """Edge-aware smoothness: mean |dD/dx| e^{-|dI/dx|} + mean |dD/dy| e^{-|dI/dy|}.

    disparity: (B, 1, H, W) D (the estimator passes D as a fraction of the frame width).
    image: (B, C, H, W) the input (sRGB in [0, 1]); its gradient magnitude is the mean over
    channels of the absolute forward difference.
    """
    dx, dy = image_gradients(disparity)
    ix, iy = image_gradients(image)
    total = disparity.new_zeros(())
    if dx.numel():
        total = total + (dx.abs() * torch.exp(-ix.abs().mean(dim=1, keepdim=True))).mean()
    if dy.numel():
        total = total + (dy.abs() * torch.exp(-iy.abs().mean(dim=1, keepdim=True))).mean()
    return total


@dataclass
class LossResult:
    """Total loss (scalar tensor) and its parts as floats, for the log."""

    total: torch.Tensor
    parts: dict[str, float] = field(default_factory=dict)


def total_loss(
    rendered: torch.Tensor, target: torch.Tensor, disparity: torch.Tensor, image: torch.Tensor,
    adjusted: tuple[torch.Tensor, torch.Tensor] | None = None, weights: LossWeights = LossWeights(),
    vgg: VGG19Features | None = None,
) -> LossResult:
    """Eq. 7 for one sample.

    rendered, target: the primary render and its large-aperture target, sRGB (B, 3, H, W).
    adjusted: (render with alpha*D+beta, the triplet's third image), or None for a pair, whose
        rendering loss then counts twice (paper: "double the weight of L_rend").
    disparity: (B, 1, H, W) D for the smoothness term (fraction of the frame width, see the
        module docstring); image: the input (B, 3, H, W) for the smoothness edges.
    Parts: ``rend``, ``adjust`` (0 for pairs), ``smooth`` and the primary's pix/ssim/grad[/vgg].
    """
    rend, parts = rendering_loss(rendered, target, weights, vgg)
    smooth = smoothness_loss(disparity, image)
    if adjusted is None:
        total = 2.0 * rend + weights.smooth * smooth
        adjust_value = 0.0
    else:
        adjust, _ = rendering_loss(adjusted[0], adjusted[1], weights, vgg)
        total = rend + adjust + weights.smooth * smooth
        adjust_value = adjust.item()
    parts.update(rend=rend.item(), adjust=adjust_value, smooth=smooth.item(), total=total.item())
    return LossResult(total, parts)


# ------------------------------------------------------------------------------ supervised (ours)

E_ZERO_GAIN = 1.25
"""L_E0 covers unsaturated pixels whose true radiance gain is below this."""
GRADIENT_SCALES = 4


def fit_scale_shift(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-sample least-squares (s, t) minimising sum_mask (s pred + t - target)^2.

    pred, target, mask: (B, 1, H, W) (mask 0/1, target finite where mask is 1). Returns s, t of
    shape (B, 1, 1, 1); differentiable in ``pred``. A sample with a flat prediction or fewer
    than 2 valid pixels gets s = 0, t = the mean target (or s = 1, t = 0 without valid pixels).
    """
    m = mask.to(pred.dtype)
    tgt = torch.where(mask.bool(), target, torch.zeros_like(target))
    n = m.sum(dim=(1, 2, 3), keepdim=True)
    a00 = (m * pred * pred).sum(dim=(1, 2, 3), keepdim=True)
    a01 = (m * pred).sum(dim=(1, 2, 3), keepdim=True)
    b0 = (m * pred * tgt).sum(dim=(1, 2, 3), keepdim=True)
    b1 = (m * tgt).sum(dim=(1, 2, 3), keepdim=True)
    det = a00 * n - a01 * a01
    ok = det > 1e-9 * (a00 * n).clamp(min=1e-12)
    safe = torch.where(ok, det, torch.ones_like(det))
    s = torch.where(ok, (n * b0 - a01 * b1) / safe, torch.zeros_like(det))
    t = torch.where(ok, (a00 * b1 - a01 * b0) / safe, b1 / n.clamp(min=1.0))
    empty = n < 1
    return torch.where(empty, torch.ones_like(s), s), torch.where(empty, torch.zeros_like(t), t)


def align_median_scale(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``pred`` mapped onto ``target`` by matching, per sample, the median and the mean absolute
    deviation from it over ``mask`` (MiDaS's scale-and-shift-invariant alignment). The scale is
    always positive: an inverted prediction stays inverted and is penalised, and the gradient flows
    through both statistics. pred, target, mask: (B, 1, H, W)."""
    out = []
    for b in range(pred.shape[0]):
        m = mask[b].bool()
        if int(m.sum()) < 2:
            out.append(pred[b])
            continue
        p, g = pred[b][m], target[b][m]
        mp, mg = p.median(), g.median()
        sp, sg = (p - mp).abs().mean().clamp(min=1e-6), (g - mg).abs().mean()
        out.append((pred[b] - mp) / sp * sg + mg)
    return torch.stack(out)


def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    m = mask.to(x.dtype)
    return (x * m).sum() / m.sum().clamp(min=1.0)


def _aligned(pred: torch.Tensor, tgt: torch.Tensor, mask: torch.Tensor, invariant: bool, positive: bool) -> torch.Tensor:
    if positive:
        return align_median_scale(pred, tgt, mask)
    if invariant:
        s, t = fit_scale_shift(pred, tgt, mask)
        return s * pred + t
    return pred


def disparity_l1(pred: torch.Tensor, target: torch.Tensor, invariant: bool = False,
                 positive: bool = False) -> torch.Tensor:
    """L_D: mean |pred - target| over finite target pixels (after a per-sample LS scale+shift of
    ``pred`` if ``invariant``, or after :func:`align_median_scale` if ``positive``: a positive
    scale). pred, target: (B, 1, H, W) in the same unit (D_rel)."""
    mask = torch.isfinite(target)
    tgt = torch.where(mask, target, torch.zeros_like(target))
    pred = _aligned(pred, tgt, mask, invariant, positive)
    return _masked_mean((pred - tgt).abs(), mask)


def disparity_gradient_loss(pred: torch.Tensor, target: torch.Tensor, invariant: bool = False,
                            scales: int = GRADIENT_SCALES, positive: bool = False) -> torch.Tensor:
    """L_Dgrad: multi-scale gradient matching of R = pred - target (MiDaS): the sum over
    ``scales`` (every 2^k-th pixel) of the masked mean |dR/dx| + |dR/dy| (both neighbours valid)."""
    mask = torch.isfinite(target)
    tgt = torch.where(mask, target, torch.zeros_like(target))
    r = _aligned(pred, tgt, mask, invariant, positive) - tgt
    total = pred.new_zeros(())
    for k in range(scales):
        step = 2**k
        rk, mk = r[..., ::step, ::step], mask[..., ::step, ::step]
        if rk.shape[-1] > 1:
            total = total + _masked_mean((rk[..., 1:] - rk[..., :-1]).abs(), mk[..., 1:] & mk[..., :-1])
        if rk.shape[-2] > 1:
            total = total + _masked_mean((rk[..., 1:, :] - rk[..., :-1, :]).abs(), mk[..., 1:, :] & mk[..., :-1, :])
    return total


def exponent_losses(exponent: torch.Tensor, target: torch.Tensor, saturated: torch.Tensor,
                    e_max: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(L_E, L_E0) of a predicted HDR exponent (see the module docstring).

    exponent, target: (B, 3, H, W) E (eq. 3); saturated: (B, 1, H, W) bool. Both terms are in
    units of 50 E (natural-log radiance gain); a term with no pixel to cover is 0.
    """
    k = K_HDR
    sat = saturated.expand_as(exponent)
    l_e = _masked_mean(k * (exponent - target.clamp(0.0, e_max)).abs(), sat)
    clean = (~saturated) & (target.amax(dim=1, keepdim=True) < math.log(E_ZERO_GAIN) / k)
    l_e0 = _masked_mean(k * exponent.abs(), clean.expand_as(exponent))
    return l_e, l_e0


def exponent_keep_loss(exponent: torch.Tensor, teacher: torch.Tensor, gate: torch.Tensor) -> torch.Tensor:
    """L_keep: mean |50 E - 50 E_teacher| (natural-log radiance gain) over the pixels where E can
    be non-zero (``gate`` > 0: the bright, possibly clipped ones) and their channels; 0 without any.

    Pictures without HDR ground truth (real pictures with measured depth) keep the HDR recovery
    the network had before: its E on the same input, from the frozen weights it started from.
    (A mean over every pixel let E drift: clipped pixels are rare in such pictures.)"""
    return _masked_mean((K_HDR * (exponent - teacher)).abs(), (gate > 0).expand_as(exponent))


def supervised_loss(disparity_rel: torch.Tensor, gt_disparity_rel: torch.Tensor | None, exponent: torch.Tensor,
                    gt_exponent: torch.Tensor | None, saturated: torch.Tensor | None, e_max: float,
                    weights: LossWeights = LossWeights(), scale_free: bool = False) -> LossResult:
    """L_sup of one sample (unweighted by ``weights.supervised``; see the module docstring).

    disparity_rel, gt_disparity_rel: (B, 1, H, W) D in percent of the frame width (ground truth
    NaN where unknown; None: no disparity terms). exponent, gt_exponent: (B, 3, H, W) E (None:
    no E terms); saturated: (B, 1, H, W) bool. scale_free: the ground truth is known only up to a
    positive scale and a shift (procedural frames): D is aligned by :func:`align_median_scale`,
    whatever ``disparity_invariant`` says. Parts: ``sup_d``, ``sup_dgrad``, ``sup_e``,
    ``sup_e0`` (those that apply) and ``sup`` (the weighted sum).
    """
    total = disparity_rel.new_zeros(())
    parts: dict[str, float] = {}
    w = weights
    if gt_disparity_rel is not None:
        invariant = w.disparity_invariant or scale_free
        l_d = disparity_l1(disparity_rel, gt_disparity_rel, invariant, positive=scale_free)
        l_g = disparity_gradient_loss(disparity_rel, gt_disparity_rel, invariant, positive=scale_free)
        total = total + w.sup_disparity * l_d + w.sup_disparity_grad * l_g
        parts.update(sup_d=l_d.item(), sup_dgrad=l_g.item())
    if gt_exponent is not None and saturated is not None:
        l_e, l_e0 = exponent_losses(exponent, gt_exponent, saturated, e_max)
        total = total + w.sup_exponent * l_e + w.sup_exponent_zero * l_e0
        parts.update(sup_e=l_e.item(), sup_e0=l_e0.item())
    parts["sup"] = total.item()
    return LossResult(total, parts)
