"""Bilateral-grid slicing: against a brute-force trilinear loop, edge following, gradients."""
from __future__ import annotations

import math

import pytest
import torch

from rvr_addon.estimate.bilateral import bilateral_slice, luma


def brute_force_slice(grid: torch.Tensor, guide: torch.Tensor, channels: int, extent=(1.0, 1.0)) -> torch.Tensor:
    """The documented conventions, one pixel at a time with explicit trilinear weights."""
    b, cd, hg, wg = grid.shape
    depth = cd // channels
    _, _, h, w = guide.shape
    vol = grid.reshape(b, channels, depth, hg, wg)
    out = torch.zeros(b, channels, h, w, dtype=grid.dtype)
    for n in range(b):
        for y in range(h):
            for x in range(w):
                gy = min(max((y + 0.5) * extent[0] * hg / h - 0.5, 0.0), hg - 1.0)
                gx = min(max((x + 0.5) * extent[1] * wg / w - 0.5, 0.0), wg - 1.0)
                gz = min(max(float(guide[n, 0, y, x]), 0.0), 1.0) * (depth - 1)
                y0, x0, z0 = int(math.floor(gy)), int(math.floor(gx)), int(math.floor(gz))
                for dz in (0, 1):
                    for dy in (0, 1):
                        for dx in (0, 1):
                            zi, yi, xi = min(z0 + dz, depth - 1), min(y0 + dy, hg - 1), min(x0 + dx, wg - 1)
                            wz = (gz - z0) if dz else (1 - (gz - z0))
                            wy = (gy - y0) if dy else (1 - (gy - y0))
                            wx = (gx - x0) if dx else (1 - (gx - x0))
                            out[n, :, y, x] += wz * wy * wx * vol[n, :, zi, yi, xi]
    return out


@pytest.mark.parametrize("shape", [(1, 1, 4, 3, 3, 12, 10), (2, 2, 3, 2, 4, 7, 9), (1, 3, 5, 1, 1, 5, 6)],
                         ids=["C1-D4-3x3->12x10", "B2-C2-D3-2x4->7x9", "C3-D5-1x1->5x6"])
def test_slice_matches_brute_force(shape):
    b, c, d, hg, wg, h, w = shape
    g = torch.Generator().manual_seed(0)
    grid = torch.randn(b, c * d, hg, wg, generator=g, dtype=torch.float64)
    guide = torch.rand(b, 1, h, w, generator=g, dtype=torch.float64) * 1.2 - 0.1  # some out of [0, 1]
    got = bilateral_slice(grid, guide, channels=c)
    assert got.shape == (b, c, h, w)
    torch.testing.assert_close(got, brute_force_slice(grid, guide, c), rtol=1e-10, atol=1e-10)


def test_slice_with_extent_matches_brute_force():
    """A grid of a padded frame, sliced for the unpadded part at another resolution."""
    g = torch.Generator().manual_seed(2)
    grid = torch.randn(1, 4, 4, 5, generator=g, dtype=torch.float64)
    guide = torch.rand(1, 1, 11, 13, generator=g, dtype=torch.float64)
    extent = (0.75, 0.6)
    got = bilateral_slice(grid, guide, extent=extent)
    torch.testing.assert_close(got, brute_force_slice(grid, guide, 1, extent), rtol=1e-10, atol=1e-10)


def test_hand_values_luma_nodes_and_cell_centres():
    # 2 bins at luma 0 and 1, values 1 and 3: the slice is 1 + 2 * luma wherever the grid is flat in space
    grid = torch.tensor([1.0, 3.0]).view(1, 2, 1, 1).expand(1, 2, 2, 2).contiguous()
    guide = torch.tensor([[0.0, 0.25], [0.5, 1.0]]).view(1, 1, 2, 2)
    torch.testing.assert_close(bilateral_slice(grid, guide)[0, 0], torch.tensor([[1.0, 1.5], [2.0, 3.0]]))
    # one bin pair per cell, 2x2 grid on a 2x2 image: every pixel is exactly at its cell centre
    grid = torch.arange(8.0).view(1, 2, 2, 2)  # bin 0: 0..3, bin 1: 4..7
    out = bilateral_slice(grid, torch.zeros(1, 1, 2, 2))
    torch.testing.assert_close(out[0, 0], torch.tensor([[0.0, 1.0], [2.0, 3.0]]))


def test_slice_follows_guide_edges():
    # a grid with disparity 0 for dark and 5 for bright content; a step edge in the guide at
    # column 9 must be reproduced exactly at full resolution from a 2x2 grid
    grid = torch.zeros(1, 2, 2, 2)
    grid[:, 1] = 5.0
    guide = torch.zeros(1, 1, 16, 16)
    guide[..., 9:] = 1.0
    out = bilateral_slice(grid, guide)[0, 0]
    assert torch.equal(out[:, :9], torch.zeros(16, 9))
    assert torch.equal(out[:, 9:], torch.full((16, 7), 5.0))


def test_gradcheck_grid_and_guide():
    g = torch.Generator().manual_seed(1)
    grid = torch.randn(1, 2 * 3, 2, 3, generator=g, dtype=torch.float64, requires_grad=True)
    # keep the guide away from bin nodes, where trilinear interpolation has kinks
    guide = (0.1 + 0.3 * torch.rand(1, 1, 5, 4, generator=g, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda gr, gu: bilateral_slice(gr, gu, channels=2), (grid, guide))


def test_bad_shapes_are_rejected():
    with pytest.raises(ValueError, match="multiple of C"):
        bilateral_slice(torch.zeros(1, 5, 2, 2), torch.zeros(1, 1, 4, 4), channels=2)
    with pytest.raises(ValueError, match="at least 2 luma bins"):
        bilateral_slice(torch.zeros(1, 1, 2, 2), torch.zeros(1, 1, 4, 4))
    with pytest.raises(ValueError, match="guide"):
        bilateral_slice(torch.zeros(1, 4, 2, 2), torch.zeros(1, 3, 4, 4))


def test_luma_weights():
    rgb = torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1, 1)
    assert float(luma(rgb)) == pytest.approx(0.2126)
    assert float(luma(torch.ones(1, 3, 2, 2)).min()) == pytest.approx(1.0)
