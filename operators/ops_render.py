"""Render the active strip with synthetic depth of field and put the result above it.

Thin operators: :func:`plan_render` reads the strip into plain values (paths, frame numbers,
the focus track sampled from the F-curves), the engine's :class:`RenderJob` does the work,
and :func:`add_result_strip` writes the result into the sequencer in one step, only after
the video file is complete. A failure or a cancel leaves strips, F-curves and any earlier
render exactly as they were.

``execute()`` blocks (scripts, background Blender); ``invoke()`` runs the same job from a
timer in a modal handler, so the UI stays responsive and Esc (or RVR_OT_cancel_job) stops it.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import bpy
import numpy as np
from bpy.app.handlers import persistent

from . import compat, fcurves
from ..rvr_addon.errors import InputError, RvrError

if TYPE_CHECKING:
    from bpy.types import Context, Scene, Strip

    from ..rvr_addon.pipeline import RenderJob, RenderSettings

log = logging.getLogger(__name__)

RENDERABLE_TYPES = ("MOVIE", "IMAGE")
RESULT_SUFFIX = " [RVR]"
TIMER_PERIOD_S = 0.1
STEP_BUDGET_S = 0.9 * TIMER_PERIOD_S
MAX_CHANNEL = 128
_UNSAFE_FILE_CHARS = '/\\:*?"<>|'


# ----------------------------------------------------------------------------- plain helpers


@dataclass(frozen=True)
class FrameSpan:
    """Which frames of a strip are rendered, in scene and in clip frame numbers.

    scene_start/scene_stop: scene frames of the first/after-last rendered frame (no holds).
    clip_start: clip frame (0-based in the input file or folder) shown at ``scene_start``.
    final_start/final_end: the strip's visible span, holds included (the result spans it too).
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


def first_free_channel(occupied: list[tuple[int, int, int]], above: int, start: int, end: int) -> int:
    """Lowest channel > ``above`` with no (channel, start, end) of ``occupied`` overlapping
    [start, end). Raises InputError when every channel up to 128 is taken."""
    for channel in range(above + 1, MAX_CHANNEL + 1):
        if not any(c == channel and s < end and start < e for c, s, e in occupied):
            return channel
    raise InputError(f"no free channel above channel {above} between frames {start} and {end}; "
                     "free a channel above the strip")


# ----------------------------------------------------------------------------- Blender state -> plan


@dataclass
class RenderPlan:
    """Everything to run a render and to apply its result, without holding bpy objects."""

    scene_name: str
    strip_name: str
    settings: "RenderSettings"
    output: Path
    span: FrameSpan


def _abspath(path: str, what: str, strip: "Strip") -> Path:
    if path.startswith("//") and not bpy.data.filepath:
        raise InputError(f"the {what} of strip '{strip.name}' ({path}) is relative to the .blend file, which is not "
                         "saved yet: save the .blend file or choose an absolute path")
    return Path(bpy.path.abspath(path, library=strip.id_data.library))


def _image_clip(strip: "Strip") -> tuple[Path, int]:
    """(folder, clip frame of the strip's first element): the engine reads the folder in
    natural order, so the strip's images must be one run of consecutive files there."""
    from ..rvr_addon.io.paths import list_directory
    from ..rvr_addon.io.video import IMAGE_EXTENSIONS

    folder = _abspath(strip.directory, "image folder", strip)
    names = [e.filename for e in strip.elements]
    if not folder.is_dir():
        raise InputError(f"the image folder '{folder}' of strip '{strip.name}' does not exist; relink the images")
    files = [p.name for p in list_directory(folder, IMAGE_EXTENSIONS)]
    try:
        first = files.index(names[0])
    except ValueError:
        raise InputError(f"image '{names[0]}' of strip '{strip.name}' is not in '{folder}'; relink the images") from None
    if files[first:first + len(names)] != names:
        raise InputError(f"the images of strip '{strip.name}' are not consecutive files of '{folder}' in name order; "
                         "put the strip's frames in a folder of their own, numbered in order")
    return folder, first


def _scene_fps(scene: "Scene") -> float:
    return scene.render.fps / scene.render.fps_base


