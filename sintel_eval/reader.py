"""Read ground-truth clips in the harness format (sintel_eval/DATASET.md, ``rvr-laaf-harness/1``).

A *dataset* is a folder of clip folders, or one clip folder; a clip folder holds a
``manifest.json`` whose ``format`` starts with ``rvr-laaf-harness/``. :func:`find_clips` lists
them; :class:`ClipReader` checks a clip's completeness (done markers) and streams its frames
for one focus track, one :class:`GTFrame` at a time (nothing else is held in memory).

Errors are :class:`rvr_addon.errors.InputError` naming the file and the fix.
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from rvr_addon.errors import InputError
from rvr_addon.io.exr import read_exr
from rvr_addon.render.aperture import ApertureSpec

log = logging.getLogger(__name__)

FORMAT_PREFIX = "rvr-laaf-harness/"
MANIFEST = "manifest.json"


@dataclass
class GTFrame:
    """One frame of a clip and a focus track, everything a variant and the metrics need.

    frame: Blender frame number (1-based). index: 0-based clip index.
    input_srgb: (H, W, 3) uint8, the deep-DOF input (8-bit sRGB, highlights clipped).
    exponent: (H, W, 3) float32 HDR exponent E (eq. 3; 0 where not clipped).
    radiance: (H, W, 3) float32 linear HDR radiance of the input frame (never clipped).
    disparity: (H, W) float32 ground-truth D, DESIGN units (px of blur radius at aperture 1).
    dof_linear: (H, W, 3) float32 Cycles' shallow-DOF render of the track, linear radiance.
    focus: focus disparity f (DESIGN units); aperture: aperture scale a.
    depth_m: (H, W) float32 planar depth in m (channel Z of gt/disparity), world_to_camera: (4, 4)
    the frame's camera (manifest ``camera_per_frame``), f_px: focal length in px; None when the
    clip lacks them (only the ideal-filter row needs them).
    """

    frame: int
    index: int
    input_srgb: np.ndarray
    exponent: np.ndarray
    radiance: np.ndarray
    disparity: np.ndarray
    dof_linear: np.ndarray
    focus: float
    aperture: float
    depth_m: np.ndarray | None = None
    world_to_camera: np.ndarray | None = None
    f_px: float | None = None


def _load_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{what} '{path}' is missing; re-run `python -m sintel_eval generate` for this clip.") from None
    except (OSError, ValueError) as ex:
        raise InputError(f"{what} '{path}' is not readable JSON ({ex}); regenerate the clip "
                         "(`python -m sintel_eval generate ... --force`).") from ex


def is_clip(folder: Path) -> bool:
    """True if ``folder`` holds a manifest.json of the harness format."""
    path = folder / MANIFEST
    if not path.is_file():
        return False
    try:
        fmt = json.loads(path.read_text()).get("format", "")
    except (OSError, ValueError, AttributeError):
        return True  # looks like a clip; ClipReader reports the broken manifest by name
    return isinstance(fmt, str) and fmt.startswith(FORMAT_PREFIX)


def find_clips(dataset: str | Path) -> list[Path]:
    """Clip folders of a dataset (the folder itself if it is a clip), sorted by name.

    Raises InputError if ``dataset`` does not exist or holds no clip (no manifest.json of
    format ``rvr-laaf-harness/...`` in it or in its sub-folders).
    """
    root = Path(dataset)
    if not root.is_dir():
        raise InputError(f"Dataset folder '{root}' does not exist; pass a folder written by "
                         "`python -m sintel_eval generate -o DIR` (or a folder of such folders).")
    if is_clip(root):
        return [root]
    clips = sorted((p for p in root.iterdir() if p.is_dir() and is_clip(p)), key=lambda p: p.name)
    if not clips:
        raise InputError(f"'{root}' is not a harness dataset: neither it nor its sub-folders hold a "
                         f"{MANIFEST} with format '{FORMAT_PREFIX}...'. Generate clips with "
                         "`python -m sintel_eval generate --seed 7 -o DIR/clip7`.")
    return clips


def aperture_spec(camera: dict) -> ApertureSpec:
    """Our aperture shape for the manifest's camera (``blades`` 0 = round disk)."""
    blades = int(camera.get("blades", 0) or 0)
    ratio = float(camera.get("ratio", 1.0) or 1.0)
    if blades >= 3:
        return ApertureSpec(shape="polygon", blades=blades,
                            rotation_deg=math.degrees(float(camera.get("rotation", 0.0) or 0.0)))
    if abs(ratio - 1.0) > 1e-6:
        log.warning("aperture ratio %.3g of the dataset camera is not modelled; using a round disk", ratio)
    return ApertureSpec()


