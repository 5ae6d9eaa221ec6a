"""The parallax cue's photometric check (rvr_addon/depth/sweep.py): a plane sweep on synthetic
views of textured planes with exact geometry, and the confidence it takes away."""
from __future__ import annotations

import numpy as np
import pytest

from rvr_addon.depth.sweep import CHECK_PENALTY, checked_confidence, plane_sweep
from tests.engine.test_depth_parallax import H, W, default_K, render


def _views(steps=(-0.08, 0.08)):
    """The reference view at the origin and views moved sideways by ``steps`` (m): their gray
    frames, (R, T) with x_view = R x_ref + T (m), and the reference's depth (m)."""
    ref, z = render(np.zeros(3))
    views = []
    for s in steps:
        img, _ = render(np.array([s, 0.0, 0.0]))
        views.append((img[..., 0], np.eye(3), np.array([-s, 0.0, 0.0])))
    return ref[..., 0], views, z


def test_plane_sweep_finds_the_inverse_depth_of_textured_planes():
    ref, views, z = _views()
    K = default_K(W, H)
    q = plane_sweep(ref, views, K, q_max=0.7, planes=48)
    assert q.shape == (H, W) and q.dtype == np.float32
    inner = np.zeros((H, W), bool)
    inner[12:-12, 12:-12] = True  # the patches at the border see less
    rel = np.abs(q * z - 1.0)[inner]
    assert np.median(rel) < 0.03
    assert np.mean(rel < 0.1) > 0.85


def test_the_check_lowers_the_confidence_only_where_the_sweep_contradicts():
    ref, views, z = _views()
    K = default_K(W, H)
    q = (1.0 / z).astype(np.float32)
    wrong = np.zeros((H, W), bool)
    wrong[60:120, 200:280] = True  # the backdrop (7 m) said to be at 3.5 m
    q[wrong] = 1.0 / 3.5
    conf = np.ones((H, W), np.float32)
    out, share = checked_confidence(ref, views, K, q, conf)
    assert out.shape == conf.shape and out.dtype == np.float32
    assert np.mean(out[wrong] == np.float32(CHECK_PENALTY)) > 0.9
    right = ~wrong
    right[:16] = right[-16:] = False
    right[:, :16] = right[:, -16:] = False
    assert np.mean(out[right] == 1.0) > 0.85
    assert share is not None and 0.05 < share < 0.3


def test_the_check_keeps_what_it_cannot_judge():
    ref, views, z = _views()
    K = default_K(W, H)
    q = (1.0 / z).astype(np.float32)
    few = np.zeros((H, W), np.float32)
    few[:5, :5] = 1.0  # 25 trusted pixels: too few to check
    out, share = checked_confidence(ref, views, K, q, few)
    assert share is None and out is few
    out, share = checked_confidence(ref, [], K, q, np.ones((H, W), np.float32))
    assert share is None and np.all(out == 1.0)


def test_a_tiny_frame_is_swept_at_its_own_size():
    ref, views, z = _views()
    K = default_K(W, H)
    small = slice(0, 36), slice(0, 48)
    q = (1.0 / z[small]).astype(np.float32)
    Ks = K.copy()  # the crop keeps the focal length; the principal point moves with it
    out, share = checked_confidence(ref[small], [(g[small], R, T) for g, R, T in views], Ks, q,
                                    np.ones(q.shape, np.float32))
    assert out.shape == q.shape and share is not None


def test_plane_sweep_rejects_bad_arguments():
    ref, views, _ = _views()
    with pytest.raises(ValueError, match="no neighbouring view"):
        plane_sweep(ref, [], default_K(W, H), 0.5)
    with pytest.raises(ValueError, match="planes"):
        plane_sweep(ref, views, default_K(W, H), 0.0)
