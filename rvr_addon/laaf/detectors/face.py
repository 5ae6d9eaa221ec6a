"""Face detector H_face: MediaPipe's full-range face detector where ``mediapipe`` imports (the
default: it finds profiles and faces of a few dozen px that HOG misses; a close-up it misses, the
short-range model looks for; a box no person is segmented around and the face mesh does not
confirm, such as a street sign, is dropped: ``mediapipe_face``, ``depth.face_check``; its models
are built once per process), else dlib's HOG frontal
face detector (as the paper used dlib), else OpenCV's Haar cascades (frontal + profile, shipped in
``cv2.data.haarcascades``). ``backend='auto'`` takes the first that loads and logs one line saying
which runs; 'mediapipe', 'dlib' and 'haar' ask for one (RuntimeError naming the fix if missing).

Faces are detected every ``every`` frames (boxes are held in between) and linked into face
tracks by overlap, so the speech detector can follow each face's mouth. The heat map is 1
inside each face box. Boxes are in analysis px.
"""
from __future__ import annotations

import functools
import logging
import time
from collections import OrderedDict

import numpy as np

from ...depth.face_tiles import iou
from ..nft import Box
from .base import AnalysisFrame, DetectorOutput, FocusDetector, boxes_heat

log = logging.getLogger(__name__)


def _nms(boxes: list[Box], thresh: float = 0.3) -> list[Box]:
    kept: list[Box] = []
    for b in sorted(boxes, key=lambda b: -b[2] * b[3]):
        if all(iou(b, k) < thresh for k in kept):
            kept.append(b)
    return kept


@functools.lru_cache(maxsize=1)
def _dlib_detector():
    """dlib's HOG face detector (loading it takes ~1.5 s: built once per process)."""
    import dlib

    return dlib.get_frontal_face_detector()


@functools.lru_cache(maxsize=1)
def _mediapipe_faces():
    """MediaPipe's face models for the face backend (full and short range, the person segmentation
    that confirms a box, the mesh when one must), built once per process: a job's clip reading, its
    detector and each shot's first target without a face box would otherwise each load them again
    (PeopleModelError is not cached: a later call tries again). Frames are processed one at a time."""
    from .mediapipe_face import MediaPipeFaces

    faces = MediaPipeFaces(mesh=False)
    faces.load()
    return faces


BACKENDS = ("auto", "mediapipe", "dlib", "haar")
_announced: set[str] = set()


def _announce(kind: str, why: str = "") -> None:
    """One log line per process and backend: which face detector LAAF runs."""
    if kind not in _announced:
        _announced.add(kind)
        names = {"mediapipe": "MediaPipe full-range face detection + face mesh", "dlib": "dlib HOG",
                 "haar": "OpenCV Haar cascades"}
        log.info("LAAF face detector: %s%s", names[kind], f" ({why})" if why else "")


