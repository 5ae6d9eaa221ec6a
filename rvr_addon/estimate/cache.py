"""The per-clip estimation cache (DESIGN.md "Per-clip cache").

```
CACHE/
  meta.json            format, engine version, model hash, source file hash, resolution, fps,
                       frame range, depth source, and the frames written under this key
  frame_00001.exr      channels D (px at the native width, DESIGN units), E.R, E.G, E.B (eq. 3);
  frame_00002.exr      one file per frame, numbered from 1 (frame = 0-based clip index + 1);
                       after ``rvr stabilize`` also S.D, S.E.R, S.E.G, S.E.B (the temporally
                       stabilized D and E) and S.C (its confidence, 0..1), added to the same file
```

A frame is trusted only if ``meta.json`` carries the same *key* (format, engine version,
model hash, source hash, resolution, depth settings), lists the frame with the file's byte
size, and the EXR reads back with every channel at the clip's resolution and finite values.
Anything else (another model, another source, a truncated or unreadable EXR, a frame written
but not yet recorded when a run was killed) is recomputed, never trusted. All writes are atomic
(temp file + rename); ``meta.json`` is rewritten every few frames and at the end, so an
interrupted run loses at most those frames.

Another key never destroys a usable cache: when ``CACHE`` holds recorded frames under another
key, the new frames are built beside it in ``PARENT/.NAME.rebuild-<key hash>/`` (a complete
cache folder of its own; an interrupted rebuild of the same key resumes there), and
:meth:`ClipCache.commit` swaps it into place only once the caller has finished every frame
(``rvr estimate`` at the end of its range). Until then ``CACHE`` stays as it was, also after
Ctrl-C or Esc. The swap renames the old folder aside, the new one into place, then deletes the
old one; the rebuilt ``meta.json`` says ``"committing"`` first, so a crash between the two
renames is finished by the next open. A folder without a readable ``meta.json`` holds nothing
to keep and is rebuilt in place.

One writer at a time: a :class:`ClipCache` holds the OS lock of its folder
(:mod:`rvr_addon.io.lock`, ``PARENT/.NAME.lock``) from opening to :meth:`ClipCache.close`; a
second writer is refused naming the process that holds it, and readers (``rvr render --depth
CACHE``, :func:`rvr_addon.io.maps.open_map_sequence`) refuse a cache another process writes.

Which clip a cache belongs to: ``meta.json``'s ``source`` records the path, the fingerprint and
a content fingerprint (sizes and first and last MiB, no times or names of a video file), so a
copied or moved clip is still recognised; :func:`check_cache_source` refuses a cache made from
another clip (or from an earlier version of this one) naming both and the fix.

The cache folder can be given to ``rvr render --depth CACHE --hdr CACHE`` directly (it reads
channel D, then E.R/E.G/E.B) when it covers the clip from its first frame; it reads the
stabilized channels instead when :func:`stabilized_complete` says every frame has them.

Stabilized channels (``rvr stabilize``, :mod:`rvr_addon.temporal.job`) are recorded in
``meta.json`` under ``"stabilized"``: the filter settings and, per frame, the byte size of
the file holding them. The raw D and E are copied into every rewritten file, never dropped.
A frame file is rewritten in two steps (the new file is complete under a temp name, its size
is recorded as ``pending`` in meta.json, then it is renamed into place), so an interrupted run
leaves every raw frame valid. Rewriting a raw frame (``rvr estimate``) drops the record, since
stabilized frames depend on their neighbours; a run with other settings starts a new record.

Source hash (:func:`source_fingerprint`): SHA-256 over the file's size, its modification time
(ns) and its first and last MiB; for an image sequence over every file's name, size and mtime
plus the first and last MiB of its first and last file. Cheap for any clip length, and it
changes whenever the file is replaced or edited in place (a copy with a new mtime also counts
as a new source: recomputed, never wrongly trusted).
"""
from __future__ import annotations

import glob
import hashlib
import json
import logging
import os
import re
import time
from pathlib import Path

import numpy as np

from ..errors import InputError, OutputError
from ..io import lock as folder_lock
from ..io.exr import read_exr, read_exr_header, write_exr
from ..io.paths import expand_sequence, replace_folder, temp_sibling

