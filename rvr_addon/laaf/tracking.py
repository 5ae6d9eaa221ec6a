"""Follow a focus subject from its NFT with a KCF tracker (paper section 5.1, OpenCV contrib).

KCF alone drifts silently when the subject is occluded or leaves, and fails outright on fast
motion. :class:`SubjectTracker` wraps it:

- every frame the tracked patch is compared (normalised cross-correlation, 24x24 grey) with
  the subject's appearance at the NFT and at its last confident frame; a KCF box that no
  longer looks like the subject counts as a loss (no silent drift);
- on a loss it searches around the last good box (template matching) and re-initialises KCF
  there when the match is good (status ``reinit``); otherwise the box is held and the status is
  ``lost``, or ``left`` when the last good box touched the frame border (the subject walked out);
- every loss, re-initialisation and exit is recorded in ``events`` (frame, status, score).

Frames are (H, W, 3) uint8 RGB or (H, W) uint8 grey at the analysis resolution; boxes are
(x, y, w, h) px of those frames. Tracking backwards is the same tracker fed frames in reverse.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .nft import Box, clip_box

log = logging.getLogger(__name__)

STATUSES = ("init", "tracked", "reinit", "lost", "left")
_TEMPLATE = 24


@dataclass(frozen=True)
class TrackState:
    """Where the subject is on one frame. status: one of STATUSES; score: appearance NCC -1..1."""

    frame: int
    box: Box
    status: str
    score: float

    @property
    def ok(self) -> bool:
        """True when the box is on the subject (init, tracked, reinit)."""
        return self.status in ("init", "tracked", "reinit")


def _gray(frame: np.ndarray) -> np.ndarray:
    import cv2

    return frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)


def _color(frame: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB) if frame.ndim == 2 else frame


def _patch(gray: np.ndarray, box: Box) -> np.ndarray | None:
    import cv2

    h, w = gray.shape
    x0, y0 = int(round(max(box[0], 0))), int(round(max(box[1], 0)))
    x1, y1 = int(round(min(box[0] + box[2], w))), int(round(min(box[1] + box[3], h)))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    p = cv2.resize(gray[y0:y1, x0:x1], (_TEMPLATE, _TEMPLATE), interpolation=cv2.INTER_AREA).astype(np.float32)
    p -= p.mean()
    norm = float(np.sqrt((p * p).sum()))
    return p / norm if norm > 1e-6 else None


def _ncc(a: np.ndarray | None, b: np.ndarray | None) -> float:
    if a is None or b is None:
        return -1.0
    return float((a * b).sum())


def create_kcf():
    """A KCF tracker from opencv-contrib (``cv2.TrackerKCF_create`` or ``cv2.legacy``)."""
    import cv2

    if hasattr(cv2, "TrackerKCF_create"):
        return cv2.TrackerKCF_create()
    if hasattr(cv2, "legacy") and hasattr(cv2.legacy, "TrackerKCF_create"):
        return cv2.legacy.TrackerKCF_create()
    raise RuntimeError("OpenCV has no KCF tracker: install opencv-contrib-python-headless (requirements.txt)")


def _int_box(box: Box) -> tuple[int, int, int, int]:
    return (int(round(box[0])), int(round(box[1])), max(int(round(box[2])), 2), max(int(round(box[3])), 2))


@dataclass
class SubjectTracker:
    """KCF with appearance checks, re-initialisation and loss reporting (module docstring).

    reinit_score: template-match NCC needed to re-acquire the subject. drift_score: below this
    appearance NCC a KCF box counts as lost. search_scale: the re-acquisition search region, in
    box sizes around the last good box. border_px: a last good box this close to the frame
    edge makes a loss an exit (``left``). max_box_px: the tracker works on frames scaled so the
    box's longer side is at most this (KCF's cost grows with the box area); boxes in and out
    are in the caller's px.
    """

    reinit_score: float = 0.55
    drift_score: float = 0.2
    search_scale: float = 2.0
    border_px: float = 2.0
    max_box_px: float = 48.0
    events: list[TrackState] = field(default_factory=list)

    def _work(self, frame: np.ndarray) -> np.ndarray:
        import cv2

        if self._s >= 1.0:
            return frame
        return cv2.resize(frame, None, fx=self._s, fy=self._s, interpolation=cv2.INTER_AREA)

    def start(self, frame: np.ndarray, box: Box, t: int) -> TrackState:
        """Initialise on ``frame`` (index t) with ``box`` (clipped to the frame)."""
        full_h, full_w = frame.shape[:2]
        box = clip_box(box, full_w, full_h)
        # KCF's cost grows with the box area: work at a scale where the box is <= max_box_px
        self._s = min(1.0, self.max_box_px / max(box[2], box[3], 1.0))
        self._full = (full_w, full_h)
        frame = self._work(frame)
        box = tuple(v * self._s for v in box)
        gray = _gray(frame)
        h, w = gray.shape
        box = clip_box(box, w, h)
        self._kcf = create_kcf()
        self._kcf.init(_color(frame), _int_box(box))
        self._first = _patch(gray, box)
        self._recent = self._first
        self._recent_raw = self._raw(gray, box)
        self._good = box
        self._size = (box[2], box[3])
        self._lost = 0
        self.state = TrackState(t, self._out(box), "init", 1.0)
        return self.state

    def _out(self, box: Box) -> Box:
        return clip_box(tuple(v / self._s for v in box), *self._full)

    @staticmethod
    def _raw(gray: np.ndarray, box: Box) -> np.ndarray | None:
        x, y, w, h = _int_box(box)
        piece = gray[max(y, 0):y + h, max(x, 0):x + w]
        return piece.copy() if piece.size >= 4 else None

    def _touches_border(self, box: Box, shape: tuple[int, int]) -> bool:
        h, w = shape
        b = self.border_px
        return box[0] <= b or box[1] <= b or box[0] + box[2] >= w - b or box[1] + box[3] >= h - b

    def _reacquire(self, gray: np.ndarray) -> tuple[Box, float] | None:
        import cv2

        templ = self._recent_raw
        if templ is None:
            return None
        th, tw = templ.shape
        h, w = gray.shape
        gx, gy, gw, gh = self._good
        cx, cy = gx + gw / 2, gy + gh / 2
        sw, sh = max(gw * self.search_scale, tw + 2), max(gh * self.search_scale, th + 2)
        x0, y0 = int(max(cx - sw / 2 - tw / 2, 0)), int(max(cy - sh / 2 - th / 2, 0))
        x1, y1 = int(min(cx + sw / 2 + tw / 2, w)), int(min(cy + sh / 2 + th / 2, h))
        region = gray[y0:y1, x0:x1]
        if region.shape[0] < th or region.shape[1] < tw:
            return None
        res = cv2.matchTemplate(region, templ, cv2.TM_CCOEFF_NORMED)
        _, score, _, loc = cv2.minMaxLoc(res)
        return (float(x0 + loc[0]), float(y0 + loc[1]), float(tw), float(th)), float(score)

    def update(self, frame: np.ndarray, t: int) -> TrackState:
        """Track into ``frame`` (index t); returns (and records, if not plain ``tracked``) the state."""
        frame = self._work(frame)
        gray = _gray(frame)
        h, w = gray.shape
        score = -1.0
        box = self._good
        ok = False
        if self._lost == 0:  # after a loss KCF's model is stale: only the template search may re-acquire
            ok, raw = self._kcf.update(_color(frame))
        if ok:
            box = clip_box(tuple(float(v) for v in raw), w, h)
            if box[2] * box[3] < 0.25 * self._size[0] * self._size[1]:
                ok = False  # mostly outside the frame
            else:
                p = _patch(gray, box)
                score = max(_ncc(p, self._first), _ncc(p, self._recent))
                ok = score >= self.drift_score
        if ok:
            status = "tracked"
            self._good = box
            self._lost = 0
            if score >= 0.6:
                self._recent = _patch(gray, box)
                self._recent_raw = self._raw(gray, box)
        else:
            found = self._reacquire(gray)
            if found is not None and found[1] >= self.reinit_score:
                box, score = found
                self._kcf = create_kcf()
                self._kcf.init(_color(frame), _int_box(box))
                self._good = box
                self._lost = 0
                status = "reinit"
            else:
                score = found[1] if found else -1.0
                box = self._good
                self._lost += 1
                status = "left" if self._touches_border(self._good, (h, w)) else "lost"
        self.state = TrackState(t, self._out(box), status, score)
        if status != "tracked":
            if status in ("lost", "left") and self._lost == 1:
                log.debug("tracker: subject %s at frame %d (score %.2f)", status, t, score)
            self.events.append(self.state)
        return self.state

    @property
    def frames_lost(self) -> int:
        """Consecutive frames without the subject (0 while tracked)."""
        return self._lost
