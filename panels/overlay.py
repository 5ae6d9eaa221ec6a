"""Draw over the Sequencer preview: the refocused frame or the disparity map (from the cache),
the tracked boxes of the focus targets, the focus point, and the box being dragged.

One ``POST_VIEW`` draw handler on the preview region, added only when Blender has a UI
(never in background mode). :func:`overlay_shapes` computes what to draw in view
coordinates from plain Blender state (tested headless); :func:`draw` hands it to the gpu
module.
"""
from __future__ import annotations

import bpy

from ..operators import compat, preview
from ..operators.source import resolve_source
from ..rvr_addon.errors import RvrError

_handle = None

BOX_COLOR = (1.0, 0.8, 0.1, 0.9)
LOST_COLOR = (1.0, 0.3, 0.2, 0.6)
FOCUS_COLOR = (0.2, 1.0, 0.4, 1.0)
DRAG_COLOR = (1.0, 1.0, 1.0, 0.8)


def current_target(strip, clip_frame: int):
    """The target the focus is on at ``clip_frame``: the last one at or before it (or the first)."""
    items = sorted(strip.rvr.nfts, key=lambda n: n.frame)
    before = [n for n in items if n.frame <= clip_frame]
    return before[-1] if before else (items[0] if items else None)


def overlay_shapes(scene, strip) -> dict:
    """{"boxes": [(corners, color)], "focus": (x, y) | None, "picture_rect": (x0, y0, x1, y1) | None}
    in view coordinates, for the strip at the scene's current frame."""
    out = {"boxes": [], "focus": None, "picture_rect": None}
    size = preview.strip_clip_size(strip)
    if size is None:
        return out
    place = preview.placement(strip, *size)
    try:  # the frame mapping every operator uses (offsets, retiming); None off the strip
        clip_frame = resolve_source(scene, strip).scene_to_clip(scene.frame_current)
    except RvrError:
        return out
    (x0, y0), (x1, y1) = preview.clip_to_view(place, 0, size[1]), preview.clip_to_view(place, size[0], 0)
    out["picture_rect"] = (x0, y0, x1, y1)
    if not strip.rvr.show_targets or clip_frame is None:
        return out
    focus_on = current_target(strip, clip_frame)
    for nft in strip.rvr.nfts:
        entry = next((e for e in nft.track if e.frame == clip_frame), None)
        if entry is not None:
            box, ok = tuple(entry.box), entry.ok
        elif nft.frame == clip_frame:
            box, ok = tuple(nft.box), True
        else:
            continue
        out["boxes"].append((preview.box_corners(place, box), BOX_COLOR if ok else LOST_COLOR))
        if nft == focus_on:
            out["focus"] = preview.clip_to_view(place, box[0] + box[2] / 2, box[1] + box[3] / 2)
    return out


def _texture(picture):
    import gpu

    h, w = picture.shape[:2]
    buf = gpu.types.Buffer("FLOAT", w * h * 4, picture.ravel())
    return gpu.types.GPUTexture((w, h), format="RGBA16F", data=buf)


def draw() -> None:
    """The draw handler (POST_VIEW of the Sequencer preview)."""
    import gpu
    from gpu_extras.batch import batch_for_shader

    context = bpy.context
    scene = compat.sequencer_scene(context)
    strip = compat.active_strip(context)
    if scene is None or strip is None or not hasattr(strip, "rvr") or compat.strip_type(strip) not in ("MOVIE", "IMAGE"):
        return
    shapes = overlay_shapes(scene, strip)
    if strip.rvr.preview_mode != "OFF" and shapes["picture_rect"] is not None:
        picture = preview.preview_picture(scene, strip, strip.rvr.preview_mode)
        if picture is not None:
            from gpu_extras.presets import draw_texture_2d

            x0, y0, x1, y1 = shapes["picture_rect"]
            draw_texture_2d(_texture(picture), (x0, y0), x1 - x0, y1 - y0)
    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    gpu.state.blend_set("ALPHA")
    gpu.state.line_width_set(2.0)
    loops = [(c, col) for c, col in shapes["boxes"]]
    drag = preview.BoxDrag.active
    if drag is not None and drag.view_rect() is not None:
        loops.append((drag.view_rect(), DRAG_COLOR))
    for corners, color in loops:
        batch = batch_for_shader(shader, "LINE_LOOP", {"pos": corners})
        shader.uniform_float("color", color)
        batch.draw(shader)
    if shapes["focus"] is not None:
        fx, fy = shapes["focus"]
        r = max(abs(shapes["picture_rect"][2] - shapes["picture_rect"][0]) / 60.0, 2.0)
        cross = [(fx - r, fy), (fx + r, fy), (fx, fy - r), (fx, fy + r)]
        batch = batch_for_shader(shader, "LINES", {"pos": cross})
        shader.uniform_float("color", FOCUS_COLOR)
        batch.draw(shader)
    gpu.state.line_width_set(1.0)
    gpu.state.blend_set("NONE")


def register() -> None:
    global _handle
    if bpy.app.background or _handle is not None:
        return
    _handle = bpy.types.SpaceSequenceEditor.draw_handler_add(draw, (), "PREVIEW", "POST_VIEW")


def unregister() -> None:
    global _handle
    if _handle is not None:
        bpy.types.SpaceSequenceEditor.draw_handler_remove(_handle, "PREVIEW")
        _handle = None