log = logging.getLogger(__name__)

CACHE_FORMAT = "rvr-laaf-cache/1"
FRAME_NAME = "frame_{:05d}.exr"
_FRAME_RE = re.compile(r"frame_(\d{5,})\.exr$")
CHANNELS = ("D", "E.R", "E.G", "E.B")
EXR_COMPRESSION = "rle"
"""Compression of the cache's frame files: RLE (lossless; writes about 3x and reads 1.4x faster
than ZIP for 15 % more disk; at 1080p ZIP's encoding was a fifth of the whole pipeline).
Files of either compression are read alike, so caches written with ZIP stay valid."""
STABILIZED_CHANNELS = ("S.D", "S.E.R", "S.E.G", "S.E.B", "S.C")
MIB = 1 << 20
KEY_FIELDS = ("format", "engine_version", "model_hash", "source_hash", "resolution", "depth")
OPTIONAL_KEY_FIELDS = ("max_pixels", "context_pixels", "layout", "blur_span", "hdr_source", "frame_timeline")
"""Key fields compared like KEY_FIELDS but absent (= None) in older caches: ``max_pixels`` is the
network trunk's size when it is not DEFAULT_MAX_PIXELS (``--max-pixels``); ``context_pixels`` the
size of D's layout pass (``infer.CONTEXT_PIXELS``; caches made before it have none and recompute);
``layout`` the hash of the layout head that gives D's layout since 2026-12-08 (``infer.SHIPPED_LAYOUT``);
``blur_span`` "long side" on a portrait clip, whose D spans its height since 2026-12-07
(``depth.cues.blur_span``; portrait caches made before recompute, landscape ones stay valid);
``hdr_source`` on an HDR video (HLG, PQ), whose frames are tone-mapped to SDR since 2026-12-07
(``io.video.HDR_TO_SDR``; HDR caches made before recompute); ``frame_timeline`` on a
variable-frame-rate video, whose frames are those of its constant-rate timeline since 2026-12-07
(``io.video.video_timeline``; caches made before counted its decoded frames and recompute)."""
REBUILD_TAG = ".rebuild-"
GENERATED_FIELDS = frozenset({"channels", "frame_numbering", "frame_range", "frame_count", "updated", "frames",
                              "stabilized", "committing"})
"""meta.json fields :meth:`ClipCache.flush` derives (neither key nor info)."""


def key_of(meta: dict) -> dict:
    """The cache key recorded in a meta.json (KEY_FIELDS, and the optional ones it has)."""
    key = {k: meta.get(k) for k in KEY_FIELDS}
    key.update({k: meta[k] for k in OPTIONAL_KEY_FIELDS if meta.get(k) is not None})
    return key


def key_differences(meta: dict, key: dict) -> list[str]:
    """Names of the key fields in which ``meta`` (a meta.json) differs from ``key``."""
    key = json.loads(json.dumps(key))
    return [k for k in KEY_FIELDS + OPTIONAL_KEY_FIELDS if meta.get(k) != key.get(k)]


def rebuild_folder(target: str | Path, key: dict) -> Path:
    """Where a cache under ``key`` is built beside ``target`` while it holds another key."""
    target = Path(target)
    digest = hashlib.sha256(json.dumps(json.loads(json.dumps(key)), sort_keys=True).encode()).hexdigest()[:12]
    return target.parent / f".{target.name}{REBUILD_TAG}{digest}"


def _read_meta(folder: Path) -> tuple[dict | None, str | None]:
    """(meta.json of ``folder`` or None, why its frames cannot be trusted or None)."""
    meta_path = folder / "meta.json"
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text())
            if not isinstance(meta, dict):
                raise ValueError("not a JSON object")
            return meta, None
        except (OSError, ValueError) as ex:
            return None, f"meta.json is unreadable ({ex})"
    if folder.is_dir() and any(_FRAME_RE.match(p.name) for p in folder.iterdir()):
        return None, "frames without meta.json"
    return None, None


_TEMP_RE = re.compile(r"\.+(frame_\d{5,}\.exr|meta\.json)\.[0-9a-f]{8}\.")


