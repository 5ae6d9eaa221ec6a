"""Who speaks, on real clips: LAAF's speech detector with dlib HOG faces + box mouth motion
("before") and with MediaPipe faces + face-mesh mouth opening and mouth motion correlated with
the voice ("after", the default); both decide through the same decision chain (speech.py).

Clips from ../shared/data/clips (relative to the repository root; a missing clip is skipped):

* visualvoice_interview.mp4: split screen, two men; the clear single-speaker stretches of
  tests/data/interview_speakers.json (annotated by eye, see its "how"). Per variant:
  ``correct_share`` = voiced frames of the stretches whose attributed speaker is the annotated
  one (a frame with no speaker counts as not correct), ``wrong_share`` = attributed to the other
  face, ``none_share``.
* lipnet_grid_lwbsza.mpg: one woman speaking ~0.7-2.4 s: ``found_share`` = voiced frames where
  she is the speaker.
* visualvoice_noisy_restaurant.mp4: one man talking, loud background (nearly every frame voiced):
  ``attributed_share`` of voiced frames (no annotation: reported, not scored).

Off-screen voice: each clip again with its audio shifted in time (circularly, by 40% of the clip):
a voice no face on screen utters; ``shifted_voice.attributed_share`` should be near 0.

Usage: python bench/speaker_bench.py [--frames N]   (last stdout line: one flat JSON)
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

CLIPS = ROOT.parent / "shared" / "data" / "clips"
ANNOTATION = ROOT / "tests" / "data" / "interview_speakers.json"
VARIANTS = {"before": {"face_backend": "dlib", "mouth": "motion"},
            "after": {"face_backend": "auto", "mouth": "auto"}}


def attribute(clip: Path, face_backend: str, mouth: str, analysis_width: int = 320, stop: int | None = None,
              shifts: tuple[float, ...] = (0.0, 0.4)) -> dict:
    """Run H_face + H_aud over a clip as LAAF does (measure, ingest in order, decide once the
    look-ahead is in). Returns {shift: per-frame speaker centre x / analysis width (NaN: none)},
    the voiced flags per shift, and timings. shift: the audio rolled by that fraction of the clip."""
    import cv2

    from rvr_addon.io.video import iter_frames, probe_clip
    from rvr_addon.laaf.analysis import FrameAnalyser
    from rvr_addon.laaf.audio import AudioTrack, analyse_audio, decode_audio
    from rvr_addon.laaf.detectors.base import AnalysisFrame
    from rvr_addon.laaf.detectors.face import FaceDetector
    from rvr_addon.laaf.detectors.speech import SpeechDetector

    info = probe_clip(clip)
    n = info.frame_count if stop is None else min(stop, info.frame_count)
    fps = info.fps
    base = analyse_audio(decode_audio(clip, duration_s=n / fps), fps, n)
    scale = min(1.0, analysis_width / info.width)
    size = (int(round(info.width * scale)), int(round(info.height * scale)))
    runs = []
    for shift in shifts:
        k = int(round(shift * n))
        audio = AudioTrack(np.roll(base.voiced, k), np.roll(base.envelope, k), np.roll(base.vad_fraction, k), fps)
        face = FaceDetector(backend=face_backend)
        runs.append((face, SpeechDetector(face, fps, n, audio=audio, mouth=mouth)))
    face0, speech0 = runs[0]
    analyser = FrameAnalyser({"face": face0, "speech": speech0}, ["face", "speech"])
    lag = speech0.lookahead_frames
    picks = {shift: np.full(n, np.nan) for shift in shifts}
    t0 = time.perf_counter()

    def decide(t: int) -> None:
        for shift, (_, sp) in zip(shifts, runs):
            box, _, _ = sp.decide(t)
            if box is not None:
                picks[shift][t] = (box[0] + box[2] / 2) / size[0]

    for t, rgb in enumerate(iter_frames(clip, stop=n)):
        small = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        af = AnalysisFrame(t, small, cv2.cvtColor(small, cv2.COLOR_RGB2GRAY), None, scale, fps, native=rgb)
        features, _ = analyser.measure(af)
        for face, sp in runs:
            face.ingest(t, af, features["face"])
            sp.ingest(t, af, features["speech"])
        if t - lag >= 0:
            decide(t - lag)
    for t in range(max(0, n - lag), n):
        decide(t)
    return {"picks": picks, "voiced": {s: np.roll(base.voiced, int(round(s * n))) for s in shifts}, "n": n,
            "fps": fps, "s_per_frame": (time.perf_counter() - t0) / max(n, 1), "backend": face0.backend.kind,
            "metrics": speech0.metrics()}


def interview_scores(run: dict, annotation: dict) -> dict:
    """correct / wrong / none shares over the voiced frames of the annotated stretches."""
    picks, voiced, fps = run["picks"][0.0], run["voiced"][0.0], run["fps"]
    counts = {"correct": 0, "wrong": 0, "none": 0}
    per = {"left": [0, 0], "right": [0, 0]}
    for st in annotation["stretches"]:
        for t in range(int(round(st["start_s"] * fps)), min(int(round(st["end_s"] * fps)) + 1, run["n"])):
            if not voiced[t]:
                continue
            x = picks[t]
            got = None if np.isnan(x) else ("left" if x < 0.5 else "right")
            key = "none" if got is None else ("correct" if got == st["speaker"] else "wrong")
            counts[key] += 1
            per[st["speaker"]][0] += key == "correct"
            per[st["speaker"]][1] += 1
    total = max(sum(counts.values()), 1)
    out = {f"{k}_share": v / total for k, v in counts.items()}
    out["scored_frames"] = float(sum(counts.values()))
    for side, (ok, cnt) in per.items():
        out[f"{side}.correct_share"] = ok / max(cnt, 1)
    return out


def attributed_share(run: dict, shift: float) -> float:
    picks, voiced = run["picks"][shift], run["voiced"][shift]
    return float(np.mean(~np.isnan(picks[voiced]))) if voiced.any() else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=None, help="only the first N frames of each clip")
    ap.add_argument("--variants", default="before,after")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(message)s")
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:  # pragma: no cover
        pass
    annotation = json.loads(ANNOTATION.read_text())
    result: dict[str, float] = {}
    for variant in args.variants.split(","):
        opts = VARIANTS[variant]
        for name, file in (("interview", "visualvoice_interview.mp4"), ("lipnet", "lipnet_grid_lwbsza.mpg"),
                           ("restaurant", "visualvoice_noisy_restaurant.mp4")):
            clip = CLIPS / file
            if not clip.is_file():
                print(f"{file}: not in {CLIPS}, skipped", file=sys.stderr)
                continue
            run = attribute(clip, opts["face_backend"], opts["mouth"], stop=args.frames)
            key = f"laaf.speaker.{name}.{variant}"
            if name == "interview":
                for k, v in interview_scores(run, annotation).items():
                    result[f"{key}.{k}"] = round(v, 4)
            elif name == "lipnet":
                result[f"{key}.found_share"] = round(attributed_share(run, 0.0), 4)
            else:
                result[f"{key}.attributed_share"] = round(attributed_share(run, 0.0), 4)
            result[f"{key}.shifted_voice.attributed_share"] = round(attributed_share(run, 0.4), 4)
            result[f"{key}.s_per_frame"] = round(run["s_per_frame"], 4)
            print(f"{file} {variant}: backend {run['backend']}, mouth {run['metrics']['mouth']}, "
                  f"lags {run['metrics']['track_lags_frames']}", file=sys.stderr)
            print(json.dumps({k: v for k, v in result.items() if k.startswith(key)}), flush=True)
    if "laaf.speaker.interview.after.correct_share" in result:
        result["laaf.speaker.interview.correct_share"] = result["laaf.speaker.interview.after.correct_share"]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
