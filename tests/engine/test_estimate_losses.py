"""Estimator losses (paper eq. 5-7) on tiny tensors with hand-computed values."""
from __future__ import annotations

import math

import pytest
import torch

from rvr_addon.errors import InputError
from rvr_addon.estimate.losses import (
    MS_SSIM_WEIGHTS, SSIM_C1, LossWeights, VGG19Features, gradient_l1, load_vgg19, ms_ssim, ms_ssim_scales,
    pixel_l1, render_member, rendering_loss, smoothness_loss, ssim_terms, to_display, total_loss, vgg_loss,
)
from rvr_addon.render.torch_render import render_torch


def t(rows) -> torch.Tensor:
    """A (1, 1, H, W) tensor from nested lists."""
    return torch.tensor(rows, dtype=torch.float64)[None, None]


def test_pixel_l1_hand_value():
    a, b = t([[0.0, 0.5], [1.0, 0.25]]), t([[0.5, 0.5], [0.0, 0.0]])
    assert float(pixel_l1(a, b)) == pytest.approx((0.5 + 0 + 1 + 0.25) / 4)


def test_gradient_l1_hand_value():
    a = t([[0.0, 1.0, 3.0], [0.0, 0.0, 0.0]])
    b = torch.zeros_like(a)
    # dx of a: [1, 2], [0, 0] -> mean 0.75; dy: [0, -1, -3] -> mean 4/3
    assert float(gradient_l1(a, b)) == pytest.approx(0.75 + 4 / 3)
    assert float(gradient_l1(a, a + 7.0)) == 0.0  # a constant offset has no gradient


def test_smoothness_hand_value():
    d = t([[0.0, 2.0], [1.0, 1.0]])
    img = t([[0.0, 1.0], [0.0, 0.0]])
    # x: |2| e^{-1} and |0| e^0 -> mean e^{-1};  y: |1| e^0 and |-1| e^{-1} -> mean (1 + e^{-1}) / 2
    want = math.exp(-1) + (1 + math.exp(-1)) / 2
    assert float(smoothness_loss(d, img)) == pytest.approx(want)


def test_smoothness_uses_channel_mean_of_image_gradient():
    d = t([[0.0, 1.0]])
    img = torch.tensor([[[[0.0, 1.0]], [[0.0, 0.0]], [[0.0, 0.5]]]], dtype=torch.float64)  # (1, 3, 1, 2)
    assert float(smoothness_loss(d, img)) == pytest.approx(math.exp(-0.5))


def test_ssim_of_constant_images_is_the_luminance_term():
    a = torch.full((1, 1, 32, 32), 0.2, dtype=torch.float64)
    b = torch.full((1, 1, 32, 32), 0.6, dtype=torch.float64)
    lum = (2 * 0.2 * 0.6 + SSIM_C1) / (0.2**2 + 0.6**2 + SSIM_C1)
    ssim, cs = ssim_terms(a, b)
    assert float(cs) == pytest.approx(1.0) and float(ssim) == pytest.approx(lum)
    # 32 px: 2 scales; cs = 1 at every scale, so MS-SSIM = lum ** (normalised weight of the last scale)
    assert ms_ssim_scales(32, 32) == 2
    w_last = MS_SSIM_WEIGHTS[1] / (MS_SSIM_WEIGHTS[0] + MS_SSIM_WEIGHTS[1])
    assert float(ms_ssim(a, b)) == pytest.approx(lum**w_last)


def test_ms_ssim_identity_and_scales():
    x = torch.rand(2, 3, 40, 52, generator=torch.Generator().manual_seed(0))
    assert float(ms_ssim(x, x)) == pytest.approx(1.0)
    assert float(ms_ssim(x, torch.rand_like(x))) < 0.5
    assert [ms_ssim_scales(s, s) for s in (8, 11, 22, 44, 88, 176, 1000)] == [1, 1, 2, 3, 4, 5, 5]
    tiny = torch.rand(1, 3, 5, 7)
    assert float(ms_ssim(tiny, tiny)) == pytest.approx(1.0)  # window shrinks to the image


def test_ms_ssim_gradient_is_finite_for_anticorrelated_images():
    a = torch.rand(1, 1, 24, 24, generator=torch.Generator().manual_seed(3), requires_grad=True)
    (1 - ms_ssim(a, 1 - a.detach())).backward()
    assert torch.isfinite(a.grad).all()


