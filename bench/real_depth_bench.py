"""Depth figures on REAL material, through the user's entry point ``rvr eval-estimator``.

    .venv/bin/python bench/real_depth_bench.py [--data ../shared/data] [--weights W.pt]
        [--weights-per-scene FOLDS.json] [--depth-method network|auto] [--depth-methods auto,network]
        [--video-frames N] [--aperture-size 512] [--parts pictures,video,aperture] [-o REPORT]

Runs, on whatever of the shared data is present (a part whose data is absent is skipped, said on
stderr):

- **pictures**: ``--real-set DATA/real_depth`` (Middlebury 2006 + 2001/2003, Kinect) and the
  Middlebury 2014 Motorcycle pair (``--motorcycle``, when scikit-image is installed):
  ``estimate.real.<set>.affine_error`` / ``.ramp_error`` / ``.better_than_ramp_share``,
  ``estimate.real.middlebury.*`` (46 views of 25 scenes), ``estimate.motorcycle.*``;
- **video**: ``--real-video`` on hololens_office and tum_fr1_rpy_window with each of
  ``--depth-methods`` (default ``auto,auto+centred,network``; ``auto+centred`` is auto's D after the
  default temporal filter, the D ``rvr refocus`` renders with): ``estimate.video.<clip>.<method>.{affine_error,
  clip_affine_error, flicker, ...}`` and the ramp;
- **aperture**: ``--aperture DATA/real_depth/aperture``: ``estimate.aperture.<scene>.psnr_*_db``,
  ``estimate.aperture.mean_margin_db`` (ours - Gaussian) and ``mean_margin_ramp_db``.

One ``rvr eval-estimator`` run writes the report folder (default ``out/real_depth_report``:
summary.json, README.md, pictures); the last stdout line is the summary as one flat JSON object
(DESIGN.md "Benchmarks"), plus ``bench.real_depth.wall_s``. Torch and OpenCV use one thread.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--weights", type=Path, help="estimator weights (default: the shipped ones)")
    ap.add_argument("--weights-per-scene", type=Path, metavar="JSON", help="fold models for the real pictures")
    ap.add_argument("--depth-method", default="network", help="single pictures: network | auto (default network)")
    ap.add_argument("--depth-methods", default="auto,auto+centred,network",
                    help="video: methods (default auto,auto+centred,network; auto+centred: auto's D after the "
                         "default temporal filter, what rvr refocus renders with)")
    ap.add_argument("--video-frames", type=int, help="at most N frames a clip (default all)")
    ap.add_argument("--aperture-size", type=int, default=512)
    ap.add_argument("--parts", default="pictures,video,aperture")
    ap.add_argument("-o", "--output", type=Path, default=ROOT / "out" / "real_depth_report")
    args = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    from rvr_addon.cli import main as rvr

    parts = {p.strip() for p in args.parts.split(",") if p.strip()}
    argv = ["eval-estimator", "-o", str(args.output), "--force", "-q", "--depth-method", args.depth_method]
    if args.weights is not None:
        argv += ["--weights", str(args.weights)]
    real = args.data / "real_depth"
    if "pictures" in parts:
        if real.is_dir():
            argv += ["--real-set", str(real)]
            if args.weights_per_scene is not None:
                argv += ["--weights-per-scene", str(args.weights_per_scene)]
        else:
            print(f"skip pictures: {real} missing", file=sys.stderr)
        try:
            import skimage  # noqa: F401

            argv += ["--motorcycle"]
        except ImportError:
            print("skip motorcycle: scikit-image not installed", file=sys.stderr)
    if "video" in parts:
        clips = [args.data / "real_video_depth" / n for n in ("hololens_office", "tum_fr1_rpy_window")]
        for c in clips:
            if c.is_dir():
                argv += ["--real-video", str(c)]
            else:
                print(f"skip video {c.name}: missing", file=sys.stderr)
        argv += ["--depth-methods", args.depth_methods]
        if args.video_frames is not None:
            argv += ["--video-frames", str(args.video_frames)]
    if "aperture" in parts:
        if (real / "aperture").is_dir():
            argv += ["--aperture", str(real / "aperture"), "--aperture-size", str(args.aperture_size)]
        else:
            print(f"skip aperture: {real / 'aperture'} missing", file=sys.stderr)
    if not any(a in argv for a in ("--real-set", "--motorcycle", "--real-video", "--aperture")):
        print("nothing to run: no shared data found", file=sys.stderr)
        print(json.dumps({}))
        return
    print("rvr " + " ".join(argv), file=sys.stderr)
    t0 = time.perf_counter()
    import contextlib

    with contextlib.redirect_stdout(sys.stderr):  # the command's own print goes before our last line
        rc = rvr(argv)
    if rc != 0:
        raise SystemExit(rc)
    summary = json.loads((args.output / "summary.json").read_text())
    summary["bench.real_depth.wall_s"] = time.perf_counter() - t0
    print(json.dumps({k: round(float(v), 4) for k, v in sorted(summary.items())}))


if __name__ == "__main__":
    main()
