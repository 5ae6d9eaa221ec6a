"""The procedural Cycles demo scene: files, colour encoding, HDR highlights and exact disparity."""
from __future__ import annotations

import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import cv2  # noqa: E402
import OpenEXR  # noqa: E402

from rvr_addon.color import linear_to_srgb  # noqa: E402

W, H, N = 64, 36, 2


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from sintel_eval.demo_scene import render_demo_scene

    out = render_demo_scene(tmp_path_factory.mktemp("demo"), frames=N, size=(W, H), samples=4, seed=3,
                            progress=False)
    return out, json.loads((out / "meta.json").read_text())


def _exr_rgb(path) -> dict:
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {name: ch.pixels for name, ch in f.channels().items()}


def _png_rgb(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return img[..., ::-1]


def _wall_depth(meta, frame: int) -> float:
    return meta["wall_plane_y_m"] - meta["camera_positions_m"][frame - 1][1]


def _depth_from_disparity(d: np.ndarray, cam: dict) -> np.ndarray:
    return 1.0 / (1.0 / cam["s_ref_m"] - d.astype(np.float64) / cam["K_px"])


def test_files_shapes_and_meta(demo):
    out, meta = demo
    assert (meta["frames"], meta["width"], meta["height"], meta["fps"], meta["seed"]) == (N, W, H, 24, 3)
    assert meta["disparity_units"] == "px blur radius at aperture 1, native width"
    for frame in range(1, N + 1):
        png = _png_rgb(out / "frames" / f"frame_{frame:05d}.png")
        assert png.shape == (H, W, 3) and png.dtype == np.uint8
        chans = _exr_rgb(out / "hdr" / f"frame_{frame:05d}.exr")
        assert sorted(chans) == ["B", "G", "R"]
        for c in chans.values():
            assert c.shape == (H, W) and c.dtype == np.float32 and np.isfinite(c).all()
        disp = np.load(out / "disparity" / f"frame_{frame:05d}.npy")
        assert disp.shape == (H, W) and disp.dtype == np.float32 and np.isfinite(disp).all()
    assert not (out / "frames" / f"frame_{N + 1:05d}.png").exists()
    assert not list(out.glob("*.exr")) and not list(out.rglob(".*")), "temporary files left behind"

    # K is the exact thin-lens constant of the recorded camera (mm -> px, divided by 1000 for metres).
    cam = meta["camera"]
    f, n, sw, s_ref = cam["focal_mm"], cam["f_number"], cam["sensor_width_mm"], cam["s_ref_m"] * 1000.0
    k = (f / n / 2.0) * (f * s_ref / (s_ref - f)) * (W / sw) / 1000.0
    assert cam["K_px"] == pytest.approx(k, rel=1e-12)
    # Cinematic background blur at aperture scale 1: 6-10% of the frame width.
    assert 0.06 <= meta["background_disparity"] / W <= 0.10


def test_png_is_srgb_of_clipped_radiance(demo):
    out, _ = demo
    for frame in range(1, N + 1):
        chans = _exr_rgb(out / "hdr" / f"frame_{frame:05d}.exr")
        linear = np.dstack([chans[c] for c in "RGB"])
        expected = np.round(linear_to_srgb(linear) * 255.0)
        png = _png_rgb(out / "frames" / f"frame_{frame:05d}.png").astype(np.float64)
        diff = np.abs(png - expected)
        assert diff.mean() <= 1.0, diff.mean()
        assert diff.max() <= 2.0, diff.max()
        assert 40 < png.mean() < 200  # well exposed, neither dark nor washed out


def test_hdr_keeps_emitters_far_above_one(demo):
    out, meta = demo
    cam = meta["camera"]
    assert 20.0 <= meta["emitter_radiance_max"] <= 200.0
    for frame in range(1, N + 1):
        chans = _exr_rgb(out / "hdr" / f"frame_{frame:05d}.exr")
        peak = np.max(np.dstack([chans[c] for c in "RGB"]), axis=2)
        cx, cy, cz = meta["camera_positions_m"][frame - 1]
        seen = 0
        for e in meta["emitters"]:
            x, y, z = e["position_m"]
            col = W / 2 + cam["f_px"] * (x - cx) / (y - cy)
            row = H / 2 - cam["f_px"] * (z - cz) / (y - cy)
            if not (0 <= col < W and 0 <= row < H):
                continue
            c, r = int(col), int(row)
            window = peak[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
            # Emitters are placed where nothing hides them from the camera; even sub-pixel at this
            # size they lift their pixel far above display white.
            assert window.max() > 1.0, (e, window.max())
            seen += 1
        assert seen >= len(meta["emitters"]) // 2
        assert 10.0 < peak.max() <= meta["emitter_radiance_max"] * (1 + 1e-6)
        # Elsewhere the scene is display-referred (a diffuse set under modest lights).
        assert np.median(peak) < 1.0


def test_disparity_is_exact_on_the_fronto_parallel_wall(demo):
    """D = K (1/S_ref - 1/S) with S the *planar* depth.

    The wall is the plane y = wall_plane_y_m and the camera looks along +y without rotation, so its
    planar depth is wall_y - camera_y on every pixel, including the top corners where a radial
    distance would be larger by sqrt(1 + tan^2) = 2.1% (0.4 m) with this lens. Tolerance: D is
    stored in float32 (ulp ~5e-7 px at ~4 px) from a float32 Z (ulp ~2e-6 m at 20 m); both map
    to well under 1e-3 m in depth and 1e-4 px in disparity, so 1e-3 m / 1e-4 px bound only the
    numerical noise while any radial/planar, unit or sign slip is larger by orders of magnitude.
    """
    out, meta = demo
    cam = meta["camera"]
    for frame in range(1, N + 1):
        disp = np.load(out / "disparity" / f"frame_{frame:05d}.npy")
        depth = _depth_from_disparity(disp, cam)
        s_wall = _wall_depth(meta, frame)
        d_wall = cam["K_px"] * (1.0 / cam["s_ref_m"] - 1.0 / s_wall)
        # Above the horizon only the wall lies beyond 0.96 of its distance (lights stop at 18.5 m).
        wall = depth > 0.96 * s_wall
        wall[H // 2:] = False
        assert wall.mean() > 0.15 * 0.5
        assert wall[0, 0] and wall[0, W - 1], "the top corners should see the wall"
        assert np.abs(depth[wall] - s_wall).max() < 1e-3
        assert np.abs(disp[wall] - d_wall).max() < 1e-4
        # Nothing sees the empty world: every depth is finite and no farther than the wall.
        assert depth.max() < s_wall + 1e-3
    assert meta["background_disparity"] == pytest.approx(
        cam["K_px"] * (1.0 / cam["s_ref_m"] - 1.0 / _wall_depth(meta, 1)), rel=1e-12)


def test_sign_convention_subject_near_zero_background_positive(demo):
    out, meta = demo
    cam = meta["camera"]
    disp = np.load(out / "disparity" / "frame_00001.npy")
    x, y, z = meta["subject_point_m"]
    cx, cy, cz = meta["camera_positions_m"][0]
    col = int(W / 2 + cam["f_px"] * (x - cx) / (y - cy))
    row = int(H / 2 - cam["f_px"] * (z - cz) / (y - cy))
    d_wall = meta["background_disparity"]
    # The subject's eye plane is the focus reference: |D| there is a few hundredths of a pixel
    # (the curved face within one pixel), versus ~4 px for the wall at this width.
    assert abs(disp[row, col]) < 0.02 * d_wall
    assert abs(meta["subject_disparity"]) < 0.02 * d_wall
    assert d_wall > 0.05 * W
    assert meta["background_disparity_measured"] == pytest.approx(d_wall, abs=1e-4)
    # Everything in the scene lies at or behind the subject, so D >= ~0 and grows with depth.
    assert disp.min() > -0.02 * d_wall
    assert disp.max() <= d_wall + 1e-4


def test_cli_rejects_a_bad_size(capsys):
    from sintel_eval.__main__ import main

    with pytest.raises(SystemExit) as exc:
        main(["demo", "-o", "unused", "--size", "wide"])
    assert exc.value.code == 2
    assert "WxH" in capsys.readouterr().err