class FaceBackend:
    """Raw face boxes of one frame: MediaPipe ('mediapipe'), dlib HOG ('dlib') or Haar cascades
    ('haar'); 'auto' = the first of these that loads."""

    def __init__(self, backend: str = "auto", min_face_px: int = 24, dlib_threshold: float = 0.0) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"face backend {backend!r} is not known; use one of {', '.join(BACKENDS)}")
        self.min_face_px = min_face_px
        self.dlib_threshold = dlib_threshold
        self.kind = backend
        self.mediapipe = None
        self.rejected = 0  # MediaPipe boxes face_check did not confirm (not faces)
        why = ""
        if backend in ("auto", "mediapipe"):
            from .mediapipe_face import mediapipe_importable

            if mediapipe_importable() or backend == "mediapipe":
                try:
                    self.mediapipe = _mediapipe_faces()
                    self.kind = "mediapipe"
                except Exception as exc:  # PeopleModelError: not importable / a model does not load
                    self.mediapipe = None
                    if backend == "mediapipe":
                        raise RuntimeError(f"the MediaPipe face backend cannot run: {exc}") from exc
                    why = f"mediapipe failed: {exc}"
            else:
                why = "mediapipe is not installed"
        if self.kind in ("auto", "dlib"):
            try:
                self._dlib = _dlib_detector()
                self.kind = "dlib"
            except ImportError:
                if backend == "dlib":
                    raise RuntimeError("dlib is not installed: pip install -r requirements.txt (dlib-bin), "
                                       "or use the Haar cascades (backend='haar')") from None
                self.kind = "haar"
                why = (why + "; " if why else "") + "dlib is not installed"
        if self.kind == "haar":
            import cv2

            root = cv2.data.haarcascades
            self._front = cv2.CascadeClassifier(root + "haarcascade_frontalface_default.xml")
            self._profile = cv2.CascadeClassifier(root + "haarcascade_profileface.xml")
            if self._front.empty():
                raise RuntimeError(f"OpenCV's Haar cascades are missing from {root}; reinstall opencv-contrib")
        _announce(self.kind, why)

    def detect_frame(self, gray: np.ndarray, rgb: np.ndarray | None = None,
                     native: np.ndarray | None = None) -> list[Box]:
        """Face boxes (x, y, w, h) px of a frame: MediaPipe sees ``rgb`` (the grey frame when
        None) and, for small faces, tiles of ``native`` (the same frame decoded at its own size;
        None: of ``rgb``), dlib and Haar the grey one (:meth:`detect`)."""
        if self.kind == "mediapipe" and rgb is not None:
            return self._mediapipe(rgb, native)
        return self.detect(gray)

    def _mediapipe(self, rgb: np.ndarray, native: np.ndarray | None = None) -> list[Box]:
        # MediaPipe finds faces well below dlib's 80 px window: keep boxes of >= 8 px (a 32 px face
        # at 4x the analysis size, where the face mesh still reads a mouth on the native frame)
        before = self.mediapipe.rejected
        boxes = [b for b, _ in self.mediapipe.detect(rgb, native)]
        self.rejected += self.mediapipe.rejected - before
        return [b for b in _nms(boxes) if min(b[2], b[3]) >= min(8.0, self.min_face_px * 0.6)]

    def detect(self, gray: np.ndarray) -> list[Box]:
        """Face boxes (x, y, w, h) px of a (H, W) uint8 frame."""
        import cv2

        h, w = gray.shape
        if self.kind == "mediapipe":
            return self._mediapipe(np.dstack([gray, gray, gray]))
        if self.kind == "dlib":
            # dlib's HOG window is 80 px: upsample (x2 per step) until faces of min_face_px are found
            up = int(np.clip(np.ceil(np.log2(80.0 / max(self.min_face_px, 1))), 0, 3))
            rects, scores, _ = self._dlib.run(gray, up, self.dlib_threshold)
            boxes = [(float(r.left()), float(r.top()), float(r.width()), float(r.height())) for r in rects]
        else:
            m = self.min_face_px
            boxes = [tuple(map(float, b)) for b in self._front.detectMultiScale(gray, 1.1, 4, minSize=(m, m))]
            if not self._profile.empty():
                boxes += [tuple(map(float, b)) for b in self._profile.detectMultiScale(gray, 1.1, 4, minSize=(m, m))]
                flipped = self._profile.detectMultiScale(np.ascontiguousarray(gray[:, ::-1]), 1.1, 4, minSize=(m, m))
                boxes += [(float(w - x - bw), float(y), float(bw), float(bh)) for x, y, bw, bh in flipped]
            boxes = _nms(boxes)
        return [b for b in boxes if min(b[2], b[3]) >= self.min_face_px * 0.6]


