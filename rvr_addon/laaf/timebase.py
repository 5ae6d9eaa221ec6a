"""LAAF's durations at any frame rate: a count of frames at the rate they were set on.

The focus puller's defaults (DESIGN.md: a pull of 10 frames landing 5 frames early) and the step
detector's windows were chosen on clips at 24-25 fps. Phones record 30 or 60 fps, where the same
frame counts are shorter in time: a 10-frame pull is 0.4 s at 25 fps but 0.17 s at 60 fps, a snap
no focus puller makes. So such a duration is kept as frames at :data:`REFERENCE_FPS` and turned into
frames of the clip by :func:`frames_at`; at 24-25 fps every count is the one it always was.
"""
from __future__ import annotations

import math

REFERENCE_FPS = 25.0
"""Frame rate (frames/s) at which LAAF's frame-count defaults hold as written."""


def frames_at(reference_frames: float, fps: float | None, minimum: int = 1) -> int:
    """``reference_frames`` (frames at :data:`REFERENCE_FPS`) as frames at ``fps`` frames/s:
    the same seconds, rounded, at least ``minimum``. fps None, 0 or not finite: the count as
    given (rounded)."""
    scale = float(fps) / REFERENCE_FPS if fps and math.isfinite(fps) and fps > 0 else 1.0
    return max(int(minimum), int(round(float(reference_frames) * scale)))


def reference_frames_per_frame(fps: float | None) -> float:
    """How many frames at :data:`REFERENCE_FPS` one frame at ``fps`` lasts (1 for None, 0 or not
    finite): scales a per-frame rate (px a frame, a decay a frame) set at the reference rate."""
    return REFERENCE_FPS / float(fps) if fps and math.isfinite(fps) and fps > 0 else 1.0
