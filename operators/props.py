"""Properties: ``strip.rvr`` (saved with the strip: settings, New Focus Targets, the cache it
was analysed into) and the job status on the WindowManager.

The WindowManager properties are transient (a running job, its text and progress): they are
never stored on the Scene, so nothing of a job leaks into the user's .blend.

NFTs (``strip.rvr.nfts``, :class:`RVR_PG_nft`) are stored in **clip** frames (0-based index
in the strip's movie file or image folder) and **native clip pixels** (origin top-left, y
down), the engine's units, so moving or trimming the strip never detaches a target from the
picture it was drawn on. Editing a target's frame, point or box by hand sets its ``keep``
flag: Auto Focus never replaces a kept target.
"""
from __future__ import annotations

import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, FloatVectorProperty,
                       IntProperty, PointerProperty, StringProperty)

from ..rvr_addon.laaf.presets import DEFAULT_CALM
from . import compat

APERTURE_SHAPES = (
    ("DISK", "Disk", "Round bokeh of an open iris"),
    ("POLYGON", "Polygon", "Bokeh shaped by straight aperture blades"),
    ("ANAMORPHIC", "Anamorphic", "Oval bokeh, taller than wide, as from an anamorphic lens"),
)

NFT_SOURCES = (
    ("manual", "Manual", "Added by the editor"),
    ("face", "Face", "Found by the face detector"),
    ("saliency", "Saliency", "Found by the saliency detector"),
    ("action", "Action", "Found by the action (motion) detector"),
    ("speech", "Speech", "Found by the speech detector (who is talking)"),
    ("afnet", "AF-Net", "Proposed by the learned autofocus model"),
    ("afnet_speech", "AF-Net + Speech", "Proposed by the learned autofocus model, on the speaker the speech detector "
     "localised"),
    ("initial", "Initial", "The focus at the start of the clip, before any target"),
)

AUTOFOCUS_PRESETS = (
    ("action", "Action", "Moving subjects: action and saliency detectors"),
    ("conversation", "Conversation", "Who is talking: speech and faces (faces when the clip has no audio)"),
    ("faces", "Faces", "The largest face"),
    ("salient", "Salient", "The most salient region"),
    ("learned", "Learned (AF-Net)", "Any scene: the learned look-ahead autofocus model (AF-Net weights in Preferences, "
     "else the shipped ones)"),
    ("auto", "Auto", "Reads the clip (speech? faces? motion?) and picks one of the others; the choice is reported"),
)
"""(``auto`` is last so that strips saved before it keep their preset.)"""

PULL_PROFILES = (
    ("linear", "Linear", "Constant speed (the paper)"),
    ("ease_in_out_cubic", "Ease In/Out (Cubic)", "Slow start and slow landing"),
    ("ease_in_out_sine", "Ease In/Out (Sine)", "Gentle start and landing"),
    ("critically_damped", "Critically Damped", "Fast start, settles without overshoot (a follow-focus motor)"),
)

RENDER_FORMATS = (
    ("MOVIE", "Movie", "H.264 MP4 with the source's sound"),
    ("IMAGES", "Image Sequence", "PNG frames in a folder"),
)

RENDER_SIZES = (
    ("1.0", "Full", "The clip's native resolution"),
    ("0.5", "Proxy 50%", "Half size: 4x faster, blur radii scaled to match"),
    ("0.25", "Proxy 25%", "Quarter size"),
)

DEPTH_METHODS = (
    ("AUTO", "Auto", "Every signal the clip has, fused: parallax where the camera moves sideways, people (MediaPipe) "
     "and the network everywhere"),
    ("PARALLAX", "Parallax", "Depth from the camera's motion (with the network), even where it barely moves"),
    ("PEOPLE", "People", "Person layers and their distance from face size (with the network); needs MediaPipe"),
    ("NETWORK", "Network", "The estimator network alone (the fastest)"),
)

PREVIEW_MODES = (
    ("OFF", "Off", "Show the strip as it is"),
    ("REFOCUS", "Refocused", "Show the refocused frame (from the cache, at preview resolution)"),
    ("DISPARITY", "Disparity", "Show the disparity map of the frame"),
)

JOB_STATES = (
    ("IDLE", "Idle", "No job is running"),
    ("RUNNING", "Running", "A refocus job (analyze, autofocus, track, render) is running"),
    ("CANCELLING", "Cancelling", "The running job was asked to stop"),
)


def _mark_kept(self, _context) -> None:
    if not self.keep:
        self.keep = True


class RVR_PG_box(bpy.types.PropertyGroup):
    """Where a tracked subject is on one clip frame (native px)."""

    frame: IntProperty(name="Frame", description="Clip frame (0-based)", default=0)
    box: FloatVectorProperty(name="Box", size=4, description="x, y, width, height in px of the clip")
    ok: BoolProperty(name="Tracked", description="False where the tracker lost the subject (box held)",
                     default=True)


