"""A before | after video: the clip and its refocused render side by side, labelled, with the
clip's audio."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.video import iter_frames, probe_clip
from ..io.writer import StillImageWriter, VideoWriter
from .videojob import VideoWriteJob

GAP_PX = 4
"""Width of the dark line between the two halves (px)."""


def label(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` (H, W, 3) uint8 RGB with ``text`` drawn in its top-left corner (white on a dark box);
    text wider than the image (a portrait clip's narrow column) is shrunk, then wrapped at spaces."""
    import cv2

    out = np.ascontiguousarray(image).copy()
    h, w = out.shape[:2]
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = max(0.35, h / 720)

    def size(s: str, sc: float) -> tuple[int, int, int]:
        (tw, th), base = cv2.getTextSize(s, font, sc, max(1, int(sc * 2)))
        return tw, th, base

    pad = max(2, int(6 * scale))
    room = max(1, w - 2 * pad)
    fit = room / max(1, size(text, 1.0)[0])
    scale = max(0.3, min(scale, fit)) if fit < scale else scale
    lines: list[str] = []
    for word in text.split(" "):
        if lines and size(lines[-1] + " " + word, scale)[0] <= room:
            lines[-1] += " " + word
        else:
            lines.append(word)
    thick = max(1, int(scale * 2))
    _tw, th, base = size(text, scale)
    step = th + base + pad
    width = max(size(s, scale)[0] for s in lines)
    cv2.rectangle(out, (0, 0), (min(w, width + 2 * pad), step * len(lines) + pad), (0, 0, 0), -1)
    for i, s in enumerate(lines):
        cv2.putText(out, s, (pad, pad + th + i * step), font, scale, (255, 255, 255), thick, cv2.LINE_AA)
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
        from ..pipeline import is_still_output

        size = (2 * self.clip.width + GAP_PX, self.clip.height)
        if is_still_output(self.output):  # a photo's before | after: one picture
            if self.total != 1:
                raise InputError(f"--side-by-side {self.output}: a picture holds one frame, the clip has "
                                 f"{self.total}; give a video name (.mp4)")
            writer = StillImageWriter(self.output)
        else:
            writer = VideoWriter(self.output, fps=self.clip.fps, size=size,
                                 audio_from=self.before if self.clip.has_audio else None)
        return zip(iter_frames(self.before, stop=self.total), iter_frames(self.after, stop=self.total)), writer

    def frame(self, item: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """The pair side by side, labelled."""
        return side_by_side(*item)
