"""From a strip to the engine's inputs: which file, which clip frames, where its cache is.

Every operator (Analyze, Add Focus Target, Track, Auto Focus, Render) reads the strip through
:func:`resolve_source`, so they agree on the frame mapping:

    clip frame = content_offset + (scene frame - strip.frame_start)

``content_offset`` is the strip's ``animation_offset_start`` plus, for an image strip, the
place of its first file in its folder (the engine reads the folder in natural order). Trimmed
handles (``frame_offset_start/end``) only narrow the visible span; frames the strip holds
beyond its content (``frame_final_start < frame_start``) are holds, not clip frames.

The pure helpers (:class:`FrameSpan`, :func:`frame_span`, :func:`safe_file_name`) take plain
numbers; :func:`resolve_source` and :func:`cache_folder` read Blender state.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import bpy

from . import compat
from ..rvr_addon.errors import InputError

if TYPE_CHECKING:
    from bpy.types import Scene, Strip

CLIP_TYPES = ("MOVIE", "IMAGE")
_UNSAFE_FILE_CHARS = '/\\:*?"<>|'


# ----------------------------------------------------------------------------- plain helpers


@dataclass(frozen=True)
class FrameSpan:
    """Which frames of a strip are shown, in scene and in clip frame numbers.

    scene_start/scene_stop: scene frames of the first/after-last shown content frame (no holds).
    clip_start: clip frame (0-based in the input file or folder) shown at ``scene_start``.
    final_start/final_end: the strip's visible span, holds included (a result spans it too).
    """

    scene_start: int
    scene_stop: int
    clip_start: int
    final_start: int
    final_end: int

    @property
    def count(self) -> int:
        return self.scene_stop - self.scene_start

    @property
    def clip_stop(self) -> int:
        return self.clip_start + self.count


def frame_span(frame_start: int, final_start: int, final_end: int, duration: int, content_offset: int) -> FrameSpan:
    """Map a strip's visible span to the frames of its content (bpy-free).

    frame_start: scene frame of content frame 0 (``strip.frame_start``); final_start/final_end:
    visible span (``frame_final_start``/``frame_final_end``); duration: content frames after
    the animation offsets (``frame_duration``); content_offset: clip frame of content frame 0
    (``animation_offset_start`` plus, for an image strip, its first file's place in the folder).
    Frames of the span outside the content are holds of the first/last frame: not rendered.
    Raises InputError when no content frame is visible.
    """
    lo = max(final_start - frame_start, 0)
    hi = min(final_end - frame_start, duration)
    if hi <= lo:
        raise InputError(f"the strip shows no frame of its clip between frames {final_start} and {final_end} "
                         "(only held frames); move its handles over the clip")
    return FrameSpan(frame_start + lo, frame_start + hi, content_offset + lo, final_start, final_end)


def safe_file_name(name: str) -> str:
    """A strip name usable as a file name (path separators and reserved characters -> '_')."""
    cleaned = "".join("_" if c in _UNSAFE_FILE_CHARS or ord(c) < 32 else c for c in name).strip(" .")
    return cleaned or "strip"


# ----------------------------------------------------------------------------- Blender state


@dataclass(frozen=True)
class StripSource:
    """A movie or image strip read into plain values.

    path: the video file or the image folder. fps: the scene's frame rate for an image folder
    (None for a movie: its own rate). span: the shown frames. frame_start: ``strip.frame_start``.
    content_offset: clip frame shown at ``frame_start``.
    """

    scene_name: str
    strip_name: str
    kind: str
    path: Path
    fps: float | None
    span: FrameSpan
    frame_start: int
    content_offset: int

    def scene_to_clip(self, scene_frame: float) -> int:
        """Clip frame (0-based) shown at ``scene_frame`` (not clamped to the span)."""
        return int(round(self.content_offset + (scene_frame - self.frame_start)))

    def clip_to_scene(self, clip_frame: float) -> float:
        """Scene frame showing clip frame ``clip_frame``."""
        return float(self.frame_start + (clip_frame - self.content_offset))

    def shows(self, clip_frame: int) -> bool:
        """True when ``clip_frame`` is one of the strip's visible content frames."""
        return self.span.clip_start <= clip_frame < self.span.clip_stop


def abspath(path: str, what: str, strip: "Strip") -> Path:
    """Absolute path of a strip setting; InputError for a //-relative path in an unsaved file."""
    if path.startswith("//") and not bpy.data.filepath:
        raise InputError(f"the {what} of strip '{strip.name}' ({path}) is relative to the .blend file, which is not "
                         "saved yet: save the .blend file or choose an absolute path")
    return Path(bpy.path.abspath(path, library=strip.id_data.library))


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


def check_not_retimed(strip: "Strip") -> None:
    """InputError for a strip whose scene frames do not map 1:1 to clip frames."""
    if len(getattr(strip, "retiming_keys", ())):
        raise InputError(f"strip '{strip.name}' is retimed (sped up or slowed down); reset its retiming "
                         "(Strip > Retiming > Reset) so each scene frame shows one clip frame, or render the "
                         "speed change as a separate step")
    if getattr(strip, "use_reverse_frames", False) or getattr(strip, "strobe", 1.0) > 1.0:
        raise InputError(f"strip '{strip.name}' plays reversed or strobed; turn that off to refocus it")


def resolve_source(scene: "Scene", strip: "Strip | None") -> StripSource:
    """Read a movie or image strip into a :class:`StripSource`.

    Raises InputError (an RvrError) naming the strip and the fix: no strip, a sound/effect
    strip, a retimed strip, a file that moved, images that are not one run of files.
    """
    strip = check_clip_strip(strip)
    check_not_retimed(strip)
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
    span = frame_span(int(strip.frame_start), int(strip.frame_final_start), int(strip.frame_final_end),
                      int(strip.frame_duration), offset)
    return StripSource(scene.name, strip.name, compat.strip_type(strip), path, fps, span, int(strip.frame_start),
                       offset)


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
