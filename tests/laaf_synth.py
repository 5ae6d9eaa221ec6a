"""Synthetic clips for the LAAF tests: textured scenes with known motion, depth and timing."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def texture(h: int, w: int, seed: int, scale: int = 4) -> np.ndarray:
    """(h, w, 3) uint8 smooth random texture (trackable, not flat)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (h // scale + 2, w // scale + 2, 3), dtype=np.uint8)
    return cv2.resize(small, (w + 2 * scale, h + 2 * scale), interpolation=cv2.INTER_CUBIC)[scale:scale + h,
                                                                                              scale:scale + w]


def entering_square(n: int = 40, size=(128, 72), enter: int = 20, side: int = 24, speed: float = 3.0,
                    d_background: float = 3.0, d_object: float = 0.0):
    """Frames (list of uint8 RGB), disparity maps (list of float32) and the square's boxes.

    A textured square slides in from the right edge: its left edge crosses into the frame at
    frame ``enter`` and it moves left ``speed`` px/frame until it stops at a third of the width.
    Background disparity ``d_background``, square ``d_object`` (nearer)."""
    w, h = size
    bg = (texture(h, w, 1) * 0.5 + 60).astype(np.uint8)
    obj = texture(side, side, 2)
    frames, maps, boxes = [], [], []
    stop_x = w // 3
    for k in range(n):
        x = w - (k - enter + 1) * speed
        x = max(x, stop_x)
        f = bg.copy()
        d = np.full((h, w), d_background, np.float32)
        y = (h - side) // 2
        x0, x1 = int(round(x)), int(round(x)) + side
        if x0 < w:
            xa, xb = max(x0, 0), min(x1, w)
            f[y:y + side, xa:xb] = obj[:, xa - x0:xb - x0]
            d[y:y + side, xa:xb] = d_object
        frames.append(f)
        maps.append(d)
        boxes.append((float(x0), float(y), float(side), float(side)))
    return frames, maps, boxes


def write_clip(folder: Path, frames, maps) -> tuple[Path, Path]:
    """PNG sequence + one NPY disparity map per frame; returns (frames dir, maps dir)."""
    fdir, ddir = folder / "frames", folder / "disparity"
    fdir.mkdir(parents=True, exist_ok=True)
    ddir.mkdir(parents=True, exist_ok=True)
    for k, (f, d) in enumerate(zip(frames, maps)):
        cv2.imwrite(str(fdir / f"f_{k:04d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        np.save(ddir / f"d_{k:04d}.npy", d)
    return fdir, ddir


def face_image(h: int, w: int, faces: list[tuple[int, int, int, float]], seed: int = 3) -> np.ndarray:
    """A frame with drawn faces: (cx, cy, radius, mouth opening 0..1) each."""
    img = (texture(h, w, seed) * 0.3 + 90).astype(np.uint8)
    for cx, cy, r, mouth in faces:
        cv2.circle(img, (cx, cy), r, (205, 170, 140), -1)
        for ex in (-r // 3, r // 3):
            cv2.circle(img, (cx + ex, cy - r // 4), max(r // 8, 1), (30, 30, 30), -1)
        mh = max(1, int(round(1 + mouth * r * 0.35)))
        cv2.ellipse(img, (cx, cy + int(r * 0.5)), (r // 3, mh), 0, 0, 360, (60, 10, 10), -1)
    return img


def talking_blobs(n: int = 64, size=(200, 120), turns=((8, 27, 0), (36, 55, 1)), pan: float = 1.0,
                  noise: float = 2.0, fps: float = 25.0, seed: int = 5):
    """Two textured blobs ("heads", no face a detector would find) whose dark "mouth" opens with
    the audio envelope of their own turns, on a textured background the camera pans across.

    turns: (first frame, last frame, speaker 0 or 1) of each voiced turn. pan: px/frame of
    camera motion (everything shifts left). noise: sigma of per-frame grey noise (render noise).
    Returns frames (list of uint8 RGB), envelope (n,) float32, voiced (n,) bool and the blobs'
    centres per frame as a list of ((x0, y0), (x1, y1)) px."""
    w, h = size
    rng = np.random.default_rng(seed)
    margin = int(abs(pan) * n) + 4
    bg = (texture(h, w + margin, seed) * 0.6 + 50).astype(np.uint8)
    heads = [texture(36, 30, seed + 1 + i) for i in range(2)]
    env = np.zeros(n, np.float32)
    voiced = np.zeros(n, bool)
    opening = np.zeros((2, n), np.float32)
    for a, b, who in turns:
        k = np.arange(a, b + 1)
        syll = np.abs(np.sin((k - a) * 2 * np.pi * 3.7 / fps + rng.uniform(0, 3))) * rng.uniform(0.5, 1.0, k.size)
        env[k] = syll
        voiced[k] = True
        opening[who, k] = syll
    frames, centres = [], []
    for k in range(n):
        off = int(round(pan * k))
        f = bg[:, off:off + w].copy()
        cs = []
        for i, cx0 in enumerate((int(w * 0.28), int(w * 0.72))):
            cx, cy = cx0 - off + int(round(pan * n / 2)), h // 2
            x0, y0 = cx - 15, cy - 18
            patch = f[y0:y0 + 36, x0:x0 + 30]
            disc = np.zeros((36, 30), np.uint8)
            cv2.ellipse(disc, (15, 18), (14, 17), 0, 0, 360, 1, -1)
            patch[disc > 0] = (heads[i][disc > 0] * 0.5 + 100).astype(np.uint8)
            mh = int(round(1 + 5 * opening[i, k]))
            cv2.ellipse(patch, (15, 27), (6, mh), 0, 0, 360, (40, 10, 10), -1)
            cs.append((float(cx), float(cy)))
        f = np.clip(f.astype(np.float32) + rng.normal(0, noise, f.shape), 0, 255).astype(np.uint8)
        frames.append(f)
        centres.append(tuple(cs))
    return frames, env, voiced, centres