def plan_render(scene: "Scene", strip: "Strip") -> RenderPlan:
    """Read ``strip`` (a movie or image strip with ``rvr.depth_path``) into a RenderPlan.

    Samples the focus and aperture F-curves at the rendered scene frames. Raises InputError
    (an RvrError) naming the strip and the fix when it cannot be rendered.
    """
    from ..rvr_addon.pipeline import RenderSettings
    from ..rvr_addon.render.aperture import ApertureSpec

    kind = compat.strip_type(strip)
    if kind not in RENDERABLE_TYPES:
        raise InputError(f"strip '{strip.name}' is a {kind.lower()} strip; select a movie or image strip")
    rvr = strip.rvr
    if not rvr.depth_path:
        raise InputError(f"strip '{strip.name}' has no disparity maps: set its Disparity path in the Refocus panel")
    if len(getattr(strip, "retiming_keys", ())):
        raise InputError(f"strip '{strip.name}' is retimed; reset its retiming (Strip > Retiming > Reset) so each "
                         "scene frame shows one clip frame")
    if getattr(strip, "use_reverse_frames", False) or getattr(strip, "strobe", 1.0) > 1.0:
        raise InputError(f"strip '{strip.name}' plays reversed or strobed; turn that off to refocus it")
    fps = None
    if kind == "IMAGE":
        source, first = _image_clip(strip)
        fps = _scene_fps(scene)
    else:
        source, first = _abspath(strip.filepath, "movie file", strip), 0
    span = frame_span(int(strip.frame_start), int(strip.frame_final_start), int(strip.frame_final_end),
                      int(strip.frame_duration), first + int(strip.animation_offset_start))
    scene_frames = np.arange(span.scene_start, span.scene_stop)
    track = fcurves.sample_track(strip, scene_frames, np.arange(span.clip_start, span.clip_stop))
    spec = ApertureSpec(shape=rvr.aperture_shape.lower(), blades=int(rvr.blades),
                        rotation_deg=math.degrees(rvr.rotation), squeeze=float(rvr.squeeze))
    output = _abspath(rvr.output_dir or "//rvr_renders/", "output folder", strip) / f"{safe_file_name(strip.name)}.mp4"
    if output.resolve() == source.resolve():
        raise InputError(f"the output '{output}' is the strip's own source; choose another output folder")
    settings = RenderSettings(
        input=source, depth=_abspath(rvr.depth_path, "disparity path", strip),
        hdr=_abspath(rvr.hdr_path, "HDR path", strip) if rvr.hdr_path else None,
        outputs=[output], track_data=track, spec=spec, start=span.clip_start, stop=span.clip_stop, fps=fps)
    return RenderPlan(scene.name, strip.name, settings, output, span)


def start_job(plan: RenderPlan) -> "RenderJob":
    """Open the clip and maps (checks them) and return the job, not yet stepped."""
    from ..rvr_addon.pipeline import RenderJob

    job = RenderJob(plan.settings)
    if job.total != plan.span.count:
        job.abort()
        raise InputError(f"the clip '{plan.settings.input}' has {job.clip.frame_count} frames but strip "
                         f"'{plan.strip_name}' shows frames {plan.span.clip_start}..{plan.span.clip_stop - 1} of it; "
                         "reload the strip (Strip > Reload) so its length matches the file")
    return job


def step_for(job: "RenderJob", budget_s: float) -> bool:
    """Step ``job`` for about ``budget_s`` seconds (at least one frame); False once it is done."""
    deadline = time.perf_counter() + budget_s
    while job.step():
        if time.perf_counter() >= deadline:
            return True
    return False


# ----------------------------------------------------------------------------- plan -> Blender state


def result_name(strip_name: str) -> str:
    return f"{strip_name}{RESULT_SUFFIX}"


def add_result_strip(plan: RenderPlan) -> "Strip":
    """Add the rendered video as a movie strip '<strip> [RVR]' in the first free channel above
    the source, spanning the same frames (holds included); an earlier result strip of that
    name is replaced. No sound strip is added: the source's sound stays where it is."""
    scene = bpy.data.scenes.get(plan.scene_name)
    editor = scene.sequence_editor if scene is not None else None
    source = compat.strip_collection_all(editor).get(plan.strip_name) if editor is not None else None
    if source is None:
        raise InputError(f"strip '{plan.strip_name}' is gone; the render was kept at '{plan.output}'")
    name = result_name(plan.strip_name)
    container = compat.strip_container(scene, source)
    old = compat.strip_collection_all(editor).get(name)
    if old is not None:
        compat.strip_container(scene, old).remove(old)
    span = plan.span
    occupied = [(s.channel, s.frame_final_start, s.frame_final_end) for s in container]
    channel = first_free_channel(occupied, source.channel, span.final_start, span.final_end)
    strip = container.new_movie(name, str(plan.output), channel, span.scene_start)
    if strip.frame_duration != span.count:
        log.warning("Blender reads %d frames from '%s' but %d were rendered", strip.frame_duration, plan.output,
                    span.count)
    strip.frame_final_start = span.final_start
    strip.frame_final_end = span.final_end
    if strip.channel != channel:  # Blender moved it to resolve an overlap
        strip.channel = channel
    return strip


# ----------------------------------------------------------------------------- operators