def _marker_files(marker: dict) -> dict[str, int | None]:
    """{relative path: size in bytes or None} from a done marker (dict or list form)."""
    files = marker.get("files", {})
    if isinstance(files, dict):
        out: dict[str, int | None] = {}
        for k, v in files.items():
            size = v.get("size", v.get("bytes")) if isinstance(v, dict) else v
            out[str(k)] = None if size is None else int(size)
        return out
    out = {}
    for item in files or []:
        if isinstance(item, str):
            out[item] = None
        elif isinstance(item, dict) and "path" in item:
            size = item.get("size", item.get("bytes"))
            out[str(item["path"])] = None if size is None else int(size)
    return out


def _channels(path: Path, names: tuple[str, ...], alternatives: tuple[tuple[str, ...], ...] = (),
              ch: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """Stack the named channels of an EXR (H, W, C) float32; InputError names a missing one or
    non-finite values. ch: the file's channels when the caller has already read it."""
    ch = read_exr(path) if ch is None else ch
    for option in (names, *alternatives):
        if all(n in ch for n in option):
            arr = np.dstack([ch[n] for n in option]).astype(np.float32, copy=False)
            if not np.all(np.isfinite(arr)):
                raise InputError(f"EXR '{path}' holds NaN or infinite values; regenerate this frame "
                                 "(delete its done marker and re-run generate).")
            return arr
    raise InputError(f"EXR '{path}' lacks channel(s) {', '.join(names)} (it has {', '.join(sorted(ch))}); "
                     "it was not written by the harness: regenerate the clip.")


def _disparity_and_depth(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """D (H, W) float32 of a gt/disparity EXR (InputError if missing or not finite) and its planar
    depth Z in m (None when the file has no Z channel; non-finite values become NaN)."""
    ch = read_exr(path)
    d = _channels(path, ("D",), ch=ch)[..., 0]
    z = ch.get("Z")
    if z is not None:
        z = np.where(np.isfinite(z), z, np.nan).astype(np.float32)
    return d, z


def _per_frame_cameras(manifest: dict) -> dict[int, np.ndarray]:
    """{frame number: (4, 4) world_to_camera} from ``camera_per_frame`` (empty when absent or malformed)."""
    out: dict[int, np.ndarray] = {}
    for rec in manifest.get("camera_per_frame") or []:
        try:
            m = np.asarray(rec["world_to_camera"], dtype=np.float64)
            if m.shape == (4, 4) and np.all(np.isfinite(m)):
                out[int(rec["frame"])] = m
        except (KeyError, TypeError, ValueError):
            continue
    return out


def _float_or_none(value: Any) -> float | None:
    try:
        f = float(value)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) and f > 0 else None


def _png(path: Path) -> np.ndarray:
    if not path.is_file():
        raise InputError(f"Frame '{path}' is missing; re-run `python -m sintel_eval generate` to resume the clip.")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"Frame '{path}' is not a readable PNG; delete it and its done marker, then re-run generate.")
    return np.ascontiguousarray(img[:, :, ::-1])


