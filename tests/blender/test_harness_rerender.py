"""Re-render a generated frame with our FastRenderer from the ground-truth disparity and HDR at
the frame's recorded (focus disparity, aperture scale), and compare with Cycles' own depth of
field: the ground-truth passes and lens records must agree with our model where the model is
exact, and HDR must beat the clipped 8-bit input."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from rvr_addon.color import linear_to_srgb, srgb_to_linear  # noqa: E402
from rvr_addon.io.exr import read_exr  # noqa: E402
from rvr_addon.render.fast import FastRenderer  # noqa: E402
from sintel_eval.dataset import GenerateConfig, generate  # noqa: E402

W, H = 128, 72


def _psnr_srgb(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    e = (linear_to_srgb(a).astype(np.float64) - linear_to_srgb(b)) ** 2
    return float(10.0 * np.log10(1.0 / (e[mask] if mask is not None else e).mean()))


def test_fast_renderer_from_ground_truth_matches_cycles_dof(tmp_path):
    """Frame 1 of an "enter" clip, constant track (f/1, focus on the main subject).

    Thresholds, from the measured 25.6 / 20.7 / 40.0 dB (the render is seeded, so the numbers
    are reproducible to ~0.1 dB; 24.5 / 20.8 / 40.0 before the delayed-occlusion compositing
    and the coverage fill of model.py steps 4-5):
    - whole frame >= 22 dB (sRGB). The single-layer model cannot match Cycles where the lens
      sees around a blurred foreground (the plant at 1.5 m is see-through in Cycles, opaque
      in ours; the background hidden behind it is only estimated) and at silhouettes.
    - interior >= 33 dB: where the depth is smooth within the blur footprint and no highlight
      is near, the model is exact, so what is left is Cycles' Monte-Carlo noise (32 samples +
      OpenImageDenoise measured ~35-40 dB against 1024 samples) -- a wrong lens record (focus,
      aperture scale, radius vs diameter, image distance) costs 5-15 dB here.
    - HDR radiance beats the clipped 8-bit input by >= 2 dB: the emitters' bokeh balls need
      their radiance (x20-150) to have the energy Cycles gives them.
    """
    cfg = GenerateConfig(seed=11, frames=1, width=W, height=H, script="enter", samples=16, dof_samples=32,
                         train_every=0)
    out = generate(tmp_path / "clip", cfg, progress=False).out
    name = "frame_00001"
    radiance = np.dstack([read_exr(out / "gt" / "hdr" / f"{name}.exr")[c] for c in "RGB"])
    disparity = read_exr(out / "gt" / "disparity" / f"{name}.exr")["D"]
    png = cv2.imread(str(out / "input" / f"{name}.png"), cv2.IMREAD_COLOR)[..., ::-1]
    rec = json.loads((out / "dof" / "constant" / f"{name}.json").read_text())
    cycles = np.dstack([read_exr(out / "dof" / "constant" / f"{name}.exr")[c] for c in "RGB"])
    f, a = rec["focus_disparity"], rec["aperture_scale"]
    renderer = FastRenderer()
    ours_hdr = renderer.render_linear(radiance, disparity, f, a)
    ours_sdr = renderer.render_linear(srgb_to_linear(png.astype(np.float32) / 255.0), disparity, f, a)

    radius = a * np.abs(disparity - f)
    size = 2 * int(np.ceil(radius.max())) + 3
    kernel = np.ones((size, size), np.uint8)
    smooth = (cv2.dilate(disparity, kernel) - cv2.erode(disparity, kernel)) < 0.25
    no_highlight = cv2.dilate(radiance.max(axis=2), kernel) < 1.0
    interior = smooth & no_highlight
    assert interior.mean() > 0.2

    psnr_hdr, psnr_sdr = _psnr_srgb(ours_hdr, cycles), _psnr_srgb(ours_sdr, cycles)
    psnr_interior = _psnr_srgb(ours_hdr, cycles, interior)
    print(f"PSNR sRGB vs Cycles DOF: HDR {psnr_hdr:.2f} dB, 8-bit {psnr_sdr:.2f} dB, interior {psnr_interior:.2f} dB")
    assert psnr_hdr >= 22.0
    assert psnr_interior >= 33.0
    assert psnr_hdr >= psnr_sdr + 2.0
    # The wrong conventions are clearly worse on the interior: diameter (2a) and no blur.
    assert _psnr_srgb(renderer.render_linear(radiance, disparity, f, 2 * a), cycles, interior) < psnr_interior - 5
    assert _psnr_srgb(radiance, cycles, interior) < psnr_interior - 5
