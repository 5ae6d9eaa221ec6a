"""Focus targets and focus tracks: Add Focus Target, edit the list, Track, Auto Focus.

The engine does the work (:class:`rvr_addon.laaf.lookahead.AutofocusJob`: detectors, KCF
tracking, the puller, the sparse keyframe list); these operators only translate:

* strip -> engine: the NFT list (``strip.rvr.nfts``, clip frames and native px, the engine's
  own units) becomes engine :class:`~rvr_addon.laaf.nft.NFT` objects; the disparity comes
  from the strip's analysis cache or its Disparity maps; pull settings from the strip.
* engine -> strip (:func:`apply_focus_result`, one step, only when the job finished): the
  tracked boxes and ranges go back onto the NFTs; Auto Focus replaces the targets it proposed
  before and never a kept (manual or edited) one; the keyframe list is written to
  ``strip.rvr.focus_disparity`` (and ``aperture`` when it varies) as GENERATED keys at the
  scene frames showing the keys' clip frames (:func:`scene_keys`: a retimed strip shows a clip
  frame on several scene frames or skips it), replacing only the keys written last time
  (:func:`.fcurves.replace_generated_keys`): keys the editor added or edited stay.

**Track** re-tracks every target in the list and rewrites the focus keys (after the editor
corrected the targets); **Auto Focus** first asks the detectors of a preset for new targets,
with a look-ahead window, keeping the kept ones.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING

import bpy
import numpy as np
from bpy.props import EnumProperty, FloatProperty, IntProperty

from . import compat, fcurves, notes, prefs
from .jobrun import JobOperator
from .ops_render import poll_clip_strip
from .props import AUTOFOCUS_PRESETS
from .source import StripSource, abspath, analysed_cache, clip_info, first_showing, resolve_source
from ..rvr_addon.errors import InputError

if TYPE_CHECKING:
    from bpy.types import Strip

# ----------------------------------------------------------------------------- helpers


def clip_size(source: StripSource) -> tuple[int, int]:
    """(width, height) of the strip's clip in native px (probed once per file version)."""
    info = clip_info(source.path, source.fps)
    return info.width, info.height


def engine_nft(item):
    """The engine NFT of one ``strip.rvr.nfts`` item (clip frame, native px)."""
    from ..rvr_addon.laaf.nft import NFT

    return NFT(float(item.x), float(item.y), int(item.frame), tuple(float(v) for v in item.box), item.source,
               known_at=int(item.known_at) if not item.keep else 0, confidence=float(item.confidence),
               pull_frames=int(item.pull_frames) or None,
               lead_frames=None if item.lead_frames < 0 else int(item.lead_frames))


def find_nft(strip: "Strip", clip_frame: int):
    """(index, item) of the target on ``clip_frame``, or (-1, None)."""
    for i, item in enumerate(strip.rvr.nfts):
        if item.frame == clip_frame:
            return i, item
    return -1, None


def _set_nft(item, nft, keep: bool) -> None:
    """Write an engine NFT into a collection item (keep last: the update callbacks set it)."""
    item.frame = int(nft.t)
    item.x, item.y = float(nft.x), float(nft.y)
    item.box = tuple(float(v) for v in nft.box)
    item.source = nft.source
    item.known_at = int(nft.known_at)
    item.confidence = float(min(max(nft.confidence, 0.0), 1.0))
    if nft.pull_frames is not None:
        item.pull_frames = int(nft.pull_frames)
    if nft.lead_frames is not None:
        item.lead_frames = int(nft.lead_frames)
    item.keep = keep


def sort_nfts(strip: "Strip") -> None:
    """Order the targets by frame (insertion sort with ``move``; keeps the active one active)."""
    nfts = strip.rvr.nfts
    active = nfts[strip.rvr.nft_index].frame if 0 <= strip.rvr.nft_index < len(nfts) else None
    for i in range(1, len(nfts)):
        j = i
        while j > 0 and nfts[j - 1].frame > nfts[j].frame:
            nfts.move(j, j - 1)
            j -= 1
    if active is not None:
        strip.rvr.nft_index = find_nft(strip, active)[0]


