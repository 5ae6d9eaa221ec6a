"""Real pictures with measured depth (``../shared/data/real_depth``): listing and reading.

Used to train the estimator on real pictures (``rvr train --real DIR``) and to score any depth
method on them (``rvr eval-estimator --real-set DIR``). The layouts (README of the data folder):

```
middlebury2006/<Scene>/view1.png view5.png disp1.png disp5.png   disparity px, uint8, 0 unknown
middlebury2001_2003/<scene>/imL.png groundtruth.png               disparity x 4/8/16, 0 unknown
kinect/ch7_{1,2}.png + ch7_{1,2}_depth.png                          depth uint16 / 5000 = m
kinect/RGBD_other_formats_TUM_color.png + _depth.png                depth uint16 (scale irrelevant)
kinect/RGBD_other_formats_SUN_color.jpg + _depth.png                SUN RGB-D: depth uint16 rotated by 3 bits
kinect/RGBD_other_formats_NYU_color.ppm + _depth.pgm                raw Kinect disparity, big-endian
```

Every ground truth is returned as an **inverse depth up to a positive scale** ``q`` (stereo
disparity as it is; 1 / depth for depth sensors; the NYU raw Kinect value ``v`` as
``1092.5 - v``, which its toolbox maps to depth by ``351.3 / (1092.5 - v)``; SUN RGB-D's value
``v`` as ``1 / ((v >> 3) | (v << 13))``, its toolbox's bit rotation), NaN where unknown.
Our disparity D grows away from the camera, so ``D = -s q + t`` for some s > 0: training targets
are ``-q`` aligned by a positive scale and a shift. The unit of leave-scene-out validation is
the *scene* (Middlebury's two views of one scene are one scene).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

NYU_RAW_OFFSET = 1092.5
"""NYU-Depth v2 toolbox: depth_m = 351.3 / (1092.5 - raw) for the byte-swapped raw Kinect value."""
HELD_OUT = ("motorcycle",)
"""Never trained on (the long-standing test picture; it ships with scikit-image, not here)."""


@dataclass(frozen=True)
class RealPicture:
    """One real view and its measured ground truth.

    name: unique, ``set/scene/view`` (e.g. ``middlebury2006/Aloe/view1``).
    scene: the leave-scene-out unit, ``set/scene``.
    image: RGB file; truth: ground-truth file; truth_kind: ``disparity`` (stored value / scale is
        an inverse depth up to scale), ``depth`` (stored value is a depth), ``sun_depth`` or ``nyu_raw``.
    """

    name: str
    scene: str
    image: Path
    truth: Path
    truth_kind: str
    set: str


def _middlebury2006(root: Path) -> list[RealPicture]:
    out = []
    for scene in sorted(p for p in root.iterdir() if p.is_dir()):
        for view, disp in (("view1", "disp1"), ("view5", "disp5")):
            img, gt = scene / f"{view}.png", scene / f"{disp}.png"
            if img.is_file() and gt.is_file():
                out.append(RealPicture(f"middlebury2006/{scene.name}/{view}", f"middlebury2006/{scene.name}",
                                       img, gt, "disparity", "middlebury2006"))
    return out


def _middlebury2001(root: Path) -> list[RealPicture]:
    out = []
    for scene in sorted(p for p in root.iterdir() if p.is_dir()):
        img, gt = scene / "imL.png", scene / "groundtruth.png"
        if img.is_file() and gt.is_file():
            out.append(RealPicture(f"middlebury2001_2003/{scene.name}/imL", f"middlebury2001_2003/{scene.name}",
                                   img, gt, "disparity", "middlebury2001_2003"))
    return out


def _kinect(root: Path) -> list[RealPicture]:
    out = []
    for img in sorted(root.iterdir()):
        stem = img.stem
        if stem.endswith("_depth"):
            continue
        if stem.endswith("_color"):
            base = stem[: -len("_color")]
            cands = [root / f"{base}_depth.png", root / f"{base}_depth.pgm"]
        else:
            base = stem
            cands = [root / f"{stem}_depth.png"]
        gt = next((c for c in cands if c.is_file()), None)
        if gt is None:
            continue
        kind = "nyu_raw" if gt.suffix == ".pgm" else "sun_depth" if "_SUN" in base else "depth"
        # the two ch7 frames are one desk seen twice: one scene
        scene = "kinect/ch7" if base.startswith("ch7_") else f"kinect/{base}"
        out.append(RealPicture(f"kinect/{base}", scene, img, gt, kind, "kinect"))
    return out


_SETS = {"middlebury2006": _middlebury2006, "middlebury2001_2003": _middlebury2001, "kinect": _kinect}


def find_real_pictures(root: str | Path, sets: tuple[str, ...] | None = None) -> list[RealPicture]:
    """Every real picture with ground truth under ``root`` (a ``real_depth`` folder, or one of its
    set folders), sorted by name. Raises InputError naming the folder when it holds none."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"real depth folder '{root}' does not exist; give ../shared/data/real_depth "
                         "(or one of its middlebury2006 / middlebury2001_2003 / kinect folders)")
    found: list[RealPicture] = []
    if root.name in _SETS:
        found = _SETS[root.name](root)
    else:
        for name, lister in _SETS.items():
            if (root / name).is_dir() and (sets is None or name in sets):
                found += lister(root / name)
    found = [p for p in found if p.scene.split("/")[-1].lower() not in HELD_OUT]
    if not found:
        raise InputError(f"no real pictures with ground truth under '{root}' (expected middlebury2006/<Scene>/"
                         "view1.png + disp1.png, middlebury2001_2003/<scene>/imL.png + groundtruth.png or "
                         "kinect/<name>.png + <name>_depth.png)")
    return sorted(found, key=lambda p: p.name)


