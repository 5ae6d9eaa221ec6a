"""Sequencer sidebar: the Refocus tab (settings of the active strip, render, job status).

Blender 5.0 cannot make an animation path to a property group held by a strip, so its own
keyframe decorators do not work on ``strip.rvr``; each animatable field gets a key button
(``rvr.keyframe_toggle``) drawn where the decorator would be.
"""
from __future__ import annotations

import bpy

from ..operators import compat, fcurves
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


def draw_job_status(layout, wm) -> None:
    """Progress bar and Cancel while a job runs; the last job's message otherwise."""
    if wm.rvr_job_status != "IDLE":
        row = layout.row(align=True)
        text = wm.rvr_job_text if wm.rvr_job_status == "RUNNING" else "Cancelling..."
        row.progress(factor=wm.rvr_job_progress / 100.0, type="BAR", text=text)
        row.operator("rvr.cancel_job", text="", icon="CANCEL")
    elif wm.rvr_job_text:
        layout.label(text=wm.rvr_job_text, icon="INFO")


class RVR_PT_focus(bpy.types.Panel):
    """Refocus settings of the active strip"""

    bl_idname = "RVR_PT_focus"
    bl_label = "Refocus"
    bl_space_type = "SEQUENCE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Refocus"

    @classmethod
    def poll(cls, context) -> bool:
        return context.scene is not None

    def draw(self, context) -> None:
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        strip = compat.active_strip(context)
        if strip is None or compat.strip_type(strip) not in RENDERABLE_TYPES:
            layout.label(text="Select a movie or image strip", icon="INFO")
            draw_job_status(layout, context.window_manager)
            return
        rvr = strip.rvr
        frame = context.scene.frame_current

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
        col.prop(rvr, "output_dir")

        layout.separator()
        layout.operator("rvr.render_strip", icon="RENDER_ANIMATION")
        draw_job_status(layout, context.window_manager)


classes = (RVR_PT_focus,)
register, unregister = bpy.utils.register_classes_factory(classes)
