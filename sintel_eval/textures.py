"""Photo texture library of the harness' ``photo`` style (no bpy): real images as texture sources.

Sources, found at generation time and never copied into the repository:

- every image (``*.png``, ``*.jpg``) under the texture root, by default ``../shared/data``
  beside the repository (``$RVR_TEXTURES`` or ``--textures DIR`` override it): the Sintel frames;
- a few frames of every video under the root (the real clips), extracted with the bundled ffmpeg
  at fixed fractions of their duration into the texture cache;
- scikit-image's sample photographs when scikit-image is installed (``skimage/data``), except the
  Middlebury "motorcycle" pair, which is the estimator's real-footage test.

A scene's plan (:mod:`sintel_eval.look`) picks, with its seed, a source and a crop rectangle for
each textured surface (:class:`TextureUse`); :func:`cut` writes the crop (at most
:data:`MAX_CROP_PX` on its longer side) into the cache under a name derived from everything that
defines its pixels, so the same plan always uses the same file. The cache defaults to
``~/.cache/rvr-laaf/textures`` (``$RVR_TEXTURE_CACHE``, ``--texture-cache DIR``). Every source is
named in the manifest with the sha256 of its file, so a dataset can be reproduced.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT_ENV = "RVR_TEXTURES"
CACHE_ENV = "RVR_TEXTURE_CACHE"
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
VIDEO_EXTENSIONS = (".mp4", ".mpg", ".mpeg", ".mov", ".mkv", ".avi", ".webm", ".m4v")
CLIP_FRAME_FRACTIONS = (0.15, 0.4, 0.65, 0.9)  # where in a clip (share of its duration) frames are taken
MAX_SOURCE_PX = 1024  # extracted clip frames are scaled to at most this width
MAX_CROP_PX = 512
CUT_VERSION = 1  # bump when cut() changes the pixels it writes for the same TextureUse
# scikit-image samples: photographs of scenes and of materials. Left out: the Middlebury
# "motorcycle" pair (the estimator is evaluated on it), synthetic, medical and text images.
SKIMAGE_SCENES = ("astronaut.png", "chelsea.png", "coffee.png", "rocket.jpg", "camera.png")
SKIMAGE_MATERIALS = ("brick.png", "grass.png", "gravel.png")
EXCLUDED_NAMES = ("motorcycle_left.png", "motorcycle_right.png")


def repo_root() -> Path:
    return Path(__file__).resolve().parents[1]


def default_root() -> Path:
    """``$RVR_TEXTURES``, else ``../shared/data`` relative to the repository."""
    env = os.environ.get(ROOT_ENV)
    return Path(env).expanduser() if env else (repo_root().parent / "shared" / "data")


def default_cache() -> Path:
    """``$RVR_TEXTURE_CACHE``, else ``$XDG_CACHE_HOME/rvr-laaf/textures`` (``~/.cache`` by default)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rvr-laaf" / "textures"


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class TextureSource:
    """One real image a texture can be cut from.

    name: stable label (path under the root, ``#t=`` seconds for a clip frame, ``skimage/`` for
    the sample data); kind: "scene" (a photo of a whole scene: posters, billboards) or
    "material" (a close-up of a surface); file/sha256: the source file and its sha256 (the clip
    for a clip frame); frame_time_s: time of a clip frame; image: the readable image (the file
    itself, or the frame extracted into the cache); width/height px; gray: single-channel.
    """

    name: str
    kind: str
    origin: str
    file: str
    sha256: str
    image: str
    width: int
    height: int
    gray: bool = False
    frame_time_s: float | None = None


@dataclass(frozen=True)
class TextureUse:
    """A crop of a source as a scene surface's texture (the plan's choice; pure data).

    slot: the surface ("wall", "floor", "crate_0", "billboard_1", "top_ana", ...); rect:
    (x0, y0, x1, y1) as fractions of the source; size: px of the crop's longer side; flip:
    mirrored left-right; tint: linear RGB multiplier (grey sources get a colour); tile_m:
    metres one copy covers on a tiled surface (None: mapped once, posters and billboards).
    """

    slot: str
    source: str
    sha256: str
    rect: tuple[float, float, float, float]
    size: int
    flip: bool = False
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    tile_m: float | None = None
    frame_time_s: float | None = None

    def cache_name(self) -> str:
        """File name of the crop in the cache: a digest of everything that defines its pixels."""
        key = json.dumps({"v": CUT_VERSION, "sha": self.sha256, "t": self.frame_time_s,
                          "rect": [round(v, 6) for v in self.rect], "size": self.size, "flip": self.flip,
                          "tint": [round(v, 6) for v in self.tint]}, sort_keys=True)
        return f"crop_{hashlib.sha256(key.encode()).hexdigest()[:24]}.png"