def _remove_stale_temps(folder: Path) -> None:
    """Remove the hidden temp files (``.frame_00001.exr.1a2b3c4d.exr``, ``.meta.json.*.json``, ...)
    a writer killed with SIGKILL (or a power cut) left in the cache folder; called while holding
    the cache's writer lock, so none belongs to a live writer."""
    if not folder.is_dir():
        return
    for p in folder.iterdir():
        if _TEMP_RE.match(p.name) and p.is_file():
            p.unlink(missing_ok=True)


def _is_cache_entry(name: str) -> bool:
    return name == "meta.json" or name.startswith(".") or _FRAME_RE.match(name) is not None


def _rebuilds(target: Path) -> list[Path]:
    """The folders built beside ``target`` (:func:`rebuild_folder`)."""
    return list(target.parent.glob(f".{glob.escape(target.name)}{REBUILD_TAG}{'?' * 12}"))


def recover_swap(target: Path) -> None:
    """Finish a swap (:meth:`ClipCache.commit`) a crash interrupted: a missing ``target`` gets the
    rebuilt folder that was being put in place (else the old one back); leftovers are removed."""
    import shutil

    parent = target.parent
    if not parent.is_dir():
        return
    asides = sorted(parent.glob(f".{glob.escape(target.name)}.{'?' * 8}.old"), key=lambda p: p.stat().st_mtime)
    if not target.exists():
        for d in _rebuilds(target):
            meta, _ = _read_meta(d)
            if meta is not None and meta.get("committing"):
                d.replace(target)
                log.warning("cache '%s': finished the swap to the rebuilt cache a crash interrupted", target)
                break
        else:
            if asides:
                asides.pop().replace(target)
                log.warning("cache '%s': put the earlier cache back after an interrupted swap", target)
    for aside in asides:
        if aside.exists():
            shutil.rmtree(aside, ignore_errors=True)


def _hash_file_ends(hashes, path: Path) -> None:
    size = path.stat().st_size
    with path.open("rb") as f:
        chunks = [f.read(MIB)]
        if size > MIB:
            f.seek(max(size - MIB, MIB))
            chunks.append(f.read(MIB))
    for h in hashes:
        for chunk in chunks:
            h.update(chunk)


def source_fingerprint(path: str | Path, extensions: tuple[str, ...] = ()) -> dict:
    """{"path", "hash", "content", "method"} of a video file or an image sequence (see the module
    docstring). ``content`` leaves out the times (and a single file's name): it stays the same
    when the clip is copied or moved, so :func:`check_cache_source` still recognises it.

    extensions: image suffixes for a folder input (default: those ``io.video`` reads).
    """
    from ..io.video import IMAGE_EXTENSIONS

    how, files = expand_sequence(str(path), extensions or IMAGE_EXTENSIONS)
    if not files:
        raise InputError(f"Input not found or empty: '{path}'")
    h, content = hashlib.sha256(), hashlib.sha256()
    for f in files:
        st = f.stat()
        h.update(f"{f.name}|{st.st_size}|{st.st_mtime_ns}\n".encode())
        content.update((f"{st.st_size}\n" if how == "file" else f"{f.name}|{st.st_size}\n").encode())
    for f in sorted({files[0], files[-1]}):
        _hash_file_ends((h, content), f)
    return {"path": str(path), "hash": h.hexdigest()[:32], "content": content.hexdigest()[:32],
            "method": "sha256(name, size, mtime_ns of every file; first and last MiB of the first/last file); "
                      "content: the same without times and a single file's name"}


