"""The shared model definition (paper eq. 2-4) and the aperture kernels."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rvr_addon.color import linear_to_srgb, srgb_to_linear
from rvr_addon.errors import InputError
from rvr_addon.render.aperture import ApertureSpec, kernel_half_size, load_kernel_image, make_kernel
from rvr_addon.render.model import (
    EXP_FLOOR,
    FILL_DEPTH_SHARPNESS,
    FILL_DEPTH_TOLERANCE,
    K_HDR,
    LAMBDA,
    MATTE_CUTOFF,
    depth_factor,
    hdr_radiance,
    matte_normaliser,
    matte_unnormalised,
    plan_layers,
    push_pull_fill,
    signed_radius,
)


def test_srgb_round_trip_and_known_values():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    assert np.allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=2e-6)
    assert srgb_to_linear(np.float32(0.5)) == pytest.approx(0.21404, abs=1e-5)
    assert linear_to_srgb(np.float32(0.0031308)) == pytest.approx(0.04045, abs=1e-5)
    assert float(linear_to_srgb(np.float32(7.0))) == pytest.approx(1.0, abs=1e-6)  # display-referred: clips


def test_hdr_radiance_is_eq3():
    lin = np.full((2, 2, 3), 0.5, np.float32)
    e = np.full((2, 2, 1), 0.02, np.float32)
    assert np.allclose(hdr_radiance(lin, e), 0.5 * math.exp(K_HDR * 0.02))
    assert hdr_radiance(lin, None) is lin


def test_signed_radius_sign_convention():
    d = np.array([-2.0, 0.0, 3.0], np.float32)
    assert signed_radius(d, 1.0, 2.0).tolist() == [-6.0, -2.0, 4.0]


@pytest.mark.parametrize("s_min,s_max,min_layers", [(-3.3, 10.2, 1), (0.0, 32.0, 1), (-2.7, 10.7, 24), (5.0, 5.0, 1)])
def test_plan_layers_grid(s_min, s_max, min_layers):
    plan = plan_layers(s_min, s_max, min_layers=min_layers)
    levels = plan.indices * plan.step
    assert np.all(np.diff(plan.indices) == -1), "back to front = descending"
    assert levels[0] >= s_max - 1e-6 and levels[-1] <= s_min + 1e-6
    assert len(plan) >= min_layers
    assert plan.step <= 1.0
    # the focal plane is on the grid whenever it is inside the range
    if s_min <= 0 <= s_max:
        assert 0 in plan.indices


def test_matte_matches_eq2_and_is_a_partition():
    d = np.float32(0.7)
    expected = math.exp(-LAMBDA * 0.49) - math.exp(-LAMBDA * MATTE_CUTOFF ** 2)
    assert float(matte_unnormalised(d, np.float32(0.0))) == pytest.approx(expected, rel=1e-6)
    assert float(matte_unnormalised(np.float32(MATTE_CUTOFF), np.float32(0))) == 0.0
    plan = plan_layers(-4, 6)
    u = np.random.default_rng(0).uniform(-4, 6, size=(50, 50)).astype(np.float32)
    total = sum(matte_unnormalised(u, np.float32(j)) for j in plan.indices)
    assert np.allclose(matte_normaliser(u, plan), total, rtol=1e-5)


def test_kernels_sum_to_one_and_grow():
    for spec in (ApertureSpec(), ApertureSpec("polygon", blades=5), ApertureSpec("anamorphic", squeeze=2.0)):
        areas = []
        for r in (0.0, 1.0, 3.0, 7.5, 16.0):
            k = make_kernel(spec, r)
            assert k.shape == (2 * kernel_half_size(r) + 1,) * 2
            assert k.sum() == pytest.approx(1.0, abs=1e-6)
            assert np.all(k >= 0)
            areas.append(1.0 / k.max())  # effective support in px
        assert areas == sorted(areas)


def test_disk_area_is_pi_r_squared():
    k = make_kernel(ApertureSpec(), 10.0)
    assert 1.0 / k.max() == pytest.approx(math.pi * 100, rel=0.02)


def test_polygon_has_a_vertex_up_and_flat_bottom():
    k = make_kernel(ApertureSpec("polygon", blades=5), 10.0)
    h = k.shape[0] // 2
    col = k[:, h]
    top = np.nonzero(col > 0.5 * col.max())[0].min()
    bottom = np.nonzero(col > 0.5 * col.max())[0].max()
    # pentagon: vertex reaches r above centre, flat side only r*cos(36deg) below
    assert h - top == pytest.approx(10, abs=1)
    assert bottom - h == pytest.approx(10 * math.cos(math.pi / 5), abs=1)


def test_anamorphic_is_squeeze_times_taller_than_wide():
    k = make_kernel(ApertureSpec("anamorphic", squeeze=2.0), 12.0)
    rows = np.nonzero(k.sum(axis=1) > 0)[0]
    cols = np.nonzero(k.sum(axis=0) > 0)[0]
    assert (rows.max() - rows.min()) / (cols.max() - cols.min()) == pytest.approx(2.0, rel=0.1)


def _extent(k):
    rows = np.nonzero(k.sum(axis=1) > 1e-6)[0]
    cols = np.nonzero(k.sum(axis=0) > 1e-6)[0]
    return rows.max() - rows.min() + 1, cols.max() - cols.min() + 1


def test_cat_eye_bokeh_is_elongated_along_the_tangent_and_centred():
    spec = ApertureSpec(cat_eye=0.7)
    centre = make_kernel(spec, 10.0, (0.0, 0.0))
    assert np.array_equal(centre, make_kernel(ApertureSpec(), 10.0))  # no vignetting at the centre
    right = make_kernel(spec, 10.0, (0.7, 0.0))
    top = make_kernel(spec, 10.0, (0.0, 0.7))
    h, w = _extent(right)
    assert h > 1.5 * w  # at the right edge: a vertical cat's eye
    h, w = _extent(top)
    assert w > 1.5 * h  # at the top: a horizontal one
    yy, xx = np.mgrid[:right.shape[0], :right.shape[1]] - right.shape[0] // 2
    assert abs((right * xx).sum()) < 0.05 and abs((right * yy).sum()) < 0.05  # centred on the point
    with pytest.raises(InputError, match="cat's-eye"):
        ApertureSpec(cat_eye=1.5)


def test_image_kernel_keeps_the_picture(tmp_path):
    import cv2

    img = np.zeros((40, 40), np.uint8)
    cv2.fillPoly(img, [np.array([[20, 2], [38, 38], [2, 38]])], 255)  # triangle, apex up
    path = tmp_path / "tri.png"
    cv2.imwrite(str(path), img)
    spec = ApertureSpec("image", kernel_image=load_kernel_image(path))
    k = make_kernel(spec, 8.0)
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    h = k.shape[0] // 2
    assert k[h - 6:h - 3].sum() < k[h + 3:h + 6].sum()  # wide bottom, narrow top


@pytest.mark.parametrize("kwargs,match", [
    pytest.param(dict(shape="star"), "unknown aperture shape", id="bad-shape"),
    pytest.param(dict(shape="polygon", blades=2), "blades", id="two-blades"),
    pytest.param(dict(shape="anamorphic", squeeze=0.0), "squeeze", id="zero-squeeze"),
    pytest.param(dict(shape="image", kernel_image=np.zeros((5, 5))), "empty", id="black-kernel"),
    pytest.param(dict(shape="image", kernel_image=np.zeros((0, 0))), "non-empty", id="empty-kernel"),
])
def test_bad_aperture_specs(kwargs, match):
    with pytest.raises(InputError, match=match):
        ApertureSpec(**kwargs)


def test_kernel_image_errors_name_the_file(tmp_path):
    with pytest.raises(InputError, match="nope.png"):
        load_kernel_image(tmp_path / "nope.png")
    black = tmp_path / "black.png"
    import cv2

    cv2.imwrite(str(black), np.zeros((8, 8), np.uint8))
    with pytest.raises(InputError, match="black.png"):
        load_kernel_image(black)
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image")
    with pytest.raises(InputError, match="junk.png"):
        load_kernel_image(junk)


def test_fill_keeps_a_constant_and_prefers_the_background():
    """The fill (model step 5) of a constant colour is that colour, whatever the weights and
    depths; a poorly covered pixel takes the colour of what lies behind it, not of itself nor of
    a nearer occluder, and surfaces within FILL_DEPTH_TOLERANCE steps count as one background."""
    rng = np.random.default_rng(0)
    w = rng.random((21, 30)) ** 2
    z = rng.uniform(-8, 8, (21, 30))
    const = np.broadcast_to(np.array([0.2, 1.5, 40.0]), (21, 30, 3))
    assert np.allclose(push_pull_fill(const, w, z), const, rtol=1e-12)

    colour = np.zeros((16, 16, 3))
    colour[:, :8] = 1.0  # left half bright, right half dark
    weight = np.ones((16, 16))
    weight[6:10, 6:10] = 0.05  # a poorly covered hole across the edge
    far = np.where(np.arange(16) < 8, FILL_DEPTH_TOLERANCE + 2.0, 0.0)[None, :].repeat(16, 0)  # 2 steps beyond it
    near = np.where(np.arange(16) < 8, 0.5, 0.0)[None, :].repeat(16, 0)  # within the tolerance
    dark_side = np.s_[6:10, 8:10, 0]
    assert push_pull_fill(colour, weight, far)[dark_side].mean() > push_pull_fill(colour, weight, near)[dark_side].mean() + 0.2
    hole = np.ones((16, 16, 3))
    hole[6:10, 6:10] = 80.0  # the hole pixel's own (occluder) colour is not used
    weight_hole = np.ones((16, 16))
    weight_hole[6:10, 6:10] = 0.1
    depth_hole = np.zeros((16, 16))
    depth_hole[6:10, 6:10] = -3.0
    assert push_pull_fill(hole, weight_hole, depth_hole)[6:10, 6:10].max() < 1.5


def test_depth_factor():
    assert float(depth_factor(np.float64(0.0))) == 1.0
    assert float(depth_factor(np.float64(-FILL_DEPTH_TOLERANCE))) == 1.0
    assert float(depth_factor(np.float64(-FILL_DEPTH_TOLERANCE - 1.0))) == pytest.approx(math.exp(-FILL_DEPTH_SHARPNESS))
    assert float(depth_factor(np.float64(-1e6))) == pytest.approx(math.exp(EXP_FLOOR))
