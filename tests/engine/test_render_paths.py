"""Fast path and torch path against the brute-force reference, and the model's promises."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from rvr_addon.color import linear_to_srgb
from rvr_addon.errors import InputError
from rvr_addon.render.aperture import ApertureSpec, make_kernel
from rvr_addon.render.fast import FastRenderer, render_frame
from rvr_addon.render.model import matte_normaliser, plan_layers, push_pull_fill
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
    # and a generic point: no two equal depths, where the fill's block maximum has a kink
    noise = torch.rand(d2.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    d2 = (d2 + 1e-3 * noise)[..., 3:8, 4:10].contiguous().requires_grad_()
    r = r[..., 3:8, 4:10]
    assert torch.autograd.gradcheck(f, (d2,), eps=1e-6, atol=1e-5)


# -- what the model promises -------------------------------------------------------------

def test_uniform_colour_stays_exact_at_every_depth():
    """Partial coverage is resolved without dark or bright halos, seams or border darkening."""
    h, w = 40, 60
    yy, xx = np.mgrid[:h, :w]
    disp = (4 * np.sin(xx / 5.0) + 3 * np.cos(yy / 7.0) + 8 * (xx > 30)).astype(np.float32)
    rad = np.full((h, w, 3), (0.2, 0.5, 3.0), np.float32)
    for naive in (False, True):
        out = FastRenderer(naive=naive).render_linear(rad, disp, 2.0, 1.5)
        assert np.abs(out - rad).max() < 1e-5
    small = (slice(0, 24), slice(20, 48))  # a depth edge, blur reaching out of the frame
    r, d = np.ascontiguousarray(rad[small]), np.ascontiguousarray(disp[small])
    assert np.abs(render_reference(r, d, 2.0, 1.5) - r).max() < 1e-5
    assert np.abs(render_torch(*to_t(r, d), 2.0, 1.5)[0].permute(1, 2, 0).numpy() - r).max() < 1e-5


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
    # the silhouette's outer pixel: the in-focus layer hands 5.5% of its matte to each of the
    # radius-1 layers around it (eq. 2 with lambda = 2.8), so the rim is 1 px soft: part of that
    # spreads outside and uncovers ~2% (corners) or ~1% (sides) of what lies behind
    assert np.abs(out[fg] - rad[fg]).max() < 0.025
    naive = FastRenderer(naive=True).render_linear(rad, disp, -4.0, 1.0)
    assert np.abs(naive[fg] - rad[fg]).max() > 0.05  # the naive sum bleeds (the ablation's point)


def test_blurred_foreground_spreads_over_a_sharp_background():
    rad, disp, fg = _fg_bg()
    exact = FastRenderer(half_res_radius=None).render_linear(rad, disp, 8.0, 1.0)  # focus on the bg: fg radius 12
    far = np.ones_like(fg)
    far[0:30 + 13, 20 - 13:40 + 13] = False
    assert np.abs(exact[far] - rad[far]).max() < 1e-5  # beyond the rim: untouched background
    rim = exact[20, 20 - 6]  # 6 px outside the silhouette: a mix of both colours
    assert 0.15 < rim[0] < 0.85
    # the default blurs radius >= 12 px at half resolution: the rim leaks a trace one or two px further
    out = FastRenderer().render_linear(rad, disp, 8.0, 1.0)
    assert np.abs(out[far] - rad[far]).max() < 0.005
    assert np.abs(out - exact).max() < 0.03 and 0.15 < out[20, 20 - 6][0] < 0.85


def test_half_resolution_blur_of_large_radii_stays_within_40_db_of_the_exact_model():
    rng = np.random.default_rng(4)
    h, w = 120, 160
    rad = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 1.5)
    rad[rng.random((h, w)) > 0.997] = 60.0  # sparse HDR highlights: bokeh balls with rims
    yy = np.mgrid[:h, :w][0].astype(np.float32)
    disp = (30.0 * yy / h - 6.0).astype(np.float32)  # radii 0..24 px at focus 0
    exact = FastRenderer(half_res_radius=None).render_linear(rad, disp, 0.0, 1.0)
    fast = FastRenderer().render_linear(rad, disp, 0.0, 1.0)
    a, b = linear_to_srgb(np.clip(exact, 0, 1)), linear_to_srgb(np.clip(fast, 0, 1))
    psnr = 10 * np.log10(1.0 / np.mean((a - b) ** 2))
    assert psnr >= 40.0
    # radius >= 12 px from row 72 on, reaching at most 24 (+2) px up: rows above 40 are the exact
    # model's (up to float summation order and the frame-wide fill)
    assert np.abs(exact[:40] - fast[:40]).max() < 1e-4


def test_hdr_point_becomes_a_bokeh_ball_conserving_energy():
    h = w = 61
    rad = np.zeros((h, w, 3), np.float32)
    rad[30, 30] = 500.0
    disp = np.full((h, w), 10.0, np.float32)
    out = FastRenderer().render_linear(rad, disp, 0.0, 1.0)
    # the ball keeps the point's energy; the frame border, where the radius-10 blur reaches out
    # of the frame, is filled with an estimate of its surroundings, which carries a trace of the
    # point (+0.26%)
    assert out.sum() == pytest.approx(3 * 500.0, rel=5e-3)
    inner = out[10:51, 10:51]
    assert inner.sum() == pytest.approx(3 * 500.0, rel=1e-4)
    disk = out[30 - 6:30 + 7, 30 - 6:30 + 7, 0]
    # a flat bright disk (the frame is one layer, 10: radius 10)
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


def test_fast_matte_normaliser_matches_the_model():
    """The two-exponential normaliser of the fast path equals model.matte_normaliser, also at
    the ends of the plan (where layers beyond it must not count)."""
    from rvr_addon.render.fast import matte_normaliser_cv

    plan = plan_layers(-4.3, 6.7)
    j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
    u = np.random.default_rng(0).uniform(j_lo, j_hi, size=(40, 300)).astype(np.float32)
    u[0, :6] = [j_lo, j_hi, j_lo + 0.5, j_hi - 0.5, 0.0, j_hi - 1]
    assert np.abs(matte_normaliser_cv(u, j_lo, j_hi) - matte_normaliser(u, plan)).max() < 1e-5


@pytest.mark.parametrize("shape", [(37, 53), (64, 64), (16, 17), (15, 40), (1, 5), (9, 1), (2, 2)])
def test_fill_paths_match_the_model(shape):
    """The OpenCV and torch push-pulls equal the model's plain numpy one (odd and tiny sizes too)."""
    from rvr_addon.render.fast import fill_cv
    from rvr_addon.render.torch_render import push_pull_fill_torch

    rng = np.random.default_rng(sum(shape))
    colour = rng.random(shape + (3,)).astype(np.float32) * 5
    weight = (rng.random(shape) ** 3).astype(np.float32)
    weight[weight < 0.2] = 0.0  # empty pixels
    depth = (rng.random(shape) * 30 - 10).astype(np.float32)
    want = push_pull_fill(colour.astype(np.float64), weight.astype(np.float64), depth.astype(np.float64))
    assert np.abs(fill_cv(colour, weight, depth) - want).max() < 1e-5
    got = push_pull_fill_torch(torch.from_numpy(colour).permute(2, 0, 1)[None], torch.from_numpy(weight)[None, None],
                               torch.from_numpy(depth)[None, None])
    assert np.abs(got[0].permute(1, 2, 0).numpy() - want).max() < 1e-5