def add_target(scene, strip: "Strip", scene_frame: int, x: float, y: float, w: float = 0.0, h: float = 0.0):
    """Add (or replace) the manual target on the clip frame shown at ``scene_frame``.

    x, y: focus point; w, h: box size (0: a default box around the point), native clip px.
    Raises InputError for a frame the strip does not show or a box outside the frame.
    """
    from ..rvr_addon.laaf.nft import NFT, default_box, validate_nfts

    source = resolve_source(scene, strip)
    clip_frame = source.scene_to_clip(scene_frame)
    if clip_frame is None:
        raise InputError(f"strip '{strip.name}' does not show a clip frame at scene frame {scene_frame} (it shows "
                         f"scene frames {source.span.scene_start}..{source.span.scene_stop - 1}); move the playhead "
                         "over the strip")
    width, height = clip_size(source)
    if w > 0 and h > 0:
        box = (x - w / 2, y - h / 2, w, h)
    else:
        box = default_box(x, y, width, height)
    (nft,) = validate_nfts([NFT(x, y, clip_frame, box, "manual")], source.span.clip_stop, width, height,
                           where=f"focus target at frame {scene_frame}")
    index, item = find_nft(strip, clip_frame)
    if item is None:
        item = strip.rvr.nfts.add()
        item.track.clear()
        item.tracked_start = item.tracked_end = -1
    _set_nft(item, nft, keep=True)
    strip.rvr.nft_index = len(strip.rvr.nfts) - 1 if index < 0 else index
    sort_nfts(strip)
    return item


# ----------------------------------------------------------------------------- plan and job


@dataclass
class FocusPlan:
    """What Track / Auto Focus run (plain values) and how to apply the result."""

    source: StripSource
    settings: object  # AutofocusSettings
    replace_auto: bool
    aperture: float


def plan_focus(scene, strip: "Strip", preset: str | None, window_s: float) -> FocusPlan:
    """Read the strip into an AutofocusSettings. preset None = Track (the list's targets only).

    Raises InputError when the strip has no disparity (not analysed, no maps) or, for Track,
    no targets.
    """
    from ..rvr_addon.laaf.lookahead import AutofocusSettings
    from ..rvr_addon.laaf.puller import PullSettings

    notes.start()  # the engine's warnings from here to the report are shown in the UI
    source = resolve_source(scene, strip)
    rvr = strip.rvr
    cache = analysed_cache(strip)
    depth = None
    if cache is None:
        if not rvr.depth_path:
            raise InputError(f"strip '{strip.name}' has no disparity yet: run Analyze on it first (or set its "
                             "Disparity maps)")
        depth = abspath(rvr.depth_path, "disparity path", strip)
    span = source.span
    kept = [item for item in rvr.nfts if (item.keep or preset is None) and source.shows(item.frame)]
    if preset is None and not kept:
        raise InputError(f"strip '{strip.name}' has no focus target in its visible frames: add one (Add Focus "
                         "Target) or run Auto Focus")
    # 0 / -1: the engine's defaults in seconds, as frames at the clip's rate (laaf.timebase)
    pull = PullSettings(pull_frames=int(rvr.pull_frames) or None,
                        lead_frames=None if rvr.lead_frames < 0 else int(rvr.lead_frames),
                        profile=rvr.pull_profile, hold_frames=None if rvr.hold_frames < 0 else int(rvr.hold_frames))
    aperture = float(rvr.aperture)
    settings = AutofocusSettings(
        input=source.path, cache=cache, depth=depth, preset=preset, nfts=[engine_nft(i) for i in kept],
        window_s=max(float(window_s), 0.0), causal=window_s <= 0, pull=pull, aperture=aperture,
        start=span.clip_start, stop=span.clip_stop, fps=source.fps, calm=float(getattr(rvr, "focus_calm", 0.5)),
        afnet_weights=prefs.afnet_weights_file(prefs.get()) if preset == "learned" else None,
        afnet_speaker=prefs.get().afnet_region != "MAP")
    return FocusPlan(source, settings, preset is not None, aperture)


def start_focus(plan: FocusPlan):
    from ..rvr_addon.laaf.lookahead import AutofocusJob

    prefs.apply_threads(prefs.get())
    return AutofocusJob(plan.settings)


