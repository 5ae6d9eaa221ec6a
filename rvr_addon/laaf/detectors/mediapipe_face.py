"""MediaPipe's faces for LAAF: full-range face boxes and the face mesh's mouth opening.

The same bundled models as the people depth cue (``rvr_addon.depth.people``): the full-range face
detector (``model_selection=1``, faces up to ~5 m, profiles and faces of a few dozen px that dlib's
HOG misses) and the refined face mesh, run on a square crop around each face box. The mouth
opening is ``people.mouth_opening`` (inner-lip gap / mouth width, 0 closed, ~0.3-0.6 wide open): a
ratio of the face's own size, so it compares across faces and distances.

The full-range model misses close-ups (a head filling much of the frame: on the shot/reverse-shot
composite 4 of its 22 detection frames in two close-up shots, where the speech detector then fell
back to audio-visual synchrony and focused the wall). Where it finds no face, the short-range
model (``model_selection=0``, made for faces within ~2 m of the camera) looks again
(``close_range``; it found the face on all four of those frames, scores 0.87-0.90): one extra
model run on the frames without a face only. Its boxes must score ``close_min_score`` (0.75):
on textures it finds "faces" at 0.6.

Both models' boxes are checked (``verify``, ``rvr_addon.depth.face_check``, as the people cue
checks its own): a box is a face when MediaPipe's person segmentation covers it, or else when the
face mesh finds a face in it (on the demo's street a sign scored 0.67, the real cyclist beside it
0.61-0.71; the sign has no person around it). The segmentation runs once per detection frame with
a box, the mesh only for a box the segmentation rejects; a frame whose full-range boxes are all
rejected gets the short-range model's look.

Faces too small for the whole frame (the model sees any picture at 192 x 192 px: a face under
about a twelfth of the frame's width, people at a table filmed from across the room) are looked
for on overlapping tiles of the native frame (``tiles``, :mod:`rvr_addon.depth.face_tiles`); a face
found only there must be one the face mesh reads (the person matte covers hands too).

The mesh runs on the *native* frame where the caller has it (``AnalysisFrame.native``, present
while a frame is measured): at a 320 px analysis width a face of an interview is ~50 px and its
lip gap a few px; at 720p it is four times that. Boxes come and go in analysis px.

mediapipe is imported (and its models built) on first use; :func:`mediapipe_importable` says
without importing it whether it can be. Without it, or when a model cannot load,
``rvr_addon.depth.people.PeopleModelError`` (an InputError naming the fix) is raised.
"""
from __future__ import annotations

import functools
import importlib.util
from typing import Any

import numpy as np

from ...depth import face_check, face_tiles
from ..nft import Box


@functools.lru_cache(maxsize=1)
def mediapipe_importable() -> bool:
    """Whether the ``mediapipe`` package can be found (it is not imported here)."""
    try:
        return importlib.util.find_spec("mediapipe") is not None
    except (ImportError, ValueError):
        return False


