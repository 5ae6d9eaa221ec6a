"""The "people" depth cue: person layers and their metric distance from face size.

MediaPipe's legacy ``solutions`` models, all bundled inside the ``mediapipe`` wheel (nothing is
downloaded at run time):

* **selfie segmentation** (landscape model): one soft matte of every person in the frame;
* **face detection** (full-range model, faces up to ~5 m): one box and six keypoints per face;
* **face mesh** (468 + refined lip/iris landmarks): on a crop around each detected face only,
  for a yaw-invariant face width and the mouth opening.

Per frame, :class:`PeopleDetector` splits the single selfie matte between the detected faces
(a geodesic split: each face's region grows inside the matte, nearer faces faster, so pixels go
to the face they are connected to; matte parts reachable from no face are dropped unless they lie
close to a person), gives each person a distance ``S = focal_px(max(W, H)) * FACE_WIDTH_M / face_width_px``
(pinhole camera of :data:`~rvr_addon.depth.cues.DEFAULT_HFOV_DEG` unless told otherwise) and
returns a :class:`~rvr_addon.depth.cues.CueMap` named ``people``: metric inverse depth (1/m) with a
gentle relief (the face a few cm nearer than the body's silhouette), NaN outside people,
confidence = the person's soft matte. Where people overlap, the nearer one wins. A detected face
:mod:`~rvr_addon.depth.face_check` does not confirm (no person matte covers its box and the face mesh
finds no face in it: a street sign) is no person, unless it follows a face confirmed on one of the
last :data:`~rvr_addon.depth.face_check.FOLLOW_FRAMES` frames (a blurred or half-hidden real face);
after a clip's first frame, a face that only the matte confirms must also have been seen on the
frame before (a bag or a plant the matte takes for a person for one frame is no person).

All models run at an analysis size (long side :data:`ANALYSIS_LONG_SIDE` px); masks are upsampled
to the frame's size once, so a 4K frame costs about what a 720p one does (plus the upsampling).

mediapipe is imported lazily by the detector; without it (or when a model fails to load) the
detector raises :class:`PeopleModelError`, an :class:`~rvr_addon.errors.InputError` whose message
names the package and the fix, so a caller can fall back to network-only depth with one message.
The detector keeps state between frames: the faces it confirmed on the last FOLLOW_FRAMES calls and
the previous call's unconfirmed ones, so give it a clip's frames in order (a new detector per clip
or picture).
"""
from __future__ import annotations

import contextlib
import importlib
import importlib.util
import os
import sys
import types
import warnings
from collections import deque
from dataclasses import dataclass
from typing import Any, Iterator

import cv2
import numpy as np

from ..errors import InputError
from . import face_check, face_tiles
from .cues import DEFAULT_HFOV_DEG, CueMap, focal_px

MEDIAPIPE_PIN = "mediapipe==0.10.14"
INSTALL_HINT = ("run scripts/setup.sh, or: pip install --no-deps mediapipe==0.10.14 absl-py==2.5.1 attrs==26.1.0 "
                "flatbuffers==25.12.19 protobuf==4.25.9")