def test_render_member_is_the_renderer_with_focus_and_aperture():
    g = torch.Generator().manual_seed(0)
    radiance = torch.rand(1, 3, 20, 20, generator=g)
    disparity = torch.rand(1, 1, 20, 20, generator=g) * 8 - 2
    focus, aperture = 1.5, 0.6  # alpha = a, beta = -a f
    got = render_member(radiance, disparity, alpha=aperture, beta=-aperture * focus)
    torch.testing.assert_close(got, render_torch(radiance, disparity, focus, aperture), rtol=1e-5, atol=1e-5)
    # a triplet's scale and shift act on the disparity: alpha = 0.5 renders half the blur
    half = render_member(radiance, disparity, alpha=0.5, beta=0.0)
    torch.testing.assert_close(half, render_torch(radiance, disparity * 0.5, 0.0, 1.0))


def test_to_display_clips_like_a_camera():
    x = torch.tensor([-0.5, 0.0, 0.0031308, 1.0, 40.0])
    y = to_display(x)
    assert float(y[0]) == 0.0 and float(y[3]) == pytest.approx(1.0) and float(y[4]) == pytest.approx(1.0)


def test_rendering_loss_parts_and_weights():
    g = torch.Generator().manual_seed(1)
    a, b = torch.rand(1, 3, 16, 16, generator=g), torch.rand(1, 3, 16, 16, generator=g)
    w = LossWeights(pix=1.0, ssim=0.25, grad=2.0)
    loss, parts = rendering_loss(a, b, w)
    want = parts["pix"] + 0.25 * parts["ssim"] + 2.0 * parts["grad"]
    assert float(loss) == pytest.approx(want, rel=1e-6)
    assert parts["pix"] == pytest.approx(float(pixel_l1(a, b)))
    assert parts["ssim"] == pytest.approx(1 - float(ms_ssim(a, b)))
    zero, _ = rendering_loss(a, a, w)
    assert float(zero) == pytest.approx(0.0, abs=1e-6)


def test_total_loss_pair_doubles_rendering_and_triplet_adds_adjusted():
    g = torch.Generator().manual_seed(2)
    r, tgt, r2, tgt2, img = (torch.rand(1, 3, 12, 12, generator=g) for _ in range(5))
    d = torch.rand(1, 1, 12, 12, generator=g) * 4
    w = LossWeights()
    rend, _ = rendering_loss(r, tgt, w)
    adj, _ = rendering_loss(r2, tgt2, w)
    smooth = smoothness_loss(d, img)
    pair = total_loss(r, tgt, d, img, adjusted=None, weights=w)
    assert float(pair.total) == pytest.approx(float(2 * rend + 10 * smooth), rel=1e-6)
    triplet = total_loss(r, tgt, d, img, adjusted=(r2, tgt2), weights=w)
    assert float(triplet.total) == pytest.approx(float(rend + adj + 10 * smooth), rel=1e-6)
    assert triplet.parts["adjust"] == pytest.approx(float(adj)) and pair.parts["adjust"] == 0.0
    assert w.smooth == 10.0  # w1 of the paper


# ------------------------------------------------------------------------------ VGG-19


@pytest.fixture(scope="module")
def vgg_file(tmp_path_factory):
    """A torchvision-layout VGG-19 state dict with random values (tests the loader only)."""
    net = VGG19Features()
    state = {k: v.clone() for k, v in net.state_dict().items()}
    state["classifier.0.weight"] = torch.zeros(2, 2)  # present in torchvision files; ignored
    path = tmp_path_factory.mktemp("vgg") / "vgg19.pth"
    torch.save(state, path)
    return path, net


def test_vgg19_layout_and_loading(vgg_file):
    path, net = vgg_file
    loaded = load_vgg19(path)
    assert all(not p.requires_grad for p in loaded.parameters())
    assert "features.30.weight" in loaded.state_dict() and "features.34.weight" not in loaded.state_dict()
    x = torch.rand(1, 3, 32, 32)
    feats = loaded(x)
    assert [f.shape[1] for f in feats] == [64, 128, 256, 512, 512]
    assert [f.shape[-1] for f in feats] == [32, 16, 8, 4, 2]
    for a, b in zip(feats, net(x)):
        torch.testing.assert_close(a, b)
    assert float(vgg_loss(loaded, x, x)) == 0.0
    y = torch.rand(1, 3, 32, 32)
    fr, ft = loaded(x), loaded(y)
    want = sum(lam * float((a - b).abs().mean()) for lam, a, b in zip((1 / 2.6, 1 / 4.8, 1 / 3.7, 1 / 5.6, 10 / 1.5), fr, ft))
    assert float(vgg_loss(loaded, x, y)) == pytest.approx(want, rel=1e-5)
    loss, parts = rendering_loss(x, y, LossWeights(), vgg=loaded)
    assert "vgg" in parts


