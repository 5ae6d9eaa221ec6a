"""Sequencer sidebar: the Refocus tab.

Main panel: Analyze (and the cache it wrote), the animatable focus and aperture, the bokeh
shape, the inputs, the preview mode, Render and the job status. Sub-panel "Focus Targets":
the NFT list (:class:`RVR_UL_nfts`: frame, source, tracked range, kept), add / delete /
jump, the active target's pull, the strip's default pull, Track and Auto Focus.

Blender 5.0 cannot make an animation path to a property group held by a strip, so its own
keyframe decorators do not work on ``strip.rvr``; each animatable field gets a key button
(``rvr.keyframe_toggle``) drawn where the decorator would be.
"""
from __future__ import annotations

import bpy

from ..operators import compat, fcurves
from ..operators.ops_analyze import depth_line
from ..operators.ops_render import RENDERABLE_TYPES


def _key_icon(strip, prop: str, frame: int) -> str:
    if fcurves.key_at(strip, prop, frame):
        return "DECORATE_KEYFRAME"
    if fcurves.find_fcurve(strip, prop) is not None:
        return "DECORATE_ANIMATE"
    return "DECORATE"


def draw_animatable(layout, strip, prop: str, frame: int) -> None:
    """``strip.rvr.<prop>`` with a key toggle button in the decorator column."""
    row = layout.row(align=True)
    row.prop(strip.rvr, prop)
    op = row.operator("rvr.keyframe_toggle", text="", icon=_key_icon(strip, prop, frame), emboss=False)
    op.prop = prop


def refocusable_strip(context):
    """The active strip when the Refocus tab can work on it (a movie or image strip), else None."""
    strip = compat.active_strip(context)
    return strip if strip is not None and compat.strip_type(strip) in RENDERABLE_TYPES else None


class _RefocusTab:
    """Mix-in: the panel sits in the Sequencer sidebar's Refocus tab."""

    bl_space_type = "SEQUENCE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Refocus"


def draw_job_status(layout, wm) -> None:
    """Progress bar and Cancel while a job runs; the last job's message otherwise."""
    if wm.rvr_job_status != "IDLE":
        row = layout.row(align=True)
        text = wm.rvr_job_text if wm.rvr_job_status == "RUNNING" else "Cancelling..."
        row.progress(factor=wm.rvr_job_progress / 100.0, type="BAR", text=text)
        row.operator("rvr.cancel_job", text="", icon="CANCEL")
    elif wm.rvr_job_text:
        layout.label(text=wm.rvr_job_text, icon="INFO")


class RVR_PT_focus(_RefocusTab, bpy.types.Panel):
    """Refocus settings of the active strip"""

    bl_idname = "RVR_PT_focus"
    bl_label = "Refocus"

    @classmethod
    def poll(cls, context) -> bool:
        return compat.sequencer_scene(context) is not None

    def draw(self, context) -> None:
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        strip = refocusable_strip(context)
        if strip is None:
            layout.label(text="Select a movie or image strip", icon="INFO")
            draw_job_status(layout, context.window_manager)
            return
        rvr = strip.rvr
        frame = compat.sequencer_scene(context).frame_current

        col = layout.column()
        draw_animatable(col, strip, "focus_disparity", frame)
        draw_animatable(col, strip, "aperture", frame)

        col = layout.column()
        col.prop(rvr, "aperture_shape")
        if rvr.aperture_shape == "POLYGON":
            col.prop(rvr, "blades")
            col.prop(rvr, "rotation")
        elif rvr.aperture_shape == "ANAMORPHIC":
            col.prop(rvr, "squeeze")

        col = layout.column()
        col.prop(rvr, "depth_path")
        col.prop(rvr, "hdr_path")
        if not rvr.depth_path:
            col.prop(rvr, "depth_method")
            if rvr.depth_method != "NETWORK":
                col.prop(rvr, "hfov_deg")
        row = layout.row(align=True)
        row.operator("rvr.analyze", icon="VIEW_CAMERA")
        if rvr.cache_path:
            layout.label(text=f"Cache: {rvr.cache_path}", icon="CHECKMARK")
            line = depth_line(bpy.path.abspath(rvr.cache_path))
            if line:
                layout.label(text=line, icon="INFO")

        col = layout.column()
        col.prop(rvr, "preview_mode")
        col.prop(rvr, "show_targets")

        layout.separator()
        col = layout.column()
        col.prop(rvr, "render_format")
        col.prop(rvr, "render_size")
        col.prop(rvr, "output_dir")
        layout.operator("rvr.render_strip", icon="RENDER_ANIMATION")
        draw_job_status(layout, context.window_manager)


