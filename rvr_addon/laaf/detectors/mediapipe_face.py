"""MediaPipe's faces for LAAF: full-range face boxes and the face mesh's mouth opening.

The same bundled models as the people depth cue (``rvr_addon.depth.people``): the full-range face
detector (``model_selection=1``, faces up to ~5 m, profiles and faces of a few dozen px that dlib's
HOG misses) and the refined face mesh, run on a square crop around each face box. The mouth
opening is ``people.mouth_opening`` (inner-lip gap / mouth width, 0 closed, ~0.3-0.6 wide open): a
ratio of the face's own size, so it compares across faces and distances.

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
    """

    def __init__(self, min_score: float = 0.5, detect: bool = True, mesh: bool = True) -> None:
        self.min_score = float(min_score)
        self._want = {"faces": detect, "mesh": mesh}
        self._models: dict[str, Any] | None = None

    def load(self) -> dict[str, Any]:
        """Build the models once (PeopleModelError naming the fix when one cannot load)."""
        if self._models is not None:
            return self._models
        # the people cue's import: it stubs matplotlib where Blender's Python lacks it
        from ...depth import people

        models = people.open_models("LAAF's MediaPipe faces", segment=False,
                                    faces=self.min_score if self._want["faces"] else None, mesh=self._want["mesh"])
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

    def detect(self, rgb: np.ndarray) -> list[tuple[Box, float]]:
        """Face boxes (x, y, w, h) px of an (H, W, 3) uint8 RGB frame with their scores."""
        h, w = rgb.shape[:2]
        result = self.load()["faces"].process(np.ascontiguousarray(rgb))
        out = []
        for det in result.detections or []:
            b = det.location_data.relative_bounding_box
            x0, y0 = max(0.0, b.xmin * w), max(0.0, b.ymin * h)
            x1, y1 = min(float(w), (b.xmin + b.width) * w), min(float(h), (b.ymin + b.height) * h)
            if x1 - x0 >= 2 and y1 - y0 >= 2:
                out.append(((x0, y0, x1 - x0, y1 - y0), float(det.score[0]) if det.score else 0.0))
        return out

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
