"""The ONE place that knows Blender 4.5 from 5.x.

Differences absorbed here, by feature detection (never by parsing version strings):

- strips: 4.4+ ``sequence_editor.strips`` / ``strips_all``; older files/builds ``sequences``.
- actions: 4.4+ layered actions (slots, layers, keyframe strips, channelbags; 5.0 removed the
  legacy ``action.fcurves``); 4.x before that: ``action.fcurves``.
- property-group paths: ``strip.rvr.path_from_id(prop)`` fails in 5.0 ("does not support path
  creation": RNA only finds property groups stored in an ID's own properties, and ``strip.rvr``
  lives on the strip), so :func:`prop_data_path` builds the path from the strip.

No other module spells ``sequences`` or ``action.fcurves``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

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


def active_strip(context: "Context") -> "Strip | None":
    """The active strip of the context's scene, or None."""
    scene = getattr(context, "scene", None)
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


def _path_options() -> set[str]:
    """``options`` for a path property that may hold ``//`` (blend-relative) paths: Blender 5.0
    warns about ``//`` unless the property declares PATH_SUPPORTS_BLEND_RELATIVE (unknown to 4.5)."""
    return {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (5, 0, 0) else set()


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
        return action.fcurve_ensure_for_datablock(id_data, data_path, index=index, group_name=group)
    fcurve = action.fcurves.find(data_path, index=index)  # pragma: no cover - Blender < 4.4
    if fcurve is None:  # pragma: no cover
        fcurve = action.fcurves.new(data_path, index=index, action_group=group)
    return fcurve  # pragma: no cover


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
