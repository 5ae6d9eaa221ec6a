"""RGBD-HDR estimator speed on this machine: per-frame inference at 640x360 and 1920x1080.

    .venv/bin/python bench/estimate_bench.py [--repeats 7] [--no-job]

Times :class:`rvr_addon.estimate.infer.Estimator` on a real picture (a Sintel frame from
../shared/data, resized; random texture if it is missing): uint8 frame in, D and E as numpy
arrays out, everything in between included (conversion, padding, U-Net, bilateral slicing,
E gating). It uses the shipped weights (rvr_addon/estimate/weights/estimator.pt) and so the
trunk size they ask for (``inference_max_pixels``: frames above it run the network on a shrunk
copy, D sliced and E gated at full size), or ``--weights W``; without any, a freshly initialised
network at full size (speed does not depend on the weights' values). ``s_per_frame`` is the median
of the repeats (the machine is shared: the minimum is reported too). Unless ``--no-job``, it
also times ``rvr estimate`` end to end at 360p (PNG decode + inference + EXR write to the
cache) over 8 frames. The last line of stdout is the JSON of DESIGN.md's keys.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PICTURE = ROOT.parent / "shared" / "data" / "sintel_frames" / "frame_0016.png"
SIZES = {"360p": (640, 360), "1080p": (1920, 1080)}


def picture(width: int, height: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB test frame with a few clipped highlights."""
    if PICTURE.is_file():
        img = cv2.cvtColor(cv2.imread(str(PICTURE)), cv2.COLOR_BGR2RGB)
    else:
        img = (np.random.default_rng(0).random((54, 96, 3)) * 255).astype(np.uint8)
    img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    rng = np.random.default_rng(1)
    for _ in range(20):
        x, y = int(rng.integers(0, width - 4)), int(rng.integers(0, height // 2))
        img[y:y + 3, x:x + 3] = 255
    return img


def time_calls(fn, repeats: int) -> list[float]:
    fn()  # warm-up (allocator, oneDNN kernels)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-job", action="store_true", help="skip the end-to-end rvr estimate timing")
    parser.add_argument("--weights", type=Path, help="estimator weights (default: the shipped ones)")
    args = parser.parse_args()

    import torch

    from rvr_addon.estimate.infer import SHIPPED_WEIGHTS, EstimateJob, EstimateSettings, Estimator, load_estimator
    from rvr_addon.estimate.train import export_weights
    from rvr_addon.estimate.unet import EstimatorNet

    result: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        weights = args.weights or (SHIPPED_WEIGHTS if SHIPPED_WEIGHTS.is_file() else None)
        if weights is None:
            torch.manual_seed(0)
            weights = export_weights(EstimatorNet(), Path(tmp) / "untrained.pt", iterations=0, wall_time_s=0.0,
                                     training={"note": "benchmark only: untrained"})
        model = load_estimator(weights)
        net = model.net
        est = Estimator(model)
        print(f"weights {weights}: trunk at most {est.max_pixels} px", file=sys.stderr)
        result["estimate.trunk_max_pixels"] = float(est.max_pixels)
        result["estimate.model.parameters"] = float(net.parameter_count())
        result["estimate.model.weights_mb"] = round(weights.stat().st_size / 1e6, 2)
        result["estimate.threads"] = float(torch.get_num_threads())
        for name, (w, h) in SIZES.items():
            frame = picture(w, h)
            times = time_calls(lambda: est(frame), args.repeats)
            result[f"estimate.{name}.s_per_frame"] = round(statistics.median(times), 4)
            result[f"estimate.{name}.min_s_per_frame"] = round(min(times), 4)
            print(f"{name} {w}x{h}: median {statistics.median(times):.3f} s, min {min(times):.3f} s "
                  f"over {len(times)}", file=sys.stderr)
        if not args.no_job:
            frames = Path(tmp) / "frames"
            frames.mkdir()
            for i in range(8):
                cv2.imwrite(str(frames / f"f{i:03d}.png"), cv2.cvtColor(np.roll(picture(640, 360), 4 * i, axis=1),
                                                                       cv2.COLOR_RGB2BGR))
            t = time.perf_counter()
            job = EstimateJob(EstimateSettings(input=frames, output=Path(tmp) / "cache", weights=weights))
            job.run(progress=False)
            per = (time.perf_counter() - t) / job.total
            result["estimate.job.360p.s_per_frame"] = round(per, 4)
            print(f"rvr estimate end to end at 360p: {per:.3f} s/frame", file=sys.stderr)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
