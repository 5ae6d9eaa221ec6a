"""Issue 22.8: tiny frames (1x1, 1xN, Nx1, 2x2) render without crashing (a 1x1 or 4x1 frame hit
``cv2.error`` in ``matte_normaliser_cv``: OpenCV's bindings read an (n <= 4, 1) array as a scalar),
exactly as the reference renders them; and a render whose frames will be expensive (4K, large
aperture) says up front what a frame will cost and how to make it cheaper."""
from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from rvr_addon.io.video import probe_clip
from rvr_addon.pipeline import RenderJob, RenderSettings
from rvr_addon.render.cost import WARN_S_PER_FRAME, cost_warning, frame_cost_s, layer_count
from rvr_addon.render.fast import FastRenderer
from rvr_addon.render.reference import render_reference

TINY = [(1, 1), (1, 2), (1, 7), (2, 1), (3, 1), (4, 1), (5, 1), (7, 1), (2, 2), (4, 2), (3, 3)]


@pytest.mark.parametrize("aperture", [0.0, 0.5, 2.0, 5.0])
@pytest.mark.parametrize("h, w", TINY, ids=[f"{h}x{w}" for h, w in TINY])
def test_tiny_frames_render_like_the_reference(h, w, aperture):
    rng = np.random.default_rng(h * 31 + w)
    radiance = rng.random((h, w, 3)).astype(np.float32) * 4
    disparity = (rng.standard_normal((h, w)) * 3).astype(np.float32)
    out = FastRenderer().render_linear(radiance, disparity, 0.5, aperture)
    assert out.shape == (h, w, 3) and out.dtype == np.float32 and np.isfinite(out).all()
    if aperture:
        np.testing.assert_allclose(out, render_reference(radiance, disparity, 0.5, aperture), atol=1e-4)


@pytest.mark.parametrize("h, w", [(1, 1), (1, 5), (5, 1), (4, 1), (2, 2)], ids=lambda v: str(v))
def test_tiny_clips_render_to_video_and_frames(tmp_path, h, w):
    clip = tmp_path / "clip"
    clip.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(clip / f"f{i}.png"), (rng.random((h, w, 3)) * 255).astype(np.uint8))
    depth = tmp_path / "d.npy"
    np.save(depth, (rng.standard_normal((h, w)) * 3).astype(np.float32))
    job = RenderJob(RenderSettings(input=clip, depth=depth, outputs=[tmp_path / "o.mp4", tmp_path / "frames"],
                                   focus=0.0, aperture=2.0))
    job.run(progress=False)
    assert probe_clip(tmp_path / "o.mp4").frame_count == 3  # odd sizes are padded to even for H.264
    frames = sorted((tmp_path / "frames").glob("frame_*.png"))
    assert len(frames) == 3 and cv2.imread(str(frames[0])).shape[:2] == (h, w)


def test_the_cost_estimate_grows_with_pixels_and_layers():
    assert layer_count(32) == 65 and layer_count(0) == 1
    assert frame_cost_s(1920, 1080, 64) == pytest.approx(4 * frame_cost_s(960, 540, 64))
    assert frame_cost_s(640, 360, 64) > 1.9 * frame_cost_s(640, 360, 32)
    assert cost_warning(640, 360, 8, 240) is None  # a cheap render says nothing
    r = FastRenderer()
    ramp = np.tile(np.linspace(-8, 8, 320, dtype=np.float32), (180, 1))
    assert r.work_px(ramp, 0.0, 0.0) == ramp.size
    assert ramp.size < r.work_px(ramp, 0.0, 1.0) < r.work_px(ramp, 0.0, 4.0) <= ramp.size * layer_count(32)
    text = cost_warning(3840, 2160, 128, 240)  # 4K with a large aperture
    assert text is not None
    assert "3840x2160" in text and "128 px" in text and "s a frame" in text and "240 frames" in text
    assert "--scale 0.5" in text and "--aperture" in text
    assert cost_warning(3840, 2160, 128, 240, work_px=1e6) is None  # counted work overrides the worst case


def test_an_expensive_render_warns_before_the_first_frame(tmp_path, caplog, monkeypatch):
    """640x360 with busy depth and blur radii up to 300 px (601 layers) is over the limit; the
    renderer itself is stubbed: only the warning is under test."""
    w, h = 640, 360
    clip = tmp_path / "clip"
    clip.mkdir()
    for i in range(2):
        cv2.imwrite(str(clip / f"f{i}.png"), np.full((h, w, 3), 100 + i, np.uint8))
    depth = tmp_path / "d.npy"
    yy, xx = np.mgrid[0:h, 0:w]
    np.save(depth, (np.sin(xx / 7.0) * np.cos(yy / 5.0) * 150).astype(np.float32))
    job = RenderJob(RenderSettings(input=clip, depth=depth, outputs=[tmp_path / "frames"], focus=0.0, aperture=2.0))
    monkeypatch.setattr(job.renderer, "render_linear", lambda radiance, disparity, focus, aperture: radiance)
    assert frame_cost_s(w, h, 300, work_px=FastRenderer().work_px(np.load(depth), 0.0, 2.0)) > WARN_S_PER_FRAME
    with caplog.at_level(logging.WARNING, logger="rvr_addon.pipeline"):
        assert job.step()
    warned = [r.getMessage() for r in caplog.records if "s a frame" in r.getMessage()]
    assert len(warned) == 1, caplog.text
    assert "640x360" in warned[0] and "300 px" in warned[0] and "--scale 0.5" in warned[0]
    caplog.clear()
    job.cancel()
    cheap = RenderJob(RenderSettings(input=clip, depth=depth, outputs=[tmp_path / "f2"], focus=0.0, aperture=0.05))
    monkeypatch.setattr(cheap.renderer, "render_linear", lambda radiance, disparity, focus, aperture: radiance)
    with caplog.at_level(logging.WARNING, logger="rvr_addon.pipeline"):
        while cheap.step():
            pass
    assert "s a frame" not in caplog.text