FACE_WIDTH_M = 0.140
"""Average adult face width (m) between face-mesh landmarks 234 and 454 (the face's outline at the
cheekbones), measured in 3-D so a turned head does not look narrower. Anthropometric bizygomatic
breadth is ~0.13 m (women) to ~0.14 m (men). Checked on this project's clips against the mean adult
interpupillary distance (0.063 m): on frontal faces the 234-454 width is 2.07-2.34x (median 2.2x)
the distance of the iris centres (468, 473), i.e. 0.13-0.147 m."""
BOX_TO_FACE_WIDTH = 0.84
"""Face width (mesh landmarks 234-454) per width of the face detector's box (median on frontal
faces of this project's clips, 0.78-0.90 per clip); used where the face mesh found no face."""
ANALYSIS_LONG_SIDE = 640
"""Long side (px) of the image the models see; larger frames are downscaled to it (never up)."""
MIN_SIDE_PX = 16
"""Frames with a side shorter than this (px) hold no detectable face: they get an empty answer."""
FACE_RELIEF_M = 0.05
"""The body's silhouette lies this much (m) behind the face at most (a smooth bump on the face)."""
EDGE_RELIEF_M = 0.03
"""Extra depth (m) at a person's outline, fading over half a face width inwards (rounded body)."""
TURN_RETRY_FRAMES = 4
"""In a clip, while the turned search (``face_check.worth_turning``) finds no face it runs on one
frame in this many (a person whose face is not visible at all, back turned, would cost the cue two
more face detections on every frame: 10 -> 25-30 ms; now 12-14 ms); a face found turned keeps it
searching every frame."""
TILE_EVERY = 5
"""In a clip the whole frame is tiled for small faces (:mod:`~rvr_addon.depth.face_tiles`, 18
detections at 720p and 1080p) on one frame in this many; on the frames between, only a tile around
each small face already found is looked at (one detection each)."""
MIN_MATTE = 0.02
"""Matte values below this are taken as 0 (outside people)."""
MAX_DISTANCE_M = 50.0
MIN_DISTANCE_M = 0.10
_GRID_LONG_SIDE = 160  # long side (px) of the grid the split between people runs on
_MESH_CROP_SCALE = 1.9  # face-mesh crop side / face box side
_MESH_CROP_PX = 256  # long side (px) the face-mesh crop is resized to at most
_MESH_MIN_CROP_PX = 192  # ... and at least (bicubic)

# face-mesh landmark indices (canonical 468-point topology; 468-477 = refined irises)
_CHEEK_R, _CHEEK_L = 234, 454
_LIP_UPPER_INNER, _LIP_LOWER_INNER = 13, 14
_MOUTH_CORNER_R, _MOUTH_CORNER_L = 61, 291
_IRIS_R, _IRIS_L = 468, 473  # (the refined mesh has them: 478 points)
_NOSE_TIP = 1


class PeopleModelError(InputError):
    """mediapipe (the people cue's models) is not installed or a bundled model cannot be loaded."""


@dataclass
class Person:
    """One person in a frame (pixel units at the frame's full size).

    mask: (H, W) float32 soft matte 0..1 of the whole person (hair, body).
    face_box: (x0, y0, x1, y1) of the face detector's box, px.
    face_width_px: face width (mesh landmarks 234-454 in 3-D, else box width * BOX_TO_FACE_WIDTH), px.
    distance_m: camera-to-face distance from face size, m.
    mouth_open: inner-lip gap / mouth width (0 closed, ~0.3-0.6 wide open); None without a face mesh.
    score: the face detector's confidence 0..1.
    """

    mask: np.ndarray
    face_box: tuple[float, float, float, float]
    face_width_px: float
    distance_m: float
    mouth_open: float | None
    score: float


@dataclass
class PeopleFrame:
    """The people cue's answer for one frame: persons nearest first, and their depth as a CueMap."""

    persons: list[Person]
    cue: CueMap


def _importable(name: str) -> bool:
    """Whether a top-level module can be found (without importing it)."""
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def import_mediapipe() -> Any:
    """``mediapipe`` (its legacy ``solutions`` API), or PeopleModelError naming the fix.

    mediapipe's ``solutions/drawing_utils`` imports matplotlib at import time for a plotting helper
    we never call; where matplotlib is absent (Blender's Python, the extension zip does not bundle
    it) a stand-in module is put in ``sys.modules`` for the import only and removed afterwards."""
    stubs: list[str] = []
    try:
        if "mediapipe" not in sys.modules and not _importable("matplotlib"):
            for name in ("matplotlib", "matplotlib.pyplot"):
                sys.modules[name] = types.ModuleType(name)
                stubs.append(name)
            sys.modules["matplotlib"].pyplot = sys.modules["matplotlib.pyplot"]  # type: ignore[attr-defined]
        mp = importlib.import_module("mediapipe")
        # protobuf 4 deprecates an API mediapipe 0.10.14 calls on every frame: one line per run is noise
        warnings.filterwarnings("ignore", message=r"SymbolDatabase\.GetPrototype\(\) is deprecated",
                                category=UserWarning)
        mp.solutions.selfie_segmentation, mp.solutions.face_detection, mp.solutions.face_mesh  # noqa: B018
    except (ImportError, AttributeError) as exc:
        raise PeopleModelError(f"the people depth cue needs the Python package {MEDIAPIPE_PIN} (its bundled "
                               f"models), which cannot be imported ({exc}); {INSTALL_HINT}. Without it, depth "
                               "comes from the other cues only") from exc
    finally:
        for name in stubs:
            sys.modules.pop(name, None)
    return mp