@dataclass
class TextureLibrary:
    """The sources found (sorted by name) and notes on what was skipped or missing."""

    root: str
    cache: str
    sources: list[TextureSource] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.sources)

    def of_kind(self, kind: str) -> list[TextureSource]:
        return [s for s in self.sources if s.kind == kind]

    def get(self, name: str) -> TextureSource:
        return next(s for s in self.sources if s.name == name)

    @property
    def digest(self) -> str:
        """Identity of the library's content (names and file hashes): part of a clip's config hash."""
        blob = json.dumps(sorted((s.name, s.sha256, s.frame_time_s) for s in self.sources))
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def describe(self) -> dict:
        return {"root": self.root, "cache": self.cache, "digest": self.digest, "sources": len(self.sources),
                "notes": list(self.notes)}


# --------------------------------------------------------------------------------------------- discovery


def _image_info(path: Path) -> tuple[int, int, bool] | None:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        return None
    if img.ndim == 2:
        return int(img.shape[1]), int(img.shape[0]), True
    c = img[..., :3]
    gray = bool(np.array_equal(c[..., 0], c[..., 1]) and np.array_equal(c[..., 1], c[..., 2]))
    return int(img.shape[1]), int(img.shape[0]), gray


def _ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def _duration_s(path: Path) -> float | None:
    done = subprocess.run([_ffmpeg(), "-hide_banner", "-nostdin", "-i", str(path)], capture_output=True, text=True)
    m = re.search(r"Duration: (\d+):(\d+):(\d+(?:\.\d+)?)", done.stderr)
    if not m:
        return None
    h, mi, s = m.groups()
    return 3600 * int(h) + 60 * int(mi) + float(s)