def _strip_of(plan: FocusPlan) -> "Strip":
    scene = bpy.data.scenes.get(plan.source.scene_name)
    editor = scene.sequence_editor if scene is not None else None
    strip = compat.strip_collection_all(editor).get(plan.source.strip_name) if editor is not None else None
    if strip is None:
        raise InputError(f"strip '{plan.source.strip_name}' is gone; nothing was changed")
    return strip


def scene_keys(source: StripSource, clip_frames: list[int], values: list[float]) -> list[tuple[float, float]]:
    """A track keyed at clip frames (linear between keys) as (scene frame, value) keys.

    Each key goes to the first scene frame showing its clip frame (or, on a sped-up strip that
    skips it, the next clip frame shown); a retimed strip also gets a key where it changes speed
    between two keys. Every key holds the track's value at the clip frame shown on its scene
    frame, so the curve follows what is on screen. Not retimed: the engine's keys, shifted.
    """
    if not len(clip_frames):
        return []
    shown = np.asarray(source.clip_frames)
    order = np.argsort(clip_frames, kind="stable")
    frames, vals = np.asarray(clip_frames, np.float64)[order], np.asarray(values, np.float64)[order]
    at = {first_showing(shown, f) for f in frames}
    lo, hi = min(at), max(at)
    at |= {c - source.span.scene_start for c in source.speed_changes if lo < c - source.span.scene_start < hi}
    at = sorted(at)
    return [(float(source.span.scene_start + i), float(v)) for i, v in zip(at, np.interp(shown[at], frames, vals))]


def apply_focus_result(plan: FocusPlan, result) -> dict:
    """Write the engine's result onto the strip (targets, tracked boxes, generated keys).

    Returns counts for the report: targets added/replaced/kept, keys written, hand keys kept.
    """
    strip = _strip_of(plan)
    rvr = strip.rvr
    start = result.start
    by_frame = {int(n.t) + start: (n, boxes) for n, boxes in zip(result.nfts, result.boxes or [{}] * len(result.nfts))}
    removed = 0
    if plan.replace_auto:  # Auto Focus: its earlier proposals in the analysed range go
        for i in reversed(range(len(rvr.nfts))):
            item = rvr.nfts[i]
            if not item.keep and plan.source.shows(item.frame):
                rvr.nfts.remove(i)
                removed += 1
    added = 0
    for frame, (nft, boxes) in sorted(by_frame.items()):
        _, item = find_nft(strip, frame)
        if item is None:
            if not plan.replace_auto:
                continue
            from dataclasses import replace

            item = rvr.nfts.add()
            _set_nft(item, replace(nft, t=frame, known_at=int(nft.known_at) + start), keep=False)
            added += 1
        item.track.clear()
        for k, (box, ok) in sorted(boxes.items()):
            entry = item.track.add()
            entry.frame = int(k) + start
            entry.box = box
            entry.ok = bool(ok)
        frames = [int(k) + start for k, (_, ok) in boxes.items() if ok]
        item.tracked_start = min(frames) if frames else -1
        item.tracked_end = max(frames) if frames else -1
    sort_nfts(strip)
    rvr.nft_index = min(rvr.nft_index, max(len(rvr.nfts) - 1, 0))

    record = json.loads(rvr.auto_keys) if rvr.auto_keys else {}
    clip_keys = [k.frame + start for k in result.keys]
    focus_keys = scene_keys(plan.source, clip_keys, [k.focus for k in result.keys])
    _, written, hand = fcurves.replace_generated_keys(strip, "focus_disparity", focus_keys,
                                                      record.get("focus_disparity", ()))
    new_record = {"focus_disparity": written}
    hand_aperture = 0
    apertures = [k.aperture for k in result.keys]
    if max(apertures) - min(apertures) > 1e-6 or record.get("aperture"):
        ap_keys = scene_keys(plan.source, clip_keys, apertures) if max(apertures) - min(apertures) > 1e-6 else []
        _, ap_written, hand_aperture = fcurves.replace_generated_keys(strip, "aperture", ap_keys,
                                                                      record.get("aperture", ()))
        new_record["aperture"] = ap_written
    rvr.auto_keys = json.dumps(new_record)
    return {"added": added, "removed": removed, "targets": len(by_frame), "keys": len(written),
            "hand_keys": hand + hand_aperture}


