"""Focus annotations as a dataset: editor exports (ground truth) and AI-assist weak labels.

Format ``rvr-laaf-focus-annotations/1``, one JSON file (UTF-8):

```json
{"format": "rvr-laaf-focus-annotations/1",
 "clips": {"shots/take3.mp4": {"depth": "shots/take3_cache", "fps": 30}},
 "annotations": [
   {"clip": "shots/take3.mp4", "frame": 120, "box": [412, 96, 180, 240],
    "source": "manual", "nft": true},
   {"clip": "shots/take3.mp4", "frame": 125, "box": [418, 98, 176, 238],
    "source": "tracked", "nft": false},
   {"clip": "shots/walk.mp4", "frame": 40, "box": [10, 50, 60, 120],
    "source": "weak:action", "nft": true, "weak": true}
 ]}
```

- ``clip``: the video or image sequence (anything ``rvr autofocus`` reads), relative to the
  JSON file's folder or absolute.
- ``frame``: 0-based clip frame index. ``box``: ``[x, y, w, h]`` in px of the clip's native
  frame (origin top-left, as ``rvr_addon.laaf.nft``); a box reaching outside the frame is
  clipped when read.
- ``source``: who made the record: ``manual`` (an editor placed the NFT), ``accepted:<detector>``
  (an editor accepted an AI-assist NFT), ``tracked`` (the tracker's box that the editor kept),
  ``weak:<preset>`` (detectors alone).
- ``nft`` (default true): the frame is a New Focus Target; false: only the focus region of
  that frame (the target being followed).
- ``weak`` (default false): produced by the AI-assist detectors without a person's check.
  Weak records train with a lower loss weight (``rvr train-afnet --weak-weight``) and are
  never used as ground truth in an evaluation. A clip's records are either all weak or all
  not (a clip with both is read as two separate clips, one of each kind).
- ``clips`` (optional): per clip, ``depth`` (an ``rvr estimate`` cache folder or disparity maps
  for ``--depth``, relative like ``clip``; without it the disparity channel is zero) and
  ``fps`` of an image sequence.

Every NFT of a listed clip is annotated: frames away from the listed NFTs are negatives when
training (a clip with region records only is a clip without NFTs). The Blender tool writes
this format from the NFTs an editor placed or accepted (the export itself lives in
``operators/``); :func:`write_annotations` writes it from Python.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from ..errors import InputError

ANNOTATION_FORMAT = "rvr-laaf-focus-annotations/1"
_HELP = ('a focus annotation file is {"format": "rvr-laaf-focus-annotations/1", "annotations": [{"clip": path, '
         '"frame": 0-based index, "box": [x, y, w, h], "source": "manual", "nft": true, "weak": false}, ...]} '
         "(see rvr_addon/afnet/annotations.py)")


@dataclass(frozen=True)
class Annotation:
    """One record: a focus region (box, native px) at a 0-based frame, an NFT or not."""

    frame: int
    box: tuple[float, float, float, float]
    source: str = "manual"
    nft: bool = True
    weak: bool = False


@dataclass
class AnnotatedClip:
    """All records of one clip of one kind (weak or not), sorted by frame.

    clip: the video or image sequence. depth: disparity source (cache folder or maps) or None.
    fps: frame rate of an image sequence (None: the reader's default)."""

    clip: Path
    records: list[Annotation] = field(default_factory=list)
    weak: bool = False
    depth: Path | None = None
    fps: float | None = None

    @property
    def nft_frames(self) -> list[int]:
        """Frames of the NFT records."""
        return sorted({r.frame for r in self.records if r.nft})


def _resolve(base: Path, value: Any, what: str, where: str) -> Path:
    if not isinstance(value, str) or not value:
        raise InputError(f"{where}: {what} {value!r} is not a path; {_HELP}")
    p = Path(value)
    return p if p.is_absolute() else base / p


def _record(d: Any, i: int, where: str) -> tuple[str, Annotation]:
    name = f"{where}: annotation #{i}"
    if not isinstance(d, dict):
        raise InputError(f"{name} is not an object; {_HELP}")
    for key in ("clip", "frame", "box"):
        if key not in d:
            raise InputError(f"{name} lacks '{key}'; {_HELP}")
    frame = d["frame"]
    if isinstance(frame, bool) or not isinstance(frame, (int, float)) or frame != int(frame) or frame < 0:
        raise InputError(f"{name}: frame {frame!r} must be a whole number >= 0 (0-based clip index)")
    box = d["box"]
    if not isinstance(box, (list, tuple)) or len(box) != 4:
        raise InputError(f"{name}: box {box!r} must be [x, y, w, h] in px")
    try:
        box_f = tuple(float(v) for v in box)
    except (TypeError, ValueError):
        raise InputError(f"{name}: box {box!r} must hold 4 numbers [x, y, w, h] in px") from None
    if not all(math.isfinite(v) for v in box_f) or box_f[2] <= 0 or box_f[3] <= 0:
        raise InputError(f"{name}: box {box!r} needs finite numbers and a positive width and height")
    for key in ("nft", "weak"):
        if key in d and not isinstance(d[key], bool):
            raise InputError(f"{name}: '{key}' must be true or false, got {d[key]!r}")
    return str(d["clip"]), Annotation(int(frame), box_f, str(d.get("source", "manual")), bool(d.get("nft", True)),
                                      bool(d.get("weak", False)))


def read_annotations(path: str | Path) -> list[AnnotatedClip]:
    """Read a focus annotation file (module docstring) into clips, sorted by path then kind.

    Raises InputError naming the file and the record for: a missing or unreadable file, another
    format, a record without clip/frame/box, a frame that is not a whole number >= 0, a box
    without area, two NFT records on one frame of a clip."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"focus annotation file '{path}' not found; export it from the Blender tool or write "
                         "it with rvr_addon.afnet.annotations.write_annotations") from None
    except (OSError, ValueError) as ex:
        raise InputError(f"focus annotation file '{path}' is not readable JSON ({ex}); {_HELP}") from ex
    if not isinstance(data, dict) or data.get("format") != ANNOTATION_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise InputError(f"'{path}' has format {got!r}, not '{ANNOTATION_FORMAT}'; {_HELP}")
    items = data.get("annotations")
    if not isinstance(items, list):
        raise InputError(f"'{path}': 'annotations' must be a list; {_HELP}")
    base = path.parent
    info = data.get("clips") or {}
    if not isinstance(info, dict):
        raise InputError(f"'{path}': 'clips' must map a clip path to {{\"depth\": ..., \"fps\": ...}}")
    groups: dict[tuple[str, bool], AnnotatedClip] = {}
    for i, item in enumerate(items):
        clip, rec = _record(item, i, str(path))
        key = (clip, rec.weak)
        if key not in groups:
            extra = info.get(clip) or {}
            depth = _resolve(base, extra["depth"], "depth", f"{path}: clips[{clip!r}]") if extra.get("depth") else None
            fps = float(extra["fps"]) if extra.get("fps") else None
            groups[key] = AnnotatedClip(_resolve(base, clip, "clip", f"{path}: annotation #{i}"), [], rec.weak,
                                        depth, fps)
        groups[key].records.append(rec)
    out = []
    for (clip, _), group in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1])):
        group.records.sort(key=lambda r: (r.frame, not r.nft))
        frames = [r.frame for r in group.records if r.nft]
        dup = sorted({f for f in frames if frames.count(f) > 1})
        if dup:
            raise InputError(f"'{path}': clip {clip!r} has two NFT records on frame(s) {dup}; keep one per frame")
        out.append(group)
    return out


def write_annotations(path: str | Path, clips: Iterable[AnnotatedClip]) -> Path:
    """Write clips' records in the format of the module docstring (paths relative to the
    file's folder where possible), atomically. Returns the path."""
    import os

    from ..io.paths import temp_sibling

    path = Path(path)
    base = path.parent.resolve()
    records, info = [], {}

    def rel(p: Path) -> str:
        try:
            return str(Path(p).resolve().relative_to(base))
        except ValueError:
            return str(Path(p).resolve())

    for c in clips:
        name = rel(c.clip)
        if c.depth is not None or c.fps is not None:
            info[name] = {k: v for k, v in (("depth", rel(c.depth) if c.depth else None), ("fps", c.fps)) if v}
        for r in c.records:
            records.append({"clip": name, "frame": int(r.frame), "box": [round(float(v), 3) for v in r.box],
                            "source": r.source, "nft": bool(r.nft), "weak": bool(r.weak or c.weak)})
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path, ".json")
    tmp.write_text(json.dumps({"format": ANNOTATION_FORMAT, "clips": info, "annotations": records}, indent=1))
    os.replace(tmp, path)
    return path
