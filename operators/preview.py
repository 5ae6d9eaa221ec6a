"""What the Sequencer preview shows over a strip: geometry, the box being dragged, and the
refocused (or disparity) picture of the current frame, computed from the cache.

Geometry (bpy-free, :func:`clip_to_view` / :func:`view_to_clip`): the preview's view space
is the scene frame in render pixels, origin at its centre, y up. A strip's picture (its
clip, ``clip_w`` x ``clip_h`` px, origin top-left, y down) is centred there, scaled by
``transform.scale_x/y`` (Blender bakes the fit method into the scale when a strip is added),
rotated by ``transform.rotation`` around its ``origin`` and moved by ``offset_x/y``. Crop and
flips are not modelled (boxes drawn over a cropped or flipped strip are off by them).

:func:`preview_picture` renders the current frame at preview resolution (at most
``PREVIEW_WIDTH`` px wide) with the engine's renderer, from the strip's cache and the
*evaluated* focus and aperture (so scrubbing shows the F-curves), or colour-maps its
disparity. Results are memoised per (cache, frame, focus, aperture, mode).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

PREVIEW_WIDTH = 480


@dataclass(frozen=True)
class Placement:
    """How a strip's picture sits in the preview (see the module docstring)."""

    clip_w: float
    clip_h: float
    scale_x: float = 1.0
    scale_y: float = 1.0
    offset_x: float = 0.0
    offset_y: float = 0.0
    rotation: float = 0.0
    origin: tuple[float, float] = (0.5, 0.5)


def clip_to_view(p: Placement, x: float, y: float) -> tuple[float, float]:
    """Clip pixel (x right, y down, origin top-left) -> preview view coordinates."""
    ox, oy = p.origin[0] * p.clip_w, (1 - p.origin[1]) * p.clip_h  # pivot in clip px (y down)
    u, v = (x - ox) * p.scale_x, (oy - y) * p.scale_y
    c, s = math.cos(p.rotation), math.sin(p.rotation)
    u, v = c * u - s * v, s * u + c * v
    # the pivot sits where it is in the unrotated, centred picture
    px = (ox - p.clip_w / 2) * p.scale_x + p.offset_x
    py = (p.clip_h / 2 - oy) * p.scale_y + p.offset_y
    return u + px, v + py


def view_to_clip(p: Placement, vx: float, vy: float) -> tuple[float, float]:
    """Inverse of :func:`clip_to_view`."""
    ox, oy = p.origin[0] * p.clip_w, (1 - p.origin[1]) * p.clip_h
    px = (ox - p.clip_w / 2) * p.scale_x + p.offset_x
    py = (p.clip_h / 2 - oy) * p.scale_y + p.offset_y
    u, v = vx - px, vy - py
    c, s = math.cos(-p.rotation), math.sin(-p.rotation)
    u, v = c * u - s * v, s * u + c * v
    return ox + u / p.scale_x, oy - v / p.scale_y


def box_corners(p: Placement, box) -> list[tuple[float, float]]:
    """The four corners of a clip-px box (x, y, w, h) in view coordinates (a closed loop's points)."""
    x, y, w, h = box
    return [clip_to_view(p, cx, cy) for cx, cy in ((x, y), (x + w, y), (x + w, y + h), (x, y + h))]


def placement(strip, clip_w: int, clip_h: int) -> Placement:
    """The Placement of a strip's picture from its transform."""
    t = strip.transform
    return Placement(float(clip_w), float(clip_h), t.scale_x or 1e-6, t.scale_y or 1e-6, t.offset_x, t.offset_y,
                     t.rotation, tuple(t.origin) if hasattr(t, "origin") else (0.5, 0.5))


def strip_clip_size(strip) -> tuple[int, int] | None:
    """(w, h) Blender read for the strip's first element (0 until loaded), or None."""
    elem = strip.elements[0] if len(getattr(strip, "elements", ())) else None
    if elem is None or not elem.orig_width:
        return None
    return int(elem.orig_width), int(elem.orig_height)


def preview_region(context):
    """The Sequencer preview region under the context (None in the timeline or headless)."""
    area = getattr(context, "area", None)
    if area is None or area.type != "SEQUENCE_EDITOR":
        return None
    space = area.spaces.active
    if getattr(space, "view_type", "") not in ("PREVIEW", "SEQUENCER_PREVIEW"):
        return None
    region = context.region
    if region is not None and region.type == "PREVIEW":
        return region
    return next((r for r in area.regions if r.type == "PREVIEW"), None)


# ----------------------------------------------------------------------------- the box being dragged


