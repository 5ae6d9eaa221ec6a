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


def _text_size(text: str, scale: float) -> tuple[int, int, int]:
    """(width, height, baseline) px of ``text`` in the captions' font at ``scale``."""
    import cv2

    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, int(scale * 2)))
    return tw, th, base


def _height_scale_and_pad(height: int) -> tuple[float, int]:
    """The captions' font scale by a picture's height, and their padding (px)."""
    scale = max(0.35, height / 720)
    return scale, max(2, int(6 * scale))


def label_scale(text: str, width: int, height: int) -> float:
    """The font scale :func:`label` uses for ``text`` on a ``width`` x ``height`` picture: by the
    picture's height, shrunk (to 0.3 at the least) where the text would not fit its width."""
    scale, pad = _height_scale_and_pad(height)
    room = max(1, width - 2 * pad)
    fit = room / max(1, _text_size(text, 1.0)[0])
    return max(0.3, fit) if fit < scale else scale


def label(image: np.ndarray, text: str, scale: float | None = None) -> np.ndarray:
    """``image`` (H, W, 3) uint8 RGB with ``text`` drawn in its top-left corner (white on a dark box);
    text wider than the image (a portrait clip's narrow column) is shrunk, then wrapped at spaces.
    ``scale``: the font scale (None: :func:`label_scale`; give the smallest of a row's captions to
    draw them alike)."""
    import cv2

    out = np.ascontiguousarray(image).copy()
    h, w = out.shape[:2]
    if scale is None:
        scale = label_scale(text, w, h)
    pad = _height_scale_and_pad(h)[1]
    room = max(1, w - 2 * pad)
    lines: list[str] = []
    for word in text.split(" "):
        if lines and _text_size(lines[-1] + " " + word, scale)[0] <= room:
            lines[-1] += " " + word
        else:
            lines.append(word)
    thick = max(1, int(scale * 2))
    _tw, th, base = _text_size(text, scale)
    step = th + base + pad
    width = max(_text_size(s, scale)[0] for s in lines)
    cv2.rectangle(out, (0, 0), (min(w, width + 2 * pad), step * len(lines) + pad), (0, 0, 0), -1)
    for i, s in enumerate(lines):
        cv2.putText(out, s, (pad, pad + th + i * step), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick,
                    cv2.LINE_AA)
    return out


def side_by_side(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(H, 2W + GAP_PX, 3) uint8: ``before`` | ``after`` (after resized to before's size if needed)."""
    import cv2

    if after.shape[:2] != before.shape[:2]:
        after = cv2.resize(after, (before.shape[1], before.shape[0]), interpolation=cv2.INTER_AREA)
    gap = np.full((before.shape[0], GAP_PX, 3), 16, np.uint8)
    texts = ("before", "after (refocused)")
    scale = min(label_scale(t, before.shape[1], before.shape[0]) for t in texts)
    return np.concatenate([label(before, texts[0], scale), gap, label(after, texts[1], scale)], axis=1)


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
        from ..pipeline import is_still_output, refuse_picture_of_many

        size = (2 * self.clip.width + GAP_PX, self.clip.height)
        if is_still_output(self.output):  # a photo's before | after: one picture
            refuse_picture_of_many(self.output, self.total, "--side-by-side")
            writer = StillImageWriter(self.output)
        else:
            writer = VideoWriter(self.output, fps=self.clip.fps, size=size,
                                 audio_from=self.before if self.clip.has_audio else None)
        return zip(iter_frames(self.before, stop=self.total), iter_frames(self.after, stop=self.total)), writer

    def frame(self, item: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """The pair side by side, labelled."""
        return side_by_side(*item)
