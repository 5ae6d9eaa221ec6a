"""Readers for the real RGB-D videos with camera poses in ``../shared/data/real_video_depth``
(development and validation of the depth cues on real footage; nothing here is shipped data).

Two layouts are recognised by their files:

- **HoloLens** (deep-video-mvs sample): ``images/NNNNN.png`` and ``depth/NNNNN.png`` (uint16 mm,
  0 = unknown), ``poses.txt`` (one 4x4 camera-to-world matrix per row, row-major, 16 numbers),
  ``K.txt`` (3x3 intrinsics in px of the images).
- **TUM RGB-D**: ``rgb/<timestamp>.png``, ``depth/<timestamp>.png`` (uint16, /5000 = m, 0 =
  unknown), ``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``, camera-to-world, m).
  Depth and pose are matched to each RGB frame by the nearest timestamp. The intrinsics are
  the Freiburg 1 camera's (:data:`TUM_FR1_K`).

Every frame comes as :class:`RGBDFrame`: RGB uint8, depth in m (NaN = unknown), camera-to-world.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

TUM_FR1_K = np.array([[517.3, 0.0, 318.6], [0.0, 516.5, 255.3], [0.0, 0.0, 1.0]])
"""Intrinsics (px) of TUM RGB-D's Freiburg 1 sequences at 640x480."""
TUM_DEPTH_SCALE = 5000.0
"""TUM depth PNG units per metre."""
HOLOLENS_DEPTH_SCALE = 1000.0
"""HoloLens depth PNG units per metre (mm)."""
MAX_TIME_GAP_S = 0.03
"""Largest RGB-to-depth / RGB-to-pose timestamp gap accepted for a TUM frame (s)."""


@dataclass
class RGBDFrame:
    """One frame: ``rgb`` (H, W, 3) uint8, ``depth_m`` (H, W) float32 m (NaN = unknown),
    ``cam_to_world`` (4, 4) float64 (m), ``name`` the image file's stem."""

    rgb: np.ndarray
    depth_m: np.ndarray
    cam_to_world: np.ndarray
    name: str

    @property
    def inverse_depth(self) -> np.ndarray:
        """Ground-truth inverse depth 1/z (1/m), NaN where the depth is unknown."""
        return (1.0 / self.depth_m).astype(np.float32)


@dataclass
class RGBDClip:
    """A clip's file list: ``images``, ``depths`` (paths, matched), ``poses`` (N, 4, 4)
    camera-to-world, ``K`` (3, 3) px, ``depth_scale`` (PNG units per m)."""

    root: Path
    images: list[Path]
    depths: list[Path]
    poses: np.ndarray
    K: np.ndarray
    depth_scale: float

    def __len__(self) -> int:
        return len(self.images)

    def frame(self, i: int) -> RGBDFrame:
        """Frame ``i`` read from disk."""
        bgr = cv2.imread(str(self.images[i]), cv2.IMREAD_COLOR)
        raw = cv2.imread(str(self.depths[i]), cv2.IMREAD_UNCHANGED)
        if bgr is None or raw is None:
            raise OSError(f"cannot read frame {i} of '{self.root}' ({self.images[i].name}); re-copy the data set")
        depth = raw.astype(np.float32) / np.float32(self.depth_scale)
        depth[raw == 0] = np.nan
        return RGBDFrame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), depth, self.poses[i].copy(), self.images[i].stem)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[RGBDFrame]:
        """Frames start..stop-1, read one at a time."""
        for i in range(start, len(self) if stop is None else min(stop, len(self))):
            yield self.frame(i)

    def rgb_frames(self, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
        """The RGB frames alone (H, W, 3) uint8, one at a time (a cue's input)."""
        for f in self.frames(start, stop):
            yield f.rgb


def quaternion_to_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """(3, 3) rotation of a unit quaternion (Hamilton, x y z w)."""
    q = np.array([qw, qx, qy, qz], np.float64)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _stamps(files: list[Path]) -> np.ndarray:
    return np.array([float(f.stem) for f in files])


def _nearest(sorted_t: np.ndarray, t: float) -> int:
    i = int(np.searchsorted(sorted_t, t))
    cands = [j for j in (i - 1, i) if 0 <= j < len(sorted_t)]
    return min(cands, key=lambda j: abs(sorted_t[j] - t))


def _open_tum(root: Path) -> RGBDClip:
    rgbs = sorted((root / "rgb").glob("*.png"))
    deps = sorted((root / "depth").glob("*.png"))
    rows = [line.split() for line in (root / "groundtruth.txt").read_text().splitlines()
            if line.strip() and not line.startswith("#")]
    gt = np.array(rows, np.float64)
    gt = gt[np.argsort(gt[:, 0])]
    dt = _stamps(deps)
    images, depths, poses = [], [], []
    for f, t in zip(rgbs, _stamps(rgbs)):
        j, k = _nearest(dt, t), _nearest(gt[:, 0], t)
        if abs(dt[j] - t) > MAX_TIME_GAP_S or abs(gt[k, 0] - t) > MAX_TIME_GAP_S:
            continue
        pose = np.eye(4)
        pose[:3, :3] = quaternion_to_matrix(*gt[k, 4:8])
        pose[:3, 3] = gt[k, 1:4]
        images.append(f)
        depths.append(deps[j])
        poses.append(pose)
    return RGBDClip(root, images, depths, np.array(poses).reshape(-1, 4, 4), TUM_FR1_K.copy(), TUM_DEPTH_SCALE)


def _open_hololens(root: Path) -> RGBDClip:
    images = sorted((root / "images").glob("*.png"))
    depths = [root / "depth" / f.name for f in images]
    poses = np.loadtxt(root / "poses.txt").reshape(-1, 4, 4)
    if len(poses) != len(images):
        raise ValueError(f"'{root}': {len(images)} images but {len(poses)} poses in poses.txt")
    return RGBDClip(root, images, depths, poses, np.loadtxt(root / "K.txt").reshape(3, 3),
                    HOLOLENS_DEPTH_SCALE)


def open_rgbd_clip(root: str | Path) -> RGBDClip:
    """Open a real RGB-D clip folder (HoloLens or TUM layout, see the module docstring)."""
    root = Path(root)
    if (root / "poses.txt").is_file() and (root / "images").is_dir():
        return _open_hololens(root)
    if (root / "groundtruth.txt").is_file() and (root / "rgb").is_dir():
        return _open_tum(root)
    raise FileNotFoundError(f"'{root}' is neither a HoloLens (images/, depth/, poses.txt, K.txt) nor a "
                            "TUM RGB-D (rgb/, depth/, groundtruth.txt) folder; check the path")