class BoxDrag:
    """Mouse state of Add Focus Target's drag (region px -> clip px); the overlay draws it."""

    active: "BoxDrag | None" = None

    def __init__(self, context) -> None:
        from . import compat

        self.region = preview_region(context)
        strip = compat.active_strip(context)
        size = strip_clip_size(strip) or (1, 1)
        self.placement = placement(strip, *size)
        self.size = size
        self.start = self.current = None
        BoxDrag.active = self

    @property
    def started(self) -> bool:
        return self.start is not None

    def _view(self, mx: float, my: float) -> tuple[float, float]:
        return self.region.view2d.region_to_view(mx, my)

    def press(self, mx: float, my: float) -> None:
        self.start = self.current = self._view(mx, my)

    def move(self, mx: float, my: float) -> None:
        if self.started:
            self.current = self._view(mx, my)

    def release(self, mx: float, my: float):
        """((x, y) focus point, (w, h) box size) in clip px (w = h = 0 for a click), or None
        when the point is outside the picture."""
        self.current = self._view(mx, my)
        a = view_to_clip(self.placement, *self.start)
        b = view_to_clip(self.placement, *self.current)
        self.end()
        w, h = abs(b[0] - a[0]), abs(b[1] - a[1])
        cx, cy = (a[0] + b[0]) / 2, (a[1] + b[1]) / 2
        if not (0 <= cx < self.size[0] and 0 <= cy < self.size[1]):
            return None
        if w < 3 or h < 3:  # a click: a point with the default box
            return (b[0], b[1]), (0.0, 0.0)
        return (cx, cy), (w, h)

    def end(self) -> None:
        if BoxDrag.active is self:
            BoxDrag.active = None

    def view_rect(self):
        """The dragged rectangle's corners in view coordinates (or None)."""
        if not self.started:
            return None
        (x0, y0), (x1, y1) = self.start, self.current
        return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


# ----------------------------------------------------------------------------- refocused picture


def _colormap(d: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(d, [1, 99]) if d.size else (0.0, 1.0)
    t = np.clip((d - lo) / max(hi - lo, 1e-6), 0, 1)[..., None]
    near, far = np.array([1.0, 0.85, 0.2], np.float32), np.array([0.1, 0.2, 0.7], np.float32)
    return (1 - t) * near + t * far  # near = warm, far = cool


@lru_cache(maxsize=16)
def _picture(video: str, fps: float | None, cache: str, clip_frame: int, focus: float, aperture: float, mode: str,
             width: int, shape: tuple) -> np.ndarray:
    import cv2

    from ..rvr_addon.color import linear_to_srgb, srgb_to_linear, to_float01
    from ..rvr_addon.io.maps import open_map_sequence
    from ..rvr_addon.io.video import iter_frames
    from ..rvr_addon.render.aperture import ApertureSpec
    from ..rvr_addon.render.fast import FastRenderer
    from ..rvr_addon.render.model import hdr_radiance

    frames = iter_frames(Path(video), start=clip_frame, stop=clip_frame + 1)
    try:
        rgb = next(frames)
    finally:
        frames.close()
    h, w = rgb.shape[:2]
    scale = min(1.0, width / w)
    size = (max(int(round(w * scale)), 1), max(int(round(h * scale)), 1))
    depth = open_map_sequence(cache, kind="disparity").get(clip_frame, size=(w, h))
    if mode == "DISPARITY":
        out = _colormap(cv2.resize(depth, size, interpolation=cv2.INTER_AREA))
    else:
        exponent = open_map_sequence(cache, kind="hdr").get(clip_frame, size=(w, h))
        radiance = hdr_radiance(srgb_to_linear(to_float01(rgb)), exponent)
        radiance = cv2.resize(radiance, size, interpolation=cv2.INTER_AREA)
        d = cv2.resize(depth, size, interpolation=cv2.INTER_LINEAR) * scale
        spec = ApertureSpec(shape=shape[0], blades=shape[1], rotation_deg=shape[2], squeeze=shape[3])
        linear = FastRenderer(spec=spec).render_linear(radiance, d, focus * scale, aperture)
        out = linear_to_srgb(np.clip(linear, 0, None))
    rgba = np.ones((size[1], size[0], 4), np.float32)
    rgba[..., :3] = np.clip(out, 0, 1)
    return np.ascontiguousarray(rgba[::-1])  # bottom-up rows, as GPU textures are


def preview_picture(scene, strip, mode: str, width: int = PREVIEW_WIDTH) -> np.ndarray | None:
    """RGBA float32 (h, w, 4), rows bottom-up, of the strip at the current frame: refocused
    ('REFOCUS') or its disparity ('DISPARITY'); None when the frame is not shown or there is
    no cache (the overlay then draws nothing)."""
    from .source import analysed_cache, resolve_source
    from ..rvr_addon.errors import RvrError

    cache = analysed_cache(strip)
    if cache is None or mode == "OFF":
        return None
    try:
        source = resolve_source(scene, strip)
    except RvrError:
        return None
    clip_frame = source.scene_to_clip(scene.frame_current)
    if clip_frame is None:
        return None
    rvr = strip.rvr
    shape = (rvr.aperture_shape.lower(), int(rvr.blades), math.degrees(rvr.rotation), float(rvr.squeeze))
    try:
        return _picture(str(source.path), source.fps, str(cache), clip_frame, round(float(rvr.focus_disparity), 3),
                        round(max(float(rvr.aperture), 0.0), 3), mode, int(width), shape)
    except RvrError:
        return None
