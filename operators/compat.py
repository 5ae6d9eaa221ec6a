"""The ONE place that knows Blender 4.5 from 5.x.

Differences absorbed here, by feature detection (never by parsing version strings):

- strips: 4.4+ ``sequence_editor.strips`` / ``strips_all``; older files/builds ``sequences``.
- actions: 4.4+ layered actions (slots, layers, keyframe strips, channelbags; 5.0 removed the
  legacy ``action.fcurves``); 4.x before that: ``action.fcurves``.
- property-group paths: ``strip.rvr.path_from_id(prop)`` fails in 5.0 ("does not support path
  creation": RNA only finds property groups stored in an ID's own properties, and ``strip.rvr``
  lives on the strip), so :func:`prop_data_path` builds the path from the strip.
- the Sequencer's scene: 5.0 edits ``workspace.sequencer_scene`` (``context.sequencer_scene``),
  which may differ from the window's scene; 4.5 edits ``context.scene`` (:func:`sequencer_scene`).
- retiming keys (4.2+): RNA exposes only a key's ``timeline_frame``; the content position it
  maps to is read by :func:`retiming_keys` from the key's own struct (two known layouts).

No other module spells ``sequences`` or ``action.fcurves``.
"""
from __future__ import annotations

import ctypes
import math
from typing import TYPE_CHECKING, NamedTuple

import bpy

if TYPE_CHECKING:
    from bpy.types import Action, Context, FCurve, ID, Scene, Strip


def strip_collection_all(editor):
    """Every strip of a sequence editor, meta-strip contents included."""
    if hasattr(editor, "strips_all"):
        return editor.strips_all
    return editor.sequences_all  # pragma: no cover - Blender < 4.4


def strip_collection_top(container):
    """The direct children of a sequence editor or a meta strip (``strips`` / ``sequences``)."""
    if hasattr(container, "strips"):
        return container.strips
    return container.sequences  # pragma: no cover - Blender < 4.4


def strips_all(scene: "Scene") -> list:
    """All strips of ``scene`` (empty list when it has no sequence editor)."""
    editor = scene.sequence_editor
    if editor is None:
        return []
    return list(strip_collection_all(editor))


def sequencer_scene(context: "Context") -> "Scene | None":
    """The scene the Sequencer edits: ``context.sequencer_scene`` (5.0) when set, else ``context.scene``."""
    return getattr(context, "sequencer_scene", None) or getattr(context, "scene", None)


def active_strip(context: "Context") -> "Strip | None":
    """The active strip of the Sequencer's scene (:func:`sequencer_scene`), or None."""
    scene = sequencer_scene(context)
    editor = scene.sequence_editor if scene is not None else None
    if editor is None:
        return None
    if hasattr(editor, "active_strip"):
        return editor.active_strip
    return getattr(context, "active_sequence_strip", None)  # pragma: no cover - very old API


def strip_type(strip: "Strip") -> str:
    """'MOVIE', 'IMAGE', 'SOUND', 'META', ... (the RNA enum of the strip)."""
    return str(strip.type)


def strip_container(scene: "Scene", strip: "Strip"):
    """The collection holding ``strip`` directly: the editor's top level or its meta strip's."""
    parent = strip.parent_meta() if hasattr(strip, "parent_meta") else None
    if parent is not None:
        return strip_collection_top(parent)
    return strip_collection_top(scene.sequence_editor)


