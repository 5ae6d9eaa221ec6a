"""Per-chunk staging caches: every per-clip cache keeps a single writer.

A cache's ``meta.json`` is rewritten by the process that writes its frames, so two workers
writing chunks of one clip into the same cache would lose each other's records. Instead each
estimate or stabilize chunk works in a *staging cache* of its own (a complete cache folder
under the same key, on the same filesystem), seeded with hard links to the frames the clip
cache already holds for the chunk's range (so finished frames are reused, not recomputed).
One merge task per clip and stage then moves the finished files into the clip cache
(:meth:`rvr_addon.estimate.cache.ClipCache.adopt`: atomic renames, recorded once).

A worker killed mid-chunk leaves at most a staging folder whose recorded frames are intact
(every EXR is written to a temp name and renamed); the retried chunk resumes from it. Frames
are named by clip index, so a retried chunk can never add a frame twice.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

from ..estimate.cache import ClipCache, frame_path
from ..io.paths import temp_sibling

log = logging.getLogger(__name__)


def _link(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:  # a filesystem without hard links: copy (slower, same result)
        shutil.copy2(src, dst)


def seed_staging(clip_cache: Path, staging: Path, first: int, stop: int) -> None:
    """Create ``staging`` as a cache holding the clip cache's recorded frames first..stop-1
    (hard links) under the clip cache's key; keep an existing staging folder as it is (a
    retried chunk resumes from what it had written). Frames whose files do not match their
    record, or that are mid-rewrite (pending), are left out and so recomputed."""
    if staging.is_dir():
        return
    staging.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(staging, ".seed")
    tmp.mkdir()
    try:
        meta_path = clip_cache / "meta.json"
        meta = None
        if meta_path.is_file():
            try:
                meta = json.loads(meta_path.read_text())
            except (OSError, ValueError):
                meta = None  # unreadable: the chunk computes everything; the merge replaces it
        if isinstance(meta, dict) and isinstance(meta.get("frames"), dict):
            stab = meta.get("stabilized") if isinstance(meta.get("stabilized"), dict) else None
            pending = set((stab or {}).get("pending") or {})
            frames = {}
            for number, size in meta["frames"].items():
                index = int(number) - 1
                src = frame_path(clip_cache, index)
                if first <= index < stop and number not in pending and src.is_file() and \
                        src.stat().st_size == int(size):
                    _link(src, frame_path(tmp, index))
                    frames[number] = int(size)
            meta["frames"] = frames
            if stab is not None:
                meta["stabilized"] = {"settings": stab.get("settings"), "pending": {},
                                      "frames": {k: v for k, v in (stab.get("frames") or {}).items() if k in frames}}
            (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
        os.rename(tmp, staging)
    except FileExistsError:  # pragma: no cover - a duplicate of this task seeded it first
        shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def adopt_estimates(clip_cache: Path, staging: Path) -> int:
    """Move the raw frames of an estimate staging cache into the clip cache (opened under the
    staging key: a clip cache of another model or source is stale and cleared); remove the
    staging folder. Safe to repeat after a crash. Returns the frames moved."""
    if not staging.is_dir():
        return 0  # merged before (the folder goes only after the clip cache recorded its frames)
    part = ClipCache.open_existing(staging)
    # in place: the chunks are adopted one by one, so a cache of other settings is cleared here
    # (it is the batch's own; every chunk is complete before its merge)
    target = ClipCache(clip_cache, dict(part.key), dict(part.info), beside=False)
    part.close()
    files = {i: frame_path(staging, i) for i in part.frame_indices()}
    try:
        moved = target.adopt(files)
    finally:
        target.close()  # the lock goes now, also when a failed task's traceback outlives it
    shutil.rmtree(staging, ignore_errors=True)
    return moved


def adopt_stabilized(clip_cache: Path, staging: Path, first: int, stop: int) -> int:
    """Move the frames first..stop-1 stabilized in a staging cache into the clip cache
    (the overlap frames it only read stay behind); remove the staging folder. Safe to
    repeat. Returns the frames moved."""
    if not staging.is_dir():
        return 0
    part = ClipCache.open_existing(staging)
    if part.stabilized is None:
        raise RuntimeError(f"staging cache '{staging}' holds no stabilized record")
    files = {i: frame_path(staging, i) for i in part.frame_indices() if first <= i < stop and part.has_stabilized(i)}
    part.close()
    target = ClipCache.open_existing(clip_cache)
    try:
        moved = target.adopt(files, stabilized=part.stabilized["settings"])
    finally:
        target.close()
    shutil.rmtree(staging, ignore_errors=True)
    return moved
