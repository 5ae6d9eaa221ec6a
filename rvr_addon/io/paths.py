"""Resolve a file-sequence spec (directory, glob pattern, printf pattern) to an ordered file list.

Shared by video input (image sequences) and per-frame maps. Pure filesystem logic, no decoding.
"""
from __future__ import annotations

import glob
import os
import re
import secrets
from pathlib import Path
from typing import Iterable

from ..errors import InputError

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


# ----------------------------------------------------------------------------- outputs vs inputs


def _real(path: str | Path) -> Path:
    """Absolute path with symlinks and ``..`` resolved (also for paths that do not exist yet),
    case-folded where the filesystem ignores case; a file pattern stands for its folder."""
    text = str(path)
    p = Path(text)
    if not p.exists() and (is_printf_pattern(text) or is_glob_pattern(p.name)):
        p = p.parent
    return Path(os.path.normcase(os.path.realpath(p)))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)  # a hard link (or another name) of the same file
    except OSError:
        return False


def _inside(child: Path, folder: Path) -> bool:
    return child != folder and child.is_relative_to(folder)


def check_outputs(command: str, outputs: Iterable[tuple[str, str | Path | None]],
                  inputs: Iterable[tuple[str, str | Path | None]]) -> None:
    """Refuse an output of ``rvr COMMAND`` that would overwrite or swallow one of its inputs.

    outputs / inputs: ``(what, path)`` pairs ("video", "cache folder", ...); None paths are
    skipped; a frame pattern (``frames/f_%04d.png``, ``depth/*.exr``) stands for its folder.
    An output is refused (InputError naming both paths, before anything is written) when it
    resolves to an input (through ``..``, symlinks or case), is a hard link of one, contains
    one (an output folder is replaced as a whole), or lies inside an input folder (a frames
    folder, maps folder or cache would read it back, or lose it when it is rebuilt).
    """
    ins = [(what, Path(p), _real(p)) for what, p in inputs if p is not None and str(p) != ""]
    for out_what, out in outputs:
        if out is None or str(out) == "":
            continue
        out = Path(out)
        real_out = _real(out)
        for in_what, inp, real_in in ins:
            if real_out == real_in or _same_file(out, inp):
                raise InputError(
                    f"rvr {command}: the {out_what} '{out}' is the same file or folder as the {in_what} '{inp}'; "
                    f"writing it would destroy the input. Choose another {out_what} path (e.g. "
                    f"'{out.with_name(out.stem + '_out' + out.suffix)}')")
            if _inside(real_in, real_out):
                raise InputError(
                    f"rvr {command}: the {out_what} '{out}' contains the {in_what} '{inp}'; an output folder is "
                    f"replaced as a whole, so the input would be lost. Choose a {out_what} outside '{inp}'s folder")
            if _inside(real_out, real_in):
                raise InputError(
                    f"rvr {command}: the {out_what} '{out}' lies inside the {in_what} '{inp}'; it would be read "
                    f"back as input or lost when that folder is rebuilt. Choose a {out_what} outside '{inp}'")