def prop_data_path(struct, prop: str) -> str:
    """Data path from the owning ID to ``struct.<prop>``, e.g.
    ``sequence_editor.strips_all["Clip"].rvr.focus_disparity`` for ``strip.rvr``.

    Uses ``struct.path_from_id(prop)`` where Blender can make it. For a property group held by
    a strip, 5.0 refuses, so the path is built from the parent's path to the group (the parent
    is the last of ``struct.rna_ancestors()``, so reach ``struct`` by attribute access).
    """
    try:
        return struct.path_from_id(prop)
    except ValueError:
        pass
    ancestors = struct.rna_ancestors() if hasattr(struct, "rna_ancestors") else []
    if ancestors:
        parent = ancestors[-1]
        for p in parent.bl_rna.properties:
            if p.type == "POINTER" and p.identifier != "rna_type" and getattr(parent, p.identifier) == struct:
                return f"{parent.path_from_id(p.identifier)}.{prop}"
    raise ValueError(f"cannot make an animation data path to {struct!r}.{prop}; "
                     "reach it by attribute access from its ID (e.g. strip.rvr)")


class RetimingKey(NamedTuple):
    """One retiming key: ``timeline_frame`` (scene frame, as RNA shows it), ``index`` (Blender's
    ``strip_frame_index``: media frames after ``frame_start`` before retiming), ``factor`` (0..1
    of the strip's content) and ``flags`` (``TRANSITION_FLAGS`` = a gradual speed change)."""

    timeline_frame: int
    index: float
    factor: float
    flags: int


TRANSITION_FLAGS = 0b11
"""SEQ_SPEED_TRANSITION_IN | SEQ_SPEED_TRANSITION_OUT of DNA ``SeqRetimingKey.flag``."""

_RETIMING_FACTOR_OFFSET = {32: 12, 40: 16}
"""sizeof(SeqRetimingKey) -> offset of ``retiming_factor``: 4.2 to 5.0 pack ``int flag; float
retiming_factor`` after ``double strip_frame_index`` (32 bytes); later sources pad ``flag`` (40)."""


def retiming_keys(strip: "Strip") -> list[RetimingKey] | None:
    """The retiming keys of ``strip`` in order ([] when it is not retimed: fewer than 2 keys);
    None when this Blender stores them in a layout not known here.

    RNA has no field for the content position of a key, so ``strip_frame_index`` (a double at
    offset 0), ``flag`` (int at 8) and ``retiming_factor`` are read from the key's struct; the
    layout is recognised by the distance between two keys (``sizeof``), never by version.
    """
    keys = list(getattr(strip, "retiming_keys", ()))
    if len(keys) < 2:
        return []
    offset = _RETIMING_FACTOR_OFFSET.get(keys[1].as_pointer() - keys[0].as_pointer())
    if offset is None:
        return None
    out = []
    for key in keys:
        raw = ctypes.string_at(key.as_pointer(), offset + 4)
        index = ctypes.c_double.from_buffer_copy(raw, 0).value
        flags = ctypes.c_int.from_buffer_copy(raw, 8).value
        factor = ctypes.c_float.from_buffer_copy(raw, offset).value
        out.append(RetimingKey(int(key.timeline_frame), index, factor, flags))
    return out if _plausible(out) else None


def _plausible(keys: list[RetimingKey]) -> bool:
    """Whether values read from memory look like retiming keys (finite, timeline frames strictly
    increasing, content positions >= 0): a guard against a layout that merely has a known size."""
    frames = [k.timeline_frame for k in keys]
    return (all(math.isfinite(k.index) and k.index >= 0 for k in keys)
            and all(b > a for a, b in zip(frames, frames[1:])))


def _path_options() -> set[str]:
    """``options`` for a path property that may hold ``//`` (blend-relative) paths: Blender 5.0
    and late 4.5 LTS releases (4.5.15) warn about ``//`` unless the property declares
    PATH_SUPPORTS_BLEND_RELATIVE, which older builds refuse; found out by registering a
    throwaway property group with it."""
    option = "PATH_SUPPORTS_BLEND_RELATIVE"
    probe = type("RVR_PG_path_option_probe", (bpy.types.PropertyGroup,),
                 {"__annotations__": {"path": bpy.props.StringProperty(options={option})}})
    try:
        bpy.utils.register_class(probe)
        known = "path" in probe.bl_rna.properties
    except (TypeError, ValueError):  # pragma: no cover - builds without the option
        known = False
    finally:
        if probe.is_registered:
            bpy.utils.unregister_class(probe)
    return {option} if known else set()


