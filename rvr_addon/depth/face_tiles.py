"""Small faces: a face detector run on overlapping square tiles of a frame.

MediaPipe's full-range face detector sees every picture at 192 x 192 px, whatever its size. In a
whole wide frame a face under about a twelfth of the frame's width (a wide shot of two people at a
table: faces of 40-60 px in a 960 px frame) is a dozen model pixels and is missed, on the native
frame as on a small copy. Cut into squares of the frame's short side, and of half of it, the same
face is 2-4x larger to the model and is found (the 0.3-scale "wide shot" copies of the real
conversation composites: no face on any probed frame of the whole frame, the near face on every
frame and the far one on half of them in tiles).

:func:`tile_grid` places the squares (neighbours overlap by a third of a side, so a face up to a
third of a side lies whole in one of them); :func:`tiled_boxes` runs a detector on each and maps its
boxes back, dropping a box that touches a tile's inner edge (a face cut by the edge; the overlap
holds it whole in a neighbour) or one the coarser pass would have found itself (:data:`MAX_BOX_FRAC`);
:func:`merge_boxes` keeps the best-scoring of overlapping boxes.
Functions over arrays and a detector callable; boxes are (x, y, w, h) px.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

Box = tuple[float, float, float, float]
Found = list[tuple[Box, float]]

TILE_LEVELS = 2
"""Tile sides: the frame's short side, then half of it, at least MIN_TILE_PX (:func:`tile_sides`)."""
MIN_TILE_PX = 320
"""Tiles smaller than this (px of the picture they are cut from) are not run. The model finds faces
down to about a thirteenth of its picture, so a tile of 320 px finds faces of ~24 px, about the
smallest whose mouth the face mesh still reads; smaller tiles would cost detections (~3 ms each)
for faces LAAF cannot use. A 640x360 frame gets one level (3 tiles), 960x480 two (3 + 8 tiles of 320
px), 720p and 1080p two (18)."""
TILE_OVERLAP = 1.0 / 3.0
"""Neighbouring tiles share at least this fraction of a side."""
NEXT_LEVEL_FRAC = 0.75
"""A finer level's side is at most this fraction of the coarser one's: 480 -> 320 (a 40 px face is
16 model px in the 480 px tile, found on 27 of 93 frames of a wide shot, and 24 in the 320 px one,
found on all), 360 -> none (320 would find nothing 360 misses)."""
EDGE_PX = 2.0
"""A box within this many px of a tile's inner edge was cut by it and is dropped."""
MAX_BOX_FRAC = 1.0 / 6.0
"""A tile's box wider or taller than this fraction of the coarser pass's side (the whole picture's
long side for the first level, the level before for the next) is dropped: the coarser pass finds
faces that large itself (a whole 960 px frame: 133 px faces found, 56 px ones missed), so a box
that large found only in a tile is most likely not a face (hands on a restaurant table)."""
MERGE_IOU = 0.3
"""Boxes overlapping more than this (intersection over union) are one face."""


def tile_grid(h: int, w: int, side: int, overlap: float = TILE_OVERLAP) -> list[tuple[int, int]]:
    """Top-left corners (x0, y0) px of squares of ``side`` px covering an (h, w) picture, spaced
    evenly with neighbours sharing at least ``overlap`` of a side; one square per axis where the
    picture is no longer than ``side`` (the square is then clipped by the picture)."""

    def starts(length: int) -> list[int]:
        if length <= side:
            return [0]
        step = side * (1.0 - overlap)
        n = int(np.ceil((length - side) / step)) + 1
        return sorted({int(round(v)) for v in np.linspace(0, length - side, n)})

    return [(x0, y0) for y0 in starts(h) for x0 in starts(w)]


