"""Input/output: clips (video or image sequence), EXR, per-frame maps, focus tracks, atomic writers."""
from __future__ import annotations

from ..lazy_exports import lazy_getattr

__all__ = [
    "ClipInfo", "FocusTrack", "ImageSequenceWriter", "MapSequence", "VideoWriter", "constant_track",
    "iter_frames", "load_track", "open_map_sequence", "probe_clip", "read_exr", "resolve_track", "write_exr",
]

_LAZY = {"read_exr": ".exr", "write_exr": ".exr", "MapSequence": ".maps", "open_map_sequence": ".maps",
         "FocusTrack": ".track", "constant_track": ".track", "load_track": ".track", "resolve_track": ".track",
         "ClipInfo": ".video", "iter_frames": ".video", "probe_clip": ".video", "ImageSequenceWriter": ".writer",
         "VideoWriter": ".writer"}
"""Exports imported on first use: importing a light submodule (``io.paths``, ``io.lock``) loads no NumPy or
OpenEXR, so ``rvr --help`` stays fast."""

__getattr__ = lazy_getattr(__name__, _LAZY, globals())