def _extract_frame(clip: Path, t: float, dst: Path) -> bool:
    """Frame of ``clip`` at ``t`` s as an 8-bit PNG (square pixels, at most MAX_SOURCE_PX wide)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.parent / f".{dst.stem}.{os.getpid()}.tmp.png"
    vf = f"scale=trunc(iw*sar/2)*2:ih,setsar=1,scale='min({MAX_SOURCE_PX},iw)':-2,format=rgb24"
    cmd = [_ffmpeg(), "-hide_banner", "-nostdin", "-v", "error", "-y", "-ss", f"{t:.3f}", "-i", str(clip),
           "-frames:v", "1", "-vf", vf, str(tmp)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0 or not tmp.is_file() or tmp.stat().st_size == 0:
        tmp.unlink(missing_ok=True)
        return False
    os.replace(tmp, dst)
    return True


def _skimage_dir() -> Path | None:
    spec = importlib.util.find_spec("skimage")
    if spec is None or not spec.origin:
        return None
    folder = Path(spec.origin).parent / "data"
    return folder if folder.is_dir() else None


def skimage_sources() -> list[tuple[Path, str]]:
    """(file, kind) of the scikit-image sample photographs used as textures ([] without scikit-image)."""
    folder = _skimage_dir()
    if folder is None:
        return []
    out = [(folder / n, "scene") for n in SKIMAGE_SCENES] + [(folder / n, "material") for n in SKIMAGE_MATERIALS]
    return [(p, kind) for p, kind in out if p.is_file()]


def discover(root: str | Path | None = None, cache: str | Path | None = None,
             sample_data: bool = True) -> TextureLibrary:
    """The texture library: images and clip frames under ``root`` plus scikit-image's samples.

    A missing ``root`` is not an error: the library notes it and holds only the sample data (or
    nothing: the caller then falls back to procedural materials with a warning).
    """
    root = Path(root).expanduser() if root else default_root()
    cache = Path(cache).expanduser() if cache else default_cache()
    lib = TextureLibrary(str(root), str(cache))
    found: list[TextureSource] = []
    if root.is_dir():
        files = sorted((p for p in root.rglob("*") if p.is_file() and not any(
            part.startswith(".") for part in p.relative_to(root).parts)), key=lambda p: str(p.relative_to(root)))
        for p in files:
            rel = str(p.relative_to(root))
            ext = p.suffix.lower()
            if p.name in EXCLUDED_NAMES:
                continue
            if ext in IMAGE_EXTENSIONS:
                info = _image_info(p)
                if info is None:
                    lib.notes.append(f"skipped unreadable image '{p}'")
                    continue
                found.append(TextureSource(rel, "scene", "data", str(p), sha256_file(p), str(p), *info))
            elif ext in VIDEO_EXTENSIONS:
                found.extend(_clip_frames(p, rel, cache, lib))
    else:
        lib.notes.append(f"texture folder '{root}' not found (set --textures DIR or ${ROOT_ENV})")
    if sample_data:
        sk = skimage_sources()
        if not sk:
            lib.notes.append("scikit-image is not installed: its sample photographs are not used")
        for p, kind in sk:
            info = _image_info(p)
            if info is not None:
                found.append(TextureSource(f"skimage/{p.name}", kind, "skimage", str(p), sha256_file(p), str(p),
                                           *info))
    lib.sources = sorted(found, key=lambda s: s.name)
    return lib


def _clip_frames(clip: Path, rel: str, cache: Path, lib: TextureLibrary) -> list[TextureSource]:
    sha = sha256_file(clip)
    duration = _duration_s(clip)
    if not duration or duration <= 0:
        lib.notes.append(f"skipped clip '{clip}': ffmpeg found no duration")
        return []
    out = []
    for u in CLIP_FRAME_FRACTIONS:
        t = round(u * duration, 2)
        dst = cache / "frames" / f"{sha[:20]}_t{t:07.2f}.png"
        if not dst.is_file() and not _extract_frame(clip, t, dst):
            lib.notes.append(f"skipped frame {t} s of '{clip}': ffmpeg could not decode it")
            continue
        info = _image_info(dst)
        if info is None:
            continue
        out.append(TextureSource(f"{rel}#t={t:.2f}", "scene", "data", str(clip), sha, str(dst), *info,
                                 frame_time_s=t))
    return out


# --------------------------------------------------------------------------------------------- crops


def crop_pixels(source: TextureSource, use: TextureUse) -> np.ndarray:
    """The crop of ``use`` as (h, w, 3) uint8 RGB (longer side ``use.size`` px, never upscaled
    beyond the crop's own size by more than 2x)."""
    import cv2

    img = cv2.imread(source.image, cv2.IMREAD_COLOR)
    if img is None:
        raise OSError(f"cannot read texture source '{source.image}'")
    h, w = img.shape[:2]
    x0, y0, x1, y1 = use.rect
    c0, c1 = int(round(x0 * w)), max(int(round(x1 * w)), int(round(x0 * w)) + 2)
    r0, r1 = int(round(y0 * h)), max(int(round(y1 * h)), int(round(y0 * h)) + 2)
    crop = img[r0:min(r1, h), c0:min(c1, w)]
    ch, cw = crop.shape[:2]
    scale = min(use.size / max(ch, cw), 2.0)
    size = (max(2, int(round(cw * scale))), max(2, int(round(ch * scale))))
    crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    if use.flip:
        crop = crop[:, ::-1]
    rgb = crop[..., ::-1]
    if tuple(use.tint) != (1.0, 1.0, 1.0):
        from rvr_addon.color import linear_to_srgb, srgb_to_linear

        lin = srgb_to_linear(rgb.astype(np.float32) / 255.0) * np.asarray(use.tint, np.float32)
        rgb = np.clip(np.round(255.0 * linear_to_srgb(np.clip(lin, 0.0, 1.0))), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(rgb)


def cut(library: TextureLibrary, use: TextureUse) -> Path:
    """Write (once) the crop of ``use`` into the library's cache; returns its path."""
    import cv2

    dst = Path(library.cache) / "crops" / use.cache_name()
    if dst.is_file() and dst.stat().st_size > 0:
        return dst
    rgb = crop_pixels(library.get(use.source), use)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.parent / f".{dst.stem}.{os.getpid()}.tmp.png"
    if not cv2.imwrite(str(tmp), rgb[..., ::-1]):
        tmp.unlink(missing_ok=True)
        raise OSError(f"cannot write the texture crop '{dst}': check that the cache folder is writable")
    os.replace(tmp, dst)
    return dst


def used_sources(library: TextureLibrary, uses) -> list[dict]:
    """Manifest records of the sources behind ``uses``: name, kind, origin, sha256, frame time."""
    names = sorted({u.source for u in uses})
    out = []
    for n in names:
        s = library.get(n)
        out.append({"name": s.name, "kind": s.kind, "origin": s.origin, "sha256": s.sha256,
                    "frame_time_s": s.frame_time_s, "width": s.width, "height": s.height,
                    "file": Path(s.file).name})
    return out


__all__ = ["TextureSource", "TextureUse", "TextureLibrary", "discover", "cut", "crop_pixels", "used_sources",
           "default_root", "default_cache", "skimage_sources"]