def check_cache_source(folder: str | Path, clip: str | Path, clip_info=None, command: str = "render") -> None:
    """Refuse a cache that was not made from ``clip`` (InputError naming both and the fix).

    The same fingerprint, or the same content fingerprint (a copied or moved clip), passes. An
    older cache without a content fingerprint passes with a warning when the file name, the
    resolution and the frame count agree. ``folder`` without a cache meta.json is not checked.
    clip_info: the clip's :class:`~rvr_addon.io.video.ClipInfo` if already probed.
    """
    folder, clip = Path(folder), Path(clip)
    meta, _ = _read_meta(folder) if folder.is_dir() else (None, None)
    if meta is None or not str(meta.get("format", "")).startswith("rvr-laaf-cache/"):
        return
    fp = source_fingerprint(clip)
    recorded = meta.get("source") if isinstance(meta.get("source"), dict) else {}
    if fp["hash"] == meta.get("source_hash") or (recorded.get("content") and recorded["content"] == fp["content"]):
        return
    if clip_info is None:
        from ..io.video import probe_clip

        clip_info = probe_clip(clip)
    made = str(recorded.get("path") or "another clip")
    res = meta.get("resolution") or ["?", "?"]
    frames = meta.get("clip_frame_count", "?")
    same_shape = list(res) == [clip_info.width, clip_info.height] and frames == clip_info.frame_count
    fix = (f"run `rvr estimate {clip} -o {folder}` to estimate this clip into it (or give this clip's own cache)")
    if not recorded.get("content") and same_shape and Path(made).name == clip.name:
        log.warning("cache '%s' was made from '%s', which may be a copy of '%s' (same name, %sx%s, %s frames; this "
                    "older cache records no content fingerprint); using it. If the clip was edited, %s", folder, made,
                    clip, res[0], res[1], frames, fix)
        return
    try:
        edited = Path(made).exists() and os.path.samefile(made, clip)
    except OSError:
        edited = False
    if edited:
        why = f"'{clip}' was changed or replaced after the cache '{folder}' was made from it"
    else:
        why = (f"the cache '{folder}' was made from '{made}' ({res[0]}x{res[1]}, {frames} frames), not from "
               f"'{clip}' ({clip_info.width}x{clip_info.height}, {clip_info.frame_count} frames)")
    raise InputError(f"rvr {command}: {why}, so its depth does not belong to this clip; {fix}")


def frame_path(folder: Path, index: int) -> Path:
    """EXR of clip index ``index`` (0-based) in a cache folder."""
    return folder / FRAME_NAME.format(index + 1)


