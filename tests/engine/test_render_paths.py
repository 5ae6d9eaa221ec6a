"""Fast path and torch path against the brute-force reference, and the model's promises."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from rvr_addon.errors import InputError
from rvr_addon.render.aperture import ApertureSpec, make_kernel
from rvr_addon.render.fast import FastRenderer, render_frame
from rvr_addon.render.model import plan_layers
from rvr_addon.render.reference import render_reference, scatter
from rvr_addon.render.torch_render import render_torch

SPECS = [
    pytest.param(ApertureSpec(), id="disk"),
    pytest.param(ApertureSpec("polygon", blades=5, rotation_deg=12.0), id="pentagon"),
    pytest.param(ApertureSpec("anamorphic", squeeze=2.0), id="anamorphic-2x"),
    pytest.param(ApertureSpec("image", kernel_image=np.tri(9, 9)[::-1].copy()), id="image-asymmetric"),
    pytest.param(ApertureSpec(cat_eye=0.8, zones=5), id="disk-cat-eye"),
]


def scene(h: int = 48, w: int = 72, seed: int = 0):
    """Textured HDR radiance with a ramp background, a foreground disk and bright points."""
    rng = np.random.default_rng(seed)
    rad = rng.random((h, w, 3)).astype(np.float32)
    rad[5, w - 12] = 80.0
    rad[h - 8, 6] = (40.0, 5.0, 1.0)
    yy, xx = np.mgrid[:h, :w]
    disp = (6.0 * xx / w).astype(np.float32)
    disp[(yy - h // 2) ** 2 + (xx - w // 3) ** 2 < (h // 4) ** 2] = -2.5
    return rad, disp


def to_t(rad, disp):
    return torch.from_numpy(rad).permute(2, 0, 1)[None], torch.from_numpy(disp)[None]


def gather_reference(src: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Per-pixel loop: out(p) = sum_q src(q) * PSF(p - q). The slowest, plainest form."""
    h, w = src.shape[:2]
    half = kernel.shape[0] // 2
    out = np.zeros_like(src)
    for y in range(h):
        for x in range(w):
            for qy in range(max(0, y - half), min(h, y + half + 1)):
                for qx in range(max(0, x - half), min(w, x + half + 1)):
                    out[y, x] += src[qy, qx] * kernel[y - qy + half, x - qx + half]
    return out


@pytest.mark.parametrize("spec", SPECS)
def test_scatter_equals_per_pixel_gather(spec):
    src = np.random.default_rng(1).random((9, 11, 2))
    k = make_kernel(spec, 2.6).astype(np.float64)
    assert np.allclose(scatter(src, k), gather_reference(src, k), atol=1e-12)


@pytest.mark.parametrize("naive", [False, True], ids=["occlusion", "naive"])
@pytest.mark.parametrize("spec", SPECS)
def test_fast_equals_reference(spec, naive):
    rad, disp = scene()
    ref = render_reference(rad, disp, 1.0, 1.6, spec=spec, naive=naive)
    fast = FastRenderer(spec=spec, naive=naive).render_linear(rad, disp, 1.0, 1.6)
    assert np.abs(fast - ref).max() < 1e-4 * max(1.0, float(ref.max()))


@pytest.mark.parametrize("threads", [1, 2])
def test_fast_is_deterministic_across_threads_and_tiles(threads):
    rad, disp = scene(70, 90, seed=3)
    a = FastRenderer(threads=threads, tile=16).render_linear(rad, disp, 0.5, 2.0)
    b = FastRenderer(threads=1, tile=8).render_linear(rad, disp, 0.5, 2.0)
    assert np.abs(a - b).max() < 1e-5 * float(b.max())


def test_fast_min_layers_finer_grid():
    rad, disp = scene()
    plan = plan_layers(float((disp - 1.0).min() * 1.2), float((disp - 1.0).max() * 1.2), min_layers=30)
    assert len(plan) >= 30
    ref = render_reference(rad, disp, 1.0, 1.2, plan=plan)
    fast = FastRenderer().render_linear(rad, disp, 1.0, 1.2, plan=plan)
    assert np.abs(fast - ref).max() < 1e-4 * float(ref.max())


