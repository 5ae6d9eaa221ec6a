"""Focus that holds: how often LAAF changes target and how much of the time focus moves.

    .venv/bin/python bench/calm_bench.py [--clip PATH] [--preset action] [--calm 0 0.5 1] [--seconds 20]

Input: ``../shared/data/clips/kivy_cityCC0.mpg`` (a real street scene) resized to 640x360
(``laaf_bench.make_clip``), the first ``--seconds``; disparity: laaf_bench's static stand-in
ramp (6 px at the top to -2 px at the bottom), so only the focus *decision* is judged. Per
``--calm`` value (0 = the old, responsive behaviour): ``calm.<c>.targets_per_s`` (NFTs after the
first per second), ``calm.<c>.seconds_per_target``, ``calm.<c>.moving_share`` (share of frames
whose focus changes by more than 0.02 disparity units from the previous frame) and the fps.
The last stdout line is DESIGN.md's JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

CLIP = ROOT.parent / "shared" / "data" / "clips" / "kivy_cityCC0.mpg"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clip", type=Path, default=CLIP)
    ap.add_argument("--preset", default="action")
    ap.add_argument("--calm", type=float, nargs="+", default=[0.0, 0.5, 1.0])
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args()
    from laaf_bench import make_clip

    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    try:
        from rvr_addon.laaf.calm import focus_activity
    except ImportError:  # before the calm knob existed
        focus_activity = None
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        clip = make_clip(args.clip, Path(tmp) / "clip360.mp4", seconds=args.seconds)
        ramp = np.linspace(6.0, -2.0, 360, dtype=np.float32)[:, None].repeat(640, axis=1)
        depth = Path(tmp) / "disparity.npy"
        np.save(depth, ramp)
        for calm in args.calm:
            kw = {"calm": calm} if focus_activity is not None else {}
            job = AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset=args.preset, **kw))
            t0 = time.perf_counter()
            r = job.run(progress=False)
            dt = time.perf_counter() - t0
            focus = np.asarray(r.focus, np.float64)
            n, fps = len(focus), float(r.clip.fps)
            moving = float(np.mean(np.abs(np.diff(focus)) > 0.02)) if n > 1 else 0.0
            changes = max(len(r.nfts) - 1, 0)
            key = f"calm.{calm:g}"
            out[f"{key}.targets_per_s"] = round(changes / (n / fps), 3)
            out[f"{key}.seconds_per_target"] = round((n / fps) / max(changes, 1), 2)
            out[f"{key}.moving_share"] = round(moving, 3)
            out[f"{key}.360p.fps"] = round(n / dt, 2)
            print(f"calm {calm:g}: {n} frames, {changes} target changes, NFTs {[x.t for x in r.nfts]}, "
                  f"moving {moving:.1%}, {n / dt:.1f} fps", file=sys.stderr)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
