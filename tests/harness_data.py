"""A fake but format-correct ground-truth clip (sintel_eval/DATASET.md) made with numpy in ms.

The "Cycles" shallow-DOF passes are rendered with OUR renderer from the clip's own inputs
(srgb_to_linear(png) * exp(50 E), ground-truth D), so the ablation's expected values are exact:
the ``ours_gt`` variant reproduces the ground truth bit for bit.

Scene (DESIGN units, aperture 1): a textured far wall at D = +4 px with bright 2x2 emitters
(radiance 60, clipped in the 8-bit input) and an in-focus textured square (D = 0) moving one
px per frame. Tracks: ``constant`` (focus 0, aperture 1) and ``rack`` (focus 0 -> 4).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np

from rvr_addon.color import linear_to_srgb, srgb_to_linear, to_float01, to_uint8
from rvr_addon.io.exr import write_exr
from rvr_addon.pipeline import exponent_from_radiance
from rvr_addon.render.fast import FastRenderer
from rvr_addon.render.model import hdr_radiance

WALL_D = 4.0
FAKE_F_PX = 100.0
TRACKS = ("constant", "rack")


def _scene(frame: int, size: tuple[int, int], seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(linear radiance (H, W, 3), disparity (H, W)) of one frame (1-based)."""
    w, h = size
    rng = np.random.default_rng(seed)
    wall = cv2.resize(rng.uniform(0.05, 0.6, (h // 4, w // 4, 3)).astype(np.float32), (w, h),
                      interpolation=cv2.INTER_NEAREST)
    subject = rng.uniform(0.2, 0.9, (h, w, 3)).astype(np.float32)
    radiance = wall.copy()
    for k in range(6):  # emitters on the wall, clear of the subject's path
        y, x = int(rng.integers(2, h - 4)), int(rng.integers(w // 2 + 4, w - 4)) if k % 2 else int(rng.integers(2, 6))
        radiance[y:y + 2, x:x + 2] = np.array([60.0, 50.0, 40.0], np.float32)
    disparity = np.full((h, w), WALL_D, np.float32)
    x0, y0, side = w // 4 + frame, h // 4, h // 2
    radiance[y0:y0 + side, x0:x0 + side] = subject[y0:y0 + side, x0:x0 + side]
    disparity[y0:y0 + side, x0:x0 + side] = 0.0
    return radiance, disparity


def _lens(track: str, frame: int, frames: int) -> tuple[float, float]:
    if track == "constant":
        return 0.0, 1.0
    return WALL_D * (frame - 1) / max(frames - 1, 1), 1.0


def _write_png(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), rgb[:, :, ::-1])


def write_fake_clip(folder: Path, *, frames: int = 3, size: tuple[int, int] = (64, 36), seed: int = 0) -> Path:
    """Write one complete clip into ``folder`` (created); returns the folder."""
    folder.mkdir(parents=True, exist_ok=True)
    w, h = size
    config = {"seed": seed, "script": "fake", "frames": frames, "width": w, "height": h, "fps": 24}
    config_hash = hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()[:16]
    renderer = FastRenderer()
    for frame in range(1, frames + 1):
        stem = f"frame_{frame:05d}"
        radiance, disparity = _scene(frame, size, seed)
        png = to_uint8(linear_to_srgb(radiance))
        exponent = exponent_from_radiance(png, radiance)
        hdr = np.asarray(hdr_radiance(srgb_to_linear(to_float01(png)), exponent), np.float32)
        files = [f"input/{stem}.png", f"gt/disparity/{stem}.exr", f"gt/hdr/{stem}.exr", f"gt/exponent/{stem}.exr"]
        _write_png(folder / files[0], png)
        for rel, channels in ((files[1], {"D": disparity, "Z": 1.0 / (0.5 - disparity / 20.0),
                                          "ID": (disparity == 0).astype(np.float32)}),
                              (files[2], {"R": hdr[..., 0], "G": hdr[..., 1], "B": hdr[..., 2]}),
                              (files[3], {"E.R": exponent[..., 0], "E.G": exponent[..., 1], "E.B": exponent[..., 2]})):
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            write_exr(folder / rel, channels)
        for track in TRACKS:
            focus, aperture = _lens(track, frame, frames)
            dof = renderer.render_linear(hdr, disparity, focus, aperture)
            base = f"dof/{track}/{stem}"
            _write_png(folder / f"{base}.png", to_uint8(linear_to_srgb(dof)))
            write_exr(folder / f"{base}.exr", {"R": dof[..., 0], "G": dof[..., 1], "B": dof[..., 2]})
            (folder / f"{base}.json").write_text(json.dumps(
                {"frame": frame, "index": frame - 1, "track": track, "focus_disparity": focus,
                 "aperture_scale": aperture, "f_number": 1.4, "blades": 0, "ratio": 1.0}))
            files += [f"{base}.png", f"{base}.exr", f"{base}.json"]
        marker = {"frame": frame, "index": frame - 1, "config_hash": config_hash,
                  "files": {rel: (folder / rel).stat().st_size for rel in files}}
        (folder / "done").mkdir(exist_ok=True)
        (folder / "done" / f"{stem}.json").write_text(json.dumps(marker))
    manifest = {
        "format": "rvr-laaf-harness/1", "config": config, "config_hash": config_hash,
        "camera": {"focal_mm": 50.0, "sensor_width_mm": 36.0, "f_number_ref": 1.0, "K_px": 20.0, "s_ref_m": 2.0,
                   "blades": 0, "ratio": 1.0, "f_px": FAKE_F_PX},
        "camera_per_frame": [{"frame": n, "index": n - 1, "world_to_camera": np.eye(4).tolist()}
                             for n in range(1, frames + 1)],  # a camera standing still
        "focus_tracks": {t: {"subjects": ["square"] if t == "constant" else ["square", "wall"]} for t in TRACKS},
        "events": [], "status": {"complete": True},
    }
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return folder
