"""Properties: ``strip.rvr`` (saved with the strip) and the job status on the WindowManager.

The WindowManager properties are transient (a running job, its text and progress): they are
never stored on the Scene, so nothing of a job leaks into the user's .blend.
"""
from __future__ import annotations

import bpy
from bpy.props import EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

APERTURE_SHAPES = (
    ("DISK", "Disk", "Round bokeh of an open iris"),
    ("POLYGON", "Polygon", "Bokeh shaped by straight aperture blades"),
    ("ANAMORPHIC", "Anamorphic", "Oval bokeh, taller than wide, as from an anamorphic lens"),
)

JOB_STATES = (
    ("IDLE", "Idle", "No job is running"),
    ("RUNNING", "Running", "A render job is running"),
    ("CANCELLING", "Cancelling", "The running job was asked to stop"),
)


class RVR_PG_strip(bpy.types.PropertyGroup):
    """Refocus settings of one movie or image strip (``strip.rvr``)."""

    focus_disparity: FloatProperty(
        name="Focus",
        description="Disparity in focus (px of blur radius at aperture 1 at the clip's native width; "
                    "larger = farther). Animate it to pull focus",
        default=0.0, soft_min=-64.0, soft_max=64.0, step=10, precision=3,
        options={"ANIMATABLE"},
    )
    aperture: FloatProperty(
        name="Aperture",
        description="Defocus strength: scales every blur radius (0 = no synthetic blur)",
        default=1.0, min=0.0, soft_max=4.0, step=5, precision=3,
        options={"ANIMATABLE"},
    )
    aperture_shape: EnumProperty(name="Shape", description="Shape of the bokeh", items=APERTURE_SHAPES,
                                 default="DISK")
    blades: IntProperty(name="Blades", description="Number of aperture blades", default=6, min=3, max=16)
    rotation: FloatProperty(name="Rotation", description="Rotation of the polygonal aperture",
                            default=0.0, subtype="ANGLE")
    squeeze: FloatProperty(name="Squeeze", description="Anamorphic squeeze: bokeh height / width",
                           default=2.0, min=0.1, soft_min=1.0, soft_max=3.0)
    depth_path: StringProperty(
        name="Disparity",
        description="Disparity maps of the clip, one per frame (EXR/PNG/NPY file, folder or pattern)",
        subtype="FILE_PATH",
    )
    hdr_path: StringProperty(
        name="HDR",
        description="Optional HDR exponent maps (log space), one per frame (folder or pattern)",
        subtype="FILE_PATH",
    )
    output_dir: StringProperty(
        name="Output",
        description="Folder for the rendered video (// = next to the .blend file)",
        subtype="DIR_PATH", default="//rvr_renders/",
    )


def _redraw(self, context) -> None:
    """Redraw the sequencer sidebars showing the job status."""
    wm = context.window_manager if context is not None else bpy.context.window_manager
    for window in getattr(wm, "windows", ()):
        screen = window.screen
        if screen is None:
            continue
        for area in screen.areas:
            if area.type == "SEQUENCE_EDITOR":
                area.tag_redraw()


classes = (RVR_PG_strip,)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register() -> None:
    _register_classes()
    bpy.types.Strip.rvr = PointerProperty(type=RVR_PG_strip)
    wm = bpy.types.WindowManager
    wm.rvr_job_status = EnumProperty(name="Refocus Job", items=JOB_STATES, default="IDLE", update=_redraw)
    wm.rvr_job_text = StringProperty(name="Refocus Job Text", default="", update=_redraw)
    wm.rvr_job_progress = FloatProperty(name="Refocus Progress", subtype="PERCENTAGE", min=0.0, max=100.0,
                                        default=0.0, precision=0, update=_redraw)


def unregister() -> None:
    wm = bpy.types.WindowManager
    for name in ("rvr_job_progress", "rvr_job_text", "rvr_job_status"):
        if hasattr(wm, name):
            delattr(wm, name)
    if hasattr(bpy.types.Strip, "rvr"):
        del bpy.types.Strip.rvr
    _unregister_classes()
