"""People depth cue speed on this machine: per frame at 640x360, 1280x720 and 3840x2160.

    .venv/bin/python bench/people_bench.py [--repeats 15]

Times :class:`rvr_addon.depth.people.PeopleDetector` on the shared interview clip's frame 100
(two people on a split screen, so two face meshes; ../shared/data/clips, resized to each size)
or, when it is missing, on a blank frame (no people: the models only). ``s_per_frame`` is the
whole call (uint8 frame in, full-size mattes and CueMap out); ``models_s_per_frame`` is selfie
segmentation + face detection alone at the analysis size (the face mesh, run on a crop per face,
and the full-size mattes are the rest). Medians of the repeats (the machine is shared). The last
line of stdout is the JSON of DESIGN.md's keys (``estimate.people.<size>.s_per_frame``).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rvr_addon.depth.people import ANALYSIS_LONG_SIDE, PeopleDetector  # noqa: E402
from rvr_addon.io.video import iter_frames  # noqa: E402

CLIP = ROOT.parent / "shared" / "data" / "clips" / "visualvoice_interview.mp4"
SIZES = {"360p": (640, 360), "720p": (1280, 720), "2160p": (3840, 2160)}


def median_time(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    source = next(iter_frames(CLIP, 100, 101)) if CLIP.is_file() else np.full((720, 1280, 3), 128, np.uint8)
    out: dict[str, float] = {}
    with PeopleDetector() as detector:
        for name, (w, h) in SIZES.items():
            shrink = w <= source.shape[1]
            frame = cv2.resize(source, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_CUBIC)
            people = len(detector(frame).persons)
            s = ANALYSIS_LONG_SIDE / max(w, h)
            small = cv2.resize(frame, (round(w * min(s, 1)), round(h * min(s, 1))), interpolation=cv2.INTER_AREA)
            models = detector._models  # loaded by the first call
            whole = median_time(lambda: detector(frame), args.repeats)
            only = median_time(lambda: (models["segment"].process(small), models["faces"].process(small)), args.repeats)
            out[f"estimate.people.{name}.s_per_frame"] = round(whole, 4)
            out[f"estimate.people.{name}.models_s_per_frame"] = round(only, 4)
            out[f"estimate.people.{name}.people"] = people
            print(f"{name} {w}x{h}: {whole * 1000:.1f} ms a frame ({only * 1000:.1f} ms segmentation + face "
                  f"detection), {people} people", file=sys.stderr)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
