"""The whole product on this machine: ``rvr refocus`` from a real clip to a refocused MP4.

    .venv/bin/python bench/pipeline_bench.py [--seconds 10] [--seconds-1080p 2] [--clip CLIP] [--only 360p]

Runs the refocus pipeline (working copy, estimate with the default depth system, stabilize,
look-ahead autofocus with the default preset, render; decode and encode included) in a child
process per size, on a real clip (../shared/data/clips/visualvoice_interview.mp4: 1280x720,
two people talking, a still camera; ``--clip`` another one):

* 360p: the clip's first ``--seconds`` at 640x360 (``--max-size 640``);
* 1080p: the clip upscaled to 1920x1080 once (Lanczos, into a temporary file; there is no real
  1080p clip here) and refocused at full size for ``--seconds-1080p`` (default 2 s, to keep the
  bench short). Costs paid once per run (loading the network, the parallax probe over the
  first 48 frames, the encoder's flush at the end: about 8 s at 1080p) are spread over the
  frames, so a 2 s run overstates a longer clip's cost per frame: ``--seconds-1080p 10`` measures
  a 10-second clip.

Keys (DESIGN.md style): ``pipeline.<size>.s_per_frame`` (wall), ``pipeline.<size>.cpu_s_per_frame``,
``pipeline.<size>.stage.<name>.s_per_frame`` (the JobChain's per-stage wall time),
``pipeline.<size>.peak_rss_mb`` (the child's peak resident memory), and the reference timing
measured in the same run: ``reference.gauss16.<size>.s`` (one ``cv2.GaussianBlur`` sigma 16 of an
RGB float32 frame) with ``pipeline.<size>.gauss_ratio`` = s_per_frame / that. The load average
before each run is printed. The last line of stdout is the JSON.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLIP = ROOT.parent / "shared" / "data" / "clips" / "visualvoice_interview.mp4"
SIZES = {"360p": (640, 360), "1080p": (1920, 1080)}


def gauss_reference(size: tuple[int, int], repeats: int = 5) -> float:
    """Median seconds of one cv2.GaussianBlur (sigma 16) of an RGB float32 frame of ``size``."""
    import cv2
    import numpy as np

    img = np.random.default_rng(0).random((size[1], size[0], 3)).astype(np.float32)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cv2.GaussianBlur(img, (0, 0), 16)
        times.append(time.perf_counter() - t0)
    return float(sorted(times)[len(times) // 2])


def child(clip: Path, out: Path, max_size: int, seconds: float) -> dict:
    """Run the refocus pipeline in this process; returns its timings."""
    from rvr_addon.refocus.commands import run_with_progress
    from rvr_addon.refocus.job import RefocusSettings, refocus_job
    from rvr_addon.io.video import probe_clip
    from rvr_addon.laaf.combine import DEFAULT_PRESET

    fps = probe_clip(clip).fps
    settings = RefocusSettings(input=clip, output=out, cache=out.parent / "work", preset=DEFAULT_PRESET,
                               max_size=max_size or None, stop=int(round(seconds * fps)))
    t0, c0 = time.perf_counter(), time.process_time()
    chain, run = refocus_job(settings)
    run_with_progress(chain, quiet=True)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"frames": run.frames, "size": list(run.size), "wall_s": wall,
            "cpu_s": cpu + kids.ru_utime + kids.ru_stime, "stages": chain.seconds,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "notes": run.notes}


def upscale(clip: Path, dest: Path, size: tuple[int, int], seconds: float) -> Path:
    """``clip``'s first ``seconds`` resized to ``size`` (Lanczos, x264 crf 12, audio kept)."""
    from rvr_addon.io.video import ffmpeg_exe

    cmd = [ffmpeg_exe(), "-v", "error", "-y", "-i", str(clip), "-t", f"{seconds + 0.5:.2f}", "-vf",
           f"scale={size[0]}:{size[1]}:flags=lanczos", "-c:v", "libx264", "-preset", "fast", "-crf", "12",
           "-pix_fmt", "yuv420p", "-c:a", "aac", str(dest)]
    subprocess.run(cmd, check=True)
    return dest


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clip", type=Path, default=CLIP)
    ap.add_argument("--seconds", type=float, default=10.0, help="length at 360p (s)")
    ap.add_argument("--seconds-1080p", type=float, default=2.0, help="length at 1080p (s)")
    ap.add_argument("--only", choices=tuple(SIZES), help="one size only")
    ap.add_argument("--child", nargs=4, metavar=("CLIP", "OUT", "MAX_SIZE", "SECONDS"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        clip, out, max_size, seconds = args.child
        print(json.dumps(child(Path(clip), Path(out), int(max_size), float(seconds))))
        return 0
    if not args.clip.is_file():
        print(f"skipped: {args.clip} is absent (../shared/data/clips)")
        print(json.dumps({}))
        return 0
    result: dict = {"pipeline.clip": args.clip.name}
    with tempfile.TemporaryDirectory() as tmp:
        for name, size in SIZES.items():
            if args.only and name != args.only:
                continue
            seconds = args.seconds if name == "360p" else args.seconds_1080p
            clip, max_size = args.clip, size[0]
            if name == "1080p":
                clip, max_size = upscale(args.clip, Path(tmp) / "clip1080.mp4", size, seconds), 0
            load = os.getloadavg()[0]
            out = Path(tmp) / name / "out.mp4"
            done = subprocess.run([sys.executable, __file__, "--child", str(clip), str(out), str(max_size),
                                   str(seconds)], capture_output=True, text=True)
            if done.returncode != 0:
                print(done.stderr[-3000:], file=sys.stderr)
                raise SystemExit(f"the {name} run failed")
            r = json.loads(done.stdout.strip().splitlines()[-1])
            n = max(r["frames"], 1)
            gauss = gauss_reference(size)
            key = f"pipeline.{name}"
            result.update({f"{key}.frames": r["frames"], f"{key}.s_per_frame": round(r["wall_s"] / n, 4),
                           f"{key}.cpu_s_per_frame": round(r["cpu_s"] / n, 4),
                           f"{key}.peak_rss_mb": round(r["peak_rss_mb"], 1), f"{key}.load_before": round(load, 2),
                           f"reference.gauss16.{name}.s": round(gauss, 5),
                           f"{key}.gauss_ratio": round(r["wall_s"] / n / gauss, 2)})
            for stage, s in r["stages"].items():
                result[f"{key}.stage.{stage.replace(' ', '_').replace('|', '').replace('__', '_')}.s_per_frame"] = \
                    round(s / n, 4)
            print(f"{name}: {r['frames']} frames at {r['size'][0]}x{r['size'][1]}, {r['wall_s'] / n:.3f} s/frame "
                  f"(load before {load:.2f}); " + "; ".join(r["notes"]))
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