@contextlib.contextmanager
def native_stderr_silenced() -> Iterator[None]:
    """Send what native code writes to file descriptor 2 to /dev/null inside the block (MediaPipe's
    TFLite logs start-up notices there that no setting turns off); Python's own ``sys.stderr`` is
    flushed first and restored after. Errors still arrive as Python exceptions."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no real fd 2 (embedded, captured): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)


def open_models(who: str, segment: bool, faces: float | None, mesh: bool) -> dict[str, Any]:
    """MediaPipe's bundled solutions by name: ``segment`` (selfie segmentation, landscape),
    ``faces`` (full-range face detection at this score threshold; None: not loaded), ``mesh``
    (face mesh with refined lips and irises, one face per call). ``who`` names the caller in the
    PeopleModelError raised, with the fix, when one cannot load."""
    mp = import_mediapipe()
    models: dict[str, Any] = {}
    try:
        with native_stderr_silenced():  # TFLite's start-up chatter (XNNPACK, feedback manager)
            if segment:
                models["segment"] = mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=1)
            if faces is not None:
                models["faces"] = mp.solutions.face_detection.FaceDetection(min_detection_confidence=faces,
                                                                            model_selection=1)
            if mesh:
                models["mesh"] = mp.solutions.face_mesh.FaceMesh(
                    static_image_mode=True, max_num_faces=1, refine_landmarks=True, min_detection_confidence=0.5)
            blank = np.zeros((64, 64, 3), np.uint8)
            for model in models.values():  # the graphs start (and log) on their first frame
                model.process(blank)
    except Exception as exc:  # mediapipe raises RuntimeError/ValueError from its C++ graph
        for model in models.values():
            model.close()
        raise PeopleModelError(f"{who} could not load mediapipe's bundled models ({exc}); "
                               f"reinstall {MEDIAPIPE_PIN}: {INSTALL_HINT}") from exc
    return models


def check_frame(frame: np.ndarray) -> np.ndarray:
    """The frame as a contiguous (H, W, 3) uint8 RGB array, or InputError saying what is wrong."""
    if not isinstance(frame, np.ndarray):
        raise InputError(f"people cue: a frame must be a numpy array, got {type(frame).__name__}")
    if frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 1):
        raise InputError(f"people cue: frame {frame.shape} is grey; give (H, W, 3) RGB (e.g. np.dstack([g, g, g]))")
    if frame.ndim == 3 and frame.shape[2] == 4:
        raise InputError(f"people cue: frame {frame.shape} is RGBA; drop the alpha channel (frame[..., :3])")
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise InputError(f"people cue: frame shape {frame.shape} is not (H, W, 3) RGB")
    if frame.dtype != np.uint8:
        raise InputError(f"people cue: frame dtype {frame.dtype} is not uint8 sRGB (0..255)")
    return np.ascontiguousarray(frame)


def _resize(image: np.ndarray, size: tuple[int, int], cubic: bool = False) -> np.ndarray:
    """cv2.resize to size (w, h): area filter when shrinking, bilinear (or bicubic) when enlarging;
    the image itself when it has that size already."""
    if (image.shape[1], image.shape[0]) == size:
        return image
    if size[0] < image.shape[1]:
        interp = cv2.INTER_AREA
    else:
        interp = cv2.INTER_CUBIC if cubic else cv2.INTER_LINEAR
    return cv2.resize(image, size, interpolation=interp)


def _scaled_size(w: int, h: int, long_side: int) -> tuple[int, int]:
    """(w, h) scaled so the long side is at most long_side (never enlarged), each side >= 1."""
    s = min(1.0, long_side / max(w, h))
    return max(1, round(w * s)), max(1, round(h * s))


def mouth_opening(points: np.ndarray) -> float:
    """Inner-lip gap / mouth width from (N, 2+) face-mesh landmarks in px (any consistent units)."""
    gap = np.linalg.norm(points[_LIP_UPPER_INNER, :2] - points[_LIP_LOWER_INNER, :2])
    width = np.linalg.norm(points[_MOUTH_CORNER_R, :2] - points[_MOUTH_CORNER_L, :2])
    return float(gap / width) if width > 0 else 0.0


def face_width_3d(points: np.ndarray) -> float:
    """Face width (landmarks 234-454) in px from (N, 3) face-mesh landmarks (x, y, z in px):
    in 3-D, so a turned head does not look narrower."""
    return float(np.linalg.norm(points[_CHEEK_R] - points[_CHEEK_L]))


def grow_labels(core: np.ndarray, seeds: np.ndarray, rates: list[int]) -> np.ndarray:
    """Geodesic split of a mask: labels 1..N from ``seeds`` (uint8, 0 = none) grow inside ``core``
    (bool), label i by ``rates[i-1]`` steps per round (nearer = faster; a step: 1 px sideways, 2 px
    up or down), earlier labels first on ties.
    Returns a uint8 label image (0 where no seed can reach)."""
    labels = np.where(core, seeds, 0).astype(np.uint8)
    kernel = np.ones((5, 3), np.uint8)  # 2 px down/up per px sideways: bodies hang below their faces
    free = core & (labels == 0)
    while free.any():
        grew = False
        for i, rate in enumerate(rates, start=1):
            for _ in range(rate):
                mine = (labels == i).astype(np.uint8)
                new = free & (cv2.dilate(mine, kernel) > 0)
                if not new.any():
                    break
                labels[new] = i
                free &= ~new
                grew = True
        if not grew:
            break
    return labels


class PeopleDetector:
    """Finds people in RGB frames and answers with their mattes, distances and depth (CueMap).

    ``hfov_deg``: the camera's field of view (deg) across the frame's long side, for the focal length in px.
    ``analysis_long_side``: long side (px) the models work at. ``min_face_score``: the face
    detector's threshold. ``max_faces``: faces kept per frame (largest first). ``tiles``: also look
    for faces too small for the whole frame on tiles of the full-size frame
    (:mod:`~rvr_addon.depth.face_tiles`; such a face must be one the face mesh reads; needs
    ``face_mesh``). Use as a context manager or call :meth:`close`; the models load on the first frame.
    """

    def __init__(self, hfov_deg: float = DEFAULT_HFOV_DEG, analysis_long_side: int = ANALYSIS_LONG_SIDE,
                 min_face_score: float = 0.5, max_faces: int = 6, face_mesh: bool = True, tiles: bool = True) -> None:
        if not 1.0 < hfov_deg < 179.0:
            raise InputError(f"people cue: hfov_deg {hfov_deg} must be in (1, 179) degrees")
        if analysis_long_side < 64:
            raise InputError(f"people cue: analysis_long_side {analysis_long_side} px is too small (>= 64)")
        self.hfov_deg = float(hfov_deg)
        self.analysis_long_side = int(analysis_long_side)
        self.min_face_score = float(min_face_score)
        self.max_faces = int(max_faces)
        self.use_face_mesh = bool(face_mesh)
        self.tiles = bool(tiles) and self.use_face_mesh
        self._models: dict[str, Any] | None = None
        self._recent: deque[list[tuple[float, float, float, float]]] = deque(maxlen=face_check.FOLLOW_FRAMES)
        """The confirmed face boxes (analysis px) of the last calls, newest last: frames come in order."""
        self._turn_wait = 0
        """Frames until a turned search may run again (:data:`TURN_RETRY_FRAMES`)."""
        self._frames = 0
        """Frames seen (the whole frame is tiled for small faces on one in :data:`TILE_EVERY`)."""
        self._small: list[tuple[float, float, float, float]] = []
        """The small faces (x, y, w, h, full-size px) the tiles found on the last frame: followed."""
        self._pending: list[tuple[float, float, float, float]] | None = None
        """The previous call's boxes that only the matte covered (``face_check.confirmed_faces``'s
        ``pending``); None before the first frame, where the matte alone confirms a face."""

    # -- models ----------------------------------------------------------------------------------
    def _load(self) -> dict[str, Any]:
        """Build the three MediaPipe solutions once (PeopleModelError when one cannot load)."""
        if self._models is not None:
            return self._models
        self._models = open_models("the people depth cue", segment=True, faces=self.min_face_score,
                                   mesh=self.use_face_mesh)
        return self._models

    def close(self) -> None:
        """Release the models (safe to call twice; a later frame loads them again)."""
        if self._models is not None:
            for model in self._models.values():
                model.close()
            self._models = None

    def __enter__(self) -> PeopleDetector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- one frame -------------------------------------------------------------------------------
    def __call__(self, frame: np.ndarray) -> PeopleFrame:
        """People in one (H, W, 3) uint8 sRGB RGB frame, nearest first, and their depth cue."""
        frame = check_frame(frame)
        h, w = frame.shape[:2]
        if min(h, w) < MIN_SIDE_PX:
            return self._answer([], h, w, {"people": 0, "skipped": f"frame {w}x{h} too small"})
        models = self._load()
        aw, ah = _scaled_size(w, h, self.analysis_long_side)
        small = _resize(frame, (aw, ah))
        matte = models["segment"].process(small).segmentation_mask
        matte = np.clip(np.nan_to_num(np.asarray(matte, np.float32)), 0.0, 1.0) if matte is not None \
            else np.zeros((ah, aw), np.float32)
        faces = self._faces(models, small, frame)
        if not faces and face_check.worth_turning(matte):
            if self._turn_wait > 0:
                self._turn_wait -= 1
            else:
                faces = self._faces(models, small, frame, rotated=True)
                self._turn_wait = 0 if faces else TURN_RETRY_FRAMES - 1
        k = aw / w  # full-size px -> matte px; a box no person matte covers (a sign) is no face: face_check
        boxes = [(f["box"][0] * k, f["box"][1] * k, (f["box"][2] - f["box"][0]) * k, (f["box"][3] - f["box"][1]) * k)
                 for f in faces]
        kept = face_check.confirmed_faces(boxes, matte, lambda i: faces[i]["mesh"],
                                          recent=[b for frame_boxes in self._recent for b in frame_boxes],
                                          pending=self._pending)
        self._recent.append([boxes[i] for i in kept])
        self._pending = face_check.matte_only(boxes, matte, kept)
        faces = [faces[i] for i in kept]
        layers = self._split(matte, faces, (h, w)) if faces else []
        info = {"people": len(layers), "distances_m": sorted(round(lay.person.distance_m, 3) for lay in layers),
                "hfov_deg": self.hfov_deg, "face_width_m": FACE_WIDTH_M}
        return self._answer(layers, h, w, info)

    def _faces(self, models: dict[str, Any], small: np.ndarray, frame: np.ndarray,
               rotated: bool = False) -> list[dict]:
        """Detected faces (full-size px): box, score, width, mouth opening; largest first.
        rotated: search the frame turned a quarter turn each way instead (:func:`face_check.worth_turning`);
        the boxes come back in the frame's own px. A face found turned must also be one the face
        mesh reads in the turned frame (textures such as a bicycle wheel pass the detector turned;
        without the mesh loaded, the person matte alone confirms it, as upright)."""
        h, w = frame.shape[:2]
        faces = []
        for turn in (face_check.TURNS if rotated else (0,)):
            result = models["faces"].process(np.ascontiguousarray(np.rot90(small, turn)) if turn else small)
            for det in result.detections or []:
                box = det.location_data.relative_bounding_box
                rel = (box.xmin, box.ymin, box.xmin + box.width, box.ymin + box.height)
                rx0, ry0, rx1, ry1 = face_check.unturn_box(*rel, turn)
                x0, y0 = max(0.0, rx0 * w), max(0.0, ry0 * h)
                x1, y1 = min(float(w), rx1 * w), min(float(h), ry1 * h)
                if x1 - x0 < 2 or y1 - y0 < 2:
                    continue
                tw, th = (h, w) if turn % 2 else (w, h)  # the turned frame's size
                faces.append({"box": (x0, y0, x1, y1), "score": float(det.score[0]) if det.score else 0.0,
                              "box_w": float(box.width * tw), "turned": turn,
                              "turned_box": (rel[0] * tw, rel[1] * th, rel[2] * tw, rel[3] * th)})
        if not rotated and self.tiles and "mesh" in models:  # small faces: tiles of the full-size frame
            known = [face_tiles.xywh(*f["box"]) for f in faces]

            def detect(tile: np.ndarray) -> list:
                return face_tiles.detection_boxes(models["faces"].process(tile), tile.shape)

            whole = self._frames % TILE_EVERY == 0
            self._frames += 1
            found = face_tiles.tiled_boxes(detect, frame) if whole else face_tiles.around_boxes(detect, frame, self._small)
            for box in [] if whole else self._small:  # not found again in its tile: still there if the mesh reads it
                if not any(face_tiles.same_face(b, box) or face_tiles.same_face(box, b) for b, _ in found):
                    x, y, bw, bh = box
                    if face_landmarks(models["mesh"], frame, (x, y, x + bw, y + bh)) is not None:
                        found.append((box, 0.0))
            for face, box in zip(faces, known):  # a small face the whole frame found too: the tile's box, followed
                better = face_tiles.tile_box(box, found, frame.shape) if not face["turned"] else None
                if better is not None:
                    x, y, bw, bh = better
                    face.update({"box": (x, y, x + bw, y + bh), "box_w": bw, "turned_box": (x, y, x + bw, y + bh),
                                 "follow": True})
            for (x, y, bw, bh), score in face_tiles.new_boxes(found, known):
                faces.append({"box": (x, y, x + bw, y + bh), "score": score, "box_w": bw, "turned": 0,
                              "turned_box": (x, y, x + bw, y + bh), "tiled": True, "follow": True})
        faces.sort(key=lambda f: -f["box_w"])
        faces = faces[:self.max_faces]
        for face in faces:
            face["width"], face["mouth"], face["mesh"] = face["box_w"] * BOX_TO_FACE_WIDTH, None, False
            if "mesh" in models:
                turned = face["turned"]
                view = np.ascontiguousarray(np.rot90(frame, turned)) if turned else frame
                points = face_landmarks(models["mesh"], view, face["turned_box"] if turned else face["box"])
                if points is not None:
                    face["mesh"] = True
                    face["width"], face["mouth"] = face_width_3d(points), mouth_opening(points)
        if "mesh" in models:  # a face found turned or in a tile must be one the mesh reads
            faces = [f for f in faces if f["mesh"] or not (rotated or f.get("tiled"))]
        if not rotated:
            self._small = [face_tiles.xywh(*f["box"]) for f in faces if f.get("follow")]
        for face in faces:
            face["distance"] = float(np.clip(focal_px(max(w, h), self.hfov_deg) * FACE_WIDTH_M / max(face["width"], 1e-3),
                                             MIN_DISTANCE_M, MAX_DISTANCE_M))
        return faces

    def _split(self, matte: np.ndarray, faces: list[dict], full: tuple[int, int]) -> list[_Layer]:
        """Split the analysis-size matte between faces (geodesic, nearer faces grow faster); each
        person's matte and inverse depth at analysis size, its full-size matte (nearest first)."""
        h, w = full
        ah, aw = matte.shape
        faces = sorted(faces, key=lambda f: f["distance"])  # nearest first: it wins ties
        gw, gh = _scaled_size(aw, ah, _GRID_LONG_SIDE)
        grid = _resize(matte, (gw, gh))
        gs = gw / w  # full-size px -> grid px
        seeds = np.zeros((gh, gw), np.uint8)
        yy, xx = np.mgrid[0:gh, 0:gw].astype(np.float32)
        for i, face in reversed(list(enumerate(faces, start=1))):  # nearest painted last
            x0, y0, x1, y1 = face["box"]
            ex, ey = max(0.5, (x1 - x0) * gs * 0.35), max(0.5, (y1 - y0) * gs * 0.35)
            cx, cy = (x0 + x1) / 2 * gs - 0.5, (y0 + y1) / 2 * gs - 0.5
            seeds[((xx - cx) / ex) ** 2 + ((yy - cy) / ey) ** 2 <= 1.0] = i
        core = (grid > 0.5) | (seeds > 0)  # the face itself always counts, even where the matte missed it
        smallest = min(f["width"] for f in faces)
        rates = [int(np.clip(round(f["width"] / smallest), 1, 4)) for f in faces]
        labels = grow_labels(core, seeds, rates)
        # attach fringe (and matte parts no face reaches) to the nearest person when close to one
        dist, nearest = cv2.distanceTransformWithLabels((labels == 0).astype(np.uint8), cv2.DIST_L2, 5,
                                                        labelType=cv2.DIST_LABEL_PIXEL)
        lut = np.zeros(int(nearest.max()) + 1, np.uint8)
        lut[nearest[labels > 0]] = labels[labels > 0]
        attach = (labels == 0) & (grid > MIN_MATTE) & (dist <= max(0.75 * smallest * gs, 1.5))
        labels = np.where(attach, lut[nearest], labels)
        layers = []
        for i, face in enumerate(faces, start=1):
            share = labels == i
            if not share.any():
                continue
            soft = _resize(cv2.GaussianBlur(share.astype(np.float32), (3, 3), 0), (aw, ah))
            mask = matte * soft
            # the face is always part of its person (the matte sometimes misses one): a soft ellipse
            _add_face_ellipse(mask, [c * aw / w for c in face["box"]], face["score"])
            mask = cv2.threshold(mask, MIN_MATTE, 0.0, cv2.THRESH_TOZERO)[1]
            full_mask = _resize(mask, (w, h))
            person = Person(mask=full_mask, face_box=face["box"], face_width_px=float(face["width"]),
                            distance_m=float(face["distance"]), mouth_open=face["mouth"], score=face["score"])
            layers.append(_Layer(person, mask, _resize(_relief(person, share, gs), (aw, ah))))
        return layers

    @staticmethod
    def _answer(layers: list[_Layer], h: int, w: int, info: dict) -> PeopleFrame:
        """Combine the people into the CueMap: far to near, a nearer person takes a pixel where its
        matte is above 0.3 or above the matte there so far. The winner's matte (confidence) and
        inverse depth are chosen at analysis size (q on every pixel: no NaN to spread) and
        upsampled once each."""
        if not layers:
            q, conf = np.full((h, w), np.nan, np.float32), np.zeros((h, w), np.float32)
        else:
            far_to_near = sorted(layers, key=lambda lay: -lay.person.distance_m)
            q_low = far_to_near[0].inverse.copy()
            c_low = np.zeros_like(q_low)
            for layer in far_to_near:
                take = (layer.mask > 0) & ((layer.mask > 0.3) | (layer.mask > c_low))
                q_low[take], c_low[take] = layer.inverse[take], layer.mask[take]
            # one upsampling each; equal to the winner's own full-size matte except on seams
            conf, q = _resize(c_low, (w, h)), _resize(q_low, (w, h))
            np.copyto(q, np.float32(np.nan), where=conf <= 0)
        persons = [lay.person for lay in sorted(layers, key=lambda lay: lay.person.distance_m)]
        return PeopleFrame(persons=persons, cue=CueMap("people", q, conf, metric=True, shift_free=True, info=info))


