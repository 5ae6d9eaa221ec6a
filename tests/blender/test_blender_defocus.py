"""Smoke test of the Blender Compositor Defocus benchmark baseline (bench/blender_defocus.py)."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bpy")

_PATH = Path(__file__).resolve().parents[2] / "bench" / "blender_defocus.py"


def _load():
    spec = importlib.util.spec_from_file_location("rvr_bench_blender_defocus", _PATH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # needed by @dataclass while the module executes
    spec.loader.exec_module(mod)
    return mod


bd = _load()

W, H = 64, 36
R = 6.0  # radius of the blurred half, px


def _inputs():
    rng = np.random.default_rng(1)
    img = rng.integers(30, 226, size=(H, W, 3), dtype=np.uint8)  # i.i.d. noise: maximal detail
    radius = np.zeros((H, W), np.float32)
    radius[:, W // 2:] = R
    return img, radius


def test_blender_defocus_sharp_and_blurred_regions():
    img, radius = _inputs()
    sec, out = bd.blender_defocus(img, radius, max_radius_px=R, repeats=1)

    assert isinstance(sec, float) and sec > 0.0
    assert out.shape == (H, W, 3) and out.dtype == np.float32
    assert np.all(np.isfinite(out))

    lin = bd._srgb_to_linear(img.astype(np.float32) / 255.0)
    # radius 0 -> Blender gathers only the pixel itself: unchanged (exact up to float/EXR round trip)
    sharp = (slice(None), slice(0, W // 2 - 1))
    assert np.abs(out[sharp] - lin[sharp]).max() < 1e-4

    # radius 6 px -> a ~113-tap disk average of i.i.d. noise: variance drops ~100x; require >= 20x
    m = int(R)
    blurred = (slice(m, H - m), slice(W // 2 + m, W - m))
    var_in = float(lin[blurred].var(axis=(0, 1)).mean())
    var_out = float(out[blurred].var(axis=(0, 1)).mean())
    assert var_out * 20.0 <= var_in, (var_in, var_out)
    # the mean colour is preserved by the (normalised) gather
    assert abs(float(out[blurred].mean()) - float(lin[blurred].mean())) < 0.05

    assert bd.LAST_RUN["size"] == (W, H) and bd.LAST_RUN["use_zbuffer"] is False


def test_zbuffer_mapping_matches_size_mode_for_constant_radius():
    img, _ = _inputs()
    radius = np.full((H, W), 2.5, np.float32)  # non-integer: away from the floor(r) support steps
    _, a = bd.blender_defocus(img, radius, max_radius_px=R, repeats=1)
    _, b = bd.blender_defocus(img, radius, max_radius_px=R, repeats=1, use_zbuffer=True)
    assert np.abs(a - b).max() < 1e-4
