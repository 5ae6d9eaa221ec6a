"""Renderer speed and accuracy: fast path, torch path, Blender's Defocus node, reference PSNR.

    .venv/bin/python bench/render_bench.py [--quick] [--no-blender]

The scene: a real picture (a Sintel frame from ../shared/data, resized) with small HDR
highlights (radiance 40-400x the 8-bit white) in the background, over a synthetic depth
layout (receding ground, mid-ground objects, a far wall, an in-focus subject) whose blur
radius spans -8..+32 px at 1080p (scaled by width at 360p), focused on the subject, with at
least 24 layers. Also timed: the same picture with the depth the shipped network estimates for
it (``render.fast.1080p_real_depth.*``: noisy real depth activates more tiles; its
``psnr_vs_exact_db`` against the exact path on the same depth), the exact path without
half-resolution layers (``render.fast_exact.*``, and ``psnr_vs_exact_db`` of the default against it),
and the reference timing of the same run, one ``cv2.GaussianBlur`` (sigma 16) of the
RGB frame, timed alternately with the render (``reference.gauss16.<size>.s``;
``render.fast.<size>.gauss_ratio`` = fast / that; the real-depth ratio against its own alternated
blurs).
The last line of stdout is the JSON of DESIGN.md's keys.
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rvr_addon.color import linear_to_srgb, srgb_to_linear, to_float01  # noqa: E402
from rvr_addon.render.aperture import ApertureSpec  # noqa: E402
from rvr_addon.render.fast import FastRenderer  # noqa: E402
from rvr_addon.render.model import plan_for_radius_map  # noqa: E402
from rvr_addon.render.reference import render_reference  # noqa: E402

PICTURE = ROOT.parent / "shared" / "data" / "sintel_frames" / "frame_0016.png"
MIN_LAYERS = 24
MAX_RADIUS_1080P = 32.0


def bench_scene(width: int, height: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sRGB uint8 image, linear HDR radiance, disparity in px at aperture 1) for one size."""
    rng = np.random.default_rng(seed)
    if PICTURE.is_file():
        img = cv2.cvtColor(cv2.imread(str(PICTURE)), cv2.COLOR_BGR2RGB)
        img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    else:  # the data folder is missing: a textured stand-in
        img = cv2.resize((rng.random((height // 8, width // 8, 3)) * 255).astype(np.uint8), (width, height))
    yy, xx = np.mgrid[:height, :width].astype(np.float32)
    scale = width / 1920.0
    horizon = 0.45 * height
    # blur radius at 1080p: far wall 32 px, ground from 32 at the horizon to -8 at the bottom
    r = np.where(yy < horizon, 32.0, 32.0 - 40.0 * (yy - horizon) / (height - horizon))
    for cx, cy, rad, val in [(0.2, 0.5, 0.12, 14.0), (0.75, 0.55, 0.1, 8.0), (0.6, 0.4, 0.05, 22.0)]:
        r[(xx - cx * width) ** 2 + (yy - cy * height) ** 2 < (rad * width) ** 2] = val
    subject = ((xx - 0.45 * width) / (0.12 * width)) ** 2 + ((yy - 0.62 * height) / (0.35 * height)) ** 2 < 1
    r[subject] = 0.0
    disparity = (r * scale).astype(np.float32)  # focus 0, aperture 1: disparity == signed radius
    radiance = srgb_to_linear(to_float01(img))
    for _ in range(60):  # small bright lights in the background
        x, y = int(rng.integers(0, width - 2)), int(rng.integers(0, int(horizon)))
        size = max(int(round(2 * scale)), 1)
        radiance[y:y + size, x:x + size] = rng.uniform(40, 400) * np.array([1.0, 0.85, 0.6], np.float32)
    img = (linear_to_srgb(radiance) * 255 + 0.5).astype(np.uint8)
    return img, radiance.astype(np.float32), disparity


def seconds_per_frame(fn, repeats: int) -> float:
    fn()  # warm-up (kernel caches, thread pool)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def paired_seconds(fn, ref, repeats: int) -> tuple[float, float]:
    """Median seconds of ``fn`` and of the reference ``ref``, run alternately (after one warm-up
    each), so that a change of the machine's load between them moves both alike."""
    fn()
    ref()
    a, b = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        a.append(time.perf_counter() - t)
        t = time.perf_counter()
        ref()
        b.append(time.perf_counter() - t)
    return float(np.median(a)), float(np.median(b))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two images in [0, 1]."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def load_blender_defocus():
    """bench/blender_defocus.py as a module (the shared loader in sintel_eval.blender_baseline)."""
    from sintel_eval.blender_baseline import load_blender_defocus as load

    return load()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer repeats, no 1080p torch/Blender runs")
    ap.add_argument("--no-blender", action="store_true", help="skip Blender's Defocus node")
    args = ap.parse_args()
    repeats = 3 if args.quick else 7
    sizes = {"360p": (640, 360), "1080p": (1920, 1080)}
    res: dict[str, float] = {}
    scenes = {k: bench_scene(*wh) for k, wh in sizes.items()}

    # fast path first, so peak RSS is the fast path's own (torch/bpy are not imported yet)
    # the reference timing of the same run, alternated with the render: one Gaussian blur (sigma 16)
    # of the RGB frame
    for key, (img, rad, disp) in scenes.items():
        plan = plan_for_radius_map(disp, min_layers=MIN_LAYERS)
        fr = FastRenderer(min_layers=MIN_LAYERS)
        x = np.ascontiguousarray(rad, np.float32)
        res[f"render.fast.{key}.s_per_frame"], res[f"reference.gauss16.{key}.s"] = paired_seconds(
            lambda: fr.render_linear(rad, disp, 0.0, 1.0), lambda: cv2.GaussianBlur(x, (0, 0), 16), repeats)
        res[f"render.fast.{key}.gauss_ratio"] = res[f"render.fast.{key}.s_per_frame"] / res[f"reference.gauss16.{key}.s"]
        res[f"render.fast.{key}.layers"] = len(plan)
        res[f"render.fast.{key}.max_radius_px"] = float(np.abs(disp).max())
        print(f"fast {key}: {res[f'render.fast.{key}.s_per_frame']:.3f} s/frame, {len(plan)} layers", file=sys.stderr)
    res["render.fast.1080p.peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    # the exact path (no half-resolution layers) with its distance to the default
    for key, (img, rad, disp) in scenes.items():
        ex = FastRenderer(min_layers=MIN_LAYERS, half_res_radius=None)
        res[f"render.fast_exact.{key}.s_per_frame"] = seconds_per_frame(lambda: ex.render_linear(rad, disp, 0.0, 1.0),
                                                                       repeats)
        a = linear_to_srgb(np.clip(ex.render_linear(rad, disp, 0.0, 1.0), 0, 1))
        b = linear_to_srgb(np.clip(FastRenderer(min_layers=MIN_LAYERS).render_linear(rad, disp, 0.0, 1.0), 0, 1))
        res[f"render.fast.{key}.psnr_vs_exact_db"] = min(psnr(b, a), 200.0)  # 200: identical
        print(f"{key}: gauss16 {res[f'reference.gauss16.{key}.s']:.3f} s, ratio "
              f"{res[f'render.fast.{key}.gauss_ratio']:.2f}; exact path {res[f'render.fast_exact.{key}.s_per_frame']:.3f} s, "
              f"default vs exact {res[f'render.fast.{key}.psnr_vs_exact_db']:.1f} dB", file=sys.stderr)
    # a real estimated depth map (the shipped network on the same picture), focused on its median,
    # the aperture set so the largest blur radius is 32 px as in the bench scene
    try:
        from rvr_addon.estimate.infer import Estimator, default_weights, load_estimator

        img, rad, _ = scenes["1080p"]
        d_real, _ = Estimator(load_estimator(default_weights()))(img)
        f = float(np.median(d_real))
        a = MAX_RADIUS_1080P / max(float(np.abs(d_real - f).max()), 1e-6)
        fr = FastRenderer(min_layers=MIN_LAYERS)
        x = np.ascontiguousarray(rad, np.float32)
        res["render.fast.1080p_real_depth.s_per_frame"], gauss = paired_seconds(
            lambda: fr.render_linear(rad, d_real, f, a), lambda: cv2.GaussianBlur(x, (0, 0), 16), repeats)
        res["render.fast.1080p_real_depth.gauss_ratio"] = res["render.fast.1080p_real_depth.s_per_frame"] / gauss
        res["render.fast.1080p_real_depth.layers"] = len(
            plan_for_radius_map((d_real - f) * a, min_layers=MIN_LAYERS))
        # the default against the exact path (no half-resolution layers) on the same depth, full frame
        ex = FastRenderer(min_layers=MIN_LAYERS, half_res_radius=None)
        res["render.fast_exact.1080p_real_depth.s_per_frame"] = seconds_per_frame(
            lambda: ex.render_linear(rad, d_real, f, a), 1 if args.quick else 3)
        exact = linear_to_srgb(np.clip(ex.render_linear(rad, d_real, f, a), 0, 1))
        fast = linear_to_srgb(np.clip(fr.render_linear(rad, d_real, f, a), 0, 1))
        res["render.fast.1080p_real_depth.psnr_vs_exact_db"] = min(psnr(fast, exact), 200.0)
        # how much of the exact render is white in sRGB (the model's fill spreads the HDR lights the
        # network puts behind their surroundings: docs/renderer.md)
        res["render.fast_exact.1080p_real_depth.white_fraction"] = float(np.mean(exact.min(axis=2) >= 0.999))
        print(f"real depth: {res['render.fast.1080p_real_depth.s_per_frame']:.3f} s, ratio "
              f"{res['render.fast.1080p_real_depth.gauss_ratio']:.2f}, vs exact "
              f"{res['render.fast.1080p_real_depth.psnr_vs_exact_db']:.1f} dB", file=sys.stderr)
    except Exception as ex:  # noqa: BLE001 - no weights: the key is absent, said once
        print(f"real-depth timing skipped: {ex}", file=sys.stderr)
    img, rad, disp = scenes["1080p"]
    for name, spec in [("polygon7", ApertureSpec("polygon", blades=7)), ("anamorphic2x", ApertureSpec("anamorphic")),
                       ("cat_eye", ApertureSpec(cat_eye=0.5))]:
        fr = FastRenderer(spec=spec, min_layers=MIN_LAYERS)
        res[f"render.fast_{name}.1080p.s_per_frame"] = seconds_per_frame(
            lambda: fr.render_linear(rad, disp, 0.0, 1.0), 1 if args.quick else 3)

    # accuracy: fast vs brute-force reference on sRGB output; full 360p frame, and a 1080p crop
    img, rad, disp = scenes["360p"]
    fast = linear_to_srgb(FastRenderer(min_layers=MIN_LAYERS).render_linear(rad, disp, 0.0, 1.0))
    ref = linear_to_srgb(render_reference(rad, disp, 0.0, 1.0, min_layers=MIN_LAYERS))
    res["render.fast.psnr_vs_reference_db"] = psnr(fast, ref)
    res["render.fast.360p.max_abs_err_vs_reference"] = float(np.abs(fast - ref).max())
    if not args.quick:
        img, rad, disp = scenes["1080p"]
        crop = (slice(300, 560), slice(700, 1100))  # horizon, wall, lights, ground, subject edge
        rc, dc = np.ascontiguousarray(rad[crop]), np.ascontiguousarray(disp[crop])
        fast = linear_to_srgb(FastRenderer(min_layers=MIN_LAYERS).render_linear(rc, dc, 0.0, 1.0))
        ref = linear_to_srgb(render_reference(rc, dc, 0.0, 1.0, min_layers=MIN_LAYERS))
        res["render.fast.1080p_crop.psnr_vs_reference_db"] = psnr(fast, ref)
    print(f"fast vs reference: {res['render.fast.psnr_vs_reference_db']:.1f} dB", file=sys.stderr)

    import torch

    from rvr_addon.render.torch_render import render_torch

    torch.set_num_threads(2)
    for key, (img, rad, disp) in scenes.items():
        if key == "1080p" and args.quick:
            continue
        r = torch.from_numpy(rad).permute(2, 0, 1)[None]
        d = torch.from_numpy(disp)[None]
        with torch.no_grad():
            res[f"render.torch.{key}.s_per_frame"] = seconds_per_frame(
                lambda: render_torch(r, d, 0.0, 1.0, min_layers=MIN_LAYERS), 1 if key == "1080p" else 3)
        print(f"torch {key}: {res[f'render.torch.{key}.s_per_frame']:.3f} s/frame", file=sys.stderr)

    if not args.no_blender:
        try:
            bd = load_blender_defocus()
        except ImportError as ex:
            print(f"skipping Blender's Defocus node: {ex}", file=sys.stderr)
        else:
            for key, (img, rad, disp) in scenes.items():
                if key == "1080p" and args.quick:
                    continue
                sec, out = bd.blender_defocus(img, np.abs(disp), max_radius_px=float(np.abs(disp).max()),
                                              repeats=1 if key == "1080p" else 3)
                res[f"render.blender_defocus.{key}.s_per_frame"] = sec
                print(f"blender defocus {key}: {sec:.3f} s/frame", file=sys.stderr)
            if "render.blender_defocus.1080p.s_per_frame" in res:
                res["render.fast.1080p.speedup_vs_blender_defocus"] = (
                    res["render.blender_defocus.1080p.s_per_frame"] / res["render.fast.1080p.s_per_frame"])
    print(json.dumps({k: round(v, 5) for k, v in res.items()}))


if __name__ == "__main__":
    main()