# ----------------------------------------------------------------------------- operators


class _FocusJobOperator(JobOperator):
    def _report_result(self, plan: FocusPlan, job, counts: dict, what: str) -> None:
        result = job.result
        note = f"; {result.settings['fallback']}" if result.settings.get("fallback") else ""
        hand = f", kept {counts['hand_keys']} keys you set by hand" if counts["hand_keys"] else ""
        notes.report(self.report)  # first: the summary stays the last report (the status bar's)
        self.report({"INFO"}, f"{what} '{plan.source.strip_name}': {counts['targets']} targets "
                              f"({counts['added']} new), {counts['keys']} focus keys{hand}{note}")


class RVR_OT_track_targets(_FocusJobOperator, bpy.types.Operator):
    """Track every focus target of the active strip to the next one and write the focus keyframes (keys you set by hand are kept)"""

    bl_idname = "rvr.track_targets"
    bl_label = "Track"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Track"

    @classmethod
    def poll(cls, context) -> bool:
        if not poll_clip_strip(cls, context):
            return False
        if not len(compat.active_strip(context).rvr.nfts):
            cls.poll_message_set("Add a focus target first (Add Focus Target or Auto Focus).")
            return False
        return True

    def _prepare(self, context):
        plan = plan_focus(compat.sequencer_scene(context), compat.active_strip(context), None, 0.0)
        return plan, start_focus(plan)

    def _apply(self, context, plan, job) -> None:
        self._report_result(plan, job, apply_focus_result(plan, job.result), "Tracked")


class RVR_OT_auto_focus(_FocusJobOperator, bpy.types.Operator):
    """Find focus targets with a detector preset, looking ahead, track them and write the focus keyframes; kept targets and keys you set by hand are never replaced"""

    bl_idname = "rvr.auto_focus"
    bl_label = "Auto Focus"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Auto Focus"

    preset: EnumProperty(name="Preset", items=(("STRIP", "Strip's Preset", "The preset set on the strip"),)
                         + AUTOFOCUS_PRESETS, default="STRIP")
    lookahead_s: FloatProperty(name="Look-Ahead (s)", default=-1.0, min=-1.0,
                               description="Seconds of look-ahead (0 = causal); -1 = the strip's setting")

    @classmethod
    def poll(cls, context) -> bool:
        return poll_clip_strip(cls, context)

    def _prepare(self, context):
        strip = compat.active_strip(context)
        preset = strip.rvr.autofocus_preset if self.preset == "STRIP" else self.preset
        window = strip.rvr.lookahead_s if self.lookahead_s < 0 else self.lookahead_s
        plan = plan_focus(compat.sequencer_scene(context), strip, preset, window)
        return plan, start_focus(plan)

    def _apply(self, context, plan, job) -> None:
        self._report_result(plan, job, apply_focus_result(plan, job.result), "Auto Focus on")