class RVR_UL_nfts(bpy.types.UIList):
    """Focus targets of a strip: clip frame, source, tracked range; the pin shows a kept target"""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0) -> None:
        row = layout.row(align=True)
        row.label(text=f"{item.frame}", icon="PINNED" if item.keep else "UNPINNED")
        row.label(text=item.source)
        if item.tracked_start >= 0:
            row.label(text=f"{item.tracked_start}-{item.tracked_end}")
        else:
            row.label(text="not tracked")


class RVR_PT_targets(_RefocusTab, bpy.types.Panel):
    """Focus targets, pulls, Track and Auto Focus of the active strip"""

    bl_idname = "RVR_PT_targets"
    bl_label = "Focus Targets"
    bl_parent_id = "RVR_PT_focus"

    @classmethod
    def poll(cls, context) -> bool:
        return refocusable_strip(context) is not None

    def draw(self, context) -> None:
        layout = self.layout
        rvr = compat.active_strip(context).rvr
        row = layout.row()
        row.template_list("RVR_UL_nfts", "", rvr, "nfts", rvr, "nft_index", rows=3)
        col = row.column(align=True)
        col.operator("rvr.add_focus_target", text="", icon="ADD")
        col.operator("rvr.remove_focus_target", text="", icon="REMOVE")
        col.operator("rvr.jump_to_target", text="", icon="TIME")
        layout.use_property_split = True
        layout.use_property_decorate = False
        if 0 <= rvr.nft_index < len(rvr.nfts):
            item = rvr.nfts[rvr.nft_index]
            box = layout.box()
            box.prop(item, "frame")
            box.prop(item, "box")
            box.prop(item, "keep")
            box.prop(item, "pull_frames")
            box.prop(item, "lead_frames")
        col = layout.column(align=True)
        col.prop(rvr, "pull_frames")
        col.prop(rvr, "lead_frames")
        col.prop(rvr, "pull_profile")
        col.prop(rvr, "hold_frames")
        auto = auto_pull_line(context.scene, compat.active_strip(context))
        if auto:
            col.label(text=auto, icon="TIME")
        layout.operator("rvr.track_targets", icon="TRACKER")
        col = layout.column()
        col.prop(rvr, "autofocus_preset")
        col.prop(rvr, "focus_calm")
        col.prop(rvr, "lookahead_s")
        layout.operator("rvr.auto_focus", icon="VIEWZOOM")


def auto_pull_line(scene, strip) -> str | None:
    """What the strip's automatic pull settings (Pull 0, Lead / Hold -1) are in frames of its
    clip: 0.4 / 0.2 / 0.48 s at the media's frame rate; None when every one is set."""
    rvr = strip.rvr
    if rvr.pull_frames > 0 and rvr.lead_frames >= 0 and rvr.hold_frames >= 0:
        return None
    from ..operators.source import scene_fps
    from ..rvr_addon.laaf.puller import DEFAULT_HOLD_FRAMES, DEFAULT_LEAD_FRAMES, DEFAULT_PULL_FRAMES
    from ..rvr_addon.laaf.timebase import frames_at

    fps = float(getattr(strip, "fps", 0.0) or 0.0) or scene_fps(scene)
    return (f"Automatic at {fps:g} fps: pull {frames_at(DEFAULT_PULL_FRAMES, fps)}, lead "
            f"{frames_at(DEFAULT_LEAD_FRAMES, fps, 0)}, hold {frames_at(DEFAULT_HOLD_FRAMES, fps, 0)} frames")


classes = (RVR_PT_focus, RVR_UL_nfts, RVR_PT_targets)
register, unregister = bpy.utils.register_classes_factory(classes)
