"""From a strip to the engine's inputs: which file, which clip frames, where its cache is.

Every operator (Analyze, Add Focus Target, Track, Auto Focus, Render, the preview) reads the
strip through :func:`resolve_source`, so they agree on the frame mapping. Blender shows at
scene frame ``t`` the content frame (Blender's ``SEQ_give_frame_index``, reproduced by
:func:`content_frames`)::

    x = (t - strip.frame_start) * rate          rate: media fps / scene fps for a movie that
                                                plays at its own rate, else 1
    x = factor(x) * span                        retimed: piecewise linear between the retiming
                                                keys (index -> factor 0..1 of the content)
    clip frame = content_offset + round(x)      (x clamped to the content, strobe applied)

``content_offset`` is the strip's ``animation_offset_start`` plus, for an image strip, the
place of its first file in its folder (the engine reads the folder in natural order). Trimmed
handles (``frame_offset_start/end``) only narrow the visible span; frames the strip holds
beyond its content are holds, not clip frames. A slowed-down strip shows a clip frame on
several scene frames, a sped-up one skips clip frames; the engine still analyses and tracks
every clip frame between the first and the last one shown (``span.clip_start..clip_stop``).

Refused, with the fix in the message: reversed playback (look-ahead autofocus runs forward in
clip time), gradual speed transitions (an arc, not a line, between keys), and a strip feeding
a Speed Control effect (its mapping lives in another strip).

The pure helpers (:class:`FrameSpan`, :func:`frame_span`, :class:`Retiming`,
:func:`content_frames`, :func:`safe_file_name`) take plain numbers; :func:`resolve_source`
and :func:`cache_folder` read Blender state.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import bpy
import numpy as np

from . import compat
from ..rvr_addon.errors import InputError

if TYPE_CHECKING:
    from bpy.types import Scene, Strip

    from ..rvr_addon.io.video import ClipInfo

CLIP_TYPES = ("MOVIE", "IMAGE")
_UNSAFE_FILE_CHARS = '/\\:*?"<>|'
_PROBES: dict[tuple, "ClipInfo"] = {}


# ----------------------------------------------------------------------------- plain helpers


@dataclass(frozen=True)
class FrameSpan:
    """Which frames of a strip are shown, in scene and in clip frame numbers.

    scene_start/scene_stop: scene frames of the first/after-last shown content frame (no holds).
    clip_start/clip_stop: first/after-last clip frame (0-based in the input file or folder)
    shown in the span (every clip frame between them is analysed and tracked).
    final_start/final_end: the strip's visible span, holds included (a result spans it too).
    """

    scene_start: int
    scene_stop: int
    clip_start: int
    final_start: int
    final_end: int
    clip_stop: int

    @property
    def count(self) -> int:
        """Scene frames shown (= frames a render has)."""
        return self.scene_stop - self.scene_start


def frame_span(frame_start: int, final_start: int, final_end: int, duration: int, content_offset: int) -> FrameSpan:
    """Map a strip's visible span to the frames of its content, one clip frame per scene frame
    (bpy-free; :func:`resolve_source` corrects the clip range of a retimed strip).

    frame_start: scene frame of content frame 0 (``strip.frame_start``); final_start/final_end:
    visible span (``frame_final_start``/``frame_final_end``); duration: scene frames of content
    (``frame_duration``); content_offset: clip frame of content frame 0
    (``animation_offset_start`` plus, for an image strip, its first file's place in the folder).
    Frames of the span outside the content are holds of the first/last frame: not rendered.
    Raises InputError when no content frame is visible.
    """
    lo = max(final_start - frame_start, 0)
    hi = min(final_end - frame_start, duration)
    if hi <= lo:
        raise InputError(f"the strip shows no frame of its clip between frames {final_start} and {final_end} "
                         "(only held frames); move its handles over the clip")
    return FrameSpan(frame_start + lo, frame_start + hi, content_offset + lo, final_start, final_end,
                     content_offset + hi)


@dataclass(frozen=True)
class Retiming:
    """How a strip's time runs (bpy-free): see the module docstring.

    rate: media frames per scene frame (1 unless a movie plays at its own, other frame rate).
    keys: (index, factor) of each retiming key (index: media frames after ``frame_start``,
    factor: 0..1 of the content); empty = not retimed. length: content frames after the
    animation offsets (Blender's ``len``). factor_span: content frames factor 1 stands for
    (``length`` where the last key sits at the content's end, as in 5.0.1; ``length - 1`` where
    it sits on the last frame, as in 4.5 LTS). strobe: show only every strobe-th frame (1 = off).
    """

    rate: float = 1.0
    keys: tuple[tuple[float, float], ...] = ()
    length: int = 0
    factor_span: float = 0.0
    strobe: float = 1.0

    @property
    def identity(self) -> bool:
        """True when content frame = scene frame - frame_start (no speed change of any kind)."""
        return self.rate == 1.0 and not self.keys and self.strobe <= 1.0


def _retiming_factor(x: np.ndarray, keys: tuple[tuple[float, float], ...]) -> np.ndarray:
    """Blender's ``seq_retiming_evaluate``: the factor of the segment starting at the last key
    at or before ``x`` (never the last key), extended linearly, at most 1."""
    index = np.array([k[0] for k in keys], np.float64)
    factor = np.array([k[1] for k in keys], np.float64)
    seg = np.clip(np.searchsorted(index[:-1], x, side="right") - 1, 0, len(keys) - 2)
    width = index[seg + 1] - index[seg]
    step = np.divide(factor[seg + 1] - factor[seg], width, out=np.zeros_like(width), where=width > 0)
    return np.minimum(factor[seg] + step * (x - index[seg]), 1.0)


ROUND_TOLERANCE = 1e-4
"""Content positions within this of a half frame round up: Blender computes them in float32,
whose error falls on either side of an exact half (e.g. every other frame at 50 % speed)
depending on the version; a half rounds up in its intent (``round_fl_to_int``)."""


def content_frames(offsets: np.ndarray, timing: Retiming) -> np.ndarray:
    """Content frame (0-based after the animation offset) shown ``offsets`` scene frames after
    ``frame_start``, as Blender computes it (rounded half up)."""
    x = np.maximum(np.asarray(offsets, np.float64), 0.0)
    if timing.identity:
        return np.round(x).astype(np.int64)
    x = x * float(np.float32(timing.rate))
    if timing.keys:
        x = _retiming_factor(x, timing.keys) * timing.factor_span
    x = np.clip(x, 0.0, max(timing.length - 1, 0))
    if timing.strobe > 1.0:
        x = np.floor((x + ROUND_TOLERANCE) / timing.strobe) * timing.strobe  # the last multiple at or before
    return np.floor(x + 0.5 + ROUND_TOLERANCE).astype(np.int64)


def first_showing(clip_frames: np.ndarray, clip_frame: float) -> int:
    """Index of the first entry of non-decreasing ``clip_frames`` at or after ``clip_frame``
    (clamped to the array): where a key of that clip frame goes on the scene's timeline."""
    return int(min(np.searchsorted(clip_frames, clip_frame, side="left"), len(clip_frames) - 1))


def safe_file_name(name: str) -> str:
    """A strip name usable as a file name (path separators and reserved characters -> '_')."""
    cleaned = "".join("_" if c in _UNSAFE_FILE_CHARS or ord(c) < 32 else c for c in name).strip(" .")
    return cleaned or "strip"


# ----------------------------------------------------------------------------- Blender state


@dataclass(frozen=True)
class StripSource:
    """A movie or image strip read into plain values.

    path: the video file or the image folder. fps: the scene's frame rate for an image folder
    (None for a movie: its own rate). span: the shown frames. clip_frames: the clip frame shown
    at each scene frame of the span (non-decreasing). speed_changes: scene frames in the span
    where a retimed strip changes speed. retimed: the scene and clip frames do not run 1:1.
    """

    scene_name: str
    strip_name: str
    kind: str
    path: Path
    fps: float | None
    span: FrameSpan
    clip_frames: tuple[int, ...]
    speed_changes: tuple[int, ...] = ()
    retimed: bool = False

    @property
    def scene_frames(self) -> np.ndarray:
        """The span's scene frames, (count,) int64."""
        return np.arange(self.span.scene_start, self.span.scene_stop)

    def scene_to_clip(self, scene_frame: float) -> int | None:
        """Clip frame (0-based) shown at ``scene_frame``; None outside the span (holds included)."""
        k = int(round(scene_frame)) - self.span.scene_start
        return self.clip_frames[k] if 0 <= k < len(self.clip_frames) else None

    def clip_to_scene(self, clip_frame: float) -> int:
        """First scene frame of the span showing ``clip_frame`` or, when it is never shown (a
        sped-up strip skips it), the next clip frame shown; clamped to the span."""
        return self.span.scene_start + first_showing(np.asarray(self.clip_frames), clip_frame)

    def shows(self, clip_frame: int) -> bool:
        """True when ``clip_frame`` lies in the span's clip range (shown, or skipped between two shown)."""
        return self.span.clip_start <= clip_frame < self.span.clip_stop


def abspath(path: str, what: str, strip: "Strip") -> Path:
    """Absolute path of a strip setting; InputError for a //-relative path in an unsaved file."""
    if path.startswith("//") and not bpy.data.filepath:
        raise InputError(f"the {what} of strip '{strip.name}' ({path}) is relative to the .blend file, which is not "
                         "saved yet: save the .blend file or choose an absolute path")
    return Path(bpy.path.abspath(path, library=strip.id_data.library))


def clip_info(path: Path, fps: float | None) -> "ClipInfo":
    """The engine's probe of a clip (size, frame count), once per file version and frame rate."""
    from ..rvr_addon.io.video import probe_clip

    key = (str(path), path.stat().st_mtime_ns, fps)
    if key not in _PROBES:
        _PROBES[key] = probe_clip(path, fps=fps)
    return _PROBES[key]


def image_clip(strip: "Strip") -> tuple[Path, int]:
    """(folder, clip frame of the strip's first element): the engine reads the folder in
    natural order, so the strip's images must be one run of consecutive files there."""
    from ..rvr_addon.io.paths import list_directory
    from ..rvr_addon.io.video import IMAGE_EXTENSIONS

    folder = abspath(strip.directory, "image folder", strip)
    names = [e.filename for e in strip.elements]
    if not folder.is_dir():
        raise InputError(f"the image folder '{folder}' of strip '{strip.name}' does not exist (moved or renamed?); "
                         "relink the images (Strip > Image > Change Path/Files)")
    files = [p.name for p in list_directory(folder, IMAGE_EXTENSIONS)]
    try:
        first = files.index(names[0])
    except ValueError:
        raise InputError(f"image '{names[0]}' of strip '{strip.name}' is not in '{folder}'; relink the images") from None
    if files[first:first + len(names)] != names:
        raise InputError(f"the images of strip '{strip.name}' are not consecutive files of '{folder}' in name order; "
                         "put the strip's frames in a folder of their own, numbered in order")
    return folder, first


def scene_fps(scene: "Scene") -> float:
    return scene.render.fps / scene.render.fps_base


def check_clip_strip(strip: "Strip | None") -> "Strip":
    """The strip if it is a movie or image strip; InputError naming what is wrong otherwise."""
    if strip is None:
        raise InputError("no active strip: click a movie or image strip in the Sequencer first")
    kind = compat.strip_type(strip)
    if kind not in CLIP_TYPES:
        raise InputError(f"strip '{strip.name}' is a {kind.lower()} strip; select a movie or image strip "
                         "(sound, effect and meta strips cannot be refocused)")
    return strip


def check_playback(scene: "Scene", strip: "Strip") -> None:
    """InputError for time mappings the tool does not follow: reversed playback, a Speed Control
    effect fed by the strip (retiming keys, strobe and a movie's own frame rate are followed)."""
    if getattr(strip, "use_reverse_frames", False):
        raise InputError(f"strip '{strip.name}' plays reversed: look-ahead autofocus and tracking run forward in "
                         "clip time; turn Reverse Frames off, refocus the strip, then reverse the result strip "
                         f"'{strip.name} [RVR]' (Strip > Time > Reverse Frames)")
    for other in compat.strips_all(scene):
        if compat.strip_type(other) == "SPEED" and getattr(other, "input_1", None) == strip:
            raise InputError(f"strip '{strip.name}' is sped up by the Speed Control strip '{other.name}', whose frame "
                             f"mapping the refocus tool does not follow; retime '{strip.name}' itself instead "
                             "(Strip > Retiming, Set Speed) and delete the Speed Control strip")


def _content_length(strip: "Strip", path: Path, fps: float | None) -> int:
    """Blender's ``len`` of the strip: clip frames after the animation offsets."""
    if compat.strip_type(strip) == "IMAGE":
        total = len(strip.elements)
    else:
        total = clip_info(path, fps).frame_count
    return total - int(strip.animation_offset_start) - int(strip.animation_offset_end)


def _playback_rate(scene: "Scene", strip: "Strip", keys: list, length: Callable[[], int]) -> float:
    """Media frames per scene frame: movie fps / scene fps when the movie plays at its own rate
    (its retiming keys or its length in scene frames say so), else 1."""
    media, rate = float(getattr(strip, "fps", 0.0) or 0.0), scene_fps(scene)
    if compat.strip_type(strip) != "MOVIE" or media <= 0 or abs(media - rate) < 1e-6:
        return 1.0
    own = float(np.float32(media / rate))
    start = float(strip.frame_start)
    if keys:  # a key's timeline frame = frame_start + index / rate
        last = keys[-1]
        miss_own = abs(start + last.index / own - last.timeline_frame)
        return own if miss_own < abs(start + last.index - last.timeline_frame) else 1.0
    return own if int(strip.frame_duration) != length() else 1.0


def read_retiming(scene: "Scene", strip: "Strip", length: Callable[[], int]) -> Retiming:
    """The strip's :class:`Retiming`; ``length`` returns Blender's ``len`` (probes a movie, so it
    is only called when the strip is retimed or plays at its own rate). InputError for a speed
    transition or retiming data this Blender stores in an unknown way."""
    keys = compat.retiming_keys(strip)
    if keys is None:
        raise InputError(f"strip '{strip.name}' is retimed, but this Blender version stores retiming in a way the "
                         "refocus tool cannot read; reset its retiming (Strip > Retiming > Reset) or render the "
                         "speed change as a separate step")
    if any(k.flags & compat.TRANSITION_FLAGS for k in keys):
        raise InputError(f"strip '{strip.name}' has a gradual speed transition between retiming keys, which the "
                         "refocus tool cannot follow; remove the transition (keep sharp speed changes)")
    strobe = max(float(getattr(strip, "strobe", 1.0)), 1.0)
    rate = _playback_rate(scene, strip, keys, length)
    if not keys and rate == 1.0:
        return Retiming(strobe=strobe, length=length() if strobe > 1.0 else 0)
    n = length()
    # 5.0.1: the last key sits at the content's end (factor 1 = len); 4.5 LTS: on the last frame
    end_at_last_frame = bool(keys) and keys[-1].timeline_frame - int(strip.frame_start) + 1 == int(strip.frame_duration)
    return Retiming(rate, tuple((k.index, k.factor) for k in keys), n, n - 1 if end_at_last_frame else n, strobe)


def resolve_source(scene: "Scene", strip: "Strip | None") -> StripSource:
    """Read a movie or image strip into a :class:`StripSource`.

    Raises InputError (an RvrError) naming the strip and the fix: no strip, a sound/effect
    strip, reversed playback or a Speed Control effect, a file that moved, images that are not
    one run of files.
    """
    strip = check_clip_strip(strip)
    check_playback(scene, strip)
    fps = None
    if compat.strip_type(strip) == "IMAGE":
        path, first = image_clip(strip)
        fps = scene_fps(scene)
    else:
        path, first = abspath(strip.filepath, "movie file", strip), 0
        if not path.is_file():
            raise InputError(f"the movie file '{path}' of strip '{strip.name}' was not found (moved or renamed?); "
                             "relink it (Strip > Movie > Change Path/Files) and try again")
    offset = first + int(strip.animation_offset_start)
    start = int(strip.frame_start)
    span = frame_span(start, int(strip.frame_final_start), int(strip.frame_final_end), int(strip.frame_duration),
                      offset)
    timing = read_retiming(scene, strip, lambda: _content_length(strip, path, fps))
    clips = offset + content_frames(np.arange(span.scene_start, span.scene_stop) - start, timing)
    span = replace(span, clip_start=int(clips[0]), clip_stop=int(clips[-1]) + 1)
    inner = list(getattr(strip, "retiming_keys", ()))[1:-1] if timing.keys else []  # where the speed changes
    changes = tuple(int(k.timeline_frame) for k in inner if span.scene_start < k.timeline_frame < span.scene_stop)
    return StripSource(scene.name, strip.name, compat.strip_type(strip), path, fps, span,
                       tuple(int(c) for c in clips), changes, not timing.identity)


def cache_folder(source: StripSource, base: str) -> Path:
    """The strip's per-clip cache: ``<base>/<clip-hash>/`` (DESIGN.md: ``//rvr_cache/<clip-hash>/``).

    base: the cache location (Preferences; ``//`` = next to the .blend). The clip hash is the
    engine's source fingerprint, so a relinked (moved) file finds its cache again and an edited
    file gets a fresh one. Raises InputError for a //-relative location in an unsaved file.
    """
    from ..rvr_addon.estimate.cache import source_fingerprint

    base = base or "//rvr_cache/"
    if base.startswith("//") and not bpy.data.filepath:
        raise InputError(f"the cache location '{base}' is next to the .blend file, which was never saved: save the "
                         ".blend file first, or set an absolute cache folder in Preferences > Add-ons > "
                         "RVR-LAAF Refocus")
    root = Path(bpy.path.abspath(base))
    return root / source_fingerprint(source.path)["hash"][:16]


def analysed_cache(strip: "Strip") -> Path | None:
    """The cache folder Analyze recorded on the strip, if it still holds a cache (else None)."""
    text = strip.rvr.cache_path
    if not text:
        return None
    if text.startswith("//") and not bpy.data.filepath:
        return None
    folder = Path(bpy.path.abspath(text, library=strip.id_data.library))
    return folder if (folder / "meta.json").is_file() else None