PATH_OPTIONS = _path_options()


# ----------------------------------------------------------------------------- F-curves


def _is_layered(action: "Action") -> bool:
    return hasattr(action, "layers") and hasattr(action, "slots")


def _channelbag(id_data: "ID", create: bool):
    """Channelbag of ``id_data``'s assigned action slot (layered actions), or None."""
    adt = id_data.animation_data
    if adt is None or adt.action is None:
        return None
    action = adt.action
    slot = getattr(adt, "action_slot", None)
    if slot is None:
        return None
    from bpy_extras import anim_utils

    if create:
        return anim_utils.action_ensure_channelbag_for_slot(action, slot)
    return anim_utils.action_get_channelbag_for_slot(action, slot)


def fcurve_find(id_data: "ID", data_path: str, index: int = 0) -> "FCurve | None":
    """The F-curve animating ``id_data.<data_path>[index]`` in its assigned action, or None."""
    adt = id_data.animation_data
    if adt is None or adt.action is None:
        return None
    action = adt.action
    if _is_layered(action):
        bag = _channelbag(id_data, create=False)
        return None if bag is None else bag.fcurves.find(data_path, index=index)
    return action.fcurves.find(data_path, index=index)  # pragma: no cover - Blender < 4.4


def fcurve_ensure(id_data: "ID", data_path: str, index: int = 0, group: str = "") -> "FCurve":
    """Find or create the F-curve for ``id_data.<data_path>[index]``.

    Creates the animation data, an action ("<ID name>Action") and, for layered actions, the
    slot, layer, keyframe strip and channelbag as needed, the same way inserting a key in the
    UI does.
    """
    adt = id_data.animation_data or id_data.animation_data_create()
    if adt.action is None:
        adt.action = bpy.data.actions.new(f"{id_data.name}Action")
    action = adt.action
    if hasattr(action, "fcurve_ensure_for_datablock"):
        if "group_name" in action.bl_rna.functions["fcurve_ensure_for_datablock"].parameters:  # 5.0
            return action.fcurve_ensure_for_datablock(id_data, data_path, index=index, group_name=group)
        fcurve = action.fcurve_ensure_for_datablock(id_data, data_path, index=index)  # 4.4/4.5: no group
        _set_group(id_data, fcurve, group)
        return fcurve
    fcurve = action.fcurves.find(data_path, index=index)  # pragma: no cover - Blender < 4.4
    if fcurve is None:  # pragma: no cover
        fcurve = action.fcurves.new(data_path, index=index, action_group=group)
    return fcurve  # pragma: no cover


def _set_group(id_data: "ID", fcurve: "FCurve", group: str) -> None:
    """Put an ungrouped ``fcurve`` of a layered action into the channel group ``group``."""
    bag = _channelbag(id_data, create=False)
    if not group or bag is None or fcurve.group is not None:
        return
    fcurve.group = bag.groups.get(group) or bag.groups.new(group)


def fcurves_all(id_data: "ID") -> list:
    """Every F-curve of ``id_data``'s assigned action (its slot's channelbag on 4.4+)."""
    adt = id_data.animation_data
    if adt is None or adt.action is None:
        return []
    if _is_layered(adt.action):
        bag = _channelbag(id_data, create=False)
        return [] if bag is None else list(bag.fcurves)
    return list(adt.action.fcurves)  # pragma: no cover - Blender < 4.4


def fcurve_remove(id_data: "ID", fcurve: "FCurve") -> None:
    """Remove ``fcurve`` from ``id_data``'s action."""
    adt = id_data.animation_data
    if adt is None or adt.action is None:
        return
    if _is_layered(adt.action):
        bag = _channelbag(id_data, create=False)
        if bag is not None:
            bag.fcurves.remove(fcurve)
        return
    adt.action.fcurves.remove(fcurve)  # pragma: no cover - Blender < 4.4