class RVR_PG_nft(bpy.types.PropertyGroup):
    """A New Focus Target: where the focus goes (point and box) from which frame (clip frame)."""

    frame: IntProperty(name="Frame", description="Clip frame of the target (0-based index in the strip's file)",
                       default=0, min=0, update=_mark_kept)
    x: FloatProperty(name="X", description="Focus point, px from the left of the clip", update=_mark_kept)
    y: FloatProperty(name="Y", description="Focus point, px from the top of the clip", update=_mark_kept)
    box: FloatVectorProperty(name="Box", size=4, description="x, y, width, height in px of the clip",
                             update=_mark_kept)
    source: EnumProperty(name="Source", items=NFT_SOURCES, default="manual")
    keep: BoolProperty(name="Keep", description="Auto Focus never replaces a kept target (set when you add or edit "
                                                "a target)", default=True)
    known_at: IntProperty(name="Known At", description="Clip frame from which the autofocus knew of it", default=0)
    confidence: FloatProperty(name="Confidence", default=1.0, min=0.0, max=1.0)
    pull_frames: IntProperty(name="Pull", description="Length of the pull to this target in frames (0 = the strip's "
                                                      "default)", default=0, min=0, soft_max=96)
    lead_frames: IntProperty(name="Lead", description="The pull lands this many frames before the target (-1 = the "
                                                      "strip's default)", default=-1, min=-1, soft_max=96)
    track: CollectionProperty(type=RVR_PG_box, options={"HIDDEN"})
    tracked_start: IntProperty(name="Tracked From", description="First clip frame the subject was tracked", default=-1)
    tracked_end: IntProperty(name="Tracked To", description="Last clip frame the subject was tracked", default=-1)


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
        subtype="FILE_PATH", options=compat.PATH_OPTIONS,
    )
    depth_method: EnumProperty(name="Depth", items=DEPTH_METHODS, default="AUTO",
                               description="Where Analyze takes the disparity from (the strip's Disparity maps, when "
                                           "set, replace it)")
    hfov_deg: FloatProperty(name="Field of view", default=0.0, min=0.0, max=179.0, soft_max=120.0, precision=1,
                            description="The camera's field of view in degrees across the frame's long side, for depth from parallax "
                                        "and face size (0 = unknown: a phone's main camera, 66)")
    hdr_path: StringProperty(
        name="HDR",
        description="Optional HDR exponent maps (log space), one per frame (folder or pattern)",
        subtype="FILE_PATH", options=compat.PATH_OPTIONS,
    )
    output_dir: StringProperty(
        name="Output",
        description="Folder for the rendered video (// = next to the .blend file)",
        subtype="DIR_PATH", default="//rvr_renders/", options=compat.PATH_OPTIONS,
    )
    render_format: EnumProperty(name="Format", items=RENDER_FORMATS, default="MOVIE",
                                description="Bake to a movie (with sound) or to an image sequence")
    render_size: EnumProperty(name="Size", items=RENDER_SIZES, default="1.0",
                              description="Render at full resolution or as a smaller proxy")
    cache_path: StringProperty(
        name="Cache",
        description="Per-clip cache written by Analyze (disparity, HDR, stabilized); the render and Auto Focus "
                    "read it. Empty = not analysed (the Disparity maps are used)",
        subtype="DIR_PATH", options=compat.PATH_OPTIONS,
    )
    # -- focus targets and pulls
    nfts: CollectionProperty(type=RVR_PG_nft, name="Focus Targets")
    nft_index: IntProperty(name="Active Target", default=0, min=0)
    pull_frames: IntProperty(name="Pull", description="Default length of a focus pull in frames (0 = 0.4 s at the "
                                                      "clip's frame rate: 10 frames at 25 fps, 24 at 60)",
                             default=0, min=0, soft_max=96)
    lead_frames: IntProperty(name="Lead", description="By default a pull lands this many frames before its target "
                                                      "(-1 = 0.2 s at the clip's frame rate: 5 frames at 25 fps)",
                             default=-1, min=-1, soft_max=96)
    pull_profile: EnumProperty(name="Profile", items=PULL_PROFILES, default="linear",
                               description="How the focus moves during a pull")
    hold_frames: IntProperty(name="Hold", description="After a subject is lost, hold its focus this many frames "
                                                      "before releasing to the next target (-1 = 0.48 s at the "
                                                      "clip's frame rate: 12 frames at 25 fps)", default=-1, min=-1)
    autofocus_preset: EnumProperty(name="Preset", items=AUTOFOCUS_PRESETS, default="auto",
                                   description="What Auto Focus looks for")
    focus_calm: FloatProperty(name="Calm", default=DEFAULT_CALM, min=0.0, max=1.0, subtype="FACTOR",
                              description="Calm <-> responsive: 1 holds focus (minimum hold, hysteresis, a cost for "
                                          "each change), 0 pulls on every change the detectors see")
    lookahead_s: FloatProperty(name="Look-Ahead (s)", description="Auto Focus may look this far into the future "
                                                              "(seconds; 0 = causal, like a camera)",
                               default=2.0, min=0.0, soft_max=10.0, step=50, precision=2)
    auto_keys: StringProperty(
        name="Generated Keys", options={"HIDDEN"},
        description="The keyframes Auto Focus/Track wrote last (JSON): the only keys they may replace")
    # -- preview
    preview_mode: EnumProperty(name="Preview", items=PREVIEW_MODES, default="OFF",
                               description="What the Sequencer preview shows over this strip")
    show_targets: BoolProperty(name="Show Targets", default=True,
                               description="Draw the tracked boxes and the focus point over the preview")


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


classes = (RVR_PG_box, RVR_PG_nft, RVR_PG_strip)
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
