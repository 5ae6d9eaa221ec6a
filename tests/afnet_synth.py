"""Synthetic clips for the AF-Net tests: an obvious New Focus Target (a bright square appears).

Each clip: a static textured background (disparity 3), a dim square A on the left (disparity
1, the focus target from frame 0), and from frame ``t_enter`` a bright square B on the right
(disparity 0) that becomes the focus target: the NFT. Written as an image sequence with one
NPY disparity map per frame and a focus annotation file, or as a minimal harness clip
(``sintel_eval/DATASET.md``: manifest with subjects and events, input PNGs, GT disparity EXRs).
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from rvr_addon.afnet.annotations import AnnotatedClip, Annotation, write_annotations
from rvr_addon.afnet.model import AFNetConfig


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Tiny convolutions: one torch thread is faster on the shared 2-core machine."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


W, H = 48, 32
BOX_A = (4.0, 10.0, 10.0, 10.0)
SIDE_B = 12


def tiny_config(**kw) -> AFNetConfig:
    """A small AF-Net for tests: 32x24 input, 9 sampled frames every 2 (receptive field 17)."""
    base = dict(width=32, height=24, f_t=3, s=3, sample_step=2, stride=2, widths1=(8, 12, 16, 16),
                widths2=(16, 16, 16, 24))
    base.update(kw)
    return AFNetConfig(**base).check()


def frames_of(n: int, t_enter: int | None, seed: int, y_b: int | None = None):
    """(frames uint8 RGB list, disparity list, box of B) of one clip; t_enter None: B never appears."""
    rng = np.random.default_rng(seed)
    bg = cv2.resize(rng.integers(30, 110, (H // 4, W // 4, 3), dtype=np.uint8), (W, H), interpolation=cv2.INTER_LINEAR)
    y_b = int(rng.integers(2, H - SIDE_B - 2)) if y_b is None else y_b
    box_b = (float(W - SIDE_B - 6), float(y_b), float(SIDE_B), float(SIDE_B))
    frames, maps = [], []
    for k in range(n):
        f = bg.copy()
        d = np.full((H, W), 3.0, np.float32)
        x, y, bw, bh = (int(v) for v in BOX_A)
        f[y:y + bh, x:x + bw] = (90, 80, 70)
        d[y:y + bh, x:x + bw] = 1.0
        if t_enter is not None and k >= t_enter:
            x, y, bw, bh = (int(v) for v in box_b)
            f[y:y + bh, x:x + bw] = (250, 245, 235)
            d[y:y + bh, x:x + bw] = 0.0
        frames.append(f)
        maps.append(d)
    return frames, maps, box_b


def write_sequence(folder: Path, frames, maps) -> tuple[Path, Path]:
    """PNG frames + NPY disparity maps; returns (frames dir, disparity dir)."""
    fdir, ddir = folder / "frames", folder / "disparity"
    fdir.mkdir(parents=True, exist_ok=True)
    ddir.mkdir(parents=True, exist_ok=True)
    for k, (f, d) in enumerate(zip(frames, maps)):
        cv2.imwrite(str(fdir / f"f_{k:04d}.png"), f[..., ::-1])
        np.save(ddir / f"d_{k:04d}.npy", d)
    return fdir, ddir


def annotated_clip(folder: Path, n: int, t_enter: int | None, seed: int, weak: bool = False) -> AnnotatedClip:
    """Write one clip as an image sequence and return its records (regions on every frame)."""
    frames, maps, box_b = frames_of(n, t_enter, seed)
    fdir, ddir = write_sequence(folder, frames, maps)
    recs = []
    for k in range(n):
        after = t_enter is not None and k >= t_enter
        recs.append(Annotation(k, box_b if after else BOX_A, "manual" if k == t_enter else "tracked",
                               nft=(k == t_enter), weak=weak))
    return AnnotatedClip(fdir, recs, weak=weak, depth=ddir)


def write_annotated_dataset(root: Path, enters: list[int | None], n: int = 30, seed0: int = 0,
                            weak_from: int | None = None) -> Path:
    """Clips with B entering at each of ``enters`` (None: never), and their annotation file.
    Clips from index ``weak_from`` on are flagged weak."""
    clips = [annotated_clip(root / f"clip{i}", n, t, seed0 + i, weak=weak_from is not None and i >= weak_from)
             for i, t in enumerate(enters)]
    return write_annotations(root / "annotations.json", clips)


def write_harness_clip(folder: Path, n: int, t_enter: int | None, seed: int, script: str = "enter") -> Path:
    """A minimal complete harness clip: main subject 'ana' = A, second 'bob' = B (event 'enter')."""
    from rvr_addon.io.exr import write_exr

    frames, maps, box_b = frames_of(n, t_enter, seed)
    (folder / "input").mkdir(parents=True, exist_ok=True)
    (folder / "gt" / "disparity").mkdir(parents=True, exist_ok=True)
    for k, (f, d) in enumerate(zip(frames, maps)):
        cv2.imwrite(str(folder / "input" / f"frame_{k + 1:05d}.png"), f[..., ::-1])
        write_exr(folder / "gt" / "disparity" / f"frame_{k + 1:05d}.exr", {"D": d})

    def per_frame(box, disp, visible):
        return [{"frame": k + 1, "box": list(box) if visible(k) else [0.0, 0.0, 0.0, 0.0],
                 "visible": 1.0 if visible(k) else 0.0, "point": [box[0] + box[2] / 2, box[1] + box[3] / 3],
                 "disparity": disp, "depth_m": 3.0, "face_in_frame": visible(k)} for k in range(n)]

    events = []
    if t_enter is not None:
        events.append({"frame": t_enter + 1, "index": t_enter, "type": "enter", "subject": "bob",
                       "box": list(box_b), "point": [box_b[0] + 6, box_b[1] + 4], "disparity": 0.0,
                       "depth_m": 3.0, "detail": {}})
    manifest = {
        "format": "rvr-laaf-harness/1", "config": {"seed": seed, "script": script, "frames": n, "width": W,
                                                   "height": H, "fps": 24, "dof": False},
        "frames": n, "width": W, "height": H, "fps": 24, "config_hash": f"fake{seed}",
        "scene": {"main": "ana", "second": "bob"},
        "subjects": {"ana": {"per_frame": per_frame(BOX_A, 1.0, lambda k: True)},
                     "bob": {"per_frame": per_frame(box_b, 0.0, lambda k: t_enter is not None and k >= t_enter)}},
        "events": events, "status": {"complete": True, "frames_done": n},
    }
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=1))
    (folder / "events.json").write_text(json.dumps(events, indent=1))
    return folder
