"""Resolve a file-sequence spec (directory, glob pattern, printf pattern) to an ordered file list.

Shared by video input (image sequences) and per-frame maps. Pure filesystem logic, no decoding.
"""
from __future__ import annotations

import glob
import re
import secrets
from pathlib import Path
from typing import Iterable

_DIGITS = re.compile(r"(\d+)")
_PRINTF = re.compile(r"%(0?\d*)d")
_GLOB_CHARS = set("*?[")


def natural_key(path: str | Path) -> tuple:
    """Sort key that orders embedded numbers by value: frame2 < frame10."""
    parts = _DIGITS.split(Path(path).name)
    return tuple((0, int(p), p) if p.isdigit() else (1, 0, p.lower()) for p in parts) + (str(path),)


def is_glob_pattern(spec: str) -> bool:
    """True when the last path component holds glob wildcards (*, ?, [)."""
    return any(ch in _GLOB_CHARS for ch in spec)


def is_printf_pattern(spec: str) -> bool:
    """True when the file name holds one printf integer field such as %04d or %d."""
    return len(_PRINTF.findall(Path(spec).name)) == 1


def expand_printf(spec: str) -> list[Path]:
    """Files matching a printf pattern ("frames/f_%04d.png"), ordered by frame number.

    %04d matches exactly four or more digits padded with zeros (ffmpeg semantics); %d any digits.
    """
    path = Path(spec)
    match = _PRINTF.search(path.name)
    assert match is not None
    width = match.group(1)
    if width.startswith("0") and len(width) > 1:
        digits = r"(\d{%d,})" % int(width[1:])
    elif width:
        digits = r"\s*(\d+)"
    else:
        digits = r"(\d+)"
    before, after = path.name[: match.start()], path.name[match.end():]
    regex = re.compile(re.escape(before.replace("%%", "%")) + digits + re.escape(after.replace("%%", "%")) + r"\Z")
    folder = path.parent
    if not folder.is_dir():
        return []
    found = []
    for entry in folder.iterdir():
        m = regex.match(entry.name)
        if m and entry.is_file():
            found.append((int(m.group(1)), entry))
    found.sort(key=lambda item: (item[0], item[1].name))
    return [p for _, p in found]


def expand_glob(spec: str) -> list[Path]:
    """Files matching a glob pattern, in natural order."""
    return sorted((Path(p) for p in glob.glob(spec) if Path(p).is_file()), key=natural_key)


def list_directory(folder: Path, extensions: Iterable[str]) -> list[Path]:
    """Files in `folder` whose lower-case suffix is in `extensions` (with dot), natural order.

    Hidden files (leading dot) are skipped, so temp files of an interrupted writer are ignored.
    """
    exts = {e.lower() for e in extensions}
    files = [p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in exts]
    return sorted(files, key=natural_key)


def expand_sequence(spec: str | Path, extensions: Iterable[str]) -> tuple[str, list[Path]]:
    """Classify `spec` and list its files.

    Returns (kind, files) with kind one of "file" (an existing single file), "directory",
    "glob", "printf" or "missing" (nothing at that path and not a pattern; files is empty).
    Directories keep only files with one of `extensions`; patterns keep every match.
    """
    text = str(spec)
    path = Path(text)
    if path.is_dir():
        return "directory", list_directory(path, extensions)
    if path.is_file():
        return "file", [path]
    if is_printf_pattern(text):
        return "printf", expand_printf(text)
    if is_glob_pattern(path.name) or is_glob_pattern(str(path.parent)):
        return "glob", expand_glob(text)
    return "missing", []


def temp_sibling(path: Path, suffix: str = ".tmp") -> Path:
    """A hidden, unused name next to `path` ("dir/.name.<random><suffix>") for atomic writes.

    Not created here, so the writer creates it with the usual permissions (mkstemp would make
    the final file private to the user after the rename).
    """
    return path.parent / f".{path.name}.{secrets.token_hex(4)}{suffix}"


def replace_folder(new: Path, target: Path) -> None:
    """Put the finished folder ``new`` at ``target``: an existing ``target`` is moved aside first
    and deleted only after the rename (a crash leaves the old or the new folder, never neither)."""
    import shutil

    if target.exists():
        aside = temp_sibling(target, ".old")
        target.replace(aside)
        new.replace(target)
        shutil.rmtree(aside, ignore_errors=True)
    else:
        new.replace(target)
