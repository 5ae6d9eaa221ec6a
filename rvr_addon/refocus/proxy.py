"""The working copy of a clip: resized so its long side is at most ``max_size`` px and/or cut
to a frame range, written once as a near-lossless H.264 MP4 (the source audio kept, from the
range's start), so every later stage reads one small clip instead of resizing on each pass."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.video import ClipInfo, iter_frames, probe_clip
from ..io.writer import VideoWriter

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


class ProxyJob:
    """Write the working copy frame by frame (``step``); the file appears only when complete."""

    def __init__(self, source: Path, output: Path, max_size: int | None, start: int = 0, stop: int | None = None,
                 fps: float | None = None) -> None:
        self.source, self.output = Path(source), Path(output)
        self.clip = probe_clip(self.source, fps=fps)
        self.stop = self.clip.frame_count if stop is None else min(stop, self.clip.frame_count)
        if start < 0 or start >= self.stop:
            raise InputError(f"--start {start} / --stop {stop}: the range is empty for '{self.source}' "
                             f"({self.clip.frame_count} frames)")
        self.start = start
        self.total = self.stop - start
        self.size = proxy_size(self.clip.width, self.clip.height, max_size)
        self.done = 0
        self._frames = None
        self._writer: VideoWriter | None = None
        self._finished = False
        self.text = f"working copy of {self.source.name} at {self.size[0]}x{self.size[1]}"

    @property
    def progress(self) -> float:
        """Fraction of frames written, 0..1."""
        return self.done / self.total if self.total else 1.0

    def step(self) -> bool:
        """Resize and write the next frame; False once the copy is complete."""
        import cv2

        if self._finished:
            return False
        try:
            if self._frames is None:
                self._frames = iter_frames(self.source, start=self.start, stop=self.stop)
                audio = self.source if self.clip.has_audio else None
                self._writer = VideoWriter(self.output, fps=self.clip.fps, size=self.size, audio_from=audio,
                                           crf=PROXY_CRF, audio_start=self.start / self.clip.fps)
            frame = next(self._frames, None)
            if frame is None:
                raise InputError(f"'{self.source}' ended after {self.done} of {self.total} frames")
            if (frame.shape[1], frame.shape[0]) != self.size:
                frame = cv2.resize(frame, self.size, interpolation=cv2.INTER_AREA)
            self._writer.write(np.ascontiguousarray(frame))
            self.done += 1
            if self.done == self.total:
                self._writer.close()
                self._writer = None
                self._finished = True
                return False
            return True
        except BaseException:
            self.cancel()
            raise

    def cancel(self) -> None:
        """Stop; no partial file is left at the output path. Idempotent; after the end it changes
        nothing."""
        if self._finished:
            return
        if self._writer is not None:
            self._writer.abort()
            self._writer = None
        self._finished = True
        self.text = f"cancelled after {self.done} of {self.total} frames; no copy written"
