"""Which clips a batch covers, and the unique output name of each.

A clip is a video file or an image-sequence folder (anything ``rvr render`` reads). Arguments
may be clips, folders of clips, or list files (``.txt``/``.list``: one clip per line, ``#``
comments, paths relative to the list file). A folder holding image files is one clip (an
image sequence); otherwise its videos (and sub-folders that are image sequences) are clips.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

from ..errors import InputError
from ..io.video import IMAGE_EXTENSIONS

VIDEO_EXTENSIONS = (".mp4", ".mov", ".mkv", ".m4v", ".avi", ".webm", ".mts", ".m2ts")
LIST_EXTENSIONS = (".txt", ".list", ".lst")


def _is_image_sequence(folder: Path) -> bool:
    return any(p.suffix.lower() in IMAGE_EXTENSIONS for p in folder.iterdir() if p.is_file())


def _folder_clips(folder: Path) -> list[Path]:
    if _is_image_sequence(folder):
        return [folder]
    found = []
    for p in sorted(folder.iterdir()):
        if p.name.startswith("."):
            continue
        if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS:
            found.append(p)
        elif p.is_dir() and _is_image_sequence(p):
            found.append(p)
    return found


def _list_file(path: Path) -> list[Path]:
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as ex:
        raise InputError(f"cannot read the clip list '{path}' ({ex}); give a text file with one clip per line") from ex
    out = []
    for line in lines:
        line = line.strip()
        if line and not line.startswith("#"):
            p = Path(line).expanduser()
            out.append(p if p.is_absolute() else path.parent / p)
    return out


def collect_clips(items: list[Path]) -> list[Path]:
    """The clips named by ``items`` (clips, folders, list files), in order, without duplicates.

    A path that does not exist is kept: it fails alone as a clip, reported with the others
    (a batch of many should not stop for one bad entry). Raises InputError when nothing
    at all is given or a folder argument holds no clip.
    """
    if not items:
        raise InputError("rvr batch needs clips: give video files, folders of clips or a list file (clips.txt)")
    clips: list[Path] = []
    for item in items:
        item = Path(item).expanduser()
        if item.is_dir():
            found = _folder_clips(item)
            if not found:
                raise InputError(f"the folder '{item}' holds no clip (videos {', '.join(VIDEO_EXTENSIONS)} or "
                                 "image-sequence folders); check the path")
            clips += found
        elif item.is_file() and item.suffix.lower() in LIST_EXTENSIONS:
            clips += _list_file(item)
        else:
            clips.append(item)
    seen, unique = set(), []
    for c in clips:
        key = os.path.abspath(c)
        if key not in seen:
            seen.add(key)
            unique.append(c)
    return unique


def path_id(path: Path, length: int = 8) -> str:
    """Short stable id (hex) of a clip's absolute path."""
    return hashlib.sha1(os.path.abspath(path).encode()).hexdigest()[:length]


def clip_names(clips: list[Path]) -> list[str]:
    """Output stems, one per clip: the file (or folder) stem, plus ``-<path id>`` when two
    clips of the batch share a stem (``a/take1.mp4`` and ``b/take1.mp4``)."""
    stems = [(c.stem if c.suffix.lower() in VIDEO_EXTENSIONS else c.name) or "clip" for c in clips]
    counts: dict[str, int] = {}
    for s in stems:
        counts[s] = counts.get(s, 0) + 1
    return [s if counts[s] == 1 else f"{s}-{path_id(c, 6)}" for s, c in zip(stems, clips)]
