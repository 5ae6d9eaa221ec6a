"""What a frame will cost to render, said up front (a 4K frame with a large aperture used to run
for many minutes without a word).

The fast path (``fast.FastRenderer``) plans one layer per ``max_step`` px of blur radius and
blurs and composites each layer on rectangles around its active tiles grown by the blur's
footprint; ``FastRenderer.work_px`` sums the modelled cost of those rectangles (in px-equivalents
of ``fast.WORK_NS_PER_PX``), cheap to count on the first frame (0.03-0.09 s at 1080p). Measured on
the project's 2-core machine under a load of about 10 (other jobs), 360p and 1080p, radii 8 to 32
px, the bench scene, a real estimated depth map and a busy synthetic one: 1.1-1.6e-7 s per unit of
that work (:data:`S_PER_WORK_PX`; an idle machine is faster). Without a frame to count on, every
pixel in every layer is the worst case: ``pixels x layers`` with
``layers = 2 * max_radius / max_step + 1``.
"""
from __future__ import annotations

import math

S_PER_WORK_PX = 1.2e-7
"""Seconds per pixel of layer work (``FastRenderer.work_px``) of the fast path (module docstring)."""

WARN_S_PER_FRAME = 5.0
"""A render whose frames may cost more than this many seconds each gets a warning."""


def layer_count(max_radius_px: float, max_step: float = 1.0) -> int:
    """Layers the fast path plans for blur radii up to ``max_radius_px`` (both sides of focus)."""
    return 2 * int(math.ceil(max(max_radius_px, 0.0) / max(max_step, 1e-6))) + 1


def frame_cost_s(width: int, height: int, max_radius_px: float, max_step: float = 1.0,
                 work_px: float | None = None) -> float:
    """Seconds one (width x height) frame may take with blur radii up to ``max_radius_px``: from
    its counted ``work_px`` when given, else the worst case (every pixel in every layer)."""
    if work_px is None:
        work_px = width * height * (layer_count(max_radius_px, max_step) if max_radius_px > 0.5 else 1)
    return S_PER_WORK_PX * float(work_px)


def cost_warning(width: int, height: int, max_radius_px: float, frames: int, max_step: float = 1.0,
                 scale: float = 1.0, work_px: float | None = None, what: str = "the render") -> str | None:
    """The warning to log when a frame may cost more than :data:`WARN_S_PER_FRAME`, else None.

    width, height: rendered frame size (px, after ``scale``). max_radius_px: largest blur radius
    in rendered px. frames: how many frames the render has. work_px: the first frame's counted
    work (``FastRenderer.work_px``; None: the worst case). The text says what a frame and the
    whole render may cost and how to make it cheaper: ``--scale 0.5`` (a quarter of the pixels
    and half the radii: 4-8x less work) or a smaller ``--aperture`` (radii in proportion)."""
    cost = frame_cost_s(width, height, max_radius_px, max_step, work_px)
    if cost <= WARN_S_PER_FRAME:
        return None
    now = f" (it is {scale:g} now)" if scale != 1.0 else ""
    return (f"{what}: {width}x{height} px with blur radii up to {max_radius_px:.0f} px "
            f"({layer_count(max_radius_px, max_step)} layers) will take about {cost:.0f} s a frame, "
            f"{_duration(cost * frames)} for {frames} frames. To make it faster, render a proxy with --scale 0.5{now} "
            f"(4-8x faster) or a smaller --aperture (half the aperture: about 2x faster)")


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