@pytest.mark.parametrize("naive", [False, True], ids=["occlusion", "naive"])
@pytest.mark.parametrize("spec", [SPECS[0], SPECS[1], SPECS[4]])
def test_torch_equals_reference(spec, naive):
    rad, disp = scene()
    ref = render_reference(rad, disp, 1.0, 3.0, spec=spec, naive=naive)  # radii up to 12: FFT path too
    out = render_torch(*to_t(rad, disp), 1.0, 3.0, spec=spec, naive=naive)[0].permute(1, 2, 0).numpy()
    assert np.abs(out - ref).max() < 1e-4 * float(ref.max())


def test_torch_batch_with_per_sample_focus():
    rad, disp = scene()
    r, d = to_t(rad, disp)
    out = render_torch(r.repeat(2, 1, 1, 1), d.repeat(2, 1, 1), torch.tensor([0.0, 4.0]), torch.tensor([1.0, 2.0]))
    for k, (f, a) in enumerate([(0.0, 1.0), (4.0, 2.0)]):
        ref = render_reference(rad, disp, f, a)
        # the batch shares one layer plan, so compare against the reference on that plan
        s = np.concatenate([(disp - 0.0) * 1.0, (disp - 4.0) * 2.0])
        plan = plan_layers(float(s.min()), float(s.max()))
        ref = render_reference(rad, disp, f, a, plan=plan)
        assert np.abs(out[k].permute(1, 2, 0).numpy() - ref).max() < 1e-4 * float(ref.max())


def test_torch_gradients_reach_disparity_and_hdr():
    rad, disp = scene(12, 14)
    r = torch.from_numpy(rad).permute(2, 0, 1)[None].double()
    d = torch.from_numpy(disp)[None, None].double().requires_grad_()
    e = torch.zeros(1, 1, 12, 14, dtype=torch.float64, requires_grad=True)
    out = render_torch(r * torch.exp(50 * e), d, 1.0, 1.0)
    (out * torch.linspace(0, 1, 14, dtype=torch.float64)).sum().backward()
    assert torch.isfinite(d.grad).all() and d.grad.abs().sum() > 0
    assert torch.isfinite(e.grad).all() and e.grad.abs().sum() > 0
    plan = plan_layers(float((disp - 1).min()), float((disp - 1).max()))
    f = lambda dd: render_torch(r, dd, 1.0, 1.0, plan=plan)  # noqa: E731
    d2 = (torch.from_numpy(disp)[None, None].double() + 0.013)  # off the matte kinks
    d2 = d2[..., 3:8, 4:10].contiguous().requires_grad_()
    r = r[..., 3:8, 4:10]
    assert torch.autograd.gradcheck(f, (d2,), eps=1e-6, atol=1e-5)


# -- what the model promises -------------------------------------------------------------

def test_uniform_colour_stays_exact_at_every_depth():
    """Partial coverage is normalised: no dark halos, seams or border darkening."""
    h, w = 40, 60
    yy, xx = np.mgrid[:h, :w]
    disp = (4 * np.sin(xx / 5.0) + 3 * np.cos(yy / 7.0) + 8 * (xx > 30)).astype(np.float32)
    rad = np.full((h, w, 3), (0.2, 0.5, 3.0), np.float32)
    for naive in (False, True):
        out = FastRenderer(naive=naive).render_linear(rad, disp, 2.0, 1.5)
        assert np.abs(out - rad).max() < 1e-5


def _fg_bg(h=40, w=60):
    rad = np.zeros((h, w, 3), np.float32)
    rad[...] = (0.1, 0.1, 0.8)  # blue background
    fg = np.zeros((h, w), bool)
    fg[10:30, 20:40] = True
    rad[fg] = (0.9, 0.6, 0.1)  # orange foreground
    disp = np.where(fg, -4.0, 8.0).astype(np.float32)
    return rad, disp, fg


