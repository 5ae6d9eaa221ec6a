"""Metrics of the artifact ablations (sintel_eval/metrics.py, scoring.py, panels.py): hand-computed
values. No bpy."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sintel_eval import metrics as m
from sintel_eval.panels import comparison_image, crop_box, grid, label_panel
from sintel_eval.scoring import METRICS, RunScorer, ScoreSettings, aggregate

# ---------------------------------------------------------------------------------------------
# PSNR


def test_psnr_hand_values():
    a = np.zeros((4, 4, 3))
    assert m.psnr(a, a + 0.1) == pytest.approx(20.0)  # mse 0.01, peak 1
    assert m.psnr(a, a + 0.01) == pytest.approx(40.0)
    assert m.psnr(a, a + 0.1, peak=2.0) == pytest.approx(20.0 + 20 * math.log10(2.0))
    assert m.psnr(a, a) == m.MAX_PSNR_DB  # identical: capped, not infinite


def test_psnr_mask_and_empty_mask():
    a = np.zeros((2, 2, 3))
    b = a.copy()
    b[0, 0] = 1.0  # a single wrong pixel (error 1 in all channels)
    mask = np.zeros((2, 2), bool)
    mask[1, 1] = True
    assert m.psnr(a, b, mask=mask) == m.MAX_PSNR_DB
    mask[0, 0] = True  # 2 pixels, 6 values, 3 wrong by 1 -> mse 0.5
    assert m.psnr(a, b, mask=mask) == pytest.approx(10 * math.log10(2.0))
    assert math.isnan(m.psnr(a, b, mask=np.zeros((2, 2), bool)))


def test_psnr_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="shape"):
        m.psnr(np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="mask"):
        m.psnr(np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), mask=np.ones((3, 3), bool))


def test_display_conversions_clip_at_white():
    lin = np.array([[[-0.5, 0.0, 0.2140411], [1.0, 7.0, 300.0]]], np.float32)
    np.testing.assert_allclose(m.display_linear(lin), [[[0.0, 0.0, 0.2140411], [1.0, 1.0, 1.0]]], rtol=1e-6)
    srgb = m.display_srgb(lin)
    assert srgb[0, 0, 2] == pytest.approx(0.5, abs=1e-5)  # linear 0.214 -> sRGB 0.5
    assert srgb[0, 1].tolist() == pytest.approx([1.0, 1.0, 1.0])


def test_linear_psnr_ignores_radiance_above_white():
    gt = np.full((4, 4, 3), 50.0)  # a highlight 50x white
    ours = np.full((4, 4, 3), 2.0)  # much darker, but still white on a display
    assert m.psnr(m.display_linear(ours), m.display_linear(gt)) == m.MAX_PSNR_DB


# ---------------------------------------------------------------------------------------------
# SSIM


def _ssim_brute(a: np.ndarray, b: np.ndarray) -> float:
    """Direct SSIM of 2-D images: explicit 11x11 Gaussian window over every valid position."""
    x = np.arange(-5, 6)
    g = np.exp(-(x**2) / (2 * 1.5**2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = 0.01**2, 0.03**2
    vals = []
    for i in range(5, a.shape[0] - 5):
        for j in range(5, a.shape[1] - 5):
            pa, pb = a[i - 5:i + 6, j - 5:j + 6], b[i - 5:i + 6, j - 5:j + 6]
            ma, mb = (w * pa).sum(), (w * pb).sum()
            va, vb = (w * pa * pa).sum() - ma**2, (w * pb * pb).sum() - mb**2
            cov = (w * pa * pb).sum() - ma * mb
            vals.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma**2 + mb**2 + c1) * (va + vb + c2)))
    return float(np.mean(vals))


def test_ssim_identical_is_one():
    img = np.random.default_rng(0).random((20, 24, 3))
    assert m.ssim(img, img) == pytest.approx(1.0)


def test_ssim_constant_images_is_the_luminance_term():
    a, b = np.full((16, 16, 3), 0.2), np.full((16, 16, 3), 0.4)
    c1 = 0.01**2
    want = (2 * 0.2 * 0.4 + c1) / (0.2**2 + 0.4**2 + c1)  # variances and covariance are 0
    assert m.ssim(a, b) == pytest.approx(want, rel=1e-9)


def test_ssim_matches_a_direct_computation_per_channel():
    rng = np.random.default_rng(1)
    a = rng.random((18, 21, 3))
    b = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1)
    want = np.mean([_ssim_brute(a[..., c], b[..., c]) for c in range(3)])
    assert m.ssim(a, b) == pytest.approx(want, abs=1e-9)


def test_ssim_rejects_images_smaller_than_the_window():
    with pytest.raises(ValueError, match="11x11"):
        m.ssim(np.zeros((10, 40)), np.zeros((10, 40)))


# ---------------------------------------------------------------------------------------------
# Masks


def _step(width: int = 20, height: int = 10, left: float = 0.0, right: float = 3.0) -> np.ndarray:
    d = np.full((height, width), left, np.float32)
    d[:, width // 2:] = right
    return d


def test_edge_band_marks_both_sides_of_a_jump_and_dilates():
    d = _step()  # jump of 3 px between columns 9 and 10
    cols = np.flatnonzero(m.edge_band(d, 0).any(axis=0))
    assert cols.tolist() == [9, 10]
    band = m.edge_band(d, 2)
    assert np.flatnonzero(band.all(axis=0)).tolist() == [7, 8, 9, 10, 11, 12]
    assert not band[:, :7].any() and not band[:, 13:].any()


def test_edge_band_threshold_is_in_px_of_blur_at_the_aperture():
    d = _step()
    assert not m.edge_band(d, 3, aperture=0.25).any()  # 0.75 px jump < 1 px
    assert m.edge_band(d, 3, aperture=0.25, threshold_px=0.5).any()
    ramp = np.tile(np.arange(20, dtype=np.float32) * 0.5, (10, 1))  # smooth: 0.5 px per px
    assert not m.edge_band(ramp, 4).any()
    with pytest.raises(ValueError, match="width_px"):
        m.edge_band(d, -1)


def test_flat_regions_avoid_edges_and_steep_slopes():
    d = _step(width=30)  # jump between columns 14 and 15
    flat = m.flat_regions(d, erode_px=3)
    # central differences are 1.5 at columns 14 and 15; erosion by 3 px removes 11..18
    assert np.flatnonzero(~flat.all(axis=0)).tolist() == list(range(11, 19))
    gentle = np.tile(np.arange(30, dtype=np.float32) * 0.01, (10, 1))
    assert m.flat_regions(gentle).all()
    assert not m.flat_regions(gentle * 10).any()  # 0.1 px of blur per px is a slope


def test_defocused_mask():
    d = np.array([[0.0, 0.4, 2.0, -3.0]])
    assert m.defocused(d, 0.0, 1.0).tolist() == [[False, False, True, True]]
    assert m.defocused(d, 0.0, 2.5).tolist() == [[False, True, True, True]]


# ---------------------------------------------------------------------------------------------
# Splotchiness, flicker, bokeh recall


def test_blur_size_error_hand_values():
    err = m.blur_size_error(np.array([[2.0, -1.0, 0.5]]), np.array([[1.0, -1.0, -0.5]]), 0.0, 2.0)
    assert err.tolist() == [[2.0, 0.0, 0.0]]  # a|2| - a|1|; equal; |0.5| == |-0.5|


def test_splotchiness_zero_for_ground_truth_and_for_a_uniform_offset():
    gt = np.full((8, 8), 5.0)
    flat = np.ones((8, 8), bool)
    assert m.splotchiness(gt, gt, 0.0, 1.0, flat) == 0.0
    assert m.splotchiness(gt + 0.7, gt, 0.0, 1.0, flat) == pytest.approx(0.0)  # a focus error, not a splotch


def test_splotchiness_is_the_std_of_the_blur_error():
    gt = np.full((8, 8), 5.0)
    checker = np.indices((8, 8)).sum(axis=0) % 2 * 2.0 - 1.0  # +-1 px of disparity
    assert m.splotchiness(gt + checker, gt, 0.0, 2.0, np.ones((8, 8), bool)) == pytest.approx(2.0)
    only_plus = checker > 0
    assert m.splotchiness(gt + checker, gt, 0.0, 2.0, only_plus) == pytest.approx(0.0)
    assert math.isnan(m.splotchiness(gt, gt, 0.0, 1.0, np.zeros((8, 8), bool)))


def test_static_flicker_counts_change_where_the_input_stands_still():
    rng = np.random.default_rng(3)
    f0 = rng.integers(0, 255, (40, 60, 3)).astype(np.uint8)
    f1 = f0.copy()
    f1[10:20, 10:20] = 255 - f1[10:20, 10:20]  # a moving patch
    mask = m.static_mask(f0, f1, margin=2)
    assert not mask[8:22, 8:22].any() and mask[30:, 40:].all()  # the patch and its margin are out
    out0 = np.zeros((40, 60), np.float32)
    out1 = out0 + 0.25
    out1[10:20, 10:20] = 5.0  # change where the input moved is not flicker
    assert m.static_flicker(out0, out1, mask) == pytest.approx(0.25)
    assert math.isnan(m.static_flicker(out0, out1, np.zeros((40, 60), bool)))
    # a pan over a plain wall: the pixels look the same, but the flow says the scene moved under them
    flow = np.zeros((40, 60, 2), np.float32)
    flow[:, 30:, 0] = 3.0
    panned = m.static_mask(f0, f1, margin=2, flow=flow)
    assert panned[30:, 22:26].all() and not panned[:, 28:].any()
    with pytest.raises(ValueError, match="flow"):
        m.static_mask(f0, f1, flow=flow[:20])


def test_flicker_counts_only_change_beyond_the_ground_truth():
    gt0, gt1 = np.full((4, 4, 3), 0.2), np.full((4, 4, 3), 0.5)
    assert m.flicker(gt0 + 0.1, gt1 + 0.1, gt0, gt1) == pytest.approx(0.0)  # a static offset
    static = np.full((4, 4, 3), 0.3)
    assert m.flicker(static, static + 0.1, static, static) == pytest.approx(0.1)
    assert m.flicker(gt0, gt0, gt0, gt1) == pytest.approx(0.3)  # frozen output of a changing truth


def test_bokeh_recall_hand_values():
    gt = np.array([[[4.0, 4.0, 4.0], [0.5, 0.5, 0.5]]])
    ours = np.array([[[1.0, 1.0, 1.0], [0.5, 0.5, 0.5]]])  # clipped at white
    assert m.bokeh_recall(ours, gt) == pytest.approx(0.25)
    assert m.bokeh_recall(gt * 2, gt) == pytest.approx(1.0)  # brighter than the truth: all found
    gt2 = np.array([[[4.0, 0.0, 2.0]]])  # brightest channel decides; energy over all channels
    assert m.bokeh_recall(np.array([[[1.0, 0.0, 1.0]]]), gt2) == pytest.approx(2.0 / 6.0)
    assert math.isnan(m.bokeh_recall(ours, gt, threshold=10.0))
    assert math.isnan(m.bokeh_recall(ours, gt, mask=np.array([[False, True]])))


# ---------------------------------------------------------------------------------------------
# Streaming scorer


def _frames(n: int = 3, seed: int = 0):
    rng = np.random.default_rng(seed)
    d = _step(24, 16)
    for _ in range(n):
        gt = rng.random((16, 24, 3)).astype(np.float32)
        gt[2, 2] = 5.0  # an in-focus highlight (column 2 is at D = 0): not bokeh, not counted
        gt[3, 20] = 6.0  # a defocused highlight (D = 3)
        out = np.clip(gt + 0.05 * rng.standard_normal(gt.shape).astype(np.float32), 0, None)
        yield out, gt, d


def test_run_scorer_pools_mse_over_frames():
    frames = list(_frames())
    scorer = RunScorer(ScoreSettings(edge_band_px=1))
    for i, (out, gt, d) in enumerate(frames):
        scorer.add(i + 1, out, gt, d, d, 0.0, 1.0)
    res = scorer.result()
    assert set(METRICS) <= set(res) and res["frames"] == 3
    out_all = np.concatenate([m.display_srgb(o) for o, _, _ in frames])
    gt_all = np.concatenate([m.display_srgb(g) for _, g, _ in frames])
    assert res["psnr_srgb_db"] == pytest.approx(m.psnr(out_all, gt_all))
    band = m.edge_band(frames[0][2], 1)
    band_all = np.concatenate([band] * 3)
    assert res["edge_band_psnr_srgb_db"] == pytest.approx(m.psnr(out_all, gt_all, mask=band_all))
    assert res["ssim_srgb"] == pytest.approx(np.mean([f.ssim_srgb for f in scorer.frames]))
    assert res["splotchiness_px"] == 0.0  # rendered with the true disparity
    assert math.isnan(scorer.frames[0].flicker) and res["flicker"] == pytest.approx(
        np.mean([f.flicker for f in scorer.frames[1:]]))
    # only the defocused highlight (D = 3, focus 0) counts: found = sum min(out, gt) there
    found = sum(np.minimum(o[3, 20], g[3, 20]).sum() for o, g, _ in frames)
    assert res["bokeh_recall"] == pytest.approx(found / (3 * 18.0), rel=1e-6)
    assert res["edge_band_fraction"] == pytest.approx(band.mean())


def test_run_scorer_perfect_output():
    scorer = RunScorer()
    for out, gt, d in _frames(2):
        scorer.add(1, gt, gt, d, d, 0.0, 1.0)
    res = scorer.result()
    assert res["psnr_srgb_db"] == res["psnr_linear_db"] == res["edge_band_psnr_srgb_db"] == m.MAX_PSNR_DB
    assert res["ssim_srgb"] == pytest.approx(1.0) and res["flicker"] == 0.0 and res["bokeh_recall"] == 1.0


def test_flicker_exact_scores_against_the_exact_input_render():
    """flicker_exact compares frame-to-frame changes with the reference render's, not Cycles':
    the reference itself does not flicker against itself, an alternating offset does."""
    frames = list(_frames(4))
    steady, jumpy, without = RunScorer(), RunScorer(), RunScorer()
    for i, (out, gt, d) in enumerate(frames):
        ref = gt * 0.8  # the renderer's own picture of the exact inputs differs from Cycles'
        steady.add(i + 1, ref, gt, d, d, 0.0, 1.0, ref)
        jumpy.add(i + 1, ref + 0.02 * (i % 2), gt, d, d, 0.0, 1.0, ref)
        without.add(i + 1, ref, gt, d, d, 0.0, 1.0)
    assert steady.result()["flicker_exact"] == 0.0
    assert steady.result()["flicker"] > 0.001  # against Cycles the same output flickers
    assert jumpy.result()["flicker_exact"] > 0.005
    assert math.isnan(jumpy.frames[0].flicker_exact)
    assert math.isnan(without.result()["flicker_exact"])


def test_aggregate_skips_nan_and_sums_frames():
    got = aggregate([{"psnr_srgb_db": 30.0, "bokeh_recall": float("nan"), "frames": 4.0},
                     {"psnr_srgb_db": 40.0, "bokeh_recall": 0.5, "frames": 6.0}])
    assert got == {"psnr_srgb_db": 35.0, "bokeh_recall": 0.5, "frames": 10.0}
    assert math.isnan(aggregate([{"flicker": float("nan")}])["flicker"])


# ---------------------------------------------------------------------------------------------
# Panels


def test_crop_box_centres_on_the_mask():
    mask = np.zeros((40, 80), bool)
    mask[30:34, 70:74] = True
    y0, y1, x0, x1 = crop_box(mask, 0.25)
    assert (y1 - y0, x1 - x0) == (10, 20)
    assert y0 <= 30 and y1 >= 34 and x0 <= 70 and x1 >= 74
    assert crop_box(np.zeros((40, 80), bool), 0.25) == (15, 25, 30, 50)  # centre when empty


def test_panels_layout():
    img = np.full((36, 64, 3), 100, np.uint8)
    assert label_panel(img, "a long label that must be shrunk to fit").shape == (56, 64, 3)
    assert grid([img] * 4, 3).shape == (72, 192, 3)
    comp = comparison_image([("input", img), ("GT", img)], (0, 9, 0, 16))
    assert comp.shape == (20 + 36 + 36, 128, 3)


def _panning(n: int, shift: int = 2, seed: int = 3):
    """n frames of a smooth random texture panning right by ``shift`` px a frame (uint8 input)
    and the matching window offsets."""
    import cv2

    rng = np.random.default_rng(seed)
    wide = cv2.GaussianBlur(rng.random((48, 64 + shift * n, 3)).astype(np.float32), (0, 0), 1.5)
    wide = (wide - wide.min()) / (wide.max() - wide.min())
    for i in range(n):
        x0 = shift * (n - i)  # the scene moves right across the frame
        yield np.round(wide[:, x0:x0 + 64] * 255).astype(np.uint8), x0


def test_warped_flicker_ignores_an_error_moving_with_the_scene_and_counts_a_changing_one():
    """A steady error that pans with the scene is a large 'flicker vs exact' but ~0 warped
    flicker; the same error with an alternating offset is warped flicker too."""
    frames = list(_panning(5))
    flow, valid = m.evaluation_flow(frames[0][0], frames[1][0])
    inner = valid[8:-8, 8:-8]
    assert inner.mean() > 0.9 and np.allclose(flow[8:-8, 8:-8][inner], (-2.0, 0.0), atol=0.3)

    def error_of(img: np.ndarray) -> np.ndarray:
        return 0.1 * (img.astype(np.float32) / 255.0 - 0.5)  # a wrong blur tied to the texture

    steady, jumpy = RunScorer(), RunScorer()
    for i, (img, _) in enumerate(frames):
        ref = (img.astype(np.float32) / 255.0) ** 2.2  # linear radiance of the "exact" render
        motion = m.evaluation_flow(frames[i - 1][0], img) if i else None
        for scorer, offset in ((steady, 0.0), (jumpy, 0.02 * (i % 2))):
            out_s = np.clip(m.display_srgb(ref) + error_of(img) + offset, 0, 1)
            scorer.add(i + 1, out_s ** 2.2, ref, np.zeros(img.shape[:2]), np.zeros(img.shape[:2]), 0.0, 1.0, ref,
                       motion=motion)
    s, j = steady.result(), jumpy.result()
    assert s["flicker_exact"] > 3 * s["flicker_exact_warped"]
    assert s["flicker_exact_warped"] < 0.003 and j["flicker_exact_warped"] > 0.015
    assert math.isnan(steady.frames[0].flicker_exact_warped)
    without = RunScorer()
    without.add(1, ref, ref, np.zeros((48, 64)), np.zeros((48, 64)), 0.0, 1.0, ref)
    without.add(2, ref, ref, np.zeros((48, 64)), np.zeros((48, 64)), 0.0, 1.0, ref)
    assert math.isnan(without.result()["flicker_exact_warped"])
