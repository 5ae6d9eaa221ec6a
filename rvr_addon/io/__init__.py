"""Input/output: clips (video or image sequence), EXR, per-frame maps, focus tracks, atomic writers."""
from .exr import read_exr, write_exr
from .maps import MapSequence, open_map_sequence
from .track import FocusTrack, constant_track, load_track, resolve_track
from .video import ClipInfo, iter_frames, probe_clip
from .writer import ImageSequenceWriter, VideoWriter

__all__ = [
    "ClipInfo", "FocusTrack", "ImageSequenceWriter", "MapSequence", "VideoWriter", "constant_track",
    "iter_frames", "load_track", "open_map_sequence", "probe_clip", "read_exr", "resolve_track", "write_exr",
]