def tile_sides(h: int, w: int, levels: int = TILE_LEVELS, min_px: int = MIN_TILE_PX) -> list[int]:
    """The tile sides (px) for an (h, w) picture: its short side, then halved ``levels - 1`` times
    but not below ``min_px`` (a 480 px short side: tiles of 480 and 320, where half, 240, would be
    too small), a level at most :data:`NEXT_LEVEL_FRAC` of the one before (else it adds tiles but
    no face the level before misses)."""
    side, out = min(h, w), []
    for _ in range(max(levels, 0)):
        if side < min_px or (out and side > NEXT_LEVEL_FRAC * out[-1]):
            break
        out.append(int(side))
        side = max(side // 2, min_px)
    return out


def tiled_boxes(detect: Callable[[np.ndarray], Found], image: np.ndarray, levels: int = TILE_LEVELS,
                min_px: int = MIN_TILE_PX) -> Found:
    """Faces found by ``detect`` (an (h, w, 3) uint8 picture -> boxes in its px with scores) on the
    tiles of ``image`` (:func:`tile_sides`, :func:`tile_grid`), in ``image`` px, merged
    (:func:`merge_boxes`; a face found at two levels keeps the finer level's box, which saw it
    larger: on a wide shot a 480 px tile's box of a 58 px face reached 27 px above his head, the
    320 px tile's fitted it). A box touching a tile's inner edge is dropped, and one larger than
    :data:`MAX_BOX_FRAC` of the coarser pass's side."""
    h, w = image.shape[:2]
    levels_found: list[Found] = []
    coarser = max(h, w)
    for side in tile_sides(h, w, levels, min_px):
        if side >= max(h, w):  # one tile = the whole picture: the caller's own pass
            continue
        largest, coarser = coarser * MAX_BOX_FRAC, side
        found: Found = []
        for x0, y0 in tile_grid(h, w, side):
            found += _from_tile(detect, image, x0, y0, side, largest)
        levels_found.append(merge_boxes(found))
    kept: Found = []
    for found in reversed(levels_found):  # the finest level first
        kept += new_boxes(found, [b for b, _ in kept])
    return kept


def _from_tile(detect: Callable[[np.ndarray], Found], image: np.ndarray, x0: int, y0: int, side: int,
               largest: float) -> Found:
    """The boxes ``detect`` finds on the square tile of ``side`` px at (x0, y0) of ``image``, in
    ``image`` px; a box touching the tile's inner edge (not the picture's border) or wider or
    taller than ``largest`` px is dropped."""
    h, w = image.shape[:2]
    tile = np.ascontiguousarray(image[y0:y0 + side, x0:x0 + side])
    th, tw = tile.shape[:2]
    out: Found = []
    for (bx, by, bw, bh), score in detect(tile):
        inner_cut = ((x0 > 0 and bx <= EDGE_PX) or (y0 > 0 and by <= EDGE_PX)
                     or (x0 + tw < w and bx + bw >= tw - EDGE_PX) or (y0 + th < h and by + bh >= th - EDGE_PX))
        if not inner_cut and max(bw, bh) <= largest:
            out.append(((bx + x0, by + y0, bw, bh), score))
    return out


def around_boxes(detect: Callable[[np.ndarray], Found], image: np.ndarray, boxes: Sequence[Box],
                 min_px: int = MIN_TILE_PX, scale: float = 6.0) -> Found:
    """Faces found by ``detect`` on one square tile around each of ``boxes`` (x, y, w, h px of
    ``image``: faces found in tiles on an earlier frame), ``scale`` times the box's larger side and
    at least ``min_px`` (at most the picture's short side), centred on it and moved inside the
    picture; in ``image`` px, merged. One detection per box instead of a whole tiling: a video's
    small faces are followed from frame to frame this way between two whole tilings."""
    h, w = image.shape[:2]
    found: Found = []
    for bx, by, bw, bh in boxes:
        side = int(min(max(min_px, scale * max(bw, bh)), min(h, w)))
        x0 = int(np.clip(round(bx + bw / 2 - side / 2), 0, w - side))
        y0 = int(np.clip(round(by + bh / 2 - side / 2), 0, h - side))
        found += _from_tile(detect, image, x0, y0, side, max(h, w) * MAX_BOX_FRAC)
    return merge_boxes(found)


def detection_boxes(result: Any, shape: tuple[int, ...]) -> Found:
    """A MediaPipe face-detection result's boxes (x, y, w, h) px in a picture of ``shape``, clipped to
    it, with their scores (boxes under 2 px dropped)."""
    h, w = shape[:2]
    out: Found = []
    for det in result.detections or []:
        b = det.location_data.relative_bounding_box
        x0, y0 = max(0.0, b.xmin * w), max(0.0, b.ymin * h)
        x1, y1 = min(float(w), (b.xmin + b.width) * w), min(float(h), (b.ymin + b.height) * h)
        if x1 - x0 >= 2 and y1 - y0 >= 2:
            out.append(((x0, y0, x1 - x0, y1 - y0), float(det.score[0]) if det.score else 0.0))
    return out


def xywh(x0: float, y0: float, x1: float, y1: float) -> Box:
    """A box given by its corners as (x, y, w, h)."""
    return (x0, y0, x1 - x0, y1 - y0)


def iou(a: Box, b: Box) -> float:
    """Intersection over union of two (x, y, w, h) boxes."""
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = a[2] * a[3] + b[2] * b[3] - inter
    return inter / union if union > 0 else 0.0


def merge_boxes(found: Found, thresh: float = MERGE_IOU) -> Found:
    """The best-scoring box of each group of boxes overlapping by more than ``thresh`` (IoU)."""
    kept: Found = []
    for box, score in sorted(found, key=lambda f: -f[1]):
        if all(iou(box, k) <= thresh for k, _ in kept):
            kept.append((box, score))
    return kept


def same_face(a: Box, b: Box, thresh: float = MERGE_IOU) -> bool:
    """Whether boxes a and b are one face (IoU above ``thresh``, or a's centre inside b)."""
    cx, cy = a[0] + a[2] / 2, a[1] + a[3] / 2
    return iou(a, b) > thresh or (b[0] <= cx <= b[0] + b[2] and b[1] <= cy <= b[1] + b[3])


def new_boxes(found: Found, known: Sequence[Box], thresh: float = MERGE_IOU) -> Found:
    """The boxes of ``found`` that are none of ``known`` (:func:`same_face`)."""
    return [(b, s) for b, s in found if not any(same_face(b, k, thresh) for k in known)]


def tile_box(box: Box, found: Found, image_shape: tuple[int, ...]) -> Box | None:
    """The box of ``found`` (faces of tiles) that is the face ``box`` (found in the whole picture of
    ``image_shape``), when that face is small enough to be looked for in tiles (under
    :data:`MAX_BOX_FRAC` of the picture's long side): the tile saw it larger, so its box is the
    better one (a whole 640 px frame's box of a 58 px face reached 27 px above the head and missed
    the chin); None otherwise."""
    if max(box[2], box[3]) >= MAX_BOX_FRAC * max(image_shape[:2]):
        return None
    same = [(b, s) for b, s in found if same_face(b, box) or same_face(box, b)]
    return max(same, key=lambda f: f[1])[0] if same else None