class MediaPipeFaces:
    """Face boxes (full-range detector) and mouth openings (face mesh) of RGB frames.

    min_score: the face detector's threshold. detect / mesh: which models load (first use).
    close_range: where the full-range model finds no face, the short-range one looks again
    (module docstring), keeping its boxes of score >= close_min_score. tiles: the full-range model
    also looks at overlapping tiles of the frame for faces too small for it in the whole frame
    (:mod:`rvr_addon.depth.face_tiles`). verify: keep only the boxes ``face_check`` confirms (person
    segmentation, else the face mesh); ``rejected`` counts the boxes dropped so far.
    """

    def __init__(self, min_score: float = 0.5, detect: bool = True, mesh: bool = True,
                 close_range: bool = True, close_min_score: float = 0.75, verify: bool = True,
                 tiles: bool = True) -> None:
        self.min_score = float(min_score)
        self.close_min_score = float(close_min_score)
        self._want = {"faces": detect, "mesh": mesh}
        self.close_range = bool(close_range) and detect
        self.verify = bool(verify) and detect
        self.tiles = bool(tiles) and detect
        self.rejected = 0
        self._models: dict[str, Any] | None = None

    def load(self) -> dict[str, Any]:
        """Build the models once (PeopleModelError naming the fix when one cannot load)."""
        if self._models is not None:
            return self._models
        # the people cue's import: it stubs matplotlib where Blender's Python lacks it
        from ...depth import people

        models = people.open_models("LAAF's MediaPipe faces", segment=self.verify,
                                    faces=self.min_score if self._want["faces"] else None, mesh=self._want["mesh"])
        if self.close_range:
            try:
                with people.native_stderr_silenced():
                    close = people.import_mediapipe().solutions.face_detection.FaceDetection(
                        min_detection_confidence=max(self.min_score, self.close_min_score), model_selection=0)
                    close.process(np.zeros((64, 64, 3), np.uint8))
            except Exception as exc:  # mediapipe raises RuntimeError/ValueError from its C++ graph
                for model in models.values():
                    model.close()
                raise people.PeopleModelError(f"LAAF's MediaPipe faces could not load mediapipe's short-range face "
                                              f"model ({exc}); reinstall {people.MEDIAPIPE_PIN}: "
                                              f"{people.INSTALL_HINT}") from exc
            models["faces_close"] = close
        self._models = models
        return models

    def close(self) -> None:
        if self._models is not None:
            for model in self._models.values():
                model.close()
            self._models = None

    def __del__(self) -> None:  # the graphs hold native threads
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass

    def detect(self, rgb: np.ndarray, native: np.ndarray | None = None) -> list[tuple[Box, float]]:
        """Face boxes (x, y, w, h) px of an (H, W, 3) uint8 RGB frame with their scores: the
        full-range model's, or where it finds none the short-range model's (``close_range``), and
        with ``tiles`` the faces too small for either that the full-range model finds on tiles of
        ``native`` (the same frame at a larger size, e.g. the decoded one; None: tiles of ``rgb``);
        with ``verify`` only the boxes ``face_check`` confirms. Where none finds a face but the
        person matte says someone is there (``face_check.worth_turning``), the full-range model
        searches the frame turned a quarter turn each way (a face on its side); such a face must
        also be one the face mesh reads in the turned frame (a bicycle wheel passes the detector
        turned)."""
        models = self.load()
        rgb = np.ascontiguousarray(rgb)
        matte: list[np.ndarray | None] = []  # the frame's person matte, segmented once when needed
        out = self._confirmed(self._boxes(models["faces"].process(rgb), rgb.shape), rgb, matte)
        if not out and "faces_close" in models:
            out = self._confirmed([(b, score) for b, score in self._boxes(models["faces_close"].process(rgb), rgb.shape)
                                   if score >= self.close_min_score], rgb, matte)
        if self.tiles:
            out += self._tiled(models, rgb, native, [b for b, _ in out])
        if not out and self.verify and face_check.worth_turning(self._matte(rgb, matte)):
            for turn in face_check.TURNS:
                view = np.ascontiguousarray(np.rot90(rgb, turn))
                for box, score in self._boxes(models["faces"].process(view), view.shape):
                    if self._mesh_finds(view, box):
                        out.append((self._unturned(box, turn, view.shape), score))
        return out

    def _tiled(self, models: dict[str, Any], rgb: np.ndarray, native: np.ndarray | None,
               known: list[Box]) -> list[tuple[Box, float]]:
        """The faces the full-range model finds on tiles of ``native`` (else ``rgb``) that are none of
        ``known``, in ``rgb`` px; with ``verify`` only those the face mesh reads on ``native`` (not
        the person matte: it covers the person's hands too, which a tile can take for a face)."""
        image = rgb if native is None else np.ascontiguousarray(native)
        k = rgb.shape[1] / image.shape[1]  # image px -> rgb px
        found = face_tiles.tiled_boxes(lambda tile: self._boxes(models["faces"].process(tile), tile.shape), image)
        found = face_tiles.new_boxes([((x * k, y * k, w * k, h * k), s) for (x, y, w, h), s in found], known)
        if not self.verify or not found:
            return found
        kept = [(box, score) for box, score in found
                if self._mesh_finds(image, (box[0] / k, box[1] / k, box[2] / k, box[3] / k))]
        self.rejected += len(found) - len(kept)
        return kept

    def _matte(self, rgb: np.ndarray, matte: list[np.ndarray | None]) -> np.ndarray | None:
        """The frame's person matte (0..1), segmented once per frame (``matte`` caches it)."""
        if not matte:
            seg = self.load()["segment"].process(rgb).segmentation_mask
            matte.append(None if seg is None else np.clip(np.nan_to_num(np.asarray(seg, np.float32)), 0.0, 1.0))
        return matte[0]

    @staticmethod
    def _unturned(box: Box, turn: int, turned_shape: tuple[int, ...]) -> Box:
        """A box (x, y, w, h) px found in the frame turned by ``turn`` quarter turns (of
        ``turned_shape``), as (x, y, w, h) px of the frame itself."""
        th, tw = turned_shape[:2]
        x, y, bw, bh = box
        x0, y0, x1, y1 = face_check.unturn_box(x / tw, y / th, (x + bw) / tw, (y + bh) / th, turn)
        h, w = (tw, th) if turn % 2 else (th, tw)
        return x0 * w, y0 * h, (x1 - x0) * w, (y1 - y0) * h

    def _confirmed(self, found: list[tuple[Box, float]], rgb: np.ndarray,
                   matte: list[np.ndarray | None]) -> list[tuple[Box, float]]:
        """The boxes of ``found`` that face_check confirms (all without ``verify``); ``matte``
        caches the frame's person segmentation (empty: not computed yet)."""
        if not self.verify or not found:
            return found
        boxes = [b for b, _ in found]
        kept = face_check.confirmed_faces(boxes, self._matte(rgb, matte), lambda i: self._mesh_finds(rgb, boxes[i]))
        self.rejected += len(found) - len(kept)
        return [found[i] for i in kept]

    def _mesh_finds(self, rgb: np.ndarray, box: Box) -> bool:
        """Whether the face mesh finds a face whose nose tip lies in box (x, y, w, h px of rgb);
        the mesh loads here on first use when ``mesh`` did not load it."""
        from ...depth import people

        models = self.load()
        if "mesh" not in models:
            models["mesh"] = people.open_models("LAAF's MediaPipe faces", segment=False, faces=None, mesh=True)["mesh"]
        x, y, w, h = box
        return people.face_landmarks(models["mesh"], rgb, (x, y, x + w, y + h)) is not None

    @staticmethod
    def _boxes(result: Any, shape: tuple[int, ...]) -> list[tuple[Box, float]]:
        """A face-detection result's boxes (x, y, w, h) px in a frame of ``shape``, with scores."""
        return face_tiles.detection_boxes(result, shape)

    def mouths(self, image: np.ndarray, boxes: list[Box], scale: float = 1.0) -> list[float | None]:
        """Mouth opening of each box (analysis px; ``image`` is at ``1 / scale`` of the analysis
        size, e.g. the native frame), or None where the mesh finds no face in its crop."""
        from ...depth import people

        if not boxes:
            return []
        mesh = self.load()["mesh"]
        image = np.ascontiguousarray(image)
        k = 1.0 / scale if scale > 0 else 1.0
        out: list[float | None] = []
        for x, y, bw, bh in boxes:
            points = people.face_landmarks(mesh, image, (x * k, y * k, (x + bw) * k, (y + bh) * k))
            out.append(None if points is None else people.mouth_opening(points))
        return out