# -- the coverage resolve: holes, rims, borders ---------------------------------------------

def _patch_over_sharp_background():
    """The issue's repro: a tiny very bright patch at D=2 over a black background at D=5."""
    rad = np.zeros((64, 64, 3), np.float32)
    rad[29:31, 39:41] = 80.0
    disp = np.full((64, 64), 5.0, np.float32)
    disp[29:31, 39:41] = 2.0
    return rad, disp


def test_small_hdr_patch_keeps_its_energy_and_the_hole_stays_dark():
    """Focused on the background (aperture 1): the patch spreads into a radius-3 disk; the sharp
    background has a 2x2 hole where the patch was. Physically the hole shows the occluded (black)
    background plus the patch's blur on top, so the total is the patch's 4 * 80 = 320 per channel.
    (The previous model gave ~850: a full-strength copy of the patch in the back-most layer of
    its matte, and the coverage normalisation filling the hole with the patch's own colour, 80.)"""
    rad, disp = _patch_over_sharp_background()
    hole = (slice(29, 31), slice(39, 41))
    ring = np.zeros((64, 64), bool)
    ring[28:32, 38:42] = True  # the pixels around the hole
    ring[hole] = False
    for out in (FastRenderer().render_linear(rad, disp, 5.0, 1.0), render_reference(rad, disp, 5.0, 1.0)):
        assert out[..., 0].sum() == pytest.approx(320.0, rel=0.03)
        disk = out[ring][:, 0].mean()  # the bokeh disk's level next to the hole, ~80 * 4 / 28
        assert 8.0 < disk < 14.0
        assert out[hole][..., 0].max() < 1.15 * disk  # not 80: the hole is no brighter than the disk
        assert np.abs(out[..., 0] - out[..., 1]).max() < 1e-5


def _rim_scene(fg_value: float, radius: int = 5):
    """A square foreground of one colour at blur radius ``radius`` in front of a sharp, finely
    textured background (in focus), and the physically expected image: the foreground's disk-blurred
    radiance over the WHOLE background (hidden part included), attenuated by its blurred coverage,
    ``K * (L_fg 1_fg) + (1 - K * 1_fg) L_bg``."""
    h, w = 64, 96
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    bg = 0.35 + 0.25 * np.sin(xx * 1.3) * np.sin(yy * 0.9 + 0.5)  # mean 0.35, 2-3 px texture
    bg = np.repeat(bg[..., None], 3, axis=2).astype(np.float32)
    fg = np.zeros((h, w), bool)
    fg[16:48, 30:66] = True
    rad = bg.copy()
    rad[fg] = fg_value
    disp = np.where(fg, -float(radius), 0.0).astype(np.float32)
    k = make_kernel(ApertureSpec(), float(radius)).astype(np.float64)
    blurred = scatter(np.dstack([rad * fg[..., None], fg]).astype(np.float64), k)
    expected = blurred[..., :3] + (1.0 - blurred[..., 3:4]) * bg
    return rad, disp, expected, fg


