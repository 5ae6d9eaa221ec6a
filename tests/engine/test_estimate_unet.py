"""The estimator U-Net: any input size, output ranges at initialisation, units, size budget."""
from __future__ import annotations

import math

import pytest
import torch

from rvr_addon.estimate.unet import EstimatorConfig, EstimatorNet, clip_gate, disparity_to_px


@pytest.fixture(scope="module")
def net():
    torch.manual_seed(0)
    return EstimatorNet().eval()


@pytest.mark.parametrize("hw", [(1, 1), (5, 3), (32, 32), (45, 80), (67, 101)], ids=str)
def test_any_size(net, hw):
    x = torch.rand(2, 3, *hw, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        out = net(x)
    assert out.disparity_rel.shape == (2, 1, *hw) and out.exponent.shape == (2, 3, *hw)
    assert torch.isfinite(out.disparity_rel).all()


def test_initial_outputs_are_neutral(net):
    x = torch.rand(1, 3, 64, 96, generator=torch.Generator().manual_seed(2))
    x[..., :8, :8] = 1.0  # a clipped patch
    with torch.no_grad():
        out = net(x)
    cfg = net.config
    d = out.disparity_rel
    assert float(d.mean()) == pytest.approx(cfg.init_disparity, abs=0.05) and float(d.std()) < 0.05
    e = out.exponent
    assert float(e.min()) >= 0.0 and float(e.max()) <= cfg.e_max
    gain = math.exp(50 * float(e.max()))
    assert 1.0 <= gain < 1.05  # recovery starts as (almost) no change
    dark = x.amax(dim=1, keepdim=True) < cfg.gate_lo
    assert float(e.masked_select(dark.expand_as(e)).abs().max()) == 0.0  # E only on clipped pixels


def test_gate_and_units():
    x = torch.tensor([0.5, 0.9, 0.94, 0.98, 1.0]).view(1, 1, 1, 5).expand(1, 3, 1, 5)
    g = clip_gate(x, 0.9, 0.98)[0, 0, 0]
    torch.testing.assert_close(g, torch.tensor([0.0, 0.0, 0.5, 1.0, 1.0]))
    assert float(disparity_to_px(torch.tensor(1.0), 640)) == pytest.approx(6.4)
    d = disparity_to_px(torch.ones(2, 1, 1, 1), torch.tensor([100.0, 200.0]))
    assert d.flatten().tolist() == [1.0, 2.0]


def test_guide_resolution_path(net):
    full = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(3))
    small = torch.nn.functional.interpolate(full, size=(32, 32), mode="area")
    with torch.no_grad():
        out = net(small, guide_srgb=full)
        same = net(full, guide_srgb=full)
        plain = net(full)
    assert out.disparity_rel.shape == (1, 1, 64, 64) and out.exponent.shape == (1, 3, 64, 64)
    torch.testing.assert_close(same.disparity_rel, plain.disparity_rel)


def test_gradients_reach_every_parameter():
    torch.manual_seed(4)
    n = EstimatorNet()
    x = torch.rand(1, 3, 40, 40)
    x[..., 10:14, 10:14] = 1.0
    out = n(x)
    (out.disparity_rel.square().mean() + out.exponent.sum()).backward()
    missing = [name for name, p in n.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert not missing


def test_size_budget_and_config_round_trip(net):
    params = net.parameter_count()
    assert params * 4 < 20e6  # float32 weights well under 20 MB
    cfg = EstimatorConfig.from_dict(net.config.to_dict())
    assert cfg == net.config and cfg.stride == 32 and cfg.grid_scale == 8
    with pytest.raises(ValueError, match="unknown"):
        EstimatorConfig.from_dict({"widths": [8, 16], "depth_of_field": 3})
    with pytest.raises(ValueError):
        EstimatorConfig(grid_bins=1)
    with pytest.raises(ValueError, match="B, 3, H, W"):
        net(torch.zeros(1, 1, 8, 8))
