"""A tiny synthetic training clip in the harness format (sintel_eval/DATASET.md), made by hand.

The scene has a known disparity D (a far plane, a receding ground, a near square) and known
HDR: a few small lights far brighter than the 8-bit white. Every large-aperture member is
rendered with our own differentiable renderer (``render_torch``) with the member's focus and
aperture, so a perfect estimator reproduces the targets exactly.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import torch

from rvr_addon.color import linear_to_srgb, srgb_to_linear, to_uint8
from rvr_addon.io.exr import write_exr
from rvr_addon.render.torch_render import render_torch

MEMBERS = {  # name: (f-number, focus disparity, aperture scale)
    "large": (1.4, 0.0, 1.0),
    "mid": (4.0, 0.0, 0.35),
    "small": (11.0, 0.0, 0.127),
    "focusB": (1.4, 3.0, 1.0),
}


def scene(seed: int, width: int = 32, height: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """(linear HDR radiance (H, W, 3) float32, disparity (H, W) float32 in px at aperture 1)."""
    rng = np.random.default_rng(seed)
    low = rng.uniform(0.05, 0.7, (4, 4, 3)).astype(np.float32)
    radiance = cv2.resize(low, (width, height), interpolation=cv2.INTER_CUBIC).clip(0.02, 0.9)
    yy, xx = np.mgrid[:height, :width].astype(np.float32)
    disparity = np.where(yy < height * 0.4, 4.0, 4.0 - 6.0 * (yy - height * 0.4) / (height * 0.6))
    x0, y0 = int(rng.integers(2, width // 2)), int(rng.integers(height // 3, height // 2))
    disparity[y0:y0 + height // 3, x0:x0 + width // 3] = -1.5
    radiance[y0:y0 + height // 3, x0:x0 + width // 3] = rng.uniform(0.1, 0.8, 3)
    for _ in range(3):  # bright lights in the background
        x, y = int(rng.integers(0, width - 2)), int(rng.integers(0, int(height * 0.35)))
        radiance[y:y + 2, x:x + 2] = rng.uniform(8.0, 20.0) * np.array([1.0, 0.9, 0.7], np.float32)
    return radiance.astype(np.float32), disparity.astype(np.float32)


def render(radiance: np.ndarray, disparity: np.ndarray, focus: float, aperture: float) -> np.ndarray:
    """Our renderer on numpy arrays -> linear (H, W, 3)."""
    r = torch.from_numpy(radiance).permute(2, 0, 1)[None]
    d = torch.from_numpy(disparity)[None, None]
    with torch.no_grad():
        return render_torch(r, d, focus, aperture)[0].permute(1, 2, 0).numpy()


def write_png(path: Path, linear: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(to_uint8(linear_to_srgb(linear)), cv2.COLOR_RGB2BGR))


def make_clip(folder: Path, seed: int = 0, frames: int = 2, width: int = 32, height: int = 32,
              complete: bool = True, gt: bool = True) -> dict:
    """Write a clip folder; returns {frame: (radiance, disparity)} (frames are 1-based).

    complete=False leaves the last frame without its done marker (an interrupted harness run).
    gt=False leaves out the ground-truth EXRs (gt/disparity, gt/hdr).
    """
    config = {"seed": seed, "frames": frames, "width": width, "height": height, "fps": 24, "train_every": 1}
    manifest = {"format": "rvr-laaf-harness/1", "config": config, "config_hash": f"synthetic-{seed}",
                "camera": {"K_px": 10.0, "s_ref_m": 3.0, "f_number_ref": 1.4, "blades": 0, "ratio": 1.0}}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    truth = {}
    for frame in range(1, frames + 1):
        radiance, disparity = scene(seed * 100 + frame, width, height)
        truth[frame] = (radiance, disparity)
        stem = f"frame_{frame:05d}"
        files = {f"input/{stem}.png": radiance}
        members = {}
        for name, (n, f, a) in MEMBERS.items():
            rel = f"dof/constant/{stem}.png" if name == "large" else f"train/{stem}_{name}.png"
            files[rel] = render(radiance, disparity, f, a)
            members[name] = {"png": rel, "f_number": n, "focus_disparity": f, "aperture_scale": a,
                             "alpha": a, "beta": -a * f}
        for rel, lin in files.items():
            write_png(folder / rel, lin)
        if gt:  # ground truth (DATASET.md): disparity channel D, linear HDR radiance R, G, B
            write_exr(folder / "gt" / "disparity" / f"{stem}.exr", {"D": disparity})
            write_exr(folder / "gt" / "hdr" / f"{stem}.exr", {c: radiance[..., i] for i, c in enumerate("RGB")})
        sidecar = {"frame": frame, "index": frame - 1, "input": f"input/{stem}.png", "members": members,
                   "aperture_pair": {"small": "small", "large": "large"},
                   "aperture_triplet": ["large", "mid", "small"], "focal_triplet": ["input", "large", "focusB"]}
        (folder / "train").mkdir(exist_ok=True)
        (folder / "train" / f"{stem}.json").write_text(json.dumps(sidecar))
        if complete or frame < frames:
            listed = list(files) + ([f"gt/disparity/{stem}.exr", f"gt/hdr/{stem}.exr"] if gt else [])
            marker = {"config_hash": manifest["config_hash"],
                      "files": {rel: (folder / rel).stat().st_size for rel in listed}}
            (folder / "done").mkdir(exist_ok=True)
            (folder / "done" / f"{stem}.json").write_text(json.dumps(marker))
    return truth


def input_srgb(radiance: np.ndarray) -> np.ndarray:
    """The 8-bit input a camera would record, as float sRGB in [0, 1]."""
    return to_uint8(linear_to_srgb(radiance)).astype(np.float32) / 255.0


def true_exponent(radiance: np.ndarray) -> np.ndarray:
    """E of eq. 3 with srgb_to_linear(input) * exp(50 E) = radiance where clipped."""
    lin = srgb_to_linear(input_srgb(radiance))
    return np.log(np.maximum(radiance / np.maximum(lin, 1e-6), 1.0)) / 50.0