@pytest.mark.parametrize("fg_value", [1.0, 0.02], ids=["bright-fg", "dark-fg"])
def test_blurred_rim_over_a_sharp_textured_background_has_no_halo(fg_value):
    """Across the foreground's edge the profile (averaged along the straight sides) follows the
    physical expectation within 0.02 on both sides of the silhouette: no bright or dark halo
    outside (the old double-counted back layer gave +0.29 / -0.14) and none inside, where the
    occluded background must show through the rim (normalising by coverage gave the solid
    foreground colour there: +0.22 / -0.10). Outside the silhouette nothing is hidden, so there
    the render matches pixel by pixel."""
    rad, disp, expected, fg = _rim_scene(fg_value)
    out = FastRenderer().render_linear(rad, disp, 0.0, 1.0)
    rows = slice(24, 40)  # away from the corners
    for cols in (slice(20, 40), slice(56, 76)):  # left and right edges, +- 10 px
        profile = (out[rows, cols] - expected[rows, cols]).mean(axis=(0, 2))
        assert np.abs(profile).max() < 0.02, profile
    outside = ~fg
    assert np.abs(out[outside] - expected[outside]).max() < 0.03
    ref = render_reference(rad[8:56, 18:48].copy(), disp[8:56, 18:48].copy(), 0.0, 1.0)
    assert np.abs(ref - FastRenderer().render_linear(rad[8:56, 18:48].copy(), disp[8:56, 18:48].copy(), 0.0,
                                                     1.0)).max() < 1e-4


def test_frame_borders_are_not_darkened():
    """A textured picture blurred by 8 px: within 8 px of the frame edge the blur reaches out of
    the frame (coverage down to 1/2, 1/4 in corners). The estimate of what lies beyond is the
    picture near the edge, so the border band keeps the brightness of a renormalised blur (the
    usual estimate) on average and pixel by pixel stays close to it; the interior is exact."""
    h, w = 60, 90
    rng = np.random.default_rng(5)
    import cv2

    rad = (0.2 + 0.6 * cv2.resize(rng.random((h // 3, w // 3, 3)).astype(np.float32), (w, h))).astype(np.float32)
    disp = np.full((h, w), 8.0, np.float32)
    out = FastRenderer().render_linear(rad, disp, 0.0, 1.0)
    k = make_kernel(ApertureSpec(), 8.0).astype(np.float64)
    spread_ = scatter(np.dstack([rad, np.ones((h, w))]).astype(np.float64), k)
    renorm = spread_[..., :3] / spread_[..., 3:]
    band = np.ones((h, w), bool)
    band[10:-10, 10:-10] = False
    assert out[band].mean() == pytest.approx(renorm[band].mean(), rel=0.01)
    for edge in (np.s_[0], np.s_[-1], np.s_[:, 0], np.s_[:, -1]):  # the outermost rows and columns
        assert out[edge].mean() == pytest.approx(renorm[edge].mean(), rel=0.03)  # uncovered: ~1/2 as bright
    assert np.abs(out - renorm)[band].max() < 0.15
    assert np.abs(out - renorm)[~band].max() < 1e-4


def test_a_dark_depth_gradient_gets_no_veil_from_the_fill():
    """A dark textured surface on a smooth depth gradient (0 -> 24 px of blur, every tile on a slope,
    as on an estimated depth map) under a bright far band: a smooth surface has no disocclusion, so
    the blurred gradient keeps its own level. With "over" between its contour bands it lost 2-30 % of
    its coverage to the layers 2-3 steps in front and the fill (which prefers the far, bright band)
    doubled its level (+110 %); saturating within a surface leaves +5 %. All three paths agree."""
    h, w = 96, 64
    y = np.arange(h, dtype=np.float32)[:, None] * np.ones((1, w), np.float32)
    disp = (24.0 * (1.0 - y / (h - 1))).astype(np.float32)  # far (24 px) at the top, in focus at the bottom
    rad = np.full((h, w, 3), 0.05, np.float32)
    rad[:6] = 3.0  # the bright far band
    rad[6:] *= np.random.default_rng(0).uniform(0.5, 1.5, (h - 6, w, 1)).astype(np.float32)
    band = (slice(50, 86), slice(16, 48))  # >= 20 px below the band's blur
    fast = FastRenderer(half_res_radius=None).render_linear(rad, disp, 0.0, 1.0)
    ref = render_reference(rad, disp, 0.0, 1.0)
    tor = render_torch(torch.from_numpy(rad).permute(2, 0, 1)[None], torch.from_numpy(disp)[None], 0.0, 1.0)
    tor = tor[0].permute(1, 2, 0).numpy()
    for out in (fast, ref, tor):
        assert np.abs(out[band].mean(axis=(0, 1)) / rad[band].mean(axis=(0, 1)) - 1.0).max() < 0.1
    assert np.abs(fast - ref).max() < 1e-4 * float(ref.max())
