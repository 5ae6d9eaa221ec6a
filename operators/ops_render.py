"""Render the active strip with synthetic depth of field and put the result above it.

Thin operators: :func:`plan_render` reads the strip into plain values (paths, frame numbers,
the focus track sampled from the evaluated F-curves), the engine's :class:`RenderJob` does
the work, and :func:`add_result_strip` writes the result into the sequencer in one step, only
after the movie or image sequence is complete. A failure or a cancel leaves strips, F-curves
and any earlier render exactly as they were.

A retimed strip (retiming keys, strobe, a movie playing at its own frame rate) is rendered
with one output frame per *scene* frame it shows: frame N of the result is the clip frame the
strip shows at its N-th scene frame, refocused with the focus and aperture evaluated at that
scene frame. The result is a plain strip at the scene's frame rate (no retiming of its own, no
audio: the source's sound strip stays), so it lines up with the source frame by frame and
plays at the retimed speed. Not retimed, the result is the clip's own frames at its own rate.

Disparity and HDR come from the strip's analysis cache (``strip.rvr.cache_path``, written by
Analyze; stabilized channels when complete) or else from its Disparity/HDR maps.
``execute()`` blocks (scripts, background Blender); ``invoke()`` runs the same job from a timer
in a modal handler (:mod:`.jobrun`), so the UI stays responsive and Esc stops it.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import bpy
import numpy as np
from bpy.app.handlers import persistent

from . import compat, fcurves
from .jobrun import STEP_BUDGET_S, TIMER_PERIOD_S, JobOperator, job_running, step_for  # noqa: F401 (re-exported)
from .source import (CLIP_TYPES, FrameSpan, abspath, analysed_cache, frame_span, resolve_source,  # noqa: F401
                     safe_file_name, scene_fps)
from ..rvr_addon.errors import InputError

if TYPE_CHECKING:
    from bpy.types import Scene, Strip

    from ..rvr_addon.pipeline import RenderJob, RenderSettings

log = logging.getLogger(__name__)

RENDERABLE_TYPES = CLIP_TYPES
RESULT_SUFFIX = " [RVR]"
MAX_CHANNEL = 128


# ----------------------------------------------------------------------------- plain helpers


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
    images: bool = False


def plan_render(scene: "Scene", strip: "Strip") -> RenderPlan:
    """Read ``strip`` (a movie or image strip, analysed or with Disparity maps) into a RenderPlan.

    Samples the focus and aperture F-curves at the rendered scene frames (so hand edits in the
    Graph Editor change the render). Raises InputError (an RvrError) naming the strip and the
    fix when it cannot be rendered.
    """
    from ..rvr_addon.pipeline import RenderSettings
    from ..rvr_addon.render.aperture import ApertureSpec

    source = resolve_source(scene, strip)
    rvr = strip.rvr
    cache = analysed_cache(strip)
    if cache is None and not rvr.depth_path:
        raise InputError(f"strip '{strip.name}' has no disparity: run Analyze on it (Refocus panel), or set its "
                         "Disparity maps")
    if fcurves.find_fcurve(strip, "focus_disparity") is None and not rvr.is_property_set("focus_disparity"):
        # never focused: a render at the default Focus 0 would be a guess nobody made
        raise InputError(f"strip '{strip.name}' has no focus yet: run Auto Focus (or add a focus target and Track, "
                         "or set and key Focus) in the Refocus panel, then render")
    span = source.span
    # retimed: one output frame per scene frame (the clip frame shown there), track by output frame
    keyed_at = np.arange(span.count) if source.retimed else np.asarray(source.clip_frames)
    track = fcurves.sample_track(strip, source.scene_frames, keyed_at)
    spec = ApertureSpec(shape=rvr.aperture_shape.lower(), blades=int(rvr.blades),
                        rotation_deg=math.degrees(rvr.rotation), squeeze=float(rvr.squeeze))
    folder = abspath(rvr.output_dir or "//rvr_renders/", "output folder", strip)
    images = rvr.render_format == "IMAGES"
    output = folder / safe_file_name(strip.name) if images else folder / f"{safe_file_name(strip.name)}.mp4"
    if output.resolve() == source.path.resolve():
        raise InputError(f"the output '{output}' is the strip's own source; choose another output folder")
    if cache is not None:
        depth, hdr = cache, cache
    else:
        depth = abspath(rvr.depth_path, "disparity path", strip)
        hdr = abspath(rvr.hdr_path, "HDR path", strip) if rvr.hdr_path else None
    settings = RenderSettings(
        input=source.path, depth=depth, hdr=hdr, outputs=[output], track_data=track, spec=spec,
        start=span.clip_start, stop=span.clip_stop, fps=source.fps, scale=float(rvr.render_size),
        frames=list(source.clip_frames) if source.retimed else None,
        output_fps=scene_fps(scene) if source.retimed else None)
    return RenderPlan(scene.name, strip.name, settings, output, span, images)


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


# ----------------------------------------------------------------------------- plan -> Blender state


def result_name(strip_name: str) -> str:
    return f"{strip_name}{RESULT_SUFFIX}"


def add_result_strip(plan: RenderPlan) -> "Strip":
    """Add the render as a strip '<strip> [RVR]' (movie, or image sequence) in the first free
    channel above the source, spanning the same frames (holds included); an earlier result
    strip of that name is replaced. No sound strip is added: the source's sound strip stays
    where it is (and a movie render carries the source's audio too)."""
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
    if plan.images:
        files = sorted(p.name for p in plan.output.iterdir() if p.suffix.lower() == ".png")
        strip = container.new_image(name, str(plan.output / files[0]), channel, span.scene_start)
        for f in files[1:]:
            strip.elements.append(f)
    else:
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


def poll_clip_strip(cls, context, need_idle: bool = True) -> bool:
    """Shared poll: an active movie/image strip and no running job (explains itself)."""
    strip = compat.active_strip(context)
    if strip is None:
        cls.poll_message_set("No active strip: click a movie or image strip.")
        return False
    if compat.strip_type(strip) not in RENDERABLE_TYPES:
        cls.poll_message_set("The active strip is not a movie or image strip.")
        return False
    if need_idle and job_running(context):
        cls.poll_message_set("A refocus job is already running.")
        return False
    return True


class RVR_OT_render_strip(JobOperator, bpy.types.Operator):
    """Render the active strip with synthetic shallow depth of field (focus and aperture from its F-curves) and add the result above it"""

    bl_idname = "rvr.render_strip"
    bl_label = "Render Refocused Strip"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Refocus render"

    @classmethod
    def poll(cls, context) -> bool:
        if not poll_clip_strip(cls, context):
            return False
        strip = compat.active_strip(context)
        if not strip.rvr.depth_path and not strip.rvr.cache_path:
            cls.poll_message_set("Analyze the strip first (or set its Disparity maps).")
            return False
        return True

    def _prepare(self, context):
        plan = plan_render(compat.sequencer_scene(context), compat.active_strip(context))
        return plan, start_job(plan)

    def _apply(self, context, plan: RenderPlan, job) -> None:
        strip = add_result_strip(plan)
        self.report({"INFO"}, f"Rendered {plan.span.count} frames to {plan.output} (strip '{strip.name}')")


class RVR_OT_cancel_job(bpy.types.Operator):
    """Stop the running refocus job (Analyze keeps the frames it finished; a render deletes its partial output); nothing in the scene changes"""

    bl_idname = "rvr.cancel_job"
    bl_label = "Cancel Refocus Job"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context) -> bool:
        if context.window_manager.rvr_job_status != "RUNNING":
            cls.poll_message_set("No refocus job is running.")
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
