"""F-curves of ``strip.rvr.focus_disparity`` / ``strip.rvr.aperture``: read, sample, write.

The curves live in the scene's action with data paths like
``sequence_editor.strips_all["Clip"].rvr.focus_disparity`` (see :func:`data_path`), so Blender
moves them with the strip and renames them with it. Sampling evaluates the curve (modifiers
included) at scene frames, or falls back to the static property value. Writing a keyframe list
is one step: ``keyframe_points.add`` + ``foreach_set`` + one ``update()``.

Blender 5.0 cannot make an RNA path to a property group held by a strip, so the UI's keyframe
decorators and the I key do not work on ``strip.rvr`` fields; :class:`RVR_OT_keyframe_toggle`
is the panel's replacement for them.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Iterable, Sequence

import bpy
import numpy as np

from . import compat
from ..rvr_addon.io.track import FocusTrack

if TYPE_CHECKING:
    from bpy.types import FCurve, Strip

ANIMATED_PROPS = ("focus_disparity", "aperture")
INTERPOLATIONS = ("CONSTANT", "LINEAR", "BEZIER")


def data_path(strip: "Strip", prop: str) -> str:
    """Data path of ``strip.rvr.<prop>`` from the scene, e.g.
    ``sequence_editor.strips_all["Clip"].rvr.focus_disparity``."""
    if prop not in ANIMATED_PROPS:
        raise ValueError(f"strip.rvr.{prop} is not animatable here; use one of {ANIMATED_PROPS}")
    return compat.prop_data_path(strip.rvr, prop)


def find_fcurve(strip: "Strip", prop: str) -> "FCurve | None":
    """The F-curve animating ``strip.rvr.<prop>``, or None."""
    return compat.fcurve_find(strip.id_data, data_path(strip, prop), 0)


def sample_values(strip: "Strip", prop: str, scene_frames: Sequence[int]) -> np.ndarray:
    """``strip.rvr.<prop>`` at each scene frame as (N,) float32: the F-curve's value when it
    exists, is not muted and has keys (or modifiers), else the static property value."""
    frames = np.asarray(scene_frames, dtype=np.float64).reshape(-1)
    fcurve = find_fcurve(strip, prop)
    if fcurve is None or fcurve.mute or (len(fcurve.keyframe_points) == 0 and len(fcurve.modifiers) == 0):
        return np.full(frames.shape, float(getattr(strip.rvr, prop)), dtype=np.float32)
    return np.array([fcurve.evaluate(float(f)) for f in frames], dtype=np.float32)


def sample_track(strip: "Strip", scene_frames: Sequence[int], source_frames: Sequence[int]) -> FocusTrack:
    """Focus track of ``strip``: the evaluated focus and aperture at ``scene_frames``, keyed at
    the matching ``source_frames`` (0-based clip frames, or output frames of a retimed render).
    Negative apertures are clamped to 0."""
    scene_frames = np.asarray(scene_frames).reshape(-1)
    source_frames = np.asarray(source_frames, dtype=np.int64).reshape(-1)
    if scene_frames.shape != source_frames.shape:
        raise ValueError(f"{scene_frames.size} scene frames but {source_frames.size} source frames")
    focus = sample_values(strip, "focus_disparity", scene_frames)
    aperture = np.maximum(sample_values(strip, "aperture", scene_frames), 0.0)
    return FocusTrack(source_frames, focus, aperture, source=f"focus F-curves of strip '{strip.name}'")


def _enum_value(struct_type, prop: str, name: str) -> int:
    return struct_type.bl_rna.properties[prop].enum_items[name].value


def write_keyframes(strip: "Strip", prop: str, keys: Iterable[tuple[float, float]], *,
                    interpolation: str = "BEZIER", replace: bool = True) -> "FCurve":
    """Key ``strip.rvr.<prop>`` at scene frames: ``keys`` is (frame, value) pairs, any order.

    replace: drop the curve's existing keys first (else keys at other frames are kept and a key
    at the same frame is overwritten). All keys are added in one step and the curve updated
    once (sorted, handles recalculated), so one undo step covers the change.
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation {interpolation!r}: use one of {INTERPOLATIONS}")
    new = {float(f): float(v) for f, v in keys}
    if new and not (np.all(np.isfinite(list(new))) and np.all(np.isfinite(list(new.values())))):
        raise ValueError(f"keyframes of strip.rvr.{prop} must be finite numbers")
    fcurve = compat.fcurve_ensure(strip.id_data, data_path(strip, prop), 0, group=f"RVR {strip.name}")
    points = fcurve.keyframe_points
    if not replace and len(points):
        co = np.empty(2 * len(points), dtype=np.float64)
        points.foreach_get("co", co)
        old = dict(zip(co[0::2].tolist(), co[1::2].tolist()))
        old.update(new)
        new = old
    points.clear()
    frames = sorted(new)
    if frames:
        points.add(len(frames))
        co = np.empty(2 * len(frames), dtype=np.float32)
        co[0::2] = frames
        co[1::2] = [new[f] for f in frames]
        points.foreach_set("co", co)
        points.foreach_set("interpolation", [_enum_value(bpy.types.Keyframe, "interpolation", interpolation)] * len(frames))
    fcurve.update()
    return fcurve


