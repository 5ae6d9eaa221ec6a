"""The temporal filter (paper 4.2): the weighting math, flow helpers, and the streaming filter
on synthetic clips with known motion (rvr_addon/temporal/simulate.py; estimates SIMULATED).

Stated figures (checked below): on a 192x108 clip with per-frame simulated estimate errors,
the disparity RMSE after the filter is at most 1 / 1.6 of the per-frame one (causal) and
1 / 1.7 (centred); an injected outlier blob keeps under a fifth of the error a plain
average leaves; pixels disoccluded behind a passing object keep their own disparity (99th
percentile error < 0.15 px, none above 15% of the 3.6 px jump; with the occlusion checks
disabled some take on more than half the jump).
"""
from __future__ import annotations

import itertools
import logging

import numpy as np
import pytest

from rvr_addon.errors import InputError
from rvr_addon.temporal import flow as fl
from rvr_addon.temporal.filter import (
    TemporalFilter, TemporalSettings, _batcher_pairs, median_distance, outlier_weights, stabilize_stream,
)
from rvr_addon.temporal.simulate import EstimateErrors, simulate_estimates, synthetic_clip

NO_OCCLUSION_CHECKS = dict(delta_px=1e3, photometric_tol=10.0, pixel_tol=10.0, cut_fraction=1.0)


def run(frames, estimates, **kw):
    return list(stabilize_stream(frames, estimates, TemporalSettings(**kw)))


def texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    import cv2

    small = rng.random((h // 4 + 2, w // 4 + 2, 3)).astype(np.float32)
    return (cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 1) * 255).astype(np.uint8)


# ----------------------------------------------------------------------------------------- math


@pytest.mark.parametrize("n", range(1, 10))
def test_batcher_network_sorts_every_0_1_input(n):
    for bits in itertools.product((0, 1), repeat=n):
        v = list(bits)
        for i, j in _batcher_pairs(n):
            assert i < j
            v[i], v[j] = min(v[i], v[j]), max(v[i], v[j])
        assert v == sorted(bits)


@pytest.mark.parametrize("n", range(1, 9))
def test_median_distance_matches_brute_force(n):
    rng = np.random.default_rng(n)
    v = rng.normal(size=(n, 9, 11)).astype(np.float32)
    v[:, :3] = np.round(v[:, :3])  # ties
    brute = np.sort(np.abs(v[:, None] - v[None, :]), axis=1)[:, n // 2]
    np.testing.assert_allclose(median_distance(v), brute, atol=1e-6)


def test_outlier_weights_hand_computed():
    # 4 samples at one pixel: three agree at 0, one at 10; the median (3rd smallest of 4) distance
    # is 0 for the three and 10 for the outlier: weights 1, 1, 1, exp(-10 / 5)
    v = np.array([0.0, 0.0, 0.0, 10.0], np.float32).reshape(4, 1, 1)
    w = outlier_weights(v, np.ones_like(v, bool), scale=5.0)
    np.testing.assert_allclose(w.ravel(), [1, 1, 1, np.exp(-2.0)], rtol=1e-6)
    # the current frame (index 0) disagrees with two visible neighbours; two occluded samples are
    # replaced by the current value, so they vote with it instead of against it
    v = np.array([4.0, 0.0, 0.0, 99.0, 99.0], np.float32).reshape(5, 1, 1)
    valid = np.array([True, True, True, False, False]).reshape(5, 1, 1)
    w = outlier_weights(v, valid, scale=1.0).ravel()
    np.testing.assert_allclose(w[0], 1.0)  # distances 0,0,0,4,4 -> median 0
    np.testing.assert_allclose(w[1], np.exp(-4.0), rtol=1e-6)  # distances 4,0,0,4,4 -> median 4


def test_flow_helpers_on_constant_translations():
    f_ab = np.zeros((20, 30, 2), np.float32)
    f_ab[..., 0], f_ab[..., 1] = 2.0, 1.0
    f_bc = np.zeros_like(f_ab)
    f_bc[..., 0] = -0.5
    np.testing.assert_allclose(fl.concat(f_ab, f_bc)[5:15, 5:25], np.broadcast_to([1.5, 1.0], (10, 20, 2)))
    np.testing.assert_allclose(fl.fb_error(f_ab, -f_ab)[:15, :25], 0.0, atol=1e-6)
    np.testing.assert_allclose(fl.fb_error(f_ab, np.zeros_like(f_ab)), np.sqrt(5.0), rtol=1e-6)
    ins = fl.inside(f_ab)
    assert ins[:18, :27].all() and not ins[:, 28:].any() and not ins[19:].any()
    up = fl.upsample_flow(f_ab, (60, 40))
    assert up.shape == (40, 60, 2)
    np.testing.assert_allclose(up[..., 0], 4.0)
    np.testing.assert_allclose(up[..., 1], 2.0)
    assert fl.flow_size(1920, 1080, 480) == (480, 270) and fl.flow_size(8, 6, 480) == (16, 12)


def test_dis_recovers_a_known_shift():
    img = texture(90, 160, seed=1)
    shifted = np.roll(img, 3, axis=1)  # content moves right by 3 px: flow a->b = +3
    a, b = fl.to_flow_gray(img, (160, 90)), fl.to_flow_gray(shifted, (160, 90))
    f = fl.DISFlow("medium")(a, b)
    assert np.median(f[10:-10, 10:-10, 0]) == pytest.approx(3.0, abs=0.2)
    assert np.median(np.abs(f[10:-10, 10:-10, 1])) < 0.2
    ok = fl.consistent(f, fl.DISFlow("medium")(b, a), 1.0)
    assert ok[10:-10, 10:-10].mean() > 0.9


# ----------------------------------------------------------------------------------------- the filter


@pytest.fixture(scope="module")
def noisy_clip():
    clip = list(synthetic_clip(192, 108, 20, seed=0))
    ests = [simulate_estimates(f.disparity, f.exponent, f.index, seed=10) for f in clip]
    return clip, ests


@pytest.mark.parametrize("window, factor", [("causal", 1.6), ("centred", 1.7)])
def test_filter_reduces_simulated_per_frame_error(noisy_clip, window, factor):
    clip, ests = noisy_clip
    outs = run((f.image for f in clip), iter(ests), window=window)
    assert [o[0] for o in outs] == list(range(len(clip)))
    steady = slice(6, None) if window == "causal" else slice(3, -3)

    def rmse(pairs):
        return float(np.sqrt(np.mean([np.mean((d - f.disparity) ** 2) for f, d in pairs])))

    raw = rmse([(f, d) for f, (d, _) in list(zip(clip, ests))[steady]])
    filtered = rmse([(f, o[1]) for f, o in list(zip(clip, outs))[steady]])
    assert raw / filtered >= factor, (raw, filtered)
    hl_raw = np.mean([np.abs(e - f.exponent)[f.exponent.max(2) > 0].mean() for f, (_, e) in zip(clip, ests)])
    hl_out = np.mean([np.abs(o[2] - f.exponent)[f.exponent.max(2) > 0].mean() for f, o in zip(clip, outs)])
    assert hl_out < hl_raw  # E is not made worse on the highlights
    for _, d, e, c in outs:
        assert d.dtype == e.dtype == c.dtype == np.float32 and np.isfinite(d).all() and (e >= 0).all()
        assert 0.0 <= c.min() and c.max() <= 1.0


def test_outlier_blob_is_rejected_not_averaged():
    """Static scene, exact estimates except one frame with a +12 px blob: the median weight
    removes it; a near-plain average (huge outlier scale) leaves about 12/7 px."""
    h, w = 72, 128
    img = texture(h, w, seed=3)
    d_gt = np.linspace(1.0, 3.0, w, dtype=np.float32)[None].repeat(h, 0)
    e = np.zeros((h, w, 3), np.float32)
    ys, xs = np.mgrid[0:h, 0:w]
    blob = (xs - 60) ** 2 + (ys - 36) ** 2 <= 64
    ests = [(d_gt + np.float32(12.0) * blob if i == 6 else d_gt, e) for i in range(8)]
    robust = run([img] * 8, ests, window="causal")[6][1]  # frame 6 and the 6 before it: 7 frames
    plain = run([img] * 8, ests, window="causal", outlier_scale_d=1e3)[6][1]
    err_robust = np.abs(robust - d_gt)[blob].mean()
    err_plain = np.abs(plain - d_gt)[blob].mean()
    assert err_plain == pytest.approx(12.0 / 7.0, rel=0.1)
    assert err_robust < err_plain / 5


@pytest.mark.parametrize("window", ["causal", "centred"])
def test_disoccluded_pixels_do_not_inherit_the_occluders_disparity(window):
    clip = list(synthetic_clip(256, 144, 16, seed=4))
    exact = [(f.disparity, f.exponent) for f in clip]
    gap = float(np.median(clip[10].disparity[~clip[10].occluder]) - clip[10].disparity[clip[10].occluder].mean())
    assert gap > 2.5  # the disk is well in front of the background

    def disoccluded_errors(outs):
        errs = []
        for t in range(7, 16):
            covered = np.zeros_like(clip[t].occluder)
            for j in range(t - 6, min(t + 4, 16)):
                covered |= clip[j].occluder
            mask = covered & ~clip[t].occluder  # background the disk covered in the window, visible now
            errs.append(np.abs(outs[t][1] - clip[t].disparity)[mask])
        return np.concatenate(errs)

    ours = disoccluded_errors(run((f.image for f in clip), iter(exact), window=window))
    unchecked = disoccluded_errors(run((f.image for f in clip), iter(exact), window=window, **NO_OCCLUSION_CHECKS))
    assert np.percentile(ours, 99) < 0.15 and ours.max() < 0.15 * gap
    assert unchecked.max() > 0.5 * gap  # without the checks the disk's disparity leaks in


def test_scene_cut_restarts_the_window(caplog):
    clip = list(synthetic_clip(128, 72, 12, seed=5, cut_at=6))
    exact = [(f.disparity, f.exponent) for f in clip]
    filt = TemporalFilter(TemporalSettings(window="causal"))  # the first frame after the cut has no past
    outs = []
    with caplog.at_level(logging.INFO, logger="rvr_addon.temporal.filter"):
        for f, (d, e) in zip(clip, exact):
            outs += filt.push(f.index, f.image, d, e)
        outs += filt.finish()
    assert filt.cuts == [6]
    assert "scene cut between frames 5 and 6" in caplog.text
    # the first frame after the cut uses itself only: exact, confidence 1 / (M + 1)
    np.testing.assert_array_equal(outs[6][1], clip[6].disparity)
    np.testing.assert_allclose(outs[6][3], 1 / 7)
    # frames after the cut never see the other scene
    for t in (7, 8):
        assert np.abs(outs[t][1] - clip[t].disparity).mean() < 0.05


def test_no_false_cut_on_a_continuous_clip(noisy_clip):
    clip, ests = noisy_clip
    filt = TemporalFilter(TemporalSettings())
    for f, (d, e) in list(zip(clip, ests))[:10]:
        filt.push(f.index, f.image, d, e)
    assert filt.cuts == []


def test_size_change_restarts_the_window_and_says_so(caplog):
    small = list(synthetic_clip(96, 54, 4, seed=6))
    large = list(synthetic_clip(128, 72, 4, seed=6))
    frames = [f.image for f in small] + [f.image for f in large]
    ests = [(f.disparity, f.exponent) for f in small + large]
    with caplog.at_level(logging.WARNING, logger="rvr_addon.temporal.filter"):
        outs = run(frames, ests)
    assert [o[0] for o in outs] == list(range(8))
    assert [o[1].shape for o in outs] == [(54, 96)] * 4 + [(72, 128)] * 4
    assert "frame 4 is 128x72" in caplog.text and "restarting the temporal window" in caplog.text


@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("window", ["causal", "centred"])
def test_one_and_two_frame_clips(n, window):
    clip = list(synthetic_clip(64, 36, n, seed=7))
    ests = [simulate_estimates(f.disparity, f.exponent, f.index) for f in clip]
    outs = run((f.image for f in clip), iter(ests), window=window)
    assert [o[0] for o in outs] == list(range(n))
    if n == 1:
        np.testing.assert_array_equal(outs[0][1], ests[0][0])
        np.testing.assert_array_equal(outs[0][2], ests[0][1])
    for _, d, e, c in outs:
        assert d.shape == (36, 64) and e.shape == (36, 64, 3) and np.isfinite(d).all()


def test_stream_equals_the_push_api_and_centred_lags_by_f():
    clip = list(synthetic_clip(96, 54, 9, seed=8))
    ests = [simulate_estimates(f.disparity, f.exponent, f.index, errors=EstimateErrors(blobs=0)) for f in clip]
    streamed = run((f.image for f in clip), iter(ests), window="centred")
    filt = TemporalFilter(TemporalSettings(window="centred"))
    pushed, lag = [], []
    for f, (d, e) in zip(clip, ests):
        got = filt.push(f.index, f.image, d, e)
        lag += [f.index - o[0] for o in got]
        pushed += got
    pushed += filt.finish()
    assert set(lag) == {3} and len(filt.buffer) == 0
    for a, b in zip(streamed, pushed):
        assert a[0] == b[0]
        np.testing.assert_array_equal(a[1], b[1])


def test_index_gap_restarts_and_bad_input_is_named(caplog):
    clip = list(synthetic_clip(64, 36, 3, seed=9))
    filt = TemporalFilter()
    filt.push(0, clip[0].image, clip[0].disparity, clip[0].exponent)
    with caplog.at_level(logging.WARNING, logger="rvr_addon.temporal.filter"):
        filt.push(5, clip[1].image, clip[1].disparity, clip[1].exponent)
    assert "jumps from 0 to 5" in caplog.text and filt.cuts == [5]
    with pytest.raises(InputError, match="estimates ended after 2"):
        run((f.image for f in clip), iter([(f.disparity, f.exponent) for f in clip[:2]]))
    with pytest.raises(InputError, match="same size"):
        filt.push(6, clip[2].image, clip[2].disparity, clip[2].exponent[:10])
    with pytest.raises(InputError, match="window 'both'"):
        TemporalSettings(window="both")
    with pytest.raises(InputError, match="M=0"):
        TemporalSettings(m=0)
