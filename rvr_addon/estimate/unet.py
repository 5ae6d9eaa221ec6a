"""The RGBD-HDR estimator network (paper section 4.1): a fully convolutional U-Net.

From one deep-DOF 8-bit frame it predicts

* ``E`` (B, 3, H, W): the HDR exponent of eq. 3 (radiance = ``srgb_to_linear(I) * exp(50 E)``),
  log space, **0 <= E <= E_max** and ~0 at initialisation;
* ``D`` (B, 1, H, W): signed disparity, sliced from a bilateral grid over luma.

Architecture (defaults; :class:`EstimatorConfig`), leaky ReLU (slope 0.2) after every layer
but the two prediction layers:

```
sRGB (B,3,H,W) -> replicate-pad to a multiple of 32 -> pixel-unshuffle x4 (lossless, 48 ch)
encoder  1/4: 2 conv 48 | 1/8: stride-2 conv + conv 96 | 1/16: 160 | 1/32: 256 (+ global mean
         feature, HDRNet-style, added before the decoder)
decoder  1/16: 160 | 1/8: 96 -> 1x1 conv -> grid (B, bins, H/8, W/8) -> slice by luma -> D
         1/4: 48 -> 3x3 conv -> E logits (B, 3, H/4, W/4) -> bilinear x4
```

Why the work starts at 1/4 resolution: on this 2-core CPU a 3x3 convolution runs at 6-30
GFLOP/s at full 360p resolution (memory bound) but at ~200 GFLOP/s at 1/8, so full-resolution
layers cost far more than their FLOPs; the pixel-unshuffle keeps every input pixel, and the two
full-resolution outputs get their detail where it matters: D from the bilateral slicing (edges
follow the full-resolution luma), E from the gate below.

The paper's last layer yields 3 + N channels at one resolution; here the N grid channels come
from the 1/8 level (a coarse grid is what makes bilateral slicing edge-aware at all, as in
HDRNet) and the 3 E channels from the 1/4 level.

HDR exponent: ``E = E_max * sigmoid(z) * gate(I)`` with ``E_max = ln(max_gain) / K_HDR``. Recovery
only ever brightens clipped pixels (an unclipped 8-bit value is already the radiance up to
quantisation), so E >= 0, and it is gated by ``gate = smoothstep(0.96, 0.98, max_rgb(I))`` on the
sRGB input: 0 below code value ~245, 1 from ~250 (JPEG/H.264 keep clipped areas a few codes below
255). The first shipped weights were trained with 0.90 (from ~230); on the real f/16 -> f/1.8
photos that brightened bright surfaces that are not lights (a white wall, a sky): our render's
margin over the best Gaussian -0.364 dB -> -0.009 dB with the gate from 245 (2026-12-07,
``scripts/set_hdr_gate.py``; the HDR of clipped pixels is unchanged). E is also bounded: the
radiance gain ``exp(50 E)`` is at most ``max_gain`` (1000 by default; the harness's brightest
emitters are ~300x the 8-bit white). A softplus, the first choice, is unbounded: where the render
of a light is itself clipped the loss has no gradient on E, Adam's momentum kept pushing it up, and
exp(50 E) overflowed float32 within 40 steps on the tiny test scene. The logits' bias starts at -6:
E = E_max * 0.0025 (a x1.017 gain) at clipped pixels, exactly 0 elsewhere.

Disparity unit of the network: ``D_rel``, percent of the frame's long side (``D_rel = 1`` is a
blur radius of L/100 px at aperture scale 1; L = W for a landscape frame, H for a portrait one,
so a phone held upright blurs as much as held sideways: :func:`..depth.cues.blur_span`). It does
not change when a frame is resized, so the network is trained at any resolution and run at any
other; :func:`disparity_to_px` converts to DESIGN units (px at the frame's native width):
``D = D_rel * L_native / 100``.

D_rel is softly bounded: ``D_rel = M tanh(g / M) + 0.01 g`` of the grid value g, M =
``max_disparity`` (25: a blur radius of a quarter of the frame width at aperture 1, far beyond
real footage). Near 0 this is the identity; it stops a runaway (one test run jumped to radii
of 80 px on a 48 px crop, where the loss has no useful gradient and the renderer needs 160
layers), and the 0.01 slope keeps a gradient where tanh saturates (a run whose grid was
thrown to -25 everywhere stayed there with zero gradient). The grid starts at ``D_rel = 1``
everywhere, not 0: the rendered blur depends on ``|a (D - f)|`` (up to occlusion order), whose
derivative vanishes at D = f, so a network starting exactly in focus would start where D gets
no gradient. Which side of the focal plane a pixel is on is learnt from the focal triplets (a
shift changes ``|D - f|`` differently on the two sides; on a harness frame the negated true D
renders the large-aperture target as well as the true D, and the second focus twice as badly)
and from occlusions.

Initialisation and scale: every convolution is He-initialised for leaky ReLU (PyTorch's
default shrank the activations about twofold per layer, so the 1/8-level features, and D, were
nearly constant); the two prediction layers are multiplied by ``head_gain`` = 10 (their
weights start 10x smaller, so the initial outputs are unchanged). Adam moves every parameter
by about lr per step whatever its gradient, and at lr 1e-4 the E logits (which travel from -6
to ~+2) stayed put: on a 64-px test scene the loss after 300 steps was 0.13 without the gain
and 0.03 with it.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import NamedTuple

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..render.model import K_HDR
from .bilateral import bilateral_slice, luma

LEAK = 0.2
"""Negative slope of the leaky ReLUs."""
DISPARITY_PERCENT = 100.0
"""D_rel = 1 is a radius of (frame span / DISPARITY_PERCENT) px, the span being the frame's long side
(its width when landscape; :func:`..depth.cues.blur_span`)."""
E_BIAS_INIT = -6.0
"""Initial bias of the E logits: sigmoid(-6) = 0.0025, a radiance gain of max_gain ** 0.0025."""


@dataclass(frozen=True)
class EstimatorConfig:
    """Hyper-parameters of :class:`EstimatorNet` (stored in every checkpoint and weights file).

    widths: channels at 1/4, 1/8, 1/16, 1/32 of the input resolution.
    grid_bins: N, luma bins of the bilateral grid (>= 2).
    grid_level: index into ``widths`` of the decoder level that yields the grid (1 = 1/8).
    gate_lo, gate_hi: sRGB max-channel values where the E gate starts / reaches 1.
    max_gain: largest radiance gain exp(K_HDR * E) the network can predict (E <= ln(max_gain) / K_HDR).
    max_disparity: soft bound M of |D_rel| (D_rel = M tanh(g / M) + 0.01 g).
    init_disparity: D_rel everywhere at initialisation (the grid head's bias).
    head_gain: the two prediction layers' outputs are multiplied by this (see the module doc).
    row_prior: feed the grid head one more channel, the row coordinate (-1 at the top of the
        image, +1 at the bottom), so the network can learn the layout prior of footage (the floor
        nearer toward the bottom) that a translation-equivariant U-Net cannot express. Off in the
        first shipped weights; :func:`grow_state_dict` starts a run with it from weights without it.
    """

    widths: tuple[int, ...] = (48, 96, 160, 256)
    grid_bins: int = 8
    grid_level: int = 1
    gate_lo: float = 0.96
    gate_hi: float = 0.98
    max_gain: float = 1000.0
    max_disparity: float = 25.0
    init_disparity: float = 1.0
    head_gain: float = 10.0
    unshuffle: int = 4
    row_prior: bool = False

    def __post_init__(self) -> None:
        if len(self.widths) < 2:
            raise ValueError(f"widths needs at least two levels, got {self.widths}")
        if not 0 <= self.grid_level < len(self.widths) - 1:  # the grid comes from a decoder level
            raise ValueError(f"grid_level {self.grid_level} is not a decoder level of widths {self.widths} "
                             f"(0 .. {len(self.widths) - 2})")
        if self.grid_bins < 2:
            raise ValueError(f"grid_bins must be >= 2, got {self.grid_bins}")
        if not 0.0 <= self.gate_lo < self.gate_hi <= 1.0:
            raise ValueError(f"need 0 <= gate_lo < gate_hi <= 1, got {self.gate_lo}, {self.gate_hi}")
        if not self.max_gain > 1.0:
            raise ValueError(f"max_gain must be > 1, got {self.max_gain}")
        if not (self.max_disparity > 0 and abs(self.init_disparity) < self.max_disparity):
            raise ValueError(f"need 0 <= |init_disparity| < max_disparity, got {self.init_disparity}, "
                             f"{self.max_disparity}")

    @property
    def e_max(self) -> float:
        """Upper bound of E: ln(max_gain) / K_HDR."""
        return math.log(self.max_gain) / K_HDR

    @property
    def stride(self) -> int:
        """Total down-sampling factor; inputs are padded to a multiple of it."""
        return self.unshuffle * 2 ** (len(self.widths) - 1)

    @property
    def grid_scale(self) -> int:
        """The grid's cell size in input px (8 by default)."""
        return self.unshuffle * 2 ** self.grid_level

    def to_dict(self) -> dict:
        """JSON-ready dict (tuples become lists)."""
        d = asdict(self)
        d["widths"] = list(self.widths)
        return d

    @classmethod
    def from_dict(cls, data: dict) -> "EstimatorConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error (another architecture)."""
        known = set(cls.__dataclass_fields__)
        extra = set(data) - known
        if extra:
            raise ValueError(f"unknown estimator hyper-parameters {sorted(extra)}")
        data = dict(data)
        if "widths" in data:
            data["widths"] = tuple(int(w) for w in data["widths"])
        return cls(**data)


class EstimatorOutput(NamedTuple):
    """disparity_rel: (B, 1, H, W) D_rel (% of the frame's long side, + = behind focus).
    exponent: (B, 3, H, W) 0 <= E <= E_max (log space, eq. 3)."""

    disparity_rel: torch.Tensor
    exponent: torch.Tensor


def _conv(cin: int, cout: int, stride: int = 1, kernel: int = 3) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, kernel, stride, kernel // 2)


def _act(x: torch.Tensor) -> torch.Tensor:
    return F.leaky_relu(x, LEAK)


BOUND_LEAK = 0.01


def bound_disparity(g: torch.Tensor, m: float) -> torch.Tensor:
    """Soft bound of the disparity grid: M tanh(g / M) + 0.01 g."""
    return m * torch.tanh(g / m) + BOUND_LEAK * g


def _inverse_bound(d: float, m: float) -> float:
    """g with bound_disparity(g, m) = d (Newton on a monotonic function)."""
    g = d
    for _ in range(50):
        t = math.tanh(g / m)
        g -= (m * t + BOUND_LEAK * g - d) / (1.0 - t * t + BOUND_LEAK)
    return g


def clip_gate(srgb: torch.Tensor, lo: float, hi: float) -> torch.Tensor:
    """Soft mask (B, 1, H, W) in [0, 1] of clipped pixels: smoothstep(lo, hi, max over RGB)."""
    t = ((srgb.amax(dim=1, keepdim=True) - lo) / (hi - lo)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _row_coordinate(x: torch.Tensor, extent: float) -> torch.Tensor:
    """(B, 1, h, w) row coordinate of the cells of ``x``: -1 at the top edge of the image, +1 at its
    bottom edge; ``extent`` is the share of the (padded) rows the image covers."""
    b, _, h, w = x.shape
    rows = (torch.arange(h, dtype=x.dtype, device=x.device) + 0.5) / (h * extent) * 2.0 - 1.0
    return rows.view(1, 1, h, 1).expand(b, 1, h, w)


def grow_state_dict(state: dict[str, torch.Tensor], old: EstimatorConfig,
                    new: EstimatorConfig) -> dict[str, torch.Tensor]:
    """Map the weights of a network with config ``old`` onto one with config ``new`` that differs
    only by ``row_prior`` switched on: the grid head gains a zero input column, so the grown
    network computes exactly what the old one did. Raises ValueError for any other difference."""
    if old == new:
        return dict(state)
    if old.row_prior or replace(old, row_prior=True) != new:
        raise ValueError(f"cannot start a network with config {new.to_dict()} from weights with config "
                         f"{old.to_dict()}: only switching row_prior on is supported")
    grown = dict(state)
    weight = state["grid_head.weight"]
    grown["grid_head.weight"] = torch.cat([weight, torch.zeros_like(weight[:, :1])], dim=1)
    return grown


def disparity_to_px(disparity_rel: torch.Tensor, frame_width: float | torch.Tensor) -> torch.Tensor:
    """D_rel (% of the frame's span) -> px of blur radius at aperture 1 for a frame whose span
    (``frame_width``: its long side, :func:`..depth.cues.blur_span`; a landscape frame's width) is
    ``frame_width`` px."""
    if isinstance(frame_width, torch.Tensor):
        frame_width = frame_width.to(disparity_rel).reshape(-1, *([1] * (disparity_rel.ndim - 1)))
    return disparity_rel * (frame_width / DISPARITY_PERCENT)


class EstimatorNet(nn.Module):
    """RGBD-HDR U-Net (see the module docstring). Any input size >= 1x1."""

    def __init__(self, config: EstimatorConfig | None = None) -> None:
        super().__init__()
        self.config = cfg = config or EstimatorConfig()
        w = cfg.widths
        cin = 3 * cfg.unshuffle**2
        self.stem = nn.ModuleList([_conv(cin, w[0]), _conv(w[0], w[0])])
        self.down = nn.ModuleList()
        for i in range(1, len(w)):
            self.down.append(nn.ModuleList([_conv(w[i - 1], w[i], stride=2), _conv(w[i], w[i])]))
        self.global_fc = nn.Linear(w[-1], w[-1])
        self.up = nn.ModuleList([_conv(w[i + 1] + w[i], w[i]) for i in range(len(w) - 1)])
        self.grid_head = _conv(w[cfg.grid_level] + int(cfg.row_prior), cfg.grid_bins, kernel=1)
        self.e_head = _conv(w[0], 3)
        for module in self.modules():
            if isinstance(module, (nn.Conv2d, nn.Linear)):  # He init for leaky ReLU: variance-preserving
                nn.init.kaiming_normal_(module.weight, a=LEAK, nonlinearity="leaky_relu")
                nn.init.zeros_(module.bias)
        with torch.no_grad():
            g, m = cfg.head_gain, cfg.max_disparity
            self.grid_head.weight.mul_(0.1 / g)
            self.grid_head.bias.fill_(_inverse_bound(cfg.init_disparity, m) / g)
            self.e_head.weight.mul_(0.1 / g)
            self.e_head.bias.fill_(E_BIAS_INIT / g)

    def parameter_count(self) -> int:
        """Number of trainable parameters."""
        return sum(p.numel() for p in self.parameters())

    def trunk(self, srgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, tuple[int, int]]:
        """Run the U-Net on (B, 3, H, W) sRGB in [0, 1].

        Returns (grid (B, bins, Hp/8, Wp/8), E logits (B, 3, Hp/4, Wp/4), (Hp, Wp)), where Hp, Wp
        are H, W padded (replicating the border) up to a multiple of ``config.stride``.
        """
        cfg = self.config
        if srgb.ndim != 4 or srgb.shape[1] != 3:
            raise ValueError(f"the estimator takes (B, 3, H, W) sRGB images, got shape {tuple(srgb.shape)}")
        h, w = srgb.shape[-2:]
        s = cfg.stride
        hp, wp = math.ceil(h / s) * s, math.ceil(w / s) * s
        x = (srgb - 0.5) * 2.0
        if (hp, wp) != (h, w):
            x = F.pad(x, (0, wp - w, 0, hp - h), mode="replicate")
        x = F.pixel_unshuffle(x, cfg.unshuffle)
        for conv in self.stem:
            x = _act(conv(x))
        skips = [x]
        for conv_down, conv in self.down:
            x = _act(conv(_act(conv_down(x))))
            skips.append(x)
        x = _act(x + self.global_fc(x.mean(dim=(2, 3)))[:, :, None, None])
        grid = None
        for level in range(len(skips) - 2, -1, -1):
            skip = skips[level]
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = _act(self.up[level](torch.cat([x, skip], dim=1)))
            if level == cfg.grid_level:
                feats = torch.cat([x, _row_coordinate(x, h / hp)], dim=1) if cfg.row_prior else x
                grid = self.grid_head(feats) * cfg.head_gain
        assert grid is not None
        return grid, self.e_head(x) * cfg.head_gain, (hp, wp)

    def forward(self, srgb: torch.Tensor, guide_srgb: torch.Tensor | None = None) -> EstimatorOutput:
        """Predict D_rel and E.

        srgb: (B, 3, H, W) sRGB-encoded input in [0, 1] (the network's view; may be a reduced copy).
        guide_srgb: optional (B, 3, H2, W2) sRGB of the same frame at the output resolution
            (e.g. the full-resolution frame when the trunk ran on a half-size copy): the grid is
            sliced with its luma and E is resampled and gated at H2 x W2. Default: ``srgb``.
        Returns :class:`EstimatorOutput` at the guide's resolution.
        """
        cfg = self.config
        guide = srgb if guide_srgb is None else guide_srgb
        h, w = srgb.shape[-2:]
        grid, e_logits, (hp, wp) = self.trunk(srgb)
        grid = bound_disparity(grid, cfg.max_disparity)  # slicing interpolates, so the bound holds per pixel too
        d_rel = bilateral_slice(grid, luma(guide), channels=1, extent=(h / hp, w / wp))
        e = torch.sigmoid(e_logits) * cfg.e_max
        e = F.interpolate(e, size=(hp, wp), mode="bilinear", align_corners=False)[..., :h, :w]
        if guide.shape[-2:] != (h, w):
            e = F.interpolate(e, size=guide.shape[-2:], mode="bilinear", align_corners=False)
        e = e * clip_gate(guide, cfg.gate_lo, cfg.gate_hi)
        return EstimatorOutput(d_rel, e)