GENERATED_TYPE = "GENERATED"
"""Keyframe type of the keys Track / Auto Focus write (Blender shows them as small, pale keys)."""


def replace_generated_keys(strip: "Strip", prop: str, keys: Iterable[tuple[float, float]],
                           previous: Iterable[tuple[float, float]] = ()) -> tuple["FCurve", list, int]:
    """Replace the keys a tool generated before with ``keys`` (scene frame, value), keeping the
    editor's keys.

    A key is the tool's to replace when its type is GENERATED *and* its (frame, value) is one
    of ``previous`` (what the tool wrote last); any other key (inserted, moved or edited by
    hand, or of another type) is the editor's and stays as it is, handles and all. A new key
    within half a frame of an editor's key is dropped (the hand key wins). New keys are LINEAR
    (the engine's keyframe list reproduces its track under linear interpolation).
    Returns (the F-curve, the (frame, value) list written, the number of editor keys kept).
    """
    new = [(float(f), float(v)) for f, v in keys]
    if not all(np.isfinite(f) and np.isfinite(v) for f, v in new):
        raise ValueError(f"keyframes of strip.rvr.{prop} must be finite numbers")
    old = {(round(float(f), 3), round(float(v), 4)) for f, v in previous}
    fcurve = compat.fcurve_ensure(strip.id_data, data_path(strip, prop), 0, group=f"RVR {strip.name}")
    points = fcurve.keyframe_points
    ours = [i for i, k in enumerate(points)
            if k.type == GENERATED_TYPE and (round(k.co[0], 3), round(k.co[1], 4)) in old]
    for i in reversed(ours):
        points.remove(points[i], fast=True)
    hand = [k.co[0] for k in points]
    written = []
    for frame, value in new:
        if any(abs(frame - h) < 0.5 for h in hand):
            continue
        key = points.insert(frame, value, options={"FAST"}, keyframe_type=GENERATED_TYPE)
        key.interpolation = "LINEAR"
        written.append((round(key.co[0], 3), round(key.co[1], 4)))
    fcurve.update()
    return fcurve, written, len(hand)


def key_at(strip: "Strip", prop: str, frame: float) -> bool:
    """True when ``strip.rvr.<prop>`` has a key at scene ``frame``."""
    fcurve = find_fcurve(strip, prop)
    if fcurve is None:
        return False
    return any(abs(k.co[0] - frame) < 1e-3 for k in fcurve.keyframe_points)


class RVR_OT_keyframe_toggle(bpy.types.Operator):
    """Insert a key for this value at the current frame, or delete the key that is there"""

    bl_idname = "rvr.keyframe_toggle"
    bl_label = "Toggle Refocus Key"
    bl_options = {"REGISTER", "UNDO"}

    prop: bpy.props.EnumProperty(
        name="Property", items=[(p, p.replace("_", " ").title(), "") for p in ANIMATED_PROPS])

    @classmethod
    def poll(cls, context) -> bool:
        strip = compat.active_strip(context)
        if strip is None or not hasattr(strip, "rvr"):
            cls.poll_message_set("No active strip.")
            return False
        return True

    def execute(self, context) -> set[str]:
        strip = compat.active_strip(context)
        frame = float(compat.sequencer_scene(context).frame_current)
        fcurve = find_fcurve(strip, self.prop)
        if fcurve is not None and key_at(strip, self.prop, frame):
            for point in fcurve.keyframe_points:
                if abs(point.co[0] - frame) < 1e-3:
                    fcurve.keyframe_points.remove(point, fast=True)
                    break
            fcurve.update()
            if len(fcurve.keyframe_points) == 0:
                compat.fcurve_remove(strip.id_data, fcurve)
        else:
            fcurve = compat.fcurve_ensure(strip.id_data, data_path(strip, self.prop), 0, group=f"RVR {strip.name}")
            fcurve.keyframe_points.insert(frame, float(getattr(strip.rvr, self.prop)), options={"FAST"})
            fcurve.update()
        return {"FINISHED"}


classes = (RVR_OT_keyframe_toggle,)
register, unregister = bpy.utils.register_classes_factory(classes)
