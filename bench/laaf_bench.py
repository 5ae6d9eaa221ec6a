"""Look-Ahead Autofocus speed: the whole LAAF pass on 640x360 video, frames per second.

    .venv/bin/python bench/laaf_bench.py [--frames 100] [--clip PATH]

Input: the first ``--frames`` frames of ``../shared/data/clips/visualvoice_interview.mp4`` (a
real TV interview: two faces, speech; 25 fps) resized to 640x360 with its audio (ffmpeg);
without ../shared/data, a synthetic testsrc2 clip with a sine tone. Disparity stand-in (no
estimator weights exist yet, and disparity estimation is excluded by the goal): one static map,
a vertical ramp from 6 px at the top to -2 px at the bottom (the floor comes nearer), read
through ``--depth`` like any user map. Timed: ``AutofocusJob.run`` end to end -- decoding, the
analysis resize, disparity read, every detector, combination, K-means, step detection, KCF
tracking, the puller and the keyframe fit (and, since issue 23, the shot-cut detector). Presets: auto (the
default: reads the clip first, then runs what it picks: ``laaf.auto.*``), conversation (face + speech, the heaviest:
MediaPipe faces every 0.24 s, the face mesh on each, the speech detector; the frames with a face
are printed as ``laaf.<preset>.<mode>.360p.frames_with_faces``: 0 would mean a run without the speaker work), action (DIS flow + parallax fit + saliency) and, when AF-Net weights
are shipped, learned (AF-Net with the clip's sound, and the speech detector for the speaker of an
NFT near a voice onset: ``laaf.learned.*``) and learned_map (AF-Net alone, ``--afnet-region map``:
``laaf.learned_map.*``), look-ahead and causal.
``laaf.360p.fps`` is the slowest of them. The last stdout line is DESIGN.md's JSON.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLIP = ROOT.parent / "shared" / "data" / "clips" / "visualvoice_interview.mp4"


def make_clip(src: Path | None, out: Path, *, frames: int | None = None, seconds: float | None = None) -> Path:
    """640x360 H.264 + AAC clip of the first ``frames`` frames or ``seconds`` of src (a synthetic
    testsrc2 clip with a tone without src); shared with ``vse_bench.py``."""
    if (frames is None) == (seconds is None):
        raise ValueError("make_clip: give frames or seconds")
    import imageio_ffmpeg

    ff = imageio_ffmpeg.get_ffmpeg_exe()
    if src is not None and src.is_file():
        inputs = ["-i", str(src)]
    else:
        inputs = ["-f", "lavfi", "-i", "testsrc2=size=640x360:rate=25", "-f", "lavfi", "-i", "sine=frequency=300"]
    length = ["-frames:v", str(frames)] if frames is not None else ["-t", str(seconds)]
    cmd = [ff, "-hide_banner", "-v", "error", "-y", *inputs, *length, "-vf", "scale=640:360",
           "-c:v", "libx264", "-preset", "veryfast", "-crf", "18", "-pix_fmt", "yuv420p", "-c:a", "aac",
           "-shortest", str(out)]
    subprocess.run(cmd, check=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--clip", type=Path, default=CLIP)
    args = ap.parse_args()
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        clip = make_clip(args.clip, Path(tmp) / "clip360.mp4", frames=args.frames)
        ramp = np.linspace(6.0, -2.0, 360, dtype=np.float32)[:, None].repeat(640, axis=1)
        depth = Path(tmp) / "disparity.npy"
        np.save(depth, ramp)
        # warm-up: loads dlib's model and OpenCV's kernels once
        AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset="conversation", stop=8)).run(progress=False)
        fps_all = []
        from rvr_addon.afnet.infer import DEFAULT_WEIGHTS

        presets = ("auto", "conversation", "action") + (("learned", "learned_map") if DEFAULT_WEIGHTS.is_file() else ())
        for preset in presets:
            for causal in (False, True):
                job = AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset=preset.replace("_map", ""),
                                                     causal=causal, afnet_speaker=preset == "learned"))
                t0 = time.perf_counter()
                result = job.run(progress=False)
                dt = time.perf_counter() - t0
                fps = len(result.focus) / dt
                fps_all.append(fps)
                mode = "causal" if causal else "lookahead"
                out[f"laaf.{preset}.{mode}.360p.fps"] = round(fps, 2)
                faces = result.detectors.get("face", {}).get("frames_with_faces")
                if faces is not None:  # a run that finds no face times no speaker work (before 2026-12-07's tiles)
                    out[f"laaf.{preset}.{mode}.360p.frames_with_faces"] = float(faces)
                print(f"{preset:12s} {mode:9s} {len(result.focus)} frames {dt:6.2f} s  {fps:6.1f} fps  "
                      f"NFTs {[n.t for n in result.nfts]}  timings {result.settings['timings_s']}", file=sys.stderr)
        out["laaf.360p.fps"] = round(min(fps_all), 2)
        out["laaf.360p.frames"] = float(len(result.focus))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