def split_channels(channels: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(D (H, W) px, E (H, W, 3)) of a cache frame's channels (the raw ones, :data:`CHANNELS`)."""
    return channels["D"], np.dstack([channels["E.R"], channels["E.G"], channels["E.B"]])


class ClipCache:
    """Read/write access to one cache folder under one key (see the module docstring).

    key: the fields of ``KEY_FIELDS`` (and any of ``OPTIONAL_KEY_FIELDS``; values
    JSON-serialisable); info: extra meta (fps, model summary, source path) recorded but not
    compared. keep: info fields taken over from the folder's meta.json when it has the same
    key (a re-run that reuses every frame keeps what the first run recorded). beside: build a
    new key beside a usable cache of another key (module docstring) instead of clearing it;
    :attr:`folder` is where the frames go, :attr:`target` the folder asked for. Holds the
    folder's lock until :meth:`close` (InputError while another process writes it).
    """

    def __init__(self, folder: str | Path, key: dict, info: dict | None = None, flush_every: int = 8,
                 keep: tuple[str, ...] = (), beside: bool = True) -> None:
        missing = [k for k in KEY_FIELDS if k not in key]
        if missing:
            raise ValueError(f"cache key lacks {missing}")
        self.target = self.folder = Path(folder)
        self.key = json.loads(json.dumps(key))  # normalised (tuples -> lists) for comparison
        self.info = dict(info or {})
        self.flush_every = flush_every
        self.frames: dict[str, int] = {}
        self.stale_reason: str | None = None
        self.replaces: str | None = None
        """Why the cache at :attr:`target` is being rebuilt beside it (None: written in place)."""
        self.stabilized: dict | None = None
        self._dirty = 0
        self._committing = False
        self._parent_lock = None
        if self.target.exists() and not self.target.is_dir():
            raise OutputError(f"cache path '{self.target}' is a file; give a folder for the cache (-o DIR)")
        self._lock = folder_lock.acquire(self.target, "the cache")
        try:
            self._open(keep, beside)
        except BaseException:
            self.close()
            raise

    @property
    def rebuilding(self) -> bool:
        """True while the frames are built beside an existing cache of another key."""
        return self.folder != self.target

    # -- opening --------------------------------------------------------------------------
    def _open(self, keep: tuple[str, ...], beside: bool) -> None:
        recover_swap(self.target)
        _remove_stale_temps(self.target)  # under the writer's lock: no other writer owns them
        try:
            self.target.mkdir(parents=True, exist_ok=True)
        except OSError as ex:
            raise OutputError(f"cannot create the cache folder '{self.target}': {ex}") from ex
        old, self.stale_reason = _read_meta(self.target)
        if old is not None:
            diff = key_differences(old, self.key)
            if diff:
                why = "written with another " + ", ".join(k.replace("_", " ") for k in diff)
                if beside and isinstance(old.get("frames"), dict) and old["frames"]:
                    self.replaces = why
                    self.folder = rebuild_folder(self.target, self.key)
                    self._prune_rebuilds()
                    try:
                        self.folder.mkdir(exist_ok=True)
                    except OSError as ex:
                        raise OutputError(f"cannot create '{self.folder}' beside the cache '{self.target}': "
                                          f"{ex}") from ex
                    log.info("cache '%s' holds %d frames %s; building the new ones beside it in '%s' (the cache stays "
                             "as it is until they are complete)", self.target, len(old["frames"]), why, self.folder)
                    old, self.stale_reason = _read_meta(self.folder)
                    if old is not None and key_differences(old, self.key):
                        self.stale_reason, old = "written with another key", None
                else:
                    self.stale_reason, old = why, None
        if old is not None:
            frames = old.get("frames") or {}
            self.frames = {str(k): int(v) for k, v in frames.items()} if isinstance(frames, dict) else {}
            self.stabilized = _stabilized_record(old.get("stabilized"))
            self._adopt_pending()
            for k in keep:
                if k in old and k not in self.info:
                    self.info[k] = old[k]
        if self.stale_reason:
            removed = self._remove_frames()
            log.warning("cache '%s' is stale (%s): %d old frames removed, recomputing", self.folder,
                        self.stale_reason, removed)
            self.frames = {}
        self.flush()

    def _prune_rebuilds(self) -> None:
        """Remove partial rebuilds of other keys beside the target (only the newest key is kept)."""
        import shutil

        for d in _rebuilds(self.target):
            if d != self.folder and d.is_dir():
                shutil.rmtree(d, ignore_errors=True)
                folder_lock.lock_path(d).unlink(missing_ok=True)

    def commit(self) -> None:
        """Put a cache rebuilt beside the old one in its place (call once every frame the caller
        wants is written); nothing to do when it was written in place. Files of the old folder
        that are not the cache's own are carried over, not lost."""
        if not self.rebuilding:
            return
        meta, _ = _read_meta(self.folder)  # another writer in this process (Analyze's stabilize) may have added
        if meta is not None and not key_differences(meta, self.key) and isinstance(meta.get("frames"), dict):
            self.frames = {str(k): int(v) for k, v in meta["frames"].items()}
            self.stabilized = _stabilized_record(meta.get("stabilized"))
            self.info.update({k: v for k, v in meta.items() if k not in self.key and k not in GENERATED_FIELDS})
        self._committing = True
        self.flush()
        try:
            for p in self.target.iterdir():
                if not _is_cache_entry(p.name) and not (self.folder / p.name).exists():
                    p.replace(self.folder / p.name)
            replace_folder(self.folder, self.target)
        except OSError as ex:
            raise OutputError(f"cannot put the rebuilt cache '{self.folder}' in place of '{self.target}': {ex}; the "
                              "earlier cache is still there; run the same command again") from ex
        rebuilt, self.folder = self.folder, self.target
        folder_lock.lock_path(rebuilt).unlink(missing_ok=True)
        self._committing = False
        self.flush()
        log.info("cache '%s': replaced the frames %s with the %d new ones", self.target, self.replaces,
                 len(self.frames))
        self.replaces = None

    def close(self) -> None:
        """Give the folder's lock back (the object must not write afterwards)."""
        self._lock = None
        self._parent_lock = None

    def fork(self, tag: dict, why: str) -> "ClipCache":
        """A copy of this cache beside it, under the same key, that :meth:`commit` puts in its place
        (``rvr stabilize`` with other settings keeps the complete stabilized cache until the new
        one is). The frames are hard links (copies where the filesystem has none): frame files are
        only ever replaced by a rename, never written in place, so the original stays as it is.
        An interrupted fork with the same ``tag`` (JSON-serialisable) is resumed."""
        import shutil

        folder = rebuild_folder(self.target, {**self.key, "fork": tag})
        if not folder.is_dir():
            tmp = temp_sibling(folder, ".seed")
            tmp.mkdir()
            try:
                for number in self.frames:
                    src = self.folder / FRAME_NAME.format(int(number))
                    try:
                        os.link(src, tmp / src.name)
                    except OSError:
                        shutil.copy2(src, tmp / src.name)
                shutil.copy2(self.folder / "meta.json", tmp / "meta.json")
                tmp.rename(folder)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        child = ClipCache(folder, self.key, self.info, self.flush_every, beside=False)
        child.target, child.replaces, child._parent_lock = self.target, why, self._lock
        log.info("cache '%s': %s; building beside it in '%s' (the cache stays as it is until that is complete)",
                 self.target, why, folder)
        return child

    def stabilized_complete(self) -> bool:
        """True if every recorded frame holds stabilized channels (see :func:`stabilized_complete`)."""
        return stabilized_complete({"frames": self.frames, "stabilized": self.stabilized})

    def _remove_frames(self) -> int:
        n = 0
        for p in self.folder.iterdir():
            if _FRAME_RE.match(p.name) and p.is_file():
                p.unlink()
                n += 1
        return n

    # -- frames ---------------------------------------------------------------------------
    def is_valid(self, index: int, size: tuple[int, int]) -> bool:
        """True if frame ``index`` (0-based) is recorded, its file has the recorded size and its
        EXR header holds every channel at size (w, h). Only the header is read: a re-run that reuses
        a clip's depth read every frame whole to check it and then again to use it (a 720p frame
        ~40 ms; 0.1 ms now). Pixel data that no longer decodes is named by the reader that meets it
        (``io.exr.read_exr``'s InputError), non-finite values are filled and logged by the maps'
        reader (``io.maps``); :meth:`read_valid` still checks a whole frame as it reads it."""
        path = frame_path(self.folder, index)
        if not self._recorded_size(index, path):
            return False
        try:
            names, dims = read_exr_header(path)
        except InputError:
            return False
        return dims == (size[0], size[1]) and all(name in names for name in CHANNELS)

    def _recorded_size(self, index: int, path: Path) -> bool:
        """Whether frame ``index`` is recorded and its file ``path`` exists at a recorded size."""
        recorded = self.frames.get(str(index + 1))
        pending = (self.stabilized or {}).get("pending", {}).get(str(index + 1))
        return recorded is not None and path.is_file() and path.stat().st_size in (recorded, pending)

    def read_valid(self, index: int, size: tuple[int, int]) -> dict[str, np.ndarray] | None:
        """Every channel of frame ``index``'s EXR ({name: (H, W) float32}) if it is recorded, intact
        and at size (w, h), else None: checking and reading in one read (:func:`split_channels`
        gives D, E)."""
        path = frame_path(self.folder, index)
        if not self._recorded_size(index, path):
            return None
        try:
            channels = read_exr(path)
        except InputError:
            return None
        for name in CHANNELS:
            arr = channels.get(name)
            if arr is None or arr.shape != (size[1], size[0]) or not np.isfinite(arr).all():
                return None
        return channels

    def read(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """(D (H, W), E (H, W, 3)) float32 of a cached frame (check :meth:`is_valid` first)."""
        return split_channels(read_exr(frame_path(self.folder, index)))

    def write(self, index: int, disparity: np.ndarray, exponent: np.ndarray) -> None:
        """Store frame ``index``: disparity (H, W) px, exponent (H, W, 3); atomic, then recorded."""
        path = frame_path(self.folder, index)
        write_exr(path, {"D": disparity, "E.R": exponent[..., 0], "E.G": exponent[..., 1],
                         "E.B": exponent[..., 2]}, compression=EXR_COMPRESSION)
        self.frames[str(index + 1)] = path.stat().st_size
        if self.stabilized is not None:
            log.info("cache '%s': frame %d re-estimated; the stabilized channels are outdated (run rvr stabilize "
                     "again)", self.folder, index)
            self._adopt_pending()
            self.stabilized = None
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
        if self.stabilized is not None:
            meta["stabilized"] = self.stabilized
        if self._committing:
            meta["committing"] = True
        path = self.folder / "meta.json"
        tmp = temp_sibling(path, ".json")
        try:
            tmp.write_text(json.dumps(meta, indent=1))
            os.replace(tmp, path)
        except OSError as ex:
            tmp.unlink(missing_ok=True)
            raise OutputError(f"cannot write '{path}': {ex}. Check free disk space and permissions.") from ex
        self._dirty = 0

    # -- stabilized channels (rvr stabilize) ----------------------------------------------
    @classmethod
    def open_existing(cls, folder: str | Path) -> "ClipCache":
        """Open a cache written by ``rvr estimate`` under the key recorded in its meta.json.

        Raises InputError naming the folder when it is not a cache (no or unreadable
        meta.json, another format) or holds no frame.
        """
        folder = Path(folder)
        meta_path = folder / "meta.json"
        if not folder.is_dir() or not meta_path.is_file():
            raise InputError(f"'{folder}' is not an estimation cache (no meta.json); create it with "
                             f"`rvr estimate INPUT -o {folder} ...` first")
        try:
            meta = json.loads(meta_path.read_text())
            if not isinstance(meta, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as ex:
            raise InputError(f"'{meta_path}' is unreadable ({ex}); re-run `rvr estimate ... -o {folder}` to "
                             "rebuild the cache") from ex
        if meta.get("format") != CACHE_FORMAT or any(k not in meta for k in KEY_FIELDS):
            raise InputError(f"'{meta_path}' is not a cache of format {CACHE_FORMAT} (format {meta.get('format')!r}); "
                             f"re-run `rvr estimate ... -o {folder}` with this version")
        if not meta.get("frames"):
            raise InputError(f"the cache '{folder}' holds no frame; run `rvr estimate ... -o {folder}` first")
        key = key_of(meta)
        info = {k: v for k, v in meta.items() if k not in key and k not in GENERATED_FIELDS}
        return cls(folder, key, info)

    def _adopt_pending(self) -> None:
        """A file renamed into place by an interrupted :meth:`write_stabilized` (its size is
        recorded as pending) holds intact raw channels: record its size as the frame's."""
        if self.stabilized is None:
            return
        for number, size in list(self.stabilized["pending"].items()):
            path = self.folder / FRAME_NAME.format(int(number))
            if number in self.frames and path.is_file() and path.stat().st_size == size:
                self.frames[number] = size
            del self.stabilized["pending"][number]

    def frame_indices(self) -> list[int]:
        """0-based clip indices of the recorded frames, ascending."""
        return sorted(int(k) - 1 for k in self.frames)

    def begin_stabilized(self, settings: dict) -> None:
        """Start or continue the stabilized record for ``settings`` (JSON-serialisable);
        a record made with other settings is replaced (its frames are recomputed)."""
        settings = json.loads(json.dumps(settings))
        self._adopt_pending()
        if self.stabilized is None or self.stabilized.get("settings") != settings:
            if self.stabilized is not None:
                log.info("cache '%s': stabilized channels were made with other settings; recomputing", self.folder)
            self.stabilized = {"settings": settings, "frames": {}, "pending": {}}
            self.flush()

    def has_stabilized(self, index: int) -> bool:
        """True if frame ``index`` holds stabilized channels under the current record."""
        if self.stabilized is None:
            return False
        size = self.stabilized["frames"].get(str(index + 1))
        return size is not None and self.frames.get(str(index + 1)) == size and \
            frame_path(self.folder, index).is_file() and frame_path(self.folder, index).stat().st_size == size

    def write_stabilized(self, index: int, disparity: np.ndarray, exponent: np.ndarray,
                         confidence: np.ndarray, existing: dict[str, np.ndarray] | None = None) -> None:
        """Add S.D, S.E.R/G/B, S.C to frame ``index``'s EXR, keeping its raw channels.

        disparity (H, W) px, exponent (H, W, 3), confidence (H, W) in [0, 1]. existing: the
        file's channels as :meth:`read_valid` gave them (None: read again). Atomic, in two
        steps (see the module docstring); call :meth:`begin_stabilized` first.
        """
        if self.stabilized is None:
            raise RuntimeError("write_stabilized before begin_stabilized")
        path = frame_path(self.folder, index)
        # every channel already there is kept (raw D, E and any other)
        channels = dict(read_exr(path) if existing is None else existing)
        channels.update({"S.D": disparity, "S.E.R": exponent[..., 0], "S.E.G": exponent[..., 1],
                         "S.E.B": exponent[..., 2], "S.C": confidence})
        tmp = temp_sibling(path, ".exr")
        try:
            write_exr(tmp, channels, compression=EXR_COMPRESSION)
            size = tmp.stat().st_size
            self.stabilized["pending"][str(index + 1)] = size
            self.flush()
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        self.frames[str(index + 1)] = size
        self.stabilized["frames"][str(index + 1)] = size
        del self.stabilized["pending"][str(index + 1)]
        self._dirty += 1
        if self._dirty >= self.flush_every:
            self.flush()

    def adopt(self, files: dict[int, Path], stabilized: dict | None = None) -> int:
        """Move frame files finished elsewhere into this cache and record them (``rvr batch``:
        each chunk writes a staging cache of its own; one task per clip adopts them here, so
        meta.json has one writer). Returns the number of files moved.

        files: clip index -> EXR on the same filesystem, checked by the writer (a staging
        :class:`ClipCache` under this key). A file that already is this cache's frame (a hard
        link, or the frame path itself) is only recorded, so adopting again after a crash is
        safe. stabilized: None for raw frames (D, E; replacing a recorded frame with another
        file drops the stabilized record, as :meth:`write` does); else the settings record
        the files' S.* channels were made with (as :meth:`begin_stabilized` takes it): the
        moves are recorded as pending first, so a crash mid-way leaves every raw frame valid.
        """
        if stabilized is not None:
            self.begin_stabilized(stabilized)
        sizes, moves = {}, []
        for index, src in sorted(files.items()):
            dst = frame_path(self.folder, index)
            sizes[index] = src.stat().st_size
            if not (dst.exists() and os.path.samefile(src, dst)):
                moves.append((index, src, dst))
        if moves:
            for index, _, _ in moves:
                if stabilized is not None:
                    self.stabilized["pending"][str(index + 1)] = sizes[index]
                else:
                    self.frames.pop(str(index + 1), None)
            if stabilized is None and self.stabilized is not None:
                log.info("cache '%s': %d frames re-estimated; the stabilized channels are outdated", self.folder,
                         len(moves))
                self._adopt_pending()
                self.stabilized = None
            self.flush()
            for _, src, dst in moves:
                os.replace(src, dst)
        for index, size in sizes.items():
            self.frames[str(index + 1)] = size
            if stabilized is not None:
                self.stabilized["frames"][str(index + 1)] = size
                self.stabilized["pending"].pop(str(index + 1), None)
        self.flush()
        return len(moves)

    def read_stabilized(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(S.D (H, W), S.E (H, W, 3), S.C (H, W)) float32 of a stabilized frame."""
        ch = read_exr(frame_path(self.folder, index))
        return ch["S.D"], np.dstack([ch["S.E.R"], ch["S.E.G"], ch["S.E.B"]]), ch["S.C"]


def _stabilized_record(value) -> dict | None:
    """The "stabilized" record of a meta.json, normalised (None if absent or malformed)."""
    if not isinstance(value, dict) or not isinstance(value.get("frames"), dict):
        return None
    try:
        frames = {str(k): int(v) for k, v in value["frames"].items()}
        pending = {str(k): int(v) for k, v in (value.get("pending") or {}).items()}
    except (TypeError, ValueError):
        return None
    return {"settings": value.get("settings"), "frames": frames, "pending": pending}


def stabilized_complete(meta: dict) -> bool:
    """True if a cache's meta.json records stabilized channels for every one of its frames
    (same byte sizes as the frame records, nothing pending): then renderers read S.D/S.E."""
    frames = meta.get("frames")
    rec = _stabilized_record(meta.get("stabilized"))
    if not isinstance(frames, dict) or not frames or rec is None or rec["pending"]:
        return False
    return all(rec["frames"].get(str(k)) == int(v) for k, v in frames.items())
