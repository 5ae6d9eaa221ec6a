"""The per-clip estimation cache (DESIGN.md "Per-clip cache").

```
CACHE/
  meta.json            format, engine version, model hash, source file hash, resolution, fps,
                       frame range, depth source, and the frames written under this key
  frame_00001.exr      channels D (px at the native width, DESIGN units), E.R, E.G, E.B (eq. 3);
  frame_00002.exr      one file per frame, numbered from 1 (frame = 0-based clip index + 1)
```

A frame is trusted only if ``meta.json`` carries the same *key* (format, engine version,
model hash, source hash, resolution, depth settings), lists the frame with the file's byte
size, and the EXR reads back with every channel at the clip's resolution and finite values.
Anything else (another model, another source, a truncated or unreadable EXR, a frame written
but not yet recorded when a run was killed) is recomputed, never trusted. When the key changes
the old frames are deleted before the new ``meta.json`` is written. All writes are atomic
(temp file + rename); ``meta.json`` is rewritten every few frames and at the end, so an
interrupted run loses at most those frames.

The cache folder can be given to ``rvr render --depth CACHE --hdr CACHE`` directly (it reads
channel D, then E.R/E.G/E.B) when it covers the clip from its first frame.

Source hash (:func:`source_fingerprint`): SHA-256 over the file's size, its modification time
(ns) and its first and last MiB; for an image sequence over every file's name, size and mtime
plus the first and last MiB of its first and last file. Cheap for any clip length, and it
changes whenever the file is replaced or edited in place (a copy with a new mtime also counts
as a new source: recomputed, never wrongly trusted).
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import time
from pathlib import Path

import numpy as np

from ..errors import InputError, OutputError
from ..io.exr import read_exr, write_exr
from ..io.paths import expand_sequence, temp_sibling

log = logging.getLogger(__name__)

CACHE_FORMAT = "rvr-laaf-cache/1"
FRAME_NAME = "frame_{:05d}.exr"
_FRAME_RE = re.compile(r"frame_(\d{5,})\.exr$")
CHANNELS = ("D", "E.R", "E.G", "E.B")
MIB = 1 << 20
KEY_FIELDS = ("format", "engine_version", "model_hash", "source_hash", "resolution", "depth")


def _hash_file_ends(h, path: Path) -> None:
    size = path.stat().st_size
    with path.open("rb") as f:
        h.update(f.read(MIB))
        if size > MIB:
            f.seek(max(size - MIB, MIB))
            h.update(f.read(MIB))


def source_fingerprint(path: str | Path, extensions: tuple[str, ...] = ()) -> dict:
    """{"path", "hash", "method"} of a video file or an image sequence (see the module docstring).

    extensions: image suffixes for a folder input (default: those ``io.video`` reads).
    """
    from ..io.video import IMAGE_EXTENSIONS

    how, files = expand_sequence(str(path), extensions or IMAGE_EXTENSIONS)
    if not files:
        raise InputError(f"Input not found or empty: '{path}'")
    h = hashlib.sha256()
    for f in files:
        st = f.stat()
        h.update(f"{f.name}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    for f in {files[0], files[-1]}:
        _hash_file_ends(h, f)
    return {"path": str(path), "hash": h.hexdigest()[:32],
            "method": "sha256(name, size, mtime_ns of every file; first and last MiB of the first/last file)"}


def frame_path(folder: Path, index: int) -> Path:
    """EXR of clip index ``index`` (0-based) in a cache folder."""
    return folder / FRAME_NAME.format(index + 1)


class ClipCache:
    """Read/write access to one cache folder under one key (see the module docstring).

    key: the fields of ``KEY_FIELDS`` (values JSON-serialisable); info: extra meta (fps,
    model summary, source path) recorded but not compared.
    """

    def __init__(self, folder: str | Path, key: dict, info: dict | None = None, flush_every: int = 8) -> None:
        missing = [k for k in KEY_FIELDS if k not in key]
        if missing:
            raise ValueError(f"cache key lacks {missing}")
        self.folder = Path(folder)
        self.key = json.loads(json.dumps(key))  # normalised (tuples -> lists) for comparison
        self.info = dict(info or {})
        self.flush_every = flush_every
        self.frames: dict[str, int] = {}
        self.stale_reason: str | None = None
        self._dirty = 0
        self._open()

    # -- opening --------------------------------------------------------------------------
    def _open(self) -> None:
        if self.folder.exists() and not self.folder.is_dir():
            raise OutputError(f"cache path '{self.folder}' is a file; give a folder for the cache (-o DIR)")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as ex:
            raise OutputError(f"cannot create the cache folder '{self.folder}': {ex}") from ex
        meta_path = self.folder / "meta.json"
        old = None
        if meta_path.is_file():
            try:
                old = json.loads(meta_path.read_text())
                if not isinstance(old, dict):
                    raise ValueError("not a JSON object")
            except (OSError, ValueError) as ex:
                self.stale_reason = f"meta.json is unreadable ({ex})"
                old = None
        elif any(_FRAME_RE.match(p.name) for p in self.folder.iterdir()):
            self.stale_reason = "frames without meta.json"
        if old is not None:
            diff = [k for k in KEY_FIELDS if old.get(k) != self.key[k]]
            if diff:
                self.stale_reason = "written with another " + ", ".join(k.replace("_", " ") for k in diff)
            else:
                frames = old.get("frames") or {}
                self.frames = {str(k): int(v) for k, v in frames.items()} if isinstance(frames, dict) else {}
        if self.stale_reason:
            removed = self._remove_frames()
            log.warning("cache '%s' is stale (%s): %d old frames removed, recomputing", self.folder,
                        self.stale_reason, removed)
            self.frames = {}
        self.flush()

    def _remove_frames(self) -> int:
        n = 0
        for p in self.folder.iterdir():
            if _FRAME_RE.match(p.name) and p.is_file():
                p.unlink()
                n += 1
        return n

    # -- frames ---------------------------------------------------------------------------
    def is_valid(self, index: int, size: tuple[int, int]) -> bool:
        """True if frame ``index`` (0-based) is recorded, intact and readable at size (w, h)."""
        path = frame_path(self.folder, index)
        recorded = self.frames.get(str(index + 1))
        if recorded is None or not path.is_file() or path.stat().st_size != recorded:
            return False
        try:
            channels = read_exr(path)
        except InputError:
            return False
        for name in CHANNELS:
            arr = channels.get(name)
            if arr is None or arr.shape != (size[1], size[0]) or not np.isfinite(arr).all():
                return False
        return True

    def read(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """(D (H, W), E (H, W, 3)) float32 of a cached frame (check :meth:`is_valid` first)."""
        ch = read_exr(frame_path(self.folder, index))
        return ch["D"], np.dstack([ch["E.R"], ch["E.G"], ch["E.B"]])

    def write(self, index: int, disparity: np.ndarray, exponent: np.ndarray) -> None:
        """Store frame ``index``: disparity (H, W) px, exponent (H, W, 3); atomic, then recorded."""
        path = frame_path(self.folder, index)
        write_exr(path, {"D": disparity, "E.R": exponent[..., 0], "E.G": exponent[..., 1],
                         "E.B": exponent[..., 2]})
        self.frames[str(index + 1)] = path.stat().st_size
        self._dirty += 1
        if self._dirty >= self.flush_every:
            self.flush()

    def flush(self) -> None:
        """Rewrite meta.json atomically with the key, the info and the recorded frames."""
        numbers = sorted(int(k) for k in self.frames)
        meta = {**self.key, **self.info, "channels": list(CHANNELS),
                "frame_numbering": "frame_NNNNN.exr = 0-based clip index + 1",
                "frame_range": [numbers[0] - 1, numbers[-1]] if numbers else None,
                "frame_count": len(numbers), "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "frames": {str(k): self.frames[str(k)] for k in numbers}}
        path = self.folder / "meta.json"
        tmp = temp_sibling(path, ".json")
        try:
            tmp.write_text(json.dumps(meta, indent=1))
            os.replace(tmp, path)
        except OSError as ex:
            tmp.unlink(missing_ok=True)
            raise OutputError(f"cannot write '{path}': {ex}. Check free disk space and permissions.") from ex
        self._dirty = 0
