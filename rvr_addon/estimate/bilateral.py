"""Differentiable trilinear slicing of a bilateral grid (Gharbi et al. 2017, HDRNet; Chen et al. 2007).

A bilateral grid stores, for a coarse spatial cell ``(gy, gx)`` and a luma bin ``gz``, a value
per output channel. *Slicing* reads, for every full-resolution pixel ``(y, x)`` with guide
luma ``g(y, x)``, the grid trilinearly interpolated at ``(y, x, g)``: the output follows the
guide's edges even though the grid itself is coarse (a depth edge stays where the luma edge
is), which is why the paper predicts its disparity in bilateral space.

Coordinate conventions (tested against a brute-force loop in
``tests/engine/test_estimate_bilateral.py``):

* **Space: cell centred** (``align_corners=False``). Grid cell ``i`` of ``Hg`` covers the
  pixel rows ``[i * H / Hg, (i + 1) * H / Hg)``; its value sits at the centre of that span.
  Pixel row ``y`` (centre ``y + 0.5``) reads the continuous grid row
  ``gy = (y + 0.5) * Hg / H - 0.5``; the same for columns. Beyond the outermost cell centres
  (within half a cell of the frame border) the border cell is used (``padding_mode="border"``).
  Any ``H``, ``Hg`` may be used; the grid need not divide the image. With ``extent=(fy, fx)``
  the frame spans only the top-left ``fy * Hg`` rows and ``fx * Wg`` columns of cells (the
  grid of a padded frame): ``gy = (y + 0.5) * fy * Hg / H - 0.5``.
* **Luma: node centred**. Bin ``k`` of ``D`` sits at luma ``k / (D - 1)``, so luma 0 reads bin 0
  exactly and luma 1 reads bin ``D - 1`` exactly; ``gz = g * (D - 1)``. Guides outside [0, 1]
  are clamped to the end bins. (HDRNet centres its bins at ``(k + 0.5) / D``, which wastes half a
  bin at each end; the node convention interpolates over the full range.)

Both are implemented with one call of :func:`torch.nn.functional.grid_sample` on the 5-D
volume ``(B, C, D, Hg, Wg)``, ``mode="bilinear"`` (trilinear for 5-D), ``align_corners=False``;
the luma axis is mapped to that convention's normalised coordinate by hand. Gradients flow to
the grid and to the guide.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F


def check_grid(grid: torch.Tensor, channels: int) -> int:
    """Luma bin count D of a (B, C*D, Hg, Wg) grid with C = ``channels``; ValueError otherwise."""
    if grid.ndim != 4:
        raise ValueError(f"bilateral grid must be (B, C*D, Hg, Wg), got shape {tuple(grid.shape)}")
    if channels < 1 or grid.shape[1] % channels:
        raise ValueError(f"bilateral grid has {grid.shape[1]} channels, not a multiple of C = {channels}")
    depth = grid.shape[1] // channels
    if depth < 2:
        raise ValueError(f"bilateral grid needs at least 2 luma bins, got {depth}")
    return depth


def slice_coordinates(guide: torch.Tensor, depth: int, extent: tuple[float, float] = (1.0, 1.0)) -> torch.Tensor:
    """grid_sample sampling grid (B, 1, H, W, 3) = normalised (x, y, z) of every pixel.

    guide: (B, 1, H, W) luma, nominally in [0, 1] (clamped). depth: luma bins D (>= 2).
    extent: (fy, fx), the fraction of the grid's height and width that the guide covers,
    from the top-left corner (1, 1 = the whole grid; less when the grid was computed on a
    padded frame). x, y follow ``align_corners=False`` (cell centred: pixel centre
    ``(x + 0.5) / W`` of the frame maps to ``2 fx (x + 0.5) / W - 1``); z is the normalised
    coordinate of the continuous bin index ``g (D - 1)`` under the same convention,
    ``(2 g (D - 1) + 1) / D - 1``.
    """
    b, _, h, w = guide.shape
    dtype, device = guide.dtype, guide.device
    fy, fx = float(extent[0]), float(extent[1])
    xs = (torch.arange(w, dtype=dtype, device=device) + 0.5) * (2.0 * fx / w) - 1.0
    ys = (torch.arange(h, dtype=dtype, device=device) + 0.5) * (2.0 * fy / h) - 1.0
    gz = guide[:, 0].clamp(0.0, 1.0) * (depth - 1)
    zn = (2.0 * gz + 1.0) / depth - 1.0
    xn = xs.view(1, 1, w).expand(b, h, w)
    yn = ys.view(1, h, 1).expand(b, h, w)
    return torch.stack([xn, yn, zn], dim=-1).unsqueeze(1)


def bilateral_slice(
    grid: torch.Tensor, guide: torch.Tensor, channels: int = 1, extent: tuple[float, float] = (1.0, 1.0)
) -> torch.Tensor:
    """Slice a bilateral grid at full resolution, guided by luma.

    grid: (B, C*D, Hg, Wg), channel index ``c * D + k`` holds output channel c at luma bin k
        (so ``grid.view(B, C, D, Hg, Wg)``).
    guide: (B, 1, H, W) luma in [0, 1] (values outside are clamped to the end bins).
    channels: C, the number of output channels.
    extent: (fy, fx) fraction of the grid's area (from its top-left corner) that the guide
        spans: a grid computed on a frame padded from (H, W) to (Hp, Wp) is sliced for the
        unpadded frame with ``extent = (H / Hp, W / Wp)``, at any guide resolution.
    Returns (B, C, H, W): the grid trilinearly interpolated at every pixel's (y, x, luma),
    with the conventions of the module docstring. Differentiable in grid and guide.
    """
    depth = check_grid(grid, channels)
    if guide.ndim != 4 or guide.shape[1] != 1 or guide.shape[0] != grid.shape[0]:
        raise ValueError(f"guide must be (B, 1, H, W) with B = {grid.shape[0]}, got {tuple(guide.shape)}")
    b, _, hg, wg = grid.shape
    volume = grid.reshape(b, channels, depth, hg, wg)
    if not (0.0 < extent[0] <= 1.0 and 0.0 < extent[1] <= 1.0):
        raise ValueError(f"extent must be fractions in (0, 1], got {extent}")
    coords = slice_coordinates(guide.to(grid.dtype), depth, extent)
    out = F.grid_sample(volume, coords, mode="bilinear", padding_mode="border", align_corners=False)
    return out[:, :, 0]


def luma(srgb: torch.Tensor) -> torch.Tensor:
    """Rec. 709 luma of sRGB-encoded RGB (B, 3, H, W) in [0, 1] -> (B, 1, H, W) in [0, 1].

    Computed on the encoded values (perceptually spaced, so the grid's luma bins are spread
    evenly over what the eye and the 8-bit code values distinguish).
    """
    w = srgb.new_tensor([0.2126, 0.7152, 0.0722]).view(1, 3, 1, 1)
    return (srgb * w).sum(dim=1, keepdim=True)