class FaceDetector(FocusDetector):
    """H_face with face tracks (ids ``face0``, ``face1``...); see the module docstring.

    every: detect on every n-th frame (held in between). min_face_px: smallest face side in
    analysis px (sets dlib's upsampling: 24 px at a 320 px analysis width means x4). forget_s: a face track not seen for
    this long is dropped. keep_frames: how many past frames of boxes are kept for ``faces_at``.
    """

    name = "face"

    def __init__(self, backend: str = "auto", every: int = 6, forget_s: float = 1.0, keep_frames: int = 256,
                 min_face_px: int = 24) -> None:
        self.backend = FaceBackend(backend, min_face_px=min_face_px)
        self.every = max(1, int(every))
        self.forget_s = forget_s
        self.keep_frames = keep_frames
        self._tracks: dict[str, tuple[Box, int]] = {}  # id -> (box, last frame seen)
        self._next_id = 0
        self._held: list[Box] = []
        self._at: OrderedDict[int, list[tuple[Box, float, str | None]]] = OrderedDict()
        self._shape: tuple[int, int] = (0, 0)
        self._seconds = 0.0
        self._detections = 0
        self._frames_with_faces = 0
        self._cut_at: int | None = None
        self._cuts: list[int] = []

    def cut(self, t: int) -> None:
        """A new shot from frame t: face tracks end (new ids after the cut) and frame t is
        detected afresh instead of holding the previous shot's boxes."""
        self._tracks = {}
        self._cut_at = t
        self._cuts.append(t)

    def _associate(self, boxes: list[Box], t: int, fps: float) -> list[tuple[Box, float, str | None]]:
        out = []
        free = dict(self._tracks)
        for b in sorted(boxes, key=lambda b: -b[2] * b[3]):
            best, best_score = None, 0.0
            for tid, (tb, _) in free.items():
                score = iou(b, tb)
                cx, cy = b[0] + b[2] / 2 - tb[0] - tb[2] / 2, b[1] + b[3] / 2 - tb[1] - tb[3] / 2
                if score < 0.2 and np.hypot(cx, cy) < 0.6 * max(tb[2], tb[3]):
                    score = 0.2
                if score > best_score:
                    best, best_score = tid, score
            if best is None or best_score < 0.2:
                best = f"face{self._next_id}"
                self._next_id += 1
            else:
                free.pop(best)
            self._tracks[best] = (b, t)
            out.append((b, 1.0, best))
        limit = self.forget_s * fps
        self._tracks = {k: v for k, v in self._tracks.items() if t - v[1] <= limit}
        return out

    measures = True

    def detect(self, frame: AnalysisFrame) -> list[Box]:
        """Face boxes (analysis px) of one frame, largest first (the order tracks are matched in)."""
        return sorted(self.backend.detect_frame(frame.gray, frame.rgb, frame.native), key=lambda b: -b[2] * b[3])

    def measure(self, frame: AnalysisFrame, prev: AnalysisFrame | None, faces: list[Box]) -> list[Box] | None:
        """The frame's face boxes on detection frames (t a multiple of ``every``), else None."""
        return self.detect(frame) if frame.t % self.every == 0 else None

    def process(self, t: int, frame: AnalysisFrame) -> None:
        start = time.perf_counter()
        boxes = self.measure(frame, None, [])
        self._seconds += time.perf_counter() - start
        self.ingest(t, frame, boxes)

    def ingest(self, t: int, frame: AnalysisFrame, boxes: list[Box] | None) -> None:
        """Link the boxes of a detection frame into face tracks, or hold the last frame's faces.
        (The first frame ingested is always a detection frame: detected here if not measured.)"""
        self._shape = frame.gray.shape
        if boxes is None and (not self._at or self._cut_at == t):
            start = time.perf_counter()
            boxes = self.detect(frame)
            self._seconds += time.perf_counter() - start
        if boxes is not None:
            self._detections += 1
            faces = self._associate(boxes, t, frame.fps)
        else:
            faces = list(self._at[next(reversed(self._at))])
            # keep held tracks alive
        if faces:
            self._frames_with_faces += 1
        self._at[t] = faces
        while len(self._at) > self.keep_frames:
            self._at.popitem(last=False)

    def faces_at(self, t: int) -> list[tuple[Box, float, str | None]]:
        """Face boxes with track ids on frame t (empty if none or forgotten)."""
        return self._at.get(t, [])

    def seen_before(self, t: int, frames: int) -> bool:
        """Whether a face was on one of the ``frames`` frames before t in t's shot (frames after
        the last cut at or before t): a detection frame that finds none there is a miss (a
        turned or blurred face), not a shot without faces."""
        start = max([c for c in self._cuts if c <= t], default=0)
        return any(self._at.get(k) for k in range(max(t - int(frames), start), t))

    def output(self, t: int) -> DetectorOutput:
        faces = self.faces_at(t)
        return DetectorOutput(boxes_heat(self._shape, faces), faces)

    def metrics(self) -> dict:
        return {"backend": self.backend.kind, "detections": self._detections,
                "frames_with_faces": self._frames_with_faces, "face_tracks": self._next_id,
                "boxes_not_faces": self.backend.rejected,
                "s_per_detection": self._seconds / max(self._detections, 1)}