def test_vgg19_corrupt_missing_and_wrong_files(tmp_path):
    bad = tmp_path / "vgg19_broken.pth"
    bad.write_bytes(b"not a torch file at all")
    with pytest.raises(InputError, match="vgg19_broken.pth"):
        load_vgg19(bad)
    with pytest.raises(InputError, match="not found"):
        load_vgg19(tmp_path / "nope.pth")
    other = tmp_path / "vgg16.pth"
    torch.save({"features.0.weight": torch.zeros(64, 3, 3, 3)}, other)
    with pytest.raises(InputError, match="vgg16.pth"):
        load_vgg19(other)


# ------------------------------------------------------------------------------ supervised terms (ours)


def test_fit_scale_shift_recovers_an_affine_map_and_ignores_masked_pixels():
    from rvr_addon.estimate.losses import fit_scale_shift

    pred = t([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]])
    gt = 2.0 * pred - 1.0
    gt[0, 0, 1, 2] = 100.0  # an outlier the mask leaves out
    mask = torch.ones_like(gt, dtype=torch.bool)
    mask[0, 0, 1, 2] = False
    s, tt = fit_scale_shift(pred, gt, mask)
    assert float(s) == pytest.approx(2.0) and float(tt) == pytest.approx(-1.0)
    flat_s, flat_t = fit_scale_shift(torch.ones_like(pred), gt, mask)  # a flat prediction: s = 0, t = mean
    assert float(flat_s) == 0.0 and float(flat_t) == pytest.approx(float(gt[mask].mean()))


def test_disparity_terms_hand_values():
    from rvr_addon.estimate.losses import disparity_gradient_loss, disparity_l1

    gt = t([[1.0, 2.0], [3.0, float("nan")]])  # NaN = unknown, left out
    pred = t([[1.5, 2.0], [2.0, 50.0]])
    assert float(disparity_l1(pred, gt)) == pytest.approx((0.5 + 0.0 + 1.0) / 3)
    # an affine copy is perfect for the invariant variant only
    aff = 0.5 * gt.nan_to_num(7.0) + 3.0
    assert float(disparity_l1(aff, gt, invariant=True)) == pytest.approx(0.0, abs=1e-9)
    assert float(disparity_l1(aff, gt)) > 0.5
    # a constant offset has no gradient error; one step in x of residual 1 at scale 1
    assert float(disparity_gradient_loss(gt.nan_to_num(0.0) + 4.0, gt)) == pytest.approx(0.0)
    g2 = t([[0.0, 0.0], [0.0, 0.0]])
    p2 = t([[0.0, 1.0], [0.0, 1.0]])
    # scale 1: dx |1|, |1| -> mean 1; dy 0. Coarser scales are 1 px wide/high: nothing.
    assert float(disparity_gradient_loss(p2, g2)) == pytest.approx(1.0)


def test_exponent_terms_hand_values():
    from rvr_addon.estimate.losses import exponent_losses

    target = torch.zeros(1, 3, 1, 3, dtype=torch.float64)
    target[..., 0, 0] = 0.06  # a clipped light: gain e^3
    target[..., 0, 2] = 0.04  # an unsaturated pixel mixing a light in: left out of both terms
    sat = torch.tensor([[[[True, False, False]]]])
    pred = torch.zeros_like(target)
    pred[..., 0, 0] = 0.05
    pred[..., 0, 1] = 0.002
    pred[..., 0, 2] = 0.5
    l_e, l_e0 = exponent_losses(pred, target, sat, e_max=0.138)
    assert float(l_e) == pytest.approx(50 * 0.01)
    assert float(l_e0) == pytest.approx(50 * 0.002)
    # the target is clamped to the network's range
    l_e, _ = exponent_losses(pred, target * 10, sat, e_max=0.1)
    assert float(l_e) == pytest.approx(50 * 0.05)
    # no saturated pixel: the term is 0, not NaN
    l_e, _ = exponent_losses(pred, target, torch.zeros_like(sat), e_max=0.138)
    assert float(l_e) == 0.0


def test_supervised_loss_parts_and_missing_ground_truth():
    from rvr_addon.estimate.losses import supervised_loss

    d = torch.zeros(1, 1, 4, 4, requires_grad=True)
    e = torch.zeros(1, 3, 4, 4, requires_grad=True)
    gt_d = torch.ones(1, 1, 4, 4)
    w = LossWeights(sup_disparity=2.0, sup_disparity_grad=0.0)
    res = supervised_loss(d, gt_d, e, None, None, 0.138, w)
    assert set(res.parts) == {"sup", "sup_d", "sup_dgrad"} and res.parts["sup"] == pytest.approx(2.0)
    res.total.backward()
    assert d.grad is not None and float(d.grad.abs().sum()) > 0
    none = supervised_loss(d, None, e, None, None, 0.138, w)
    assert none.parts == {"sup": 0.0} and float(none.total) == 0.0
