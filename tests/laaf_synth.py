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
