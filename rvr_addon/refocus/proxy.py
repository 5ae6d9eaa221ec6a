"""The working copy of a clip: resized so its long side is at most ``max_size`` px and/or cut
to a frame range, written once as a near-lossless H.264 MP4 (the source audio kept, from the
range's start), so every later stage reads one small clip instead of resizing on each pass. A
variable-frame-rate video is read, like any clip, on its constant-rate timeline
(``io.video.video_timeline``), so its copy is at that constant rate with its sound in sync."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.video import ClipInfo, iter_frames, probe_clip
from ..io.writer import VideoWriter
from .videojob import VideoWriteJob

PROXY_CRF = 12
"""x264 quality of the working copy (18 is visually lossless; 12 leaves no visible loss for the
depth, flow and detectors that read it)."""


def proxy_size(width: int, height: int, max_size: int | None) -> tuple[int, int]:
    """(width, height) px with the long side at most ``max_size`` (None or 0: unchanged), aspect
    kept, both even (H.264's 4:2:0 needs it) and >= 2."""
    if not max_size or max(width, height) <= max_size:
        return width, height
    s = max_size / max(width, height)
    return max(2, int(round(width * s / 2)) * 2), max(2, int(round(height * s / 2)) * 2)


def needs_proxy(clip: ClipInfo, max_size: int | None, start: int, stop: int | None) -> bool:
    """True when the clip must be resized or cut before the pipeline reads it."""
    whole = start == 0 and (stop is None or stop >= clip.frame_count)
    return proxy_size(clip.width, clip.height, max_size) != (clip.width, clip.height) or not whole


class ProxyJob(VideoWriteJob):
    """Write the working copy frame by frame (``step``); the file appears only when complete."""

    what = "copy"

    def __init__(self, source: Path, output: Path, max_size: int | None, start: int = 0, stop: int | None = None,
                 fps: float | None = None, clip: ClipInfo | None = None) -> None:
        """clip: the source's ClipInfo when the caller has probed it already (else probed here)."""
        self.source, self.output = Path(source), Path(output)
        self.clip = clip if clip is not None else probe_clip(self.source, fps=fps)
        self.stop = self.clip.frame_count if stop is None else min(stop, self.clip.frame_count)
        if start < 0 or start >= self.stop:
            raise InputError(f"--start {start} / --stop {stop}: the range is empty for '{self.source}' "
                             f"({self.clip.frame_count} frames)")
        self.start = start
        self.size = proxy_size(self.clip.width, self.clip.height, max_size)
        super().__init__(self.stop - start, f"working copy of {self.source.name} at {self.size[0]}x{self.size[1]}")

    def open(self):
        """The source's frames of the range and the writer of the copy (the audio from the range's start)."""
        audio = self.source if self.clip.has_audio else None
        writer = VideoWriter(self.output, fps=self.clip.fps, size=self.size, audio_from=audio, crf=PROXY_CRF,
                             audio_start=self.start / self.clip.fps)
        return iter_frames(self.source, start=self.start, stop=self.stop), writer

    def frame(self, item: np.ndarray) -> np.ndarray:
        """The frame resized (area filter) to the copy's size."""
        import cv2

        if (item.shape[1], item.shape[0]) != self.size:
            item = cv2.resize(item, self.size, interpolation=cv2.INTER_AREA)
        return item

    def ended_early(self) -> None:
        """A copy shorter than the range is refused."""
        raise InputError(f"'{self.source}' ended after {self.done} of {self.total} frames")
