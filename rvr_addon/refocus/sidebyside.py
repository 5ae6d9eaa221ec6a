"""A before | after video: the clip and its refocused render side by side, labelled, with the
clip's audio."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.video import iter_frames, probe_clip
from ..io.writer import VideoWriter
from .videojob import VideoWriteJob

GAP_PX = 4
"""Width of the dark line between the two halves (px)."""


def label(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` (H, W, 3) uint8 RGB with ``text`` drawn in its top-left corner (white on a dark box)."""
    import cv2

    out = np.ascontiguousarray(image).copy()
    h = out.shape[0]
    scale = max(0.35, h / 720)
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, int(scale * 2)))
    pad = max(2, int(6 * scale))
    cv2.rectangle(out, (0, 0), (tw + 2 * pad, th + base + 2 * pad), (0, 0, 0), -1)
    cv2.putText(out, text, (pad, pad + th), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255),
                max(1, int(scale * 2)), cv2.LINE_AA)
    return out


def side_by_side(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(H, 2W + GAP_PX, 3) uint8: ``before`` | ``after`` (after resized to before's size if needed)."""
    import cv2

    if after.shape[:2] != before.shape[:2]:
        after = cv2.resize(after, (before.shape[1], before.shape[0]), interpolation=cv2.INTER_AREA)
    gap = np.full((before.shape[0], GAP_PX, 3), 16, np.uint8)
    return np.concatenate([label(before, "before"), gap, label(after, "after (refocused)")], axis=1)


class SideBySideJob(VideoWriteJob):
    """Write ``output`` from ``before`` (the clip) and ``after`` (its render), frame by frame."""

    def __init__(self, before: Path, after: Path, output: Path) -> None:
        self.before, self.after, self.output = Path(before), Path(after), Path(output)
        self.clip = probe_clip(self.before)
        rendered = probe_clip(self.after)
        total = min(self.clip.frame_count, rendered.frame_count)
        if total <= 0:
            raise InputError(f"'{self.after}' holds no frame to put beside '{self.before}'")
        super().__init__(total, f"before | after video {self.output.name}")

    def open(self):
        """Pairs of (clip frame, rendered frame) and the writer (the clip's audio)."""
        size = (2 * self.clip.width + GAP_PX, self.clip.height)
        writer = VideoWriter(self.output, fps=self.clip.fps, size=size,
                             audio_from=self.before if self.clip.has_audio else None)
        return zip(iter_frames(self.before, stop=self.total), iter_frames(self.after, stop=self.total)), writer

    def frame(self, item: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """The pair side by side, labelled."""
        return side_by_side(*item)