def read_image(pic: RealPicture) -> np.ndarray:
    """(H, W, 3) uint8 RGB of the picture. InputError naming the file if unreadable."""
    import cv2

    bgr = cv2.imread(str(pic.image), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError(f"cannot read the real picture {pic.image}")
    return np.ascontiguousarray(bgr[..., ::-1])


def read_inverse_depth(pic: RealPicture) -> np.ndarray:
    """(H, W) float32 inverse depth up to a positive scale (larger = nearer), NaN where unknown."""
    import cv2

    raw = cv2.imread(str(pic.truth), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.ndim != 2:
        raise InputError(f"cannot read the ground truth {pic.truth} as a one-channel image")
    v = raw.astype(np.float64)
    if pic.truth_kind == "disparity":
        q = np.where(v > 0, v, np.nan)
    elif pic.truth_kind == "depth":
        q = np.where(v > 0, 1.0 / np.maximum(v, 1e-9), np.nan)
    elif pic.truth_kind == "sun_depth":
        r = raw.astype(np.uint16)
        v = ((r >> 3) | (r << 13)).astype(np.float64)
        q = np.where(v > 0, 1.0 / np.maximum(v, 1e-9), np.nan)
    elif pic.truth_kind == "nyu_raw":
        if raw.dtype == np.uint16 and np.median(v) > 2048:  # stored big-endian
            v = raw.byteswap().astype(np.float64)
        q = np.where((v > 0) & (v < NYU_RAW_OFFSET - 1), NYU_RAW_OFFSET - v, np.nan)
    else:
        raise InputError(f"unknown ground-truth kind {pic.truth_kind!r} for {pic.truth}")
    q = q.astype(np.float32)
    if np.isfinite(q).sum() < 2:
        raise InputError(f"the ground truth {pic.truth} has no valid pixel")
    return q


MIDDLEBURY_2001_SCALE = {"cones": 4.0, "teddy": 4.0, "venus": 8.0, "tsukuba": 16.0}
"""Stored value per px of disparity in Middlebury 2001/2003's groundtruth.png."""
KINECT_FOCAL_PX = 525.0
"""A Kinect's focal length in px at 640 px width (the stereo-like disparity of depth sensors)."""
KINECT_BASELINE_M = 0.075
"""A Kinect's projector-camera baseline (m)."""
_METRES_PER_UNIT = {"depth": 1.0 / 5000.0, "sun_depth": 1.0 / 1000.0}


def disparity_scale(pic: RealPicture) -> float:
    """Factor from :func:`read_inverse_depth` to a stereo disparity in px at the picture's width:
    Middlebury's own disparity (2001/2003 divided by its stored scale); for depth sensors the
    disparity a Kinect's own stereo pair would see (focal 525 px at 640 px width, baseline 7.5 cm),
    so every real picture's target is in the same unit and weighs by its depth contrast."""
    if pic.truth_kind == "disparity":
        return 1.0 / MIDDLEBURY_2001_SCALE.get(pic.scene.split("/")[-1], 1.0) \
            if pic.set == "middlebury2001_2003" else 1.0
    import cv2

    width = cv2.imread(str(pic.image), cv2.IMREAD_UNCHANGED).shape[1]
    fb = KINECT_FOCAL_PX * width / 640.0 * KINECT_BASELINE_M
    if pic.truth_kind == "nyu_raw":  # q = 1092.5 - raw, depth = 351.3 / q m
        return fb / 351.3
    return fb / _METRES_PER_UNIT[pic.truth_kind]  # q = 1 / stored value, stored = depth / (m per unit)


def scene_folds(pictures: list[RealPicture], folds: int) -> list[list[str]]:
    """Scenes split into ``folds`` groups for leave-scene-out validation (round robin over the
    sorted scene names, so each fold mixes the sets)."""
    scenes = sorted({p.scene for p in pictures})
    if folds < 1:
        raise InputError(f"need at least one fold, got {folds}")
    return [scenes[k::folds] for k in range(min(folds, len(scenes)))]
