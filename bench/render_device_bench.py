"""The renderer on a torch device (``rvr_addon.render.device.TorchRenderer``) beside the fast CPU path.

    .venv/bin/python bench/render_device_bench.py [--repeats N] [--no-torch-cpu] [--sizes 1080p,360p]

Same scene as bench/render_bench.py (a Sintel frame with HDR highlights over a synthetic depth
layout, blur radius -8..+32 px at 1080p, at least 24 layers, focus on the subject). Prints, from
one run: ``render.cuda.<size>.s_per_frame`` (seconds a frame on the GPU, upload and download of
the frame included; ``render.cuda.available`` = 0 and no timing where torch sees no GPU),
``render.torch_cpu.<size>.s_per_frame`` (the same renderer with torch on the CPU),
``render.fast.<size>.s_per_frame`` (the fast CPU path) and the reference timing,
``reference.gauss16.<size>.s`` (one cv2.GaussianBlur, sigma 16, of the RGB float32 frame), with
``*.gauss_ratio`` = renderer / that; and the accuracy of each device path against the exact fast
path (``render.<device>.<size>.psnr_vs_fast_exact_db``, sRGB, 200 = identical). The last line of
stdout is the JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from render_bench import MIN_LAYERS, bench_scene, psnr  # noqa: E402

from rvr_addon.color import linear_to_srgb  # noqa: E402
from rvr_addon.render.fast import FastRenderer  # noqa: E402

SIZES = {"360p": (640, 360), "1080p": (1920, 1080)}


def seconds_per_frame(fn, repeats: int, sync=None) -> float:
    """Median wall seconds of ``fn()`` over ``repeats`` runs after one warm-up; ``sync`` (e.g.
    torch.cuda.synchronize) is called before each clock read."""
    fn()
    times = []
    for _ in range(repeats):
        if sync:
            sync()
        t = time.perf_counter()
        fn()
        if sync:
            sync()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per figure (median; default 5)")
    ap.add_argument("--sizes", default="1080p,360p", help="comma-separated: 1080p, 360p (default both)")
    ap.add_argument("--no-torch-cpu", action="store_true", help="skip torch on the CPU (slow on few cores)")
    ap.add_argument("--torch-cpu-repeats", type=int, default=1, help="timed runs of torch on the CPU (default 1)")
    args = ap.parse_args()
    import torch

    from rvr_addon.render.device import TorchRenderer

    res: dict[str, float] = {}
    cuda = torch.cuda.is_available()
    res["render.cuda.available"] = 1.0 if cuda else 0.0
    if cuda:
        print(f"GPU: {torch.cuda.get_device_name(0)}", file=sys.stderr)
    else:
        print("torch sees no CUDA GPU: render.cuda.* unmeasured", file=sys.stderr)
    for key in [k.strip() for k in args.sizes.split(",") if k.strip()]:
        img, rad, disp = bench_scene(*SIZES[key])
        fr = FastRenderer(min_layers=MIN_LAYERS)
        res[f"render.fast.{key}.s_per_frame"] = seconds_per_frame(lambda: fr.render_linear(rad, disp, 0.0, 1.0),
                                                                  args.repeats)
        x = np.ascontiguousarray(rad, np.float32)
        gauss = res[f"reference.gauss16.{key}.s"] = seconds_per_frame(lambda: cv2.GaussianBlur(x, (0, 0), 16),
                                                                      args.repeats)
        res[f"render.fast.{key}.gauss_ratio"] = res[f"render.fast.{key}.s_per_frame"] / gauss
        exact = linear_to_srgb(np.clip(FastRenderer(min_layers=MIN_LAYERS, half_res_radius=None)
                                       .render_linear(rad, disp, 0.0, 1.0), 0, 1))
        print(f"{key}: fast {res[f'render.fast.{key}.s_per_frame']:.3f} s, gauss16 {gauss:.3f} s", file=sys.stderr)
        runs = [("cuda", "cuda", args.repeats)] if cuda else []
        if not args.no_torch_cpu:
            runs.append(("torch_cpu", "cpu", args.torch_cpu_repeats))
        for name, device, repeats in runs:
            tr = TorchRenderer(min_layers=MIN_LAYERS, device=device)
            sync = torch.cuda.synchronize if device == "cuda" else None
            sec = res[f"render.{name}.{key}.s_per_frame"] = seconds_per_frame(
                lambda: tr.render_linear(rad, disp, 0.0, 1.0), repeats, sync)
            res[f"render.{name}.{key}.gauss_ratio"] = sec / gauss
            out = linear_to_srgb(np.clip(tr.render_linear(rad, disp, 0.0, 1.0), 0, 1))
            res[f"render.{name}.{key}.psnr_vs_fast_exact_db"] = min(psnr(out, exact), 200.0)
            if device == "cuda":
                res[f"render.cuda.{key}.peak_gpu_mb"] = torch.cuda.max_memory_allocated() / 1e6
            print(f"{key}: {name} {sec:.4f} s/frame, {res[f'render.{name}.{key}.psnr_vs_fast_exact_db']:.1f} dB "
                  "vs the exact fast path", file=sys.stderr)
    res["torch.threads"] = float(torch.get_num_threads())
    print(json.dumps({k: round(v, 5) for k, v in res.items()}))


if __name__ == "__main__":
    main()