class RVR_OT_add_focus_target(bpy.types.Operator):
    """Add a focus target at the current frame: drag a box (or click a point) in the Sequencer preview; scripts give x, y, w, h in clip pixels"""

    bl_idname = "rvr.add_focus_target"
    bl_label = "Add Focus Target"
    bl_options = {"REGISTER", "UNDO"}

    x: FloatProperty(name="X", description="Focus point, px from the left of the clip", default=-1.0)
    y: FloatProperty(name="Y", description="Focus point, px from the top of the clip", default=-1.0)
    w: FloatProperty(name="Width", description="Box width in clip px (0 = a default box)", default=0.0, min=0.0)
    h: FloatProperty(name="Height", description="Box height in clip px (0 = a default box)", default=0.0, min=0.0)
    frame: IntProperty(name="Frame", description="Scene frame (default: the current frame)", default=-(2 ** 30))

    @classmethod
    def poll(cls, context) -> bool:
        return poll_clip_strip(cls, context, need_idle=False)

    def execute(self, context) -> set[str]:
        strip, scene = compat.active_strip(context), compat.sequencer_scene(context)
        frame = scene.frame_current if self.frame == -(2 ** 30) else self.frame
        try:
            if self.x < 0 or self.y < 0:
                source = resolve_source(scene, strip)
                width, height = clip_size(source)
                x, y = (width / 2, height / 2) if self.x < 0 and self.y < 0 else (self.x, self.y)
            else:
                x, y = self.x, self.y
            item = add_target(scene, strip, frame, x, y, self.w, self.h)
        except InputError as ex:
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Focus target at clip frame {item.frame}: ({item.x:.0f}, {item.y:.0f}); run Track "
                              "to follow it")
        return {"FINISHED"}

    def invoke(self, context, event) -> set[str]:
        from . import preview

        if bpy.app.background or not preview.preview_region(context):
            return self.execute(context)
        self._drag = preview.BoxDrag(context)
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set("Add Focus Target: drag a box or click the subject (Esc to cancel)")
        return {"RUNNING_MODAL"}

    def modal(self, context, event) -> set[str]:
        drag = self._drag
        if event.type in {"ESC", "RIGHTMOUSE"}:
            drag.end()
            context.area.header_text_set(None)
            return {"CANCELLED"}
        if event.type == "MOUSEMOVE":
            drag.move(event.mouse_region_x, event.mouse_region_y)
            context.area.tag_redraw()
        elif event.type == "LEFTMOUSE" and event.value == "PRESS":
            drag.press(event.mouse_region_x, event.mouse_region_y)
        elif event.type == "LEFTMOUSE" and event.value == "RELEASE" and drag.started:
            box = drag.release(event.mouse_region_x, event.mouse_region_y)
            context.area.header_text_set(None)
            if box is None:
                self.report({"WARNING"}, "Click inside the strip's picture")
                return {"CANCELLED"}
            (self.x, self.y), (self.w, self.h) = box
            return self.execute(context)
        return {"RUNNING_MODAL"}


class RVR_OT_remove_focus_target(bpy.types.Operator):
    """Delete the active focus target (run Track to update the focus keys)"""

    bl_idname = "rvr.remove_focus_target"
    bl_label = "Remove Focus Target"
    bl_options = {"REGISTER", "UNDO"}

    index: IntProperty(name="Index", default=-1, description="Target to delete (-1 = the active one)")

    @classmethod
    def poll(cls, context) -> bool:
        strip = compat.active_strip(context)
        if strip is None or not hasattr(strip, "rvr") or not len(strip.rvr.nfts):
            cls.poll_message_set("The active strip has no focus target.")
            return False
        return True

    def execute(self, context) -> set[str]:
        rvr = compat.active_strip(context).rvr
        index = rvr.nft_index if self.index < 0 else self.index
        if not 0 <= index < len(rvr.nfts):
            self.report({"ERROR"}, f"no focus target #{index} (the strip has {len(rvr.nfts)})")
            return {"CANCELLED"}
        rvr.nfts.remove(index)
        rvr.nft_index = min(index, max(len(rvr.nfts) - 1, 0))
        return {"FINISHED"}


class RVR_OT_jump_to_target(bpy.types.Operator):
    """Move the playhead to the focus target's frame (the first scene frame showing it)"""

    bl_idname = "rvr.jump_to_target"
    bl_label = "Jump to Target"
    bl_options = {"REGISTER", "UNDO_GROUPED"}
    bl_undo_group = "Frame Change"  # as Blender's own frame jumps: one undo step for a run of jumps

    index: IntProperty(name="Index", default=-1, description="Target (-1 = the active one)")

    @classmethod
    def poll(cls, context) -> bool:
        return RVR_OT_remove_focus_target.poll(context)

    def execute(self, context) -> set[str]:
        strip = compat.active_strip(context)
        rvr = strip.rvr
        index = rvr.nft_index if self.index < 0 else self.index
        if not 0 <= index < len(rvr.nfts):
            self.report({"ERROR"}, f"no focus target #{index}")
            return {"CANCELLED"}
        rvr.nft_index = index
        scene = compat.sequencer_scene(context)
        try:
            source = resolve_source(scene, strip)
        except InputError as ex:
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        scene.frame_set(source.clip_to_scene(rvr.nfts[index].frame))
        return {"FINISHED"}


classes = (RVR_OT_add_focus_target, RVR_OT_remove_focus_target, RVR_OT_jump_to_target, RVR_OT_track_targets,
           RVR_OT_auto_focus)
register, unregister = bpy.utils.register_classes_factory(classes)
