"""The renderer on a torch device (render/device.py) against the fast CPU path, and ``--device``.

On CPU-torch (CI) the device path equals the exact fast path (no half-resolution layers) at
>= 50 dB (sRGB) with max |error| <= 5e-3 of the frame's peak radiance, and the default fast path
at >= 40 dB, on synthetic frames with occlusion edges and HDR highlights. Why not 1e-6: the two
paths round differently (float32 FFT here, OpenCV's filters there), and the model's fill (step 5)
magnifies rounding where a pixel's coverage is within ~1e-7 of 1 beside a much farther background
(its push weights are ``w * e^-2(dz-1)`` against ``1 - w``): measured on these frames, either path
is then up to 1.6e-3 of the peak from the float64 reference (54-83 dB), the other ~1e-7 (146 dB).
With a GPU, CUDA equals CPU-torch; without one those tests skip."""
from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch

from rvr_addon.color import linear_to_srgb
from rvr_addon.errors import InputError
from rvr_addon.render import DEVICES
from rvr_addon.render import device as device_mod
from rvr_addon.render.aperture import ApertureSpec
from rvr_addon.render.device import TorchRenderer, fft_size, make_renderer, resolve_device
from rvr_addon.render.fast import FastRenderer
from rvr_addon.render.model import plan_layers
from rvr_addon.render.torch_render import render_torch

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU (torch.cuda.is_available() is False)")
REL_TOL = 5e-3
"""Max |device - exact fast| over the frame's peak radiance (see the module docstring)."""
MIN_PSNR_DB = 50.0
"""Least PSNR (sRGB) of the device path against the exact fast path."""


def assert_close(got: np.ndarray, expected: np.ndarray) -> None:
    assert got.shape == expected.shape and got.dtype == np.float32
    assert np.abs(got - expected).max() <= REL_TOL * float(expected.max())
    assert psnr_srgb(got, expected) >= MIN_PSNR_DB


