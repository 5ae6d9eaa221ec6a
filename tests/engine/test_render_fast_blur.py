"""The fast path's blur of one core (sources written straight into the DFT buffers, the least
circular period) and its frame-wide steps on worker threads (issue 24): equal to the plain zero-padded
``cv2.filter2D`` of the box, and the whole render equal to the exact path and the reference on a noisy,
real-like depth map, on 1x1 frames, all in focus and with a blur larger than the frame."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from rvr_addon.color import linear_to_srgb
from rvr_addon.render.aperture import ApertureSpec, make_kernel
from rvr_addon.render.fast import DFT_FROM_SIDE, FastRenderer, SpectrumCache, blur_core_planes
from rvr_addon.render.reference import render_reference


def _psnr_srgb(a: np.ndarray, b: np.ndarray) -> float:
    x, y = linear_to_srgb(np.clip(a, 0, 1)), linear_to_srgb(np.clip(b, 0, 1))
    return float(10 * np.log10(1.0 / max(float(np.mean((x.astype(np.float64) - y) ** 2)), 1e-30)))


@pytest.mark.parametrize("radius", [0.3, 3.0, 7.5, 12.0, 20.0])
def test_blur_of_a_core_equals_filter2d_of_its_zero_padded_box(radius):
    """Every placement of the core in its box (margins from 0, a clipped side, to more than the
    kernel's half width) and every size, direct filter and DFT alike."""
    rng = np.random.default_rng(int(radius * 10))
    kernel = np.ascontiguousarray(make_kernel(ApertureSpec(), radius)[::-1, ::-1]).astype(np.float32)
    if kernel.shape[0] > 1 and np.count_nonzero(kernel > 1e-7) == 1:
        kernel = np.ones((1, 1), np.float32)
    half = kernel.shape[0] // 2
    spectra = SpectrumCache()
    for _ in range(40):
        ch, cw = int(rng.integers(1, 70)), int(rng.integers(1, 70))
        top, left, bottom, right = (int(v) for v in rng.integers(0, half + 3, size=4))
        if kernel.shape[0] == 1:
            top = left = bottom = right = 0  # a delta's box is its core
        h, w = top + ch + bottom, left + cw + right
        src = [rng.random((ch, cw)).astype(np.float32) * 50 for _ in range(2)]
        box = np.zeros((2, h, w), np.float32)
        box[:, top:top + ch, left:left + cw] = src

        def write(views):
            for s, v in zip(src, views):
                v[...] = s

        got = blur_core_planes(write, 2, (top, left), (ch, cw), (h, w), kernel, spectra)
        for g, b in zip(got, box):
            want = cv2.filter2D(b, -1, kernel, borderType=cv2.BORDER_CONSTANT)
            assert g.shape == (h, w)
            np.testing.assert_allclose(g, want, atol=2e-5 * 50, rtol=0)
    if kernel.shape[0] >= DFT_FROM_SIDE:
        assert spectra._spectra  # the DFT path ran


def _real_like_scene(h: int = 96, w: int = 128, seed: int = 0):
    """Textured HDR radiance over a depth map like an estimated one: smooth layout (ramp, a nearer
    blob) plus per-pixel noise of about a layer step and speckle, so most tiles touch many layers."""
    rng = np.random.default_rng(seed)
    rad = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 1.0)
    rad[rng.random((h, w)) > 0.995] = 50.0  # HDR points
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    disp = 14.0 * yy / h - 4.0
    disp[(yy - 0.4 * h) ** 2 + (xx - 0.6 * w) ** 2 < (0.2 * h) ** 2] = -7.0
    disp += cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 0.7) * 1.5
    disp += (rng.random((h, w)) > 0.98) * rng.uniform(-4, 4, (h, w)).astype(np.float32)
    return rad, disp.astype(np.float32)


def test_noisy_real_like_depth_renders_like_the_exact_path_and_the_reference():
    rad, disp = _real_like_scene()
    ref = render_reference(rad, disp, 1.0, 1.0)
    exact = FastRenderer(half_res_radius=None).render_linear(rad, disp, 1.0, 1.0)
    peak = float(ref.max())
    assert np.abs(exact - ref).max() < 1e-5 * peak
    assert _psnr_srgb(exact, ref) > 60.0
    for threads, tile in [(1, 16), (2, 16), (2, 8)]:  # tiles and threads change nothing but rounding
        out = FastRenderer(half_res_radius=None, threads=threads, tile=tile).render_linear(rad, disp, 1.0, 1.0)
        assert np.abs(out - exact).max() < 1e-5 * peak
    # the default (radii from 16 px at half resolution) with a larger aperture: radii up to ~30 px
    exact = FastRenderer(half_res_radius=None).render_linear(rad, disp, 1.0, 2.2)
    fast = FastRenderer().render_linear(rad, disp, 1.0, 2.2)
    assert _psnr_srgb(fast, exact) >= 40.0


def test_a_1x1_frame_and_an_all_in_focus_frame_are_exact():
    out = FastRenderer().render_linear(np.full((1, 1, 3), 0.3, np.float32), np.full((1, 1), 5.0, np.float32), 0.0, 2.0)
    np.testing.assert_allclose(out, np.full((1, 1, 3), 0.3), atol=1e-6)
    rad, disp = _real_like_scene(40, 56, seed=2)
    flat = np.full_like(disp, 3.25)  # every pixel on the focal plane
    out = FastRenderer(threads=2).render_linear(rad, flat, 3.25, 4.0)
    np.testing.assert_allclose(out, rad, atol=1e-6 * float(rad.max()))


def test_a_blur_larger_than_the_frame_keeps_a_uniform_colour_and_the_reference():
    h, w = 30, 44
    rad = np.full((h, w, 3), (0.2, 0.5, 3.0), np.float32)
    disp = np.full((h, w), 40.0, np.float32)  # radius 40 px on a 44 x 30 frame, at half resolution
    out = FastRenderer(threads=2).render_linear(rad, disp, 0.0, 1.0)
    assert np.abs(out - rad).max() < 1e-4
    rng = np.random.default_rng(3)
    rad = rng.random((h, w, 3)).astype(np.float32)
    disp = (rng.random((h, w)) * 3 + 36).astype(np.float32)
    exact = FastRenderer(half_res_radius=None, threads=2).render_linear(rad, disp, 0.0, 1.0)
    ref = render_reference(rad, disp, 0.0, 1.0)
    assert np.abs(exact - ref).max() < 1e-4 * max(1.0, float(ref.max()))