def _add_face_ellipse(mask: np.ndarray, box: list[float], value: float) -> None:
    """Raise ``mask`` (in place) to a soft ellipse of ``value`` filling the face ``box`` (x0, y0,
    x1, y1 in mask px), slightly taller than wide so the forehead and chin are in."""
    x0, y0, x1, y1 = box
    sigma = max(0.7, 0.05 * (x1 - x0))
    pad = int(np.ceil(3 * sigma + 0.1 * (y1 - y0)))
    h, w = mask.shape
    rx0, ry0 = max(0, int(x0) - pad), max(0, int(y0) - pad)
    rx1, ry1 = min(w, int(np.ceil(x1)) + pad), min(h, int(np.ceil(y1)) + pad)
    if rx1 <= rx0 or ry1 <= ry0:
        return
    ellipse = np.zeros((ry1 - ry0, rx1 - rx0), np.float32)
    cv2.ellipse(ellipse, (((x0 + x1) / 2 - 0.5 - rx0, (y0 + y1) / 2 - 0.5 - ry0), ((x1 - x0) * 0.9, (y1 - y0) * 1.1),
                          0.0), float(value), -1)
    roi = mask[ry0:ry1, rx0:rx1]
    np.maximum(roi, cv2.GaussianBlur(ellipse, (0, 0), sigma), out=roi)