class ClipReader:
    """One clip folder: manifest, focus tracks, completeness check and frame stream."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.manifest: dict = _load_json(self.folder / MANIFEST, "Manifest")
        if not isinstance(self.manifest, dict):
            raise InputError(f"Manifest '{self.folder / MANIFEST}' is not a JSON object; regenerate the clip.")
        fmt = str(self.manifest.get("format", ""))
        if not fmt.startswith(FORMAT_PREFIX):
            raise InputError(f"Manifest '{self.folder / MANIFEST}' has format {fmt!r}, not '{FORMAT_PREFIX}...'; "
                             "it is not a harness clip.")
        config = {**{k: self.manifest.get(k) for k in ("frames", "width", "height", "fps")},
                  **self.manifest.get("config", {})}
        self.name = self.folder.name
        self.frames = int(config.get("frames") or 0)
        self.width = int(config.get("width") or 0)
        self.height = int(config.get("height") or 0)
        self.fps = float(config.get("fps") or 24)
        if self.frames < 1:
            raise InputError(f"Manifest '{self.folder / MANIFEST}' gives config.frames = {self.frames}; "
                             "regenerate the clip.")
        self.camera: dict = dict(self.manifest.get("camera", {}))
        self._world_to_camera = _per_frame_cameras(self.manifest)
        self.spec = aperture_spec(self.camera)

    # -- tracks --------------------------------------------------------------------------
    @property
    def tracks(self) -> list[str]:
        """Names of the focus tracks with a ground-truth DOF folder (``dof/<track>/``)."""
        declared = self.manifest.get("focus_tracks", {})
        if isinstance(declared, dict):
            names = list(declared)
        else:
            names = [t.get("name") if isinstance(t, dict) else str(t) for t in declared or []]
        names = [n for n in names if n and (self.folder / "dof" / n).is_dir()]
        if not names and (self.folder / "dof").is_dir():
            names = sorted(p.name for p in (self.folder / "dof").iterdir() if p.is_dir())
        return names

    # -- paths -----------------------------------------------------------------------------
    def path(self, kind: str, frame: int, track: str | None = None) -> Path:
        """Path of one per-frame file; kind: input, disparity, hdr, exponent, dof_exr, dof_json, done."""
        stem = f"frame_{frame:05d}"
        table = {
            "input": f"input/{stem}.png", "disparity": f"gt/disparity/{stem}.exr", "hdr": f"gt/hdr/{stem}.exr",
            "exponent": f"gt/exponent/{stem}.exr", "dof_exr": f"dof/{track}/{stem}.exr",
            "dof_png": f"dof/{track}/{stem}.png", "dof_json": f"dof/{track}/{stem}.json", "done": f"done/{stem}.json",
        }
        return self.folder / table[kind]

    def frame_numbers(self, max_frames: int | None = None) -> list[int]:
        """Blender frame numbers to evaluate: 1 .. min(frames, max_frames)."""
        n = self.frames if max_frames is None else min(self.frames, max_frames)
        return list(range(1, n + 1))

    def check_complete(self, tracks: list[str], max_frames: int | None = None) -> None:
        """Raise InputError naming the first frame that is not complete (DATASET.md: its done
        marker exists, carries the manifest's config_hash, and every file it lists exists with
        the listed size), or that lacks a file the ablation reads."""
        want_hash = self.manifest.get("config_hash")
        for frame in self.frame_numbers(max_frames):
            done = self.path("done", frame)
            if not done.is_file():
                raise InputError(f"Frame {frame} of clip '{self.folder}' is incomplete: its done marker '{done}' is "
                                 "missing. Re-run the same `python -m sintel_eval generate` command to resume it.")
            marker = _load_json(done, "Done marker")
            if want_hash is not None and marker.get("config_hash", want_hash) != want_hash:
                raise InputError(f"Done marker '{done}' belongs to another configuration (config_hash differs from "
                                 f"the manifest's); re-run generate to re-render frame {frame}.")
            for rel, size in _marker_files(marker).items():
                p = self.folder / rel
                if not p.is_file():
                    raise InputError(f"File '{p}' listed in '{done}' is missing; re-run generate to resume the clip.")
                if size is not None and p.stat().st_size != size:
                    raise InputError(f"File '{p}' has {p.stat().st_size} bytes but its done marker says {size}: "
                                     "it is truncated or corrupt. Delete the marker and re-run generate.")
            needed = [self.path(k, frame) for k in ("input", "disparity", "exponent", "hdr")]
            needed += [self.path(k, frame, t) for t in tracks for k in ("dof_exr", "dof_json")]
            for p in needed:
                if not p.is_file():
                    raise InputError(f"File '{p}' is missing from clip '{self.folder}'; re-run generate to resume it.")

    def lens(self, track: str, frame: int) -> tuple[float, float]:
        """(focus disparity, aperture scale) of a frame of a track, from its lens record."""
        path = self.path("dof_json", frame, track)
        rec = _load_json(path, "Lens record")
        try:
            focus, aperture = float(rec["focus_disparity"]), float(rec["aperture_scale"])
        except (KeyError, TypeError, ValueError) as ex:
            raise InputError(f"Lens record '{path}' lacks a numeric focus_disparity / aperture_scale ({ex}); "
                             "regenerate the clip.") from ex
        if not (math.isfinite(focus) and math.isfinite(aperture) and aperture >= 0):
            raise InputError(f"Lens record '{path}' has focus {focus} / aperture {aperture}; regenerate the clip.")
        return focus, aperture

    # -- frames ----------------------------------------------------------------------------
    def read(self, track: str, frame: int) -> GTFrame:
        """Load one frame of ``track``; InputError naming the file if one is missing or corrupt."""
        image = _png(self.path("input", frame))
        disparity, depth = _disparity_and_depth(self.path("disparity", frame))
        exponent = _channels(self.path("exponent", frame), ("E.R", "E.G", "E.B"), (("R", "G", "B"),))
        radiance = _channels(self.path("hdr", frame), ("R", "G", "B"))
        dof = _channels(self.path("dof_exr", frame, track), ("R", "G", "B"))
        shape = image.shape[:2]
        for name, arr in (("disparity", disparity), ("exponent", exponent), ("hdr", radiance), ("dof_exr", dof)):
            if arr.shape[:2] != shape:
                p = self.path(name, frame, track)
                raise InputError(f"'{p}' is {arr.shape[1]}x{arr.shape[0]} px but the input frame is "
                                 f"{shape[1]}x{shape[0]}; regenerate the clip.")
        focus, aperture = self.lens(track, frame)
        return GTFrame(frame=frame, index=frame - 1, input_srgb=image, exponent=exponent, radiance=radiance,
                       disparity=disparity, dof_linear=dof, focus=focus, aperture=aperture,
                       depth_m=depth if depth is not None and depth.shape == shape else None,
                       world_to_camera=self._world_to_camera.get(frame), f_px=_float_or_none(self.camera.get("f_px")))

    def iter_frames(self, track: str, max_frames: int | None = None) -> Iterator[GTFrame]:
        """Stream the frames of ``track`` in order (each read when requested)."""
        for frame in self.frame_numbers(max_frames):
            yield self.read(track, frame)

    def summary(self) -> dict[str, Any]:
        """Manifest facts for the report (seed, script, size, frames, fps, camera, tracks)."""
        config = self.manifest.get("config", {})
        return {"clip": self.name, "seed": config.get("seed"), "script": config.get("script"),
                "size": f"{self.width}x{self.height}", "frames": self.frames, "fps": self.fps,
                "f_number_ref": self.camera.get("f_number_ref"), "K_px": self.camera.get("K_px"),
                "tracks": self.tracks, "complete": bool(self.manifest.get("status", {}).get("complete", False))}
