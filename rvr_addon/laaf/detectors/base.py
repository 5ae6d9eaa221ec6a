"""The detector interface (STYLE.md: PySceneDetect's SceneDetector, adapted to focus).

A detector turns frames into a per-frame heat map at the analysis resolution: float32 in
[0, 1], where >= 0.5 means "this detector says: focus here" (the combination intersects these
binary regions). The driver calls ``process(t, frame)`` for t = 0, 1, 2, ... in order, then
``output(t)`` once frames up to ``t + lookahead_frames`` have been processed (or after
``flush()`` at the end of the clip). A detector keeps only the state it needs.

Detectors with ``measures = True`` split ``process`` in two, so that the expensive part can
run on chunks of a clip in other processes (``laaf.analysis``, ``rvr batch``):
``measure(frame, prev, faces)`` is the per-frame work (face detection, saliency, optical
flow, mouth and block motion), a pure function of this frame, the previous one and the face
boxes of the last face detection; ``ingest(t, frame, measured)`` is the cheap part that
carries state from frame to frame (face tracks, decaying motion memory, speech windows) and
runs in frame order in one process. ``process(t, frame)`` is ``ingest(measure(...))``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..nft import Box


@dataclass
class AnalysisFrame:
    """One frame as the detectors see it.

    t: 0-based clip index. rgb: (h, w, 3) uint8 sRGB at the analysis size. gray: (h, w) uint8.
    disparity: (h, w) float32 in DESIGN units of the *native* width (values not rescaled).
    scale: analysis size / native size (boxes in native px = analysis px / scale).
    fps: frames per second of the clip.
    native: the decoded (H, W, 3) uint8 RGB frame at its native size, present only while the
    frame is measured (``analysis.FrameAnalyser`` drops it after: frames are buffered at the
    analysis size); the face mesh reads mouths on it. None: use ``rgb``.
    """

    t: int
    rgb: np.ndarray
    gray: np.ndarray
    disparity: np.ndarray | None
    scale: float
    fps: float
    native: np.ndarray | None = None


@dataclass
class DetectorOutput:
    """heat: (h, w) float32 0..1 (None: nothing found on this frame). boxes: (box, score,
    label) in analysis px, e.g. faces with their track id. available: False when the detector
    cannot work on this clip at all (e.g. speech without an audio track)."""

    heat: np.ndarray | None
    boxes: list[tuple[Box, float, str | None]] = field(default_factory=list)
    available: bool = True


class FocusDetector:
    """Base class: a named detector with a look-ahead and metrics (see the module docstring)."""

    name: str = "detector"
    lookahead_frames: int = 0
    available: bool = True
    unavailable_reason: str = ""
    measures: bool = False  # True: measure() + ingest() (module docstring); False: process() only

    def measure(self, frame: AnalysisFrame, prev: AnalysisFrame | None, faces: list[Box]) -> object:
        """The per-frame work on ``frame``: a pure function of it, the previous frame of the run
        (None at its first frame) and ``faces`` (the boxes, analysis px, largest first, of the
        last face detection at or before this frame). Only when ``measures``."""
        raise NotImplementedError(f"detector {self.name} has no separate per-frame measurement")

    def ingest(self, t: int, frame: AnalysisFrame, measured: object) -> None:
        """Take frame t and what :meth:`measure` returned for it (frames in order). Detectors
        without ``measures`` do all their work here."""
        self.process(t, frame)

    def add_seconds(self, seconds: float) -> None:
        """Count time spent measuring this detector's frames (possibly in another process)."""
        self._seconds = getattr(self, "_seconds", 0.0) + seconds

    def process(self, t: int, frame: AnalysisFrame) -> None:  # pragma: no cover - interface
        """Ingest frame t (frames arrive in order)."""
        raise NotImplementedError

    def output(self, t: int) -> DetectorOutput:  # pragma: no cover - interface
        """The decision for frame t (valid once t + lookahead_frames was processed or flushed)."""
        raise NotImplementedError

    def flush(self) -> None:
        """End of the clip: the remaining frames may be decided with what is known."""

    def cut(self, t: int) -> None:
        """Frame t starts a new shot (called before frame t is ingested): forget what must not
        carry over a cut (tracks, held boxes). Outputs of earlier frames stay valid."""

    def metrics(self) -> dict:
        """Counts and timings for the report (names end in their unit)."""
        return {}


def boxes_heat(shape: tuple[int, int], boxes: list[tuple[Box, float, str | None]]) -> np.ndarray | None:
    """A heat map that is each box's score inside it (max over boxes), 0 elsewhere."""
    if not boxes:
        return None
    heat = np.zeros(shape, np.float32)
    h, w = shape
    for (x, y, bw, bh), score, _ in boxes:
        x0, y0 = int(max(round(x), 0)), int(max(round(y), 0))
        x1, y1 = int(min(round(x + bw), w)), int(min(round(y + bh), h))
        if x1 > x0 and y1 > y0:
            np.maximum(heat[y0:y1, x0:x1], float(score), out=heat[y0:y1, x0:x1])
    return heat