@dataclass
class _Layer:
    """One person while a frame is assembled: its matte and inverse depth (1/m) at analysis size."""

    person: Person
    mask: np.ndarray
    inverse: np.ndarray


def _relief(person: Person, share: np.ndarray, scale: float) -> np.ndarray:
    """Inverse depth (1/m) of one person on the split grid (``scale`` grid px per full-size px):
    1/distance at the face; the body behind it by a smooth bump of up to FACE_RELIEF_M, plus
    EDGE_RELIEF_M at the outline fading over half a face width inwards."""
    gh, gw = share.shape
    x0, y0, x1, y1 = person.face_box
    cx, cy = (x0 + x1) / 2 * scale - 0.5, (y0 + y1) / 2 * scale - 0.5
    fw = max(person.face_width_px * scale, 0.5)
    yy, xx = np.mgrid[0:gh, 0:gw].astype(np.float32)
    bump = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2.0 * (0.8 * fw) ** 2))
    inside = cv2.distanceTransform(np.pad(share.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    edge = 1.0 - np.clip(inside / max(0.5 * fw, 1.0), 0.0, 1.0)
    depth = person.distance_m + FACE_RELIEF_M * (1.0 - bump) + EDGE_RELIEF_M * edge
    return (1.0 / depth).astype(np.float32)


def face_landmarks(mesh: Any, frame: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray | None:
    """Face-mesh landmarks (478, 3) in full-size px (z in the same px scale) on a square crop
    around box, or None when the mesh finds no face there (or finds a neighbour: its nose tip
    must lie inside box)."""
    h, w = frame.shape[:2]
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    half = _MESH_CROP_SCALE * max(box[2] - box[0], box[3] - box[1]) / 2
    x0, y0 = int(max(0, np.floor(cx - half))), int(max(0, np.floor(cy - half)))
    x1, y1 = int(min(w, np.ceil(cx + half))), int(min(h, np.ceil(cy + half)))
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    crop = frame[y0:y1, x0:x1]
    # at most _MESH_CROP_PX on the long side; small faces enlarged to _MESH_MIN_CROP_PX (the face
    # mesh's own detector finds no face of a few dozen px)
    long_side = max(x1 - x0, y1 - y0)
    cs = min(_MESH_CROP_PX, max(_MESH_MIN_CROP_PX, long_side)) / long_side
    cw, ch = max(1, round((x1 - x0) * cs)), max(1, round((y1 - y0) * cs))
    found = mesh.process(np.ascontiguousarray(_resize(crop, (cw, ch), cubic=True))).multi_face_landmarks
    if not found:
        return None
    pts = np.array([(p.x, p.y, p.z) for p in found[0].landmark], np.float64)
    if pts.shape[0] <= _IRIS_L:
        return None
    sx, sy = x1 - x0, y1 - y0
    points = np.stack([x0 + pts[:, 0] * sx, y0 + pts[:, 1] * sy, pts[:, 2] * sx], axis=1)
    nose_x, nose_y = points[_NOSE_TIP, :2]
    return points if box[0] <= nose_x <= box[2] and box[1] <= nose_y <= box[3] else None