def test_background_blur_never_bleeds_over_a_sharp_foreground():
    rad, disp, fg = _fg_bg()
    out = FastRenderer().render_linear(rad, disp, -4.0, 1.0)  # focus on the foreground
    inner = np.zeros_like(fg)
    inner[12:28, 22:38] = True
    assert np.abs(out[inner] - rad[inner]).max() < 1e-5
    # the silhouette's outer pixel: the in-focus layer hands 6% of its matte to the radius-1
    # layer behind it (eq. 2 with lambda = 2.8), so the rim is 1 px soft; < 1% of background
    assert np.abs(out[fg] - rad[fg]).max() < 0.01
    naive = FastRenderer(naive=True).render_linear(rad, disp, -4.0, 1.0)
    assert np.abs(naive[fg] - rad[fg]).max() > 0.05  # the naive sum bleeds (the ablation's point)


def test_blurred_foreground_spreads_over_a_sharp_background():
    rad, disp, fg = _fg_bg()
    out = FastRenderer().render_linear(rad, disp, 8.0, 1.0)  # focus on the background: fg radius 12
    far = np.ones_like(fg)
    far[0:30 + 13, 20 - 13:40 + 13] = False
    assert np.abs(out[far] - rad[far]).max() < 1e-5  # beyond the rim: untouched background
    rim = out[20, 20 - 6]  # 6 px outside the silhouette: a mix of both colours
    assert 0.15 < rim[0] < 0.85


def test_hdr_point_becomes_a_bokeh_ball_conserving_energy():
    h = w = 61
    rad = np.zeros((h, w, 3), np.float32)
    rad[30, 30] = 500.0
    disp = np.full((h, w), 10.0, np.float32)
    out = FastRenderer().render_linear(rad, disp, 0.0, 1.0)
    assert out.sum() == pytest.approx(3 * 500.0, rel=1e-4)
    disk = out[30 - 6:30 + 7, 30 - 6:30 + 7, 0]
    # a flat bright disk (the point lies on layer 10 with 6% in layer 9 in front: radius 9-10)
    assert disk.min() == pytest.approx(500.0 / (np.pi * 100), rel=0.05)
    assert disk.max() - disk.min() < 0.05 * disk.max()
    # a clipped (8-bit) highlight of 1.0 spreads to an invisible 0.003
    dim = FastRenderer().render_linear(np.minimum(rad, 1.0), disp, 0.0, 1.0)
    assert dim.max() < 0.01


def test_aperture_zero_is_identity_and_render_frame_uses_srgb():
    rad, disp = scene()
    assert np.array_equal(FastRenderer().render_linear(rad, disp, 0.0, 0.0), rad)
    img = (np.random.default_rng(0).random((20, 30, 3)) * 255).astype(np.uint8)
    out = render_frame(img, np.zeros((20, 30), np.float32), 0.0, 1.0)
    assert np.abs(out * 255 - img).max() < 0.51  # in focus: the same 8-bit picture back


@pytest.mark.parametrize("case,match", [
    pytest.param("nan", "NaN", id="nan-disparity"),
    pytest.param("size", "resample", id="size-mismatch"),
    pytest.param("aperture", "aperture", id="negative-aperture"),
    pytest.param("focus", "focus", id="inf-focus"),
])
def test_bad_frame_inputs(case, match):
    rad, disp = scene()
    focus, aperture = 0.0, 1.0
    if case == "nan":
        disp[3, 3] = np.nan
    elif case == "size":
        disp = disp[:-1]
    elif case == "aperture":
        aperture = -1.0
    elif case == "focus":
        focus = float("inf")
    with pytest.raises(InputError, match=match):
        FastRenderer().render_linear(rad, disp, focus, aperture)


def test_fast_alpha_matches_the_model_far_from_the_layer():
    """The two-exponential alpha of the fast path equals model.layer_alpha for any u."""
    from rvr_addon.render.fast import _alpha_cv
    from rvr_addon.render.model import layer_alpha

    u = np.linspace(-40, 40, 8001, dtype=np.float32)[None, :].repeat(2, 0)
    for j, j_hi in [(1.0, 8.0), (7.0, 8.0), (8.0, 8.0), (-30.0, 39.0)]:
        assert np.abs(_alpha_cv(u, j, j_hi) - layer_alpha(u, j, j_hi)).max() < 1e-5