def occlusion_scene(h: int = 90, w: int = 120, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Textured background ramp (far), a sharp-edged near square and a mid disk, HDR lights."""
    rng = np.random.default_rng(seed)
    rad = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 1.0)
    yy, xx = np.mgrid[:h, :w]
    disp = (4.0 + 10.0 * xx / w).astype(np.float32)  # background 4..14 px behind focus
    near = (yy > h // 3) & (yy < 2 * h // 3) & (xx > w // 6) & (xx < w // 2)
    rad[near] = (0.9, 0.5, 0.1)
    disp[near] = -6.0  # in front of the focal plane: a hard occlusion edge
    mid = (yy - h // 3) ** 2 + (xx - 3 * w // 4) ** 2 < (h // 6) ** 2
    disp[mid] = 0.0  # in focus
    for fy, fx, v in [(0.09, 0.83, 300.0), (0.78, 0.75, 80.0), (0.55, 0.25, 150.0), (0.05, 0.04, 40.0)]:
        rad[int(fy * h), int(fx * w)] = v * np.array([1.0, 0.8, 0.6], np.float32)  # HDR highlights (one on the near square)
    return rad, disp


def psnr_srgb(a: np.ndarray, b: np.ndarray) -> float:
    x, y = linear_to_srgb(np.clip(a, 0, 1)), linear_to_srgb(np.clip(b, 0, 1))
    return float(10 * np.log10(1.0 / max(np.mean((x.astype(np.float64) - y) ** 2), 1e-20)))


CASES = [  # (focus, aperture): background sharp / foreground sharp / everything blurred (radii > 12)
    pytest.param(4.0, 1.0, id="focus-far"),
    pytest.param(-6.0, 1.0, id="focus-near"),
    pytest.param(0.0, 2.0, id="wide-aperture"),
]


@pytest.mark.parametrize("focus,aperture", CASES)
@pytest.mark.parametrize("naive", [False, True], ids=["occlusion", "naive"])
def test_torch_cpu_equals_the_exact_fast_path(focus, aperture, naive):
    rad, disp = occlusion_scene()
    exact = FastRenderer(half_res_radius=None, naive=naive).render_linear(rad, disp, focus, aperture)
    got = TorchRenderer(device="cpu", naive=naive).render_linear(rad, disp, focus, aperture)
    assert_close(got, exact)
    # and the default fast path (layers of radius >= 12 px at half resolution) within its 40 dB
    assert psnr_srgb(got, FastRenderer(naive=naive).render_linear(rad, disp, focus, aperture)) >= 40.0


@pytest.mark.parametrize("spec", [ApertureSpec("polygon", blades=5, rotation_deg=12.0),
                                  ApertureSpec("anamorphic", squeeze=2.0), ApertureSpec(cat_eye=0.8, zones=5)],
                         ids=["pentagon", "anamorphic", "cat-eye"])
def test_aperture_shapes_match_the_fast_path(spec):
    rad, disp = occlusion_scene(60, 80, seed=1)
    exact = FastRenderer(spec=spec, half_res_radius=None).render_linear(rad, disp, 2.0, 1.2)
    assert_close(TorchRenderer(spec=spec, device="cpu").render_linear(rad, disp, 2.0, 1.2), exact)


def test_batches_of_layers_do_not_change_the_result():
    """A batch of one layer per FFT (tiny memory budget) and all layers in one batch agree, and
    both equal the training renderer (render_torch) on the same frame."""
    rad, disp = occlusion_scene(50, 70, seed=2)
    one = TorchRenderer(device="cpu", batch_mb=1e-6).render_linear(rad, disp, 1.0, 1.5)
    all_ = TorchRenderer(device="cpu", batch_mb=1e4).render_linear(rad, disp, 1.0, 1.5)
    assert_close(one, all_)
    r, d = torch.from_numpy(rad).permute(2, 0, 1)[None], torch.from_numpy(disp)[None]
    with torch.no_grad():
        train = render_torch(r, d, 1.0, 1.5)[0].permute(1, 2, 0).numpy()
    assert_close(all_, train)


def test_a_given_plan_and_a_finer_grid_are_used():
    rad, disp = occlusion_scene(40, 60, seed=3)
    plan = plan_layers(float((disp - 1.0).min() * 1.3), float((disp - 1.0).max() * 1.3), min_layers=30)
    exact = FastRenderer(half_res_radius=None).render_linear(rad, disp, 1.0, 1.3, plan=plan)
    assert_close(TorchRenderer(device="cpu").render_linear(rad, disp, 1.0, 1.3, plan=plan), exact)
    fine = TorchRenderer(device="cpu", min_layers=30).render_linear(rad, disp, 1.0, 1.3)
    assert_close(fine, FastRenderer(half_res_radius=None, min_layers=30).render_linear(rad, disp, 1.0, 1.3))


def test_hdr_point_keeps_its_energy_and_aperture_zero_is_identity():
    rad = np.zeros((61, 61, 3), np.float32)
    rad[30, 30] = 500.0
    disp = np.full((61, 61), 10.0, np.float32)
    out = TorchRenderer(device="cpu").render_linear(rad, disp, 0.0, 1.0)
    assert out[10:51, 10:51].sum() == pytest.approx(3 * 500.0, rel=1e-4)
    assert np.array_equal(TorchRenderer(device="cpu").render_linear(rad, disp, 0.0, 0.0), rad)
    img = (np.random.default_rng(0).random((20, 30, 3)) * 255).astype(np.uint8)
    srgb = TorchRenderer(device="cpu").render_srgb(img, np.zeros((20, 30), np.float32), 0.0, 1.0)
    assert np.abs(srgb * 255 - img).max() < 0.51  # in focus: the same 8-bit picture back


def test_bad_frames_are_refused_as_by_the_fast_path():
    rad, disp = occlusion_scene(20, 30)
    with pytest.raises(InputError, match="resample the disparity"):
        TorchRenderer(device="cpu").render_linear(rad, disp[:10], 0.0, 1.0)
    disp[3, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        TorchRenderer(device="cpu").render_linear(rad, disp, 0.0, 1.0)


def test_fft_sizes_are_5_smooth_and_large_enough():
    for n in [1, 2, 7, 11, 13, 97, 1145, 1985, 2049]:
        m = fft_size(n)
        assert m >= n and m < 2 * max(n, 1)
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        assert m == 1


def test_device_choice_without_a_gpu(monkeypatch):
    monkeypatch.setattr(device_mod, "torch_cuda_available", lambda: False)
    assert resolve_device("auto") == "cpu" and resolve_device("cpu") == "cpu"
    assert isinstance(make_renderer("auto"), FastRenderer)
    with pytest.raises(InputError, match=r"--device cuda: .*use --device cpu"):
        resolve_device("cuda")
    with pytest.raises(InputError, match="use one of auto, cpu, cuda"):
        resolve_device("gpu")
    monkeypatch.setattr(device_mod, "torch_cuda_available", lambda: True)
    assert resolve_device("auto") == "cuda"
    r = make_renderer("auto", min_layers=5)
    assert isinstance(r, TorchRenderer) and r.device == "cuda" and r.min_layers == 5


def test_the_parsers_offer_the_engines_devices():
    from rvr_addon import cli

    parser = cli.build_parser()
    for command in ("render", "refocus"):
        assert parser.parse_args([command, "x", "--device", "cpu"]).device == "cpu"
        assert parser.parse_args([command, "x"]).device == "auto"
    assert DEVICES == ("auto", "cpu", "cuda")


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_rvr_render_device_cuda_without_a_gpu_says_which_flag_and_the_fix(tmp_path):
    done = subprocess.run([sys.executable, "-m", "rvr_addon", "render", str(tmp_path / "none.mp4"), "--depth",
                           str(tmp_path / "d"), "--device", "cuda", "-o", str(tmp_path / "o.mp4")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert "--device cuda" in done.stderr and "--device cpu" in done.stderr, done.stderr


@CUDA
@pytest.mark.parametrize("focus,aperture", CASES)
def test_cuda_equals_torch_cpu(focus, aperture):
    rad, disp = occlusion_scene(180, 320, seed=4)
    cpu = TorchRenderer(device="cpu").render_linear(rad, disp, focus, aperture)
    gpu = TorchRenderer(device="cuda").render_linear(rad, disp, focus, aperture)
    assert_close(gpu, cpu)
    assert psnr_srgb(gpu, FastRenderer().render_linear(rad, disp, focus, aperture)) >= 40.0


@CUDA
def test_cuda_render_job_uses_the_gpu():
    assert isinstance(make_renderer("cuda"), TorchRenderer)
    assert isinstance(make_renderer("auto"), TorchRenderer)


def test_a_thread_budget_reaches_the_cpu_renderer():
    """rvr batch passes its --task-threads to the render's blur pool (RenderSettings.threads)."""
    from rvr_addon.batch.worker import worker_task_threads

    assert make_renderer("cpu", threads=1).threads == 1
    assert make_renderer("cpu").threads == FastRenderer().threads
    assert worker_task_threads() is None  # not in a Dask worker