def _set_status(context: "Context", status: str, text: str = "", progress: float = 0.0) -> None:
    wm = context.window_manager
    wm.rvr_job_status = status
    wm.rvr_job_text = text
    wm.rvr_job_progress = progress


class RVR_OT_render_strip(bpy.types.Operator):
    """Render the active strip with synthetic shallow depth of field (focus and aperture from its F-curves) and add the result above it"""

    bl_idname = "rvr.render_strip"
    bl_label = "Render Refocused Strip"
    bl_options = {"REGISTER", "UNDO"}

    _timer = None
    _job = None
    _plan = None

    @classmethod
    def poll(cls, context) -> bool:
        strip = compat.active_strip(context)
        if strip is None:
            cls.poll_message_set("No active strip: click a movie or image strip.")
            return False
        if compat.strip_type(strip) not in RENDERABLE_TYPES:
            cls.poll_message_set("The active strip is not a movie or image strip.")
            return False
        if not strip.rvr.depth_path:
            cls.poll_message_set("Set the strip's disparity maps (Disparity) first.")
            return False
        if context.window_manager.rvr_job_status != "IDLE":
            cls.poll_message_set("A refocus job is already running.")
            return False
        return True

    def _prepare(self, context):
        plan = plan_render(context.scene, compat.active_strip(context))
        return plan, start_job(plan)

    def _apply(self, plan: RenderPlan) -> None:
        strip = add_result_strip(plan)
        self.report({"INFO"}, f"Rendered {plan.span.count} frames to {plan.output} (strip '{strip.name}')")

    def execute(self, context) -> set[str]:
        try:
            plan, job = self._prepare(context)
        except RvrError as ex:
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            while job.step():
                wm.progress_update(int(100 * job.progress))
            self._apply(plan)
        except RvrError as ex:
            job.abort()
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        return {"FINISHED"}

    def invoke(self, context, event) -> set[str]:
        if bpy.app.background or context.window is None:  # no event loop: run blocking
            return self.execute(context)
        try:
            self._plan, self._job = self._prepare(context)
        except RvrError as ex:
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        wm = context.window_manager
        _set_status(context, "RUNNING", self._job.text, 0.0)
        self._timer = wm.event_timer_add(TIMER_PERIOD_S, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event) -> set[str]:
        if event.type == "ESC" or context.window_manager.rvr_job_status == "CANCELLING":
            self._job.cancel()
            self.report({"WARNING"}, f"Refocus render {self._job.text}; nothing was changed")
            return self._finish(context, {"CANCELLED"})
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            running = step_for(self._job, STEP_BUDGET_S)
            if not running:
                self._apply(self._plan)
                return self._finish(context, {"FINISHED"})
        except RvrError as ex:
            self._job.abort()
            self.report({"ERROR"}, str(ex))
            return self._finish(context, {"CANCELLED"})
        except BaseException:
            self._job.abort()
            self._finish(context, {"CANCELLED"})
            raise
        context.window_manager.rvr_job_progress = 100.0 * self._job.progress
        context.window_manager.rvr_job_text = f"{self._job.done}/{self._job.total} frames"
        return {"PASS_THROUGH"}

    def _finish(self, context, result: set[str]) -> set[str]:
        """The one exit of the modal run: remove the timer and reset the status."""
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        _set_status(context, "IDLE", self._job.text if self._job is not None else "", 0.0)
        self._job = None
        self._plan = None
        return result

    def cancel(self, context) -> None:
        """Blender ends the modal run (file load, window closed): stop the job, clean up."""
        if self._job is not None:
            self._job.cancel()
        self._finish(context, {"CANCELLED"})


class RVR_OT_cancel_job(bpy.types.Operator):
    """Stop the running refocus render; partial output is deleted and nothing in the scene changes"""

    bl_idname = "rvr.cancel_job"
    bl_label = "Cancel Refocus Render"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context) -> bool:
        if context.window_manager.rvr_job_status != "RUNNING":
            cls.poll_message_set("No refocus render is running.")
            return False
        return True

    def execute(self, context) -> set[str]:
        context.window_manager.rvr_job_status = "CANCELLING"
        return {"FINISHED"}


@persistent
def _reset_status_on_load(*_args) -> None:
    """A job never survives loading a file: make sure the status does not claim one does."""
    wm = bpy.context.window_manager
    if wm is not None and hasattr(wm, "rvr_job_status"):
        wm.rvr_job_status = "IDLE"
        wm.rvr_job_progress = 0.0


classes = (RVR_OT_render_strip, RVR_OT_cancel_job)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register() -> None:
    _register_classes()
    bpy.app.handlers.load_post.append(_reset_status_on_load)


def unregister() -> None:
    if _reset_status_on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_reset_status_on_load)
    _unregister_classes()
