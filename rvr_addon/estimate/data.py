"""Training samples for the RGBD-HDR estimator: harness clips and a user's bracketed photos.

A sample is one deep-DOF input and the large-aperture image(s) our renderer must reproduce
from it, each with the affine factors ``(alpha, beta)`` of its signed blur radius
``alpha * D + beta`` (px at the source's native width; DATASET.md "Training sidecar").

**(a) Harness clips** (``sintel_eval/DATASET.md``, format ``rvr-laaf-harness/*``): every folder
under a dataset root holding such a ``manifest.json`` is a clip. Its ``train/frame_%05d.json``
sidecars give the input (the pinhole deep-DOF PNG) and the members (``large``, ``mid``,
``small``, ``focusB``: Cycles renders, 8-bit sRGB PNG, with the exact focus disparity and
aperture scale of the lens, so ``alpha = a``, ``beta = -a f`` are exact for our renderer).
A frame is used only when its done marker is valid (exists, carries the manifest's
``config_hash``, and lists files that exist with their sizes); others are skipped and counted.
Each draw picks one of the frame's sample kinds with equal probability:

* ``pair``: input -> ``large`` (L_rend counted twice);
* ``aperture`` triplet: input -> ``large`` + one of the other apertures (``mid`` or ``small``),
  same focus, disparity *scaled*;
* ``focal`` triplet: input -> ``large`` + ``focusB``, same aperture, disparity *shifted*.

* ``gt`` (ours): frames of clips without training sidecars (``generate --no-dof`` or
  ``--train-every 0``: the deep pass alone, ~6x cheaper to render) carry no shallow-DOF image,
  only the ground truth below; they train the supervised terms alone. A draw takes such a frame
  with probability ``gt_share`` (when both kinds of source exist), so cheap, varied scenes teach
  disparity and HDR while the triplets keep the paper's rendering loss.

Harness samples also carry the frame's ground truth for the supervised terms (ours, see
:mod:`.losses`): ``gt/disparity`` (channel D, px at the native width) resampled by exact
nearest neighbour (never a blend of a foreground and a background depth) and multiplied by the
width ratio like beta, and ``gt/hdr`` (linear radiance) resampled in linear light exactly like
the input (area when shrinking), from which the target exponent ``E_gt = max(ln(L_hdr /
L_lin), 0) / 50`` and the saturated mask (brightest input channel >= 254/255) are computed on
the resized, cropped, flipped input itself (:func:`exponent_target`). Photos have none.

**Procedural datasets** (ours, ``rvr procedural``, :mod:`.procedural`; format
``rvr-laaf-procedural/*``, the harness's file layout): every complete frame is a kind ``gt``
source of origin ``procedural`` whose D is known only up to a positive scale and a shift
(``disparity_invariant``: no lens); ``rvr train --data`` finds them next to harness clips and
draws them with probability ``procedural_share``. ``degrade`` (``--degrade``) makes that share
of ground-truth-only inputs look like phone footage (blur, noise, JPEG), targets unchanged.

``ignore_prints`` (``rvr train --ignore-prints``): the harness's photo prints (its billboards
and poster panels: whole photographs of real scenes on flat boards) get no disparity
supervision: their pixels of the ground truth are NaN (by the ``ID`` channel of
``gt/disparity`` and the manifest's ``object_ids``). Supervised there, the network learns that
a photograph of a scene is flat, and real footage is exactly that: a photograph of a scene.
They still train the HDR terms and the rendering loss.

**(b) A user's aperture-bracketed photos** (a DSLR with Magic Lantern, a phone's "pro" mode):
a folder of shots, each either flat files ``NAME_small.EXT`` + ``NAME_large.EXT``
[+ ``NAME_medium.EXT``] [+ ``NAME_focusB.EXT``] [+ ``NAME.json``], or a sub-folder per shot
holding ``small.EXT``, ``large.EXT`` [, ``medium.EXT``, ``focusB.EXT``, ``shot.json``]; EXT is
jpg/jpeg/png/tif/tiff (any case). ``small`` is the deep-DOF input (e.g. f/22), ``large`` the
wide aperture (f/2), ``medium`` a middle aperture (f/8, an aperture triplet), ``focusB`` the wide
aperture focused elsewhere (a focal triplet). Every other shot is warped onto ``small`` with ECC
(:mod:`.align`) and the shot is cropped to the pixels all of them cover.

The absolute focus disparity and aperture scale of a user's lens are unknown, and are not
learnt: by definition ``large`` has ``alpha = 1, beta = 0`` (focus 0: the focal plane of the
bracket is the disparity origin, and the disparity unit is that lens's blur at the large
aperture). ``medium`` has ``alpha = N_large / N_medium`` (the ratio of aperture diameters),
``beta = 0``; the f-numbers come from the optional JSON (``{"f_number": {"small": 22,
"medium": 8, "large": 2}}``) or else from the EXIF ``FNumber`` of the files. ``focusB`` needs
its shift in the JSON (``{"focusB": {"alpha": 1.0, "beta": -3.5}}``, beta in px of blur radius at
the photo's original width); without it the image is not used. A shot with a missing partner
image or a failed alignment is skipped with a warning and counted (:class:`SkipReport`), never
stopping the run. Aligned shots are cached (downscaled to ``max_side`` px) in a folder of the
training run, keyed by the source files' size and mtime.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from ..color import linear_to_srgb, srgb_to_linear
from ..depth.cues import blur_span
from ..errors import InputError
from ..io.paths import natural_key, temp_sibling

log = logging.getLogger(__name__)

HARNESS_FORMAT = "rvr-laaf-harness/"
PHOTO_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
PHOTO_ROLES = ("small", "large", "medium", "focusB")
KINDS = ("pair", "aperture", "focal", "gt")
_SIDECAR = re.compile(r"frame_(\d+)\.json$")
SATURATED = 254.0 / 255.0
"""An input pixel whose brightest channel reaches this sRGB value is clipped (saturated)."""
LINEAR_FLOOR = 1e-3
"""Linear radiance floor in the ratio L_hdr / L_lin of the ground-truth exponent (dark channels)."""
_FNUMBER_TAG = 0x829D
_EXIF_IFD = 0x8769


# ------------------------------------------------------------------------------ records


@dataclass(frozen=True)
class Member:
    """One shallow-DOF image of a sample: 8-bit sRGB file, signed radius ``alpha * D + beta`` px
    (beta at the sample's native width)."""

    path: Path
    alpha: float
    beta: float


@dataclass(frozen=True)
class SampleSource:
    """One training frame or shot: the input, its members by name, and which kinds it supports.

    native_width: width in px of the input file (beta is in px at this width).
    third: names of the members usable as the third image, by kind (``aperture`` / ``focal``).
    gt_disparity, gt_hdr: harness ground truth of the input (``gt/disparity`` EXR, channel D in
        px at the native width; ``gt/hdr`` EXR, linear radiance R, G, B), None for photos.
    unsupervised_ids: object IDs (channel ID of gt_disparity) whose disparity is not supervised.
    disparity_invariant: the ground-truth D is known only up to a positive scale and a shift
        (procedural frames: no lens; real pictures); the loss fits them per sample.
    """

    name: str
    origin: str  # "harness" or "photos"
    input: Path
    members: dict[str, Member]
    native_width: int
    third: dict[str, tuple[str, ...]]
    gt_disparity: Path | None = None
    gt_hdr: Path | None = None
    unsupervised_ids: tuple[int, ...] = ()
    disparity_invariant: bool = False
    truth_kind: str | None = None
    """Real pictures (origin ``real``): how ``gt_disparity`` stores its ground truth
    (:class:`.real_data.RealPicture`); None for the harness's EXR."""
    truth_scale: float = 1.0
    """Real pictures: factor from the stored inverse depth to a stereo disparity in px at the
    native width (:func:`.real_data.disparity_scale`)."""

    @property
    def kinds(self) -> tuple[str, ...]:
        """The sample kinds this source supports: ``pair`` [+ triplets], or ``gt`` alone for a
        frame with ground truth and no shallow-DOF member."""
        if "large" not in self.members:
            return ("gt",)
        return ("pair",) + tuple(k for k in ("aperture", "focal") if self.third.get(k))


@dataclass
class TrainSample:
    """A drawn, resized and cropped sample; arrays are float32 (h, w, 3) sRGB in [0, 1].

    frame_width: the long side in px of the whole resized frame the crop comes from (D_rel -> px;
        its width unless the source is portrait, :func:`..depth.cues.blur_span`).
    alpha, beta: the primary target's factors, beta in px at the working resolution (kind ``gt``:
        no target; ``target`` is the input, unused).
    adjusted: (third image, alpha, beta) of a triplet, or None for a pair.
    gt_disparity: (h, w) float32 ground-truth D in px at the working resolution (``frame_width``),
        NaN where unknown; None without ground truth (photos).
    gt_exponent: (h, w, 3) float32 ground-truth E (eq. 3) of the cropped input:
        ``max(ln(L_hdr / L_lin), 0) / 50`` per channel (``L_lin`` = the linearised input); None
        without ground truth.
    saturated: (h, w) bool, the input's brightest channel >= ``SATURATED`` (clipped pixels).
    native_width: width in px of the source file (to report D errors in DESIGN units).
    disparity_invariant: supervise D up to a positive scale and a shift (procedural frames).
    """

    name: str
    kind: str
    image: np.ndarray
    target: np.ndarray
    alpha: float
    beta: float
    frame_width: float
    adjusted: tuple[np.ndarray, float, float] | None = None
    gt_disparity: np.ndarray | None = None
    gt_exponent: np.ndarray | None = None
    saturated: np.ndarray | None = None
    native_width: float | None = None
    disparity_invariant: bool = False


@dataclass
class SkipReport:
    """What was left out and why (counted per reason, messages kept for the log)."""

    counts: Counter = field(default_factory=Counter)
    messages: list[str] = field(default_factory=list)

    def add(self, reason: str, message: str) -> None:
        """Count one skipped item under ``reason`` and warn (the first 20 warnings are logged)."""
        self.counts[reason] += 1
        self.messages.append(message)
        if len(self.messages) <= 20:
            log.warning("%s", message)
        elif len(self.messages) == 21:
            log.warning("more skipped items; the total is reported at the end")

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> str:
        """One line: 'skipped 3: 2 missing partner, 1 alignment failed' (or 'nothing skipped')."""
        if not self.counts:
            return "nothing skipped"
        parts = ", ".join(f"{n} {reason}" for reason, n in sorted(self.counts.items()))
        return f"skipped {self.total}: {parts}"


# ------------------------------------------------------------------------------ image helpers


def read_srgb(path: Path) -> np.ndarray:
    """An image file -> (H, W, 3) float32 sRGB in [0, 1] (8/16-bit, grey, RGBA handled)."""
    from ..color import to_float01
    from ..io.video import read_image_rgb8

    try:
        return to_float01(read_image_rgb8(path))
    except Exception as ex:  # VideoOpenError names the file
        raise InputError(str(ex)) from ex


def resize_linear(srgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize an sRGB float image to size (width, height) in linear light (area when shrinking)."""
    import cv2

    if (srgb.shape[1], srgb.shape[0]) == tuple(size):
        return srgb
    interp = cv2.INTER_AREA if size[0] < srgb.shape[1] else cv2.INTER_LINEAR
    lin = cv2.resize(srgb_to_linear(srgb), size, interpolation=interp)
    return linear_to_srgb(lin).astype(np.float32)


def resize_disparity(disparity: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resample a disparity map to size (width, height) by exact (pixel-centre) nearest neighbour.

    Values are not rescaled (the caller multiplies by the width ratio). Nearest neighbour never
    averages a foreground and a background depth into a value that is on neither surface.
    """
    import cv2

    if (disparity.shape[1], disparity.shape[0]) == tuple(size):
        return disparity
    return cv2.resize(disparity, size, interpolation=cv2.INTER_NEAREST_EXACT)


def resize_radiance(radiance: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize linear radiance (H, W, 3) to size (width, height) like :func:`resize_linear` does the
    input (area when shrinking, bilinear when enlarging), so the two stay consistent."""
    import cv2

    if (radiance.shape[1], radiance.shape[0]) == tuple(size):
        return radiance
    interp = cv2.INTER_AREA if size[0] < radiance.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(radiance, size, interpolation=interp)


def read_gt_disparity(path: Path, size: tuple[int, int] | None = None, ignore_ids: tuple[int, ...] = ()) -> np.ndarray:
    """Channel D of a harness ``gt/disparity`` EXR, (H, W) float32, non-finite values as NaN.

    size: the expected (width, height); InputError naming the file when it differs.
    ignore_ids: object IDs (channel ID) whose pixels become NaN (not supervised).
    """
    from ..io.exr import read_exr

    ch = read_exr(path)
    if "D" not in ch:
        raise InputError(f"ground-truth disparity {path} has no channel D (it has {', '.join(sorted(ch))})")
    d = np.asarray(ch["D"], dtype=np.float32)
    if size is not None and (d.shape[1], d.shape[0]) != tuple(size):
        raise InputError(f"ground-truth disparity {path} is {d.shape[1]}x{d.shape[0]}, the input {size[0]}x{size[1]}")
    keep = np.isfinite(d)
    if ignore_ids:
        if "ID" not in ch:
            raise InputError(f"ground-truth disparity {path} has no channel ID, needed to leave the prints out "
                             "(--ignore-prints); regenerate the clip or train without --ignore-prints")
        keep &= ~np.isin(np.rint(ch["ID"]).astype(np.int64), np.asarray(ignore_ids, np.int64))
    return np.where(keep, d, np.nan).astype(np.float32)


PRINT_OBJECTS = ("billboards", "panel_")
"""Names (or name prefixes, ending in _) of the harness objects that are photo prints."""


def print_ids(manifest: dict) -> tuple[int, ...]:
    """Object IDs of the photo prints of a harness clip (its manifest's ``object_ids``)."""
    ids = []
    for key, name in (manifest.get("object_ids") or {}).items():
        name = str(name)
        if any(name.startswith(p) if p.endswith("_") else name == p for p in PRINT_OBJECTS):
            ids.append(int(key))
    return tuple(sorted(ids))


def read_gt_radiance(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Channels R, G, B of a harness ``gt/hdr`` EXR, (H, W, 3) float32 linear radiance.

    Non-finite or negative values become 0. size as in :func:`read_gt_disparity`.
    """
    from ..io.exr import read_exr

    ch = read_exr(path)
    if not all(c in ch for c in "RGB"):
        raise InputError(f"ground-truth HDR {path} lacks channels R, G, B (it has {', '.join(sorted(ch))})")
    rad = np.dstack([ch["R"], ch["G"], ch["B"]]).astype(np.float32)
    if size is not None and (rad.shape[1], rad.shape[0]) != tuple(size):
        raise InputError(f"ground-truth HDR {path} is {rad.shape[1]}x{rad.shape[0]}, the input {size[0]}x{size[1]}")
    return np.where(np.isfinite(rad), np.maximum(rad, 0.0), 0.0).astype(np.float32)


def exponent_target(srgb: np.ndarray, radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth HDR exponent of an input and its true radiance (same size).

    srgb: (H, W, 3) the input, sRGB in [0, 1]; radiance: (H, W, 3) linear HDR radiance.
    Returns (E (H, W, 3) float32 = ``max(ln(L_hdr / max(L_lin, 1e-3)), 0) / 50`` per channel,
    saturated (H, W) bool = brightest input channel >= 254/255). E is returned everywhere; the
    loss uses it on saturated pixels and only its near-zero values elsewhere (a resized pixel
    that mixes a clipped light with its surround has E > 0 without reaching 254).
    """
    from ..render.model import K_HDR

    lin = np.maximum(srgb_to_linear(srgb.astype(np.float32)), LINEAR_FLOOR)
    e = np.log(np.maximum(radiance, LINEAR_FLOOR) / lin)
    e = np.maximum(e, 0.0) / K_HDR
    return e.astype(np.float32), srgb.max(axis=-1) >= SATURATED


# ------------------------------------------------------------------------------ (a) harness


def find_harness_clips(root: str | Path) -> list[Path]:
    """Every folder at or under ``root`` holding a manifest.json of format ``rvr-laaf-harness/*``.

    Does not descend into a clip. Raises InputError if ``root`` is not a folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"Training data folder '{root}' does not exist; pass a folder written by "
                         "`python -m sintel_eval generate -o DIR` (or a folder of such folders).")
    return _find_datasets(root, HARNESS_FORMAT)


def _find_datasets(root: Path, prefix: str) -> list[Path]:
    """Folders at or under ``root`` whose manifest.json has a ``format`` starting with ``prefix``
    (naturally sorted); a found folder is not descended into, hidden folders are skipped."""
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        if "manifest.json" in filenames:
            try:
                fmt = json.loads((Path(dirpath) / "manifest.json").read_text()).get("format", "")
            except (OSError, ValueError, AttributeError):
                fmt = ""
            if isinstance(fmt, str) and fmt.startswith(prefix):
                found.append(Path(dirpath))
                dirnames[:] = []
                continue
        dirnames[:] = [d for d in dirnames if not d.startswith(".")]
    return sorted(found, key=natural_key)


def _marker_sizes(marker: dict) -> dict[str, int | None]:
    files = marker.get("files", {})
    out: dict[str, int | None] = {}
    if isinstance(files, dict):
        for k, v in files.items():
            size = v.get("size", v.get("bytes")) if isinstance(v, dict) else v
            out[str(k)] = None if size is None else int(size)
    else:
        for item in files or []:
            if isinstance(item, str):
                out[item] = None
            elif isinstance(item, dict) and "path" in item:
                size = item.get("size", item.get("bytes"))
                out[str(item["path"])] = None if size is None else int(size)
    return out


def frame_complete(clip: Path, frame: int, config_hash: str | None) -> str | None:
    """None if frame ``frame`` of the clip is complete (DATASET.md), else the reason."""
    done = clip / "done" / f"frame_{frame:05d}.json"
    try:
        marker = json.loads(done.read_text())
    except FileNotFoundError:
        return f"done marker {done} is missing"
    except (OSError, ValueError) as ex:
        return f"done marker {done} is unreadable ({ex})"
    if config_hash is not None and marker.get("config_hash") != config_hash:
        return f"done marker {done} belongs to another configuration"
    for rel, size in _marker_sizes(marker).items():
        p = clip / rel
        if not p.is_file():
            return f"{p} (listed in {done}) is missing"
        if size is not None and p.stat().st_size != size:
            return f"{p} has {p.stat().st_size} bytes, its done marker says {size}"
    return None


def _member(clip: Path, name: str, rec: dict, sidecar: Path) -> Member:
    try:
        path = clip / str(rec["png"])
        alpha, beta = float(rec["alpha"]), float(rec["beta"])
    except (KeyError, TypeError, ValueError) as ex:
        raise InputError(f"member {name!r} of {sidecar} lacks png/alpha/beta ({ex})") from None
    if not (math.isfinite(alpha) and math.isfinite(beta) and alpha > 0):
        raise InputError(f"member {name!r} of {sidecar} has alpha {alpha}, beta {beta}")
    if not path.is_file():
        raise InputError(f"{path} (member {name!r} of {sidecar}) is missing")
    return Member(path, alpha, beta)


def harness_sources(root: str | Path, report: SkipReport, ignore_prints: bool = False,
                    clips: list[Path] | None = None) -> list[SampleSource]:
    """Training sources of every harness clip under ``root`` (see the module docstring).

    Incomplete frames and malformed sidecars are skipped and counted in ``report``.
    ignore_prints: leave the photo prints out of the disparity supervision (module docstring).
    clips: :func:`find_harness_clips` of ``root`` when the caller has already walked it.
    Raises InputError when ``root`` holds no harness clip.
    """
    clips = find_harness_clips(root) if clips is None else clips
    if not clips:
        raise InputError(f"'{root}' holds no harness clip (no manifest.json of format '{HARNESS_FORMAT}...' in it "
                         "or its sub-folders); generate clips with `python -m sintel_eval generate -o DIR`.")
    sources: list[SampleSource] = []
    for clip in clips:
        manifest = json.loads((clip / "manifest.json").read_text())
        config_hash = manifest.get("config_hash")
        width = int((manifest.get("config") or {}).get("width") or 0) or None
        train = clip / "train"
        sidecars = sorted((p for p in train.glob("frame_*.json") if _SIDECAR.search(p.name)), key=natural_key) \
            if train.is_dir() else []
        ignore = print_ids(manifest) if ignore_prints else ()
        if not sidecars:
            sources += _ground_truth_sources(clip, manifest, config_hash, width, report, ignore)
            continue
        for sidecar in sidecars:
            frame = int(_SIDECAR.search(sidecar.name).group(1))
            reason = frame_complete(clip, frame, config_hash)
            if reason:
                report.add("incomplete frame", f"training frame {frame} of {clip} is incomplete ({reason}); skipped")
                continue
            try:
                sources.append(_harness_source(clip, frame, sidecar, width, ignore))
            except (InputError, OSError, ValueError) as ex:
                report.add("bad sidecar", f"training frame {frame} of {clip}: {ex}; skipped")
    return sources


def _ground_truth_sources(clip: Path, manifest: dict, config_hash: str | None, width: int | None,
                          report: SkipReport, unsupervised_ids: tuple[int, ...] = ()) -> list[SampleSource]:
    """Kind ``gt`` sources: every complete frame of a clip without training sidecars that has
    its input, ``gt/disparity`` and ``gt/hdr``."""
    frames = int((manifest.get("config") or {}).get("frames") or 0)
    found: list[SampleSource] = []
    for frame in range(1, frames + 1):
        inp = clip / "input" / f"frame_{frame:05d}.png"
        gt_d = clip / "gt" / "disparity" / f"frame_{frame:05d}.exr"
        gt_h = clip / "gt" / "hdr" / f"frame_{frame:05d}.exr"
        reason = frame_complete(clip, frame, config_hash)
        if reason is None and not (inp.is_file() and gt_d.is_file() and gt_h.is_file()):
            reason = "its input or ground-truth disparity/HDR is missing"
        if reason:
            report.add("incomplete frame", f"frame {frame} of {clip} is incomplete ({reason}); skipped")
            continue
        found.append(SampleSource(f"{clip.name}/frame_{frame:05d}", "harness", inp, {},
                                  width or _image_width(inp), {}, gt_d, gt_h, unsupervised_ids))
    if not found:
        report.add("clip without training frames", f"clip {clip} has neither training sidecars nor complete "
                   "ground-truth frames; skipped")
    return found


def find_procedural_sets(root: str | Path) -> list[Path]:
    """Every folder at or under ``root`` holding a manifest.json of format ``rvr-laaf-procedural/*``
    (written by ``rvr procedural``); like :func:`find_harness_clips`, a found folder is not
    descended into and hidden folders are skipped."""
    from .procedural import PROCEDURAL_FORMAT

    return _find_datasets(Path(root), PROCEDURAL_FORMAT.split("/")[0] + "/")


def procedural_sources(folder: Path, report: SkipReport) -> list[SampleSource]:
    """Kind ``gt`` sources of a procedural dataset: every frame with a done marker whose files
    exist with their sizes; D is supervised up to scale and shift (``disparity_invariant``)."""
    manifest = json.loads((folder / "manifest.json").read_text())
    total = int(manifest.get("frames", 0))
    written = [f for f in range(1, total + 1) if (folder / "done" / f"frame_{f:05d}.json").is_file()]
    if len(written) < total:
        report.add("procedural frames not written yet", f"{folder}: {total - len(written)} of {total} frames are "
                   "not written yet (`rvr procedural` still running or stopped: run it again to finish); left out")
    found = []
    for frame in written:
        reason = frame_complete(folder, frame, None)
        if reason:
            report.add("incomplete frame", f"procedural frame {frame} of {folder} is incomplete ({reason}); skipped")
            continue
        name = f"frame_{frame:05d}"
        inp = folder / "input" / f"{name}.png"
        found.append(SampleSource(f"{folder.name}/{name}", "procedural", inp, {}, _image_width(inp), {},
                                  folder / "gt" / "disparity" / f"{name}.exr", folder / "gt" / "hdr" / f"{name}.exr",
                                  disparity_invariant=True))
    return found


def real_sources(root: str | Path, report: SkipReport, exclude: Iterable[str] = ()) -> list[SampleSource]:
    """Kind ``gt`` sources of the real pictures with measured depth under ``root``
    (:mod:`.real_data`; ``rvr train --real``), D supervised up to a positive scale and a shift.

    exclude: scenes to leave out (leave-scene-out validation), as ``set/scene`` or the scene's
    folder name (``middlebury2006/Aloe`` or ``Aloe``); a name that matches nothing is an error."""
    from .real_data import disparity_scale, find_real_pictures

    pictures = find_real_pictures(root)
    wanted = {e.strip().lower() for e in exclude if e.strip()}
    scenes = {p.scene.lower() for p in pictures} | {p.scene.split("/")[-1].lower() for p in pictures}
    unknown = sorted(wanted - scenes)
    if unknown:
        raise InputError(f"--real-exclude {', '.join(unknown)}: no such scene under {root} (scenes are named like "
                         f"{pictures[0].scene} or {pictures[0].scene.split('/')[-1]})")
    found = []
    for pic in pictures:
        if pic.scene.lower() in wanted or pic.scene.split("/")[-1].lower() in wanted:
            continue
        try:
            width = _image_width(pic.image)
        except InputError as ex:
            report.add("unreadable real picture", f"{pic.image}: {ex}; skipped")
            continue
        found.append(SampleSource(pic.name, "real", pic.image, {}, width, {}, pic.truth,
                                  disparity_invariant=True, truth_kind=pic.truth_kind,
                                  truth_scale=disparity_scale(pic)))
    return found


def real_target(path: Path, truth_kind: str, scale: float, size: tuple[int, int]) -> np.ndarray:
    """The training target of a real picture at ``size`` (w, h), in px at the picture's native
    width (the caller rescales to the working width like any disparity): ``-scale * q`` of its
    inverse depth q (our D grows away from the camera; ``scale`` makes it a stereo disparity in
    px, :func:`.real_data.disparity_scale`), NaN where unknown. The loss aligns it by a positive
    scale and a shift, so only its unit matters: a picture weighs by its depth contrast in px.

    (A unitless target, -q / median q, weighs a flat crop like a deep one; on Middlebury's
    leave-scene-out folds it fitted the training scenes far worse: MODEL.md.)"""
    from .real_data import RealPicture, read_inverse_depth

    q = read_inverse_depth(RealPicture(path.stem, path.parent.name, path, path, truth_kind, ""))
    return resize_disparity((-scale * q).astype(np.float32), size)


def training_sources(root: str | Path, report: SkipReport, ignore_prints: bool = False) -> list[SampleSource]:
    """Sources of every harness clip and procedural dataset under ``root`` (``rvr train --data``).

    Raises InputError when ``root`` holds neither."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"Training data folder '{root}' does not exist; pass a folder written by "
                         "`python -m sintel_eval generate -o DIR` or `rvr procedural -o DIR`.")
    sets = find_procedural_sets(root)
    sources = [src for folder in sets for src in procedural_sources(folder, report)]
    clips = find_harness_clips(root)
    if clips or not sets:
        sources += harness_sources(root, report, ignore_prints, clips)
    return sources


def _harness_source(clip: Path, frame: int, sidecar: Path, width: int | None,
                    unsupervised_ids: tuple[int, ...] = ()) -> SampleSource:
    rec = json.loads(sidecar.read_text())
    inp = clip / str(rec.get("input", f"input/frame_{frame:05d}.png"))
    if not inp.is_file():
        raise InputError(f"input {inp} is missing")
    raw = rec.get("members") or {}
    if "large" not in raw:
        raise InputError(f"{sidecar} has no 'large' member")
    members = {name: _member(clip, name, m, sidecar) for name, m in raw.items() if isinstance(m, dict)}
    aperture = tuple(n for n in (rec.get("aperture_triplet") or []) if n in members and n != "large")
    focal = tuple(n for n in (rec.get("focal_triplet") or []) if n in members and n != "large")
    width = width or _image_width(inp)
    gt_d = clip / "gt" / "disparity" / f"frame_{frame:05d}.exr"
    gt_h = clip / "gt" / "hdr" / f"frame_{frame:05d}.exr"
    return SampleSource(f"{clip.name}/frame_{frame:05d}", "harness", inp, members, width,
                        {"aperture": aperture, "focal": focal},
                        gt_d if gt_d.is_file() else None, gt_h if gt_h.is_file() else None, unsupervised_ids)


def _image_width(path: Path) -> int:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"{path} is not a readable image")
    return int(img.shape[1])


# ------------------------------------------------------------------------------ (b) user photos


@dataclass(frozen=True)
class PhotoShot:
    """The files of one bracketed shot (roles small/large/medium/focusB) and its optional JSON."""

    name: str
    files: dict[str, Path]
    settings: Path | None


def _role_of(stem: str) -> tuple[str, str] | None:
    for role in PHOTO_ROLES:
        suffix = "_" + role
        if stem.lower().endswith(suffix.lower()) and len(stem) > len(suffix):
            return stem[: -len(suffix)], role
    return None


def find_photo_shots(folder: str | Path, report: SkipReport) -> list[PhotoShot]:
    """Shots of a bracketed-photo folder (naming in the module docstring).

    A shot without both ``small`` and ``large`` is skipped and counted as "missing partner".
    Raises InputError when the folder does not exist or holds no recognisable image.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"Photo folder '{folder}' does not exist; pass a folder of NAME_small.jpg + NAME_large.jpg "
                         "pairs (or one sub-folder per shot holding small.jpg and large.jpg).")
    groups: dict[str, dict[str, Path]] = {}
    settings: dict[str, Path] = {}
    for entry in sorted(folder.iterdir(), key=natural_key):
        if entry.name.startswith("."):
            continue
        if entry.is_dir():
            files = {}
            for f in entry.iterdir():
                if f.is_file() and f.suffix.lower() in PHOTO_EXTENSIONS and f.stem in PHOTO_ROLES:
                    files[f.stem] = f
            if files:
                groups[entry.name] = files
                if (entry / "shot.json").is_file():
                    settings[entry.name] = entry / "shot.json"
            continue
        if entry.suffix.lower() == ".json":
            settings[entry.stem] = entry
            continue
        if entry.suffix.lower() not in PHOTO_EXTENSIONS:
            continue
        parsed = _role_of(entry.stem)
        if parsed is None:
            report.add("unrecognised file", f"'{entry}' is not named NAME_small/_large/_medium/_focusB; ignored")
            continue
        name, role = parsed
        groups.setdefault(name, {})[role] = entry
    if not groups:
        raise InputError(f"'{folder}' holds no bracketed photos: expected NAME_small.jpg + NAME_large.jpg "
                         "(or sub-folders with small.jpg and large.jpg).")
    shots = []
    for name, files in groups.items():
        missing = [r for r in ("small", "large") if r not in files]
        if missing:
            have = ", ".join(str(p) for p in files.values())
            report.add("missing partner", f"shot '{name}' in {folder} has no {' or '.join(missing)} image "
                                          f"(found {have}); skipped")
            continue
        shots.append(PhotoShot(name, files, settings.get(name)))
    return shots


def exif_f_number(path: Path) -> float | None:
    """FNumber from a photo's EXIF (None when absent or unreadable)."""
    try:
        from PIL import Image

        with Image.open(path) as img:
            value = img.getexif().get_ifd(_EXIF_IFD).get(_FNUMBER_TAG)
        value = float(value) if value is not None else None
    except Exception:  # noqa: BLE001 - EXIF is optional metadata
        return None
    return value if value and math.isfinite(value) and value > 0 else None


def _shot_settings(shot: PhotoShot) -> dict:
    if shot.settings is None:
        return {}
    try:
        data = json.loads(shot.settings.read_text())
    except (OSError, ValueError) as ex:
        raise InputError(f"settings {shot.settings} are not readable JSON ({ex})") from None
    if not isinstance(data, dict):
        raise InputError(f"settings {shot.settings} must be a JSON object")
    return data


def _fingerprint(shot: PhotoShot, max_side: int, motion: str) -> str:
    h = hashlib.sha256(f"{max_side}|{motion}|v1".encode())
    for role in sorted(shot.files):
        st = shot.files[role].stat()
        h.update(f"{role}|{shot.files[role].name}|{st.st_size}|{st.st_mtime_ns}".encode())
    if shot.settings is not None:
        h.update(shot.settings.read_bytes())
    return h.hexdigest()[:16]


def _write_png(path: Path, srgb: np.ndarray) -> None:
    import cv2

    from ..color import to_uint8

    tmp = temp_sibling(path, ".png")
    if not cv2.imwrite(str(tmp), cv2.cvtColor(to_uint8(srgb), cv2.COLOR_RGB2BGR)):
        raise OSError(f"cannot write {path}")
    os.replace(tmp, path)


def prepare_shot(shot: PhotoShot, cache: Path, max_side: int = 1024, motion: str = "homography",
                 report: SkipReport | None = None) -> SampleSource | None:
    """Align one shot onto its small-aperture image, cache it, return its SampleSource.

    Returns None (and counts the reason in ``report``) when alignment fails or a file is
    unreadable. A cached result with the same fingerprint is reused.
    """
    from .align import AlignmentError, ecc_align, inner_rectangle, warp_to_reference

    report = report if report is not None else SkipReport()
    out = cache / re.sub(r"[^A-Za-z0-9_.-]", "_", shot.name)
    try:
        fp = _fingerprint(shot, max_side, motion)
        meta_path = out / "shot.json"
        if meta_path.is_file():
            meta = json.loads(meta_path.read_text())
            if meta.get("fingerprint") == fp and all((out / f"{r}.png").is_file() for r in meta["members"]):
                return _photo_source(shot.name, out, meta)
        settings = _shot_settings(shot)
        images = {role: read_srgb(p) for role, p in shot.files.items()}
    except (InputError, OSError, ValueError, KeyError) as ex:
        report.add("unreadable shot", f"shot '{shot.name}': {ex}; skipped")
        return None
    small = images["small"]
    orig_w = small.shape[1]
    scale = min(1.0, max_side / max(small.shape[:2]))
    size = (max(int(round(small.shape[1] * scale)), 1), max(int(round(small.shape[0] * scale)), 1))
    for role, img in images.items():
        if img.shape[:2] != small.shape[:2]:
            report.add("size mismatch", f"shot '{shot.name}': {shot.files[role]} is {img.shape[1]}x{img.shape[0]}, "
                                        f"the small-aperture image {small.shape[1]}x{small.shape[0]}; skipped")
            return None
        images[role] = resize_linear(img, size)
    valid = np.ones(images["small"].shape[:2], dtype=bool)
    ccs = {}
    for role in ["large"] + [r for r in images if r not in ("small", "large")]:
        try:
            al = ecc_align(images["small"], images[role], motion=motion)
        except AlignmentError as ex:
            what = "skipped" if role == "large" else f"its {role} image is not used"
            report.add("alignment failed", f"shot '{shot.name}': aligning {shot.files[role].name} to "
                                           f"{shot.files['small'].name} failed ({ex}); {what}")
            if role == "large":
                return None
            del images[role]
            continue
        images[role], ok = warp_to_reference(images[role], al, size)
        valid &= ok
        ccs[role] = round(al.cc, 4)
    y0, y1, x0, x1 = inner_rectangle(valid)
    if (y1 - y0) * (x1 - x0) < 0.5 * valid.size:
        report.add("alignment failed", f"shot '{shot.name}': the aligned shots overlap on less than half the frame; "
                                       "skipped")
        return None
    members = {r: v for r, v in _photo_members(shot, settings, report).items() if r in images}
    meta = {"fingerprint": fp, "name": shot.name, "sources": {r: str(p) for r, p in shot.files.items()},
            "original_width": orig_w, "width": x1 - x0, "height": y1 - y0, "scale": scale, "ecc_cc": ccs,
            "members": {}}
    for role, (alpha, beta_orig) in members.items():
        meta["members"][role] = {"alpha": alpha, "beta": beta_orig * scale}
    out.mkdir(parents=True, exist_ok=True)
    for role in ["small", *members]:
        _write_png(out / f"{role}.png", images[role][y0:y1, x0:x1])
    tmp = temp_sibling(meta_path, ".json")
    tmp.write_text(json.dumps(meta, indent=1))
    os.replace(tmp, meta_path)
    return _photo_source(shot.name, out, meta)


def _photo_members(shot: PhotoShot, settings: dict, report: SkipReport) -> dict[str, tuple[float, float]]:
    """{role: (alpha, beta in px at the original width)} of the usable members (large always)."""
    members = {"large": (1.0, 0.0)}
    f_numbers = dict(settings.get("f_number") or {})
    if "medium" in shot.files:
        n_large = f_numbers.get("large") or exif_f_number(shot.files["large"])
        n_medium = f_numbers.get("medium") or exif_f_number(shot.files["medium"])
        if n_large and n_medium and float(n_medium) > 0:
            members["medium"] = (float(n_large) / float(n_medium), 0.0)
        else:
            report.add("medium without f-numbers", f"shot '{shot.name}': the f-numbers of the large and medium "
                                                   "apertures are unknown (no EXIF FNumber, no f_number in the JSON); "
                                                   "its medium image is not used")
    if "focusB" in shot.files:
        rel = settings.get("focusB") or {}
        if isinstance(rel, dict) and "beta" in rel:
            members["focusB"] = (float(rel.get("alpha", 1.0)), float(rel["beta"]))
        else:
            report.add("focusB without shift", f"shot '{shot.name}': focusB needs its blur shift in the JSON "
                                               '({"focusB": {"beta": px}}); its focusB image is not used')
    return members


def _photo_source(name: str, out: Path, meta: dict) -> SampleSource:
    members = {role: Member(out / f"{role}.png", float(m["alpha"]), float(m["beta"]))
               for role, m in meta["members"].items()}
    third = {"aperture": ("medium",) if "medium" in members else (), "focal": ("focusB",) if "focusB" in members else ()}
    return SampleSource(f"photos/{name}", "photos", out / "small.png", members, int(meta["width"]), third)


def photo_sources(folder: str | Path, cache: Path, report: SkipReport, max_side: int = 1024,
                  motion: str = "homography", progress: bool = False) -> list[SampleSource]:
    """Align (or reuse from ``cache``) every shot of a bracketed-photo folder."""
    from tqdm import tqdm

    shots = find_photo_shots(folder, report)
    sources = []
    for shot in tqdm(shots, desc="align photos", unit="shot", disable=not progress):
        src = prepare_shot(shot, cache, max_side=max_side, motion=motion, report=report)
        if src is not None:
            sources.append(src)
    return sources


# ------------------------------------------------------------------------------ drawing samples


def degrade_like_footage(srgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """What a phone does to a frame, at random strengths: a slight blur (sigma 0.3-1.2 px) half
    the time, sensor noise (0-2 % of full scale, stronger in the dark), JPEG at quality 35-90.
    srgb: (H, W, 3) float32 in [0, 1]; returns the same shape, 8-bit values."""
    import cv2

    out = srgb.astype(np.float32)
    if rng.random() < 0.5:
        out = cv2.GaussianBlur(out, (0, 0), float(rng.uniform(0.3, 1.2)))
    sigma = float(rng.uniform(0.0, 0.02))
    out = out + rng.normal(0.0, 1.0, out.shape).astype(np.float32) * sigma * np.sqrt(1.05 - out)
    u8 = np.clip(np.round(out * 255), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", u8[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(35, 91))])
    if ok:
        u8 = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
    return np.ascontiguousarray(u8, dtype=np.float32) / 255.0


def expose_like_footage(srgb: np.ndarray, radiance: np.ndarray | None,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray | None]:
    """Another white balance and a brighter exposure, as another phone would have chosen: the
    linear input and its true radiance are both multiplied by per-channel gains >= 1 (a
    brightest-channel gain of 1-2, i.e. 0-1 stop, times a white-balance ratio of up to 1.25
    between channels), and the input is clipped again at white. Gains >= 1 keep every pixel
    that was clipped clipped, so the HDR target stays exact. srgb: (H, W, 3) float32 in [0, 1];
    radiance: (H, W, 3) linear or None. Returns (8-bit-valued srgb, radiance)."""
    from ..color import linear_to_srgb, srgb_to_linear

    gains = np.exp(rng.uniform(0.0, np.log(1.25), 3)).astype(np.float32)
    gains *= np.float32(np.exp(rng.uniform(0.0, np.log(2.0)))) / gains.min()
    lin = np.clip(srgb_to_linear(np.clip(srgb, 0.0, 1.0)) * gains, 0.0, 1.0)
    out = np.round(linear_to_srgb(lin) * 255.0) / 255.0
    return out.astype(np.float32), (None if radiance is None else (radiance * gains).astype(np.float32))


@dataclass(frozen=True)
class Augment:
    """Random resize (relative to the stored size) and crop of training samples.

    crop: side of the square crop in px (the whole frame when it is smaller).
    scale_range: resize factors drawn uniformly (clamped so the crop still fits).
    flip: random horizontal flip (disparity is unchanged by a mirror).
    whole_frame: probability that a sample is instead the *whole* frame, shrunk to between half
        and all of a crop's pixel count (``crop**2``; never enlarged). The paper trained on whole
        images at random resolutions; the network's global feature and its receptive field see
        the whole frame at inference, and a model trained on crops alone behaved differently
        on whole frames (on the 160x90 test clips its E on clipped pixels was 2.5x larger on
        the whole frame than on 64-px crops of it). Whole frames at ~crop**2 pixels cost
        the same as a crop.
    """

    crop: int = 128
    scale_range: tuple[float, float] = (0.5, 1.0)
    flip: bool = True
    whole_frame: float = 0.0
    gt_share: float = 0.5
    procedural_share: float = 0.0
    """Share of draws from procedural frames (:mod:`.procedural`) when there are other sources too."""
    real_share: float = 0.5
    """Share of draws from real pictures with measured depth when there are other sources too."""
    degrade: float = 0.0
    """Probability that a ground-truth-only sample's input is degraded like phone footage
    (:func:`degrade_like_footage`: blur, sensor noise, JPEG); its targets are unchanged."""
    expose: float = 0.0
    """Probability that a ground-truth-only sample gets another white balance and exposure
    (:func:`expose_like_footage`; applied before ``degrade``; D unchanged, the HDR target
    follows)."""


class TrainingSet:
    """Draws :class:`TrainSample` s from sources; unreadable files are skipped and counted."""

    def __init__(self, sources: Iterable[SampleSource], augment: Augment = Augment(),
                 report: SkipReport | None = None) -> None:
        self.sources = list(sources)
        if not self.sources:
            raise InputError("no usable training samples: every frame/shot was skipped (see the warnings above)")
        self.augment = augment
        self.report = report if report is not None else SkipReport()
        self._bad: set[str] = set()
        self._real = [s for s in self.sources if s.origin == "real"]
        self._procedural = [s for s in self.sources if s.origin == "procedural"]
        self._gt_only = [s for s in self.sources if s.kinds == ("gt",) and s.origin not in ("procedural", "real")]
        self._rendered = [s for s in self.sources if s.kinds != ("gt",)]

    def __len__(self) -> int:
        return len(self.sources)

    def summary(self) -> dict:
        """Counts for the weights header: sources by origin, sample kinds available, skips."""
        by_origin = Counter(s.origin for s in self.sources)
        kinds = Counter(k for s in self.sources for k in s.kinds)
        clips = sorted({s.name.split("/")[0] for s in self.sources if s.origin == "harness"})
        return {"harness_frames": by_origin.get("harness", 0), "harness_clips": len(clips),
                "procedural_frames": by_origin.get("procedural", 0), "real_pictures": by_origin.get("real", 0),
                "photo_shots": by_origin.get("photos", 0), "kinds": dict(kinds),
                "skipped": dict(self.report.counts)}

    def draw(self, rng: np.random.Generator, retries: int = 20) -> TrainSample:
        """A random sample: a real picture with probability ``augment.real_share`` when there are
        other sources too; else a procedural frame with probability ``augment.procedural_share`` when
        there are other sources too; else a ground-truth-only harness frame with probability
        ``augment.gt_share`` when both kinds exist, else uniform over the others; then uniform over
        the source's kinds."""
        others = self._gt_only + self._rendered
        synthetic = self._procedural + others
        for _ in range(retries):
            pool = self.sources
            if self._real and synthetic and float(rng.random()) < self.augment.real_share:
                pool = self._real
            elif self._real and synthetic:
                pool = synthetic
            if pool is not self._real and self._procedural and others:
                pool = self._procedural if float(rng.random()) < self.augment.procedural_share else others
            if pool is not self._procedural and pool is not self._real and self._gt_only and self._rendered:
                pool = self._gt_only if float(rng.random()) < self.augment.gt_share else self._rendered
            src = pool[int(rng.integers(len(pool)))]
            if src.name in self._bad:
                continue
            try:
                return self.make(src, rng)
            except (InputError, OSError, ValueError) as ex:
                self._bad.add(src.name)
                self.report.add("unreadable sample", f"training sample {src.name}: {ex}; left out from now on")
        raise InputError("could not read a training sample in 20 tries; see the warnings above")

    def make(self, src: SampleSource, rng: np.random.Generator) -> TrainSample:
        """Load, resize, crop and flip one sample of ``src`` (kind drawn from its kinds)."""
        kinds = src.kinds
        kind = kinds[int(rng.integers(len(kinds)))]
        names = [] if kind == "gt" else ["large"]
        if kind not in ("pair", "gt"):
            options = src.third[kind]
            names.append(options[int(rng.integers(len(options)))])
        image = read_srgb(src.input)
        members = [read_srgb(src.members[n].path) for n in names]
        for n, m in zip(names, members):
            if m.shape != image.shape:
                raise InputError(f"{src.members[n].path} is {m.shape[1]}x{m.shape[0]} but the input "
                                 f"{src.input} is {image.shape[1]}x{image.shape[0]}")
        h, w = image.shape[:2]
        aug = self.augment
        if aug.whole_frame > 0 and float(rng.random()) < aug.whole_frame:
            s = min(1.0, math.sqrt(float(rng.uniform(0.5, 1.0)) * aug.crop**2 / (w * h)))
            size = (max(int(round(w * s)), 1), max(int(round(h * s)), 1))
            ch, cw, y0, x0 = size[1], size[0], 0, 0
        else:
            lo, hi = aug.scale_range
            lo = max(lo, min(aug.crop / min(h, w), 1.0))
            hi = max(hi, lo)
            s = float(rng.uniform(lo, hi)) if hi > lo else hi
            size = (max(int(round(w * s)), 1), max(int(round(h * s)), 1))
            ch, cw = min(aug.crop, size[1]), min(aug.crop, size[0])
            y0 = int(rng.integers(size[1] - ch + 1))
            x0 = int(rng.integers(size[0] - cw + 1))
        frame_width = float(blur_span(*size))  # D_rel is a share of the long side (a portrait source's height)
        px_scale = size[0] / src.native_width
        flip = aug.flip and bool(rng.integers(2))

        def prep(img: np.ndarray) -> np.ndarray:
            out = resize_linear(img, size)[y0:y0 + ch, x0:x0 + cw]
            return np.ascontiguousarray(out[:, ::-1] if flip else out, dtype=np.float32)

        def crop_flip(arr: np.ndarray) -> np.ndarray:
            out = arr[y0:y0 + ch, x0:x0 + cw]
            return np.ascontiguousarray(out[:, ::-1] if flip else out, dtype=np.float32)

        adjusted = None
        if kind not in ("pair", "gt"):
            third = src.members[names[1]]
            adjusted = (prep(members[1]), third.alpha, third.beta * px_scale)
        inp = prep(image)
        hdr = None if src.gt_hdr is None else crop_flip(resize_radiance(read_gt_radiance(src.gt_hdr, (w, h)), size))
        if kind == "gt" and aug.expose > 0 and float(rng.random()) < aug.expose:
            inp, hdr = expose_like_footage(inp, hdr, rng)
        if kind == "gt" and aug.degrade > 0 and float(rng.random()) < aug.degrade:
            inp = degrade_like_footage(inp, rng)
        gt_d = gt_e = sat = None
        if src.gt_disparity is not None and src.truth_kind is not None:  # a real picture: scale-free
            gt_d = crop_flip(real_target(src.gt_disparity, src.truth_kind, src.truth_scale, size) * px_scale)
        elif src.gt_disparity is not None:
            gt_d = crop_flip(resize_disparity(read_gt_disparity(src.gt_disparity, (w, h), src.unsupervised_ids), size)
                             * px_scale)
        if hdr is not None:
            gt_e, sat = exponent_target(inp, hdr)
        if kind == "gt":  # no shallow-DOF image: the supervised terms alone (target unused)
            return TrainSample(src.name, kind, inp, inp, 1.0, 0.0, frame_width, None, gt_d, gt_e, sat,
                               float(src.native_width), src.disparity_invariant)
        large = src.members["large"]
        return TrainSample(src.name, kind, inp, prep(members[0]), large.alpha, large.beta * px_scale,
                           frame_width, adjusted, gt_d, gt_e, sat, float(src.native_width))
