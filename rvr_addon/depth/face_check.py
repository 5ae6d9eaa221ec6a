"""Is a face detection a face? The check every user of MediaPipe's face detector applies (the people
depth cue, ``people.PeopleDetector``, and LAAF's faces, ``laaf.detectors.mediapipe_face``).

MediaPipe's face detectors fire on things that are not faces: on ``rvr refocus --demo``'s street a
pedestrian-crossing sign scored 0.67 (full-range model, frame 76, the first frame of a shot) while
the real, helmeted cyclist beside it scored 0.61-0.71, so no score threshold tells them apart; on
textures the short-range model finds "faces" at 0.6-0.75. Nor does the face mesh: it confirms the
large faces but none of the cyclist's (a 33 px face: the mesh's own detector does not find it).

What does tell them apart is the person around the face: a face belongs to a person, and MediaPipe's
selfie segmentation (bundled in the same wheel; the people cue computes it anyway) covers a real
face's box, even a small one in a street (the cyclist 0.61-0.97 of the box, the real faces of five
clips 0.59-1.0), not a sign (0.01). A box is kept when the person matte covers at least
:data:`PERSON_MIN_COVER` of it, or, failing that, when the face mesh finds a face whose nose tip lies
in the box (``people.face_landmarks``; a face the segmentation misses, e.g. a hand over it): the
mesh is asked only for the boxes the matte rejects.

Both users also search a frame turned a quarter turn each way (:data:`TURNS`, :func:`unturn_box`)
when no face is found upright but the person matte says someone is there (:func:`worth_turning`):
the detectors miss faces rolled by about 90 degrees (a person lying down, a phone held sideways).
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

Box = tuple[float, float, float, float]

TURN_MIN_MATTE = 0.03
"""A frame where the face detector finds no face but the person matte is above 0.5 on at least this
share of it is searched again turned a quarter turn each way (:func:`worth_turning`): MediaPipe's
face detectors miss faces rolled beyond ~60-90 degrees (a person lying down, a phone held sideways
without rotation metadata)."""
TURNS = (1, 3)
"""The quarter turns (``np.rot90``'s k: 1 counter-clockwise, 3 clockwise) searched."""

PERSON_MIN_COVER = 0.25
"""Least mean person matte (0..1) inside a face box for the box to count as a face without the face
mesh's confirmation (measured: real faces >= 0.59, the demo's sign 0.01)."""


def person_cover(matte: np.ndarray | None, box: Box) -> float:
    """Mean of a person matte (H, W, 0..1) inside box (x, y, w, h) px of the matte, clipped to the
    matte; 0 where the box lies outside it or there is no matte."""
    if matte is None:
        return 0.0
    h, w = matte.shape[:2]
    x0, y0 = int(max(0, np.floor(box[0]))), int(max(0, np.floor(box[1])))
    x1, y1 = int(min(w, np.ceil(box[0] + box[2]))), int(min(h, np.ceil(box[1] + box[3])))
    if x1 <= x0 or y1 <= y0:
        return 0.0
    return float(np.mean(matte[y0:y1, x0:x1]))


FOLLOW_FRAMES = 3
"""A face box confirmed on one of the last this many frames vouches for a box that follows it
(:func:`follows`): a real face whose person matte and mesh both fail on a frame (motion blur, a
monitor hiding the body: TUM fr1/rpy's man, matte cover 0.0-0.13 on 4 of his 9 frames) stays a face,
so the person layer does not blink; a sign is never confirmed, so it never follows anything."""


def follows(box: Box, earlier: Box) -> bool:
    """Whether ``box`` (x, y, w, h) continues ``earlier``'s face: its centre within 0.75 of the
    earlier box's size of the earlier centre on each axis, and its size within 2x of it."""
    cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
    ex, ey = earlier[0] + earlier[2] / 2, earlier[1] + earlier[3] / 2
    size, esize = max(box[2], box[3]), max(earlier[2], earlier[3])
    if size <= 0 or esize <= 0 or not 0.5 <= size / esize <= 2.0:
        return False
    return abs(cx - ex) <= 0.75 * esize and abs(cy - ey) <= 0.75 * esize


def confirmed_faces(boxes: Sequence[Box], matte: np.ndarray | None,
                    mesh_finds: Callable[[int], bool] | None = None,
                    min_cover: float = PERSON_MIN_COVER, recent: Sequence[Box] = (),
                    pending: Sequence[Box] | None = None) -> list[int]:
    """Indices of the face boxes (x, y, w, h, px of ``matte``) that are faces: the box
    :func:`follows` one of ``recent`` (the faces confirmed on the last FOLLOW_FRAMES frames, same
    px), or the person matte covers ``min_cover`` of it, or ``mesh_finds(i)`` says the face mesh
    finds a face in box i (asked only for boxes not confirmed otherwise; None: no mesh).

    pending: None (a picture, a clip's first frame): the matte alone confirms a box. Else the
    boxes the matte alone covered on the previous frame and nothing confirmed (:func:`matte_only`):
    a box the matte covers then needs to follow one of them. A face that appears from nowhere in a
    clip must be seen on two frames in a row unless the mesh confirms it: the selfie matte takes a
    bag on a sofa or a plant for a person now and then, for one frame (HoloLens office, frames 30
    and 112: matte cover 0.82 and 1.0, no mesh face, no detection on the frames around them)."""
    kept = []
    for i, box in enumerate(boxes):
        covered = person_cover(matte, box) >= min_cover
        if (any(follows(box, r) for r in recent)
                or (covered and (pending is None or any(follows(box, p) for p in pending)))
                or (mesh_finds is not None and mesh_finds(i))):
            kept.append(i)
    return kept


def matte_only(boxes: Sequence[Box], matte: np.ndarray | None, kept: Sequence[int],
               min_cover: float = PERSON_MIN_COVER) -> list[Box]:
    """The boxes the person matte covers that :func:`confirmed_faces` did not keep (the next
    frame's ``pending``)."""
    return [b for i, b in enumerate(boxes) if i not in kept and person_cover(matte, b) >= min_cover]


def worth_turning(matte: np.ndarray | None) -> bool:
    """Whether a frame whose upright search found no face should be searched turned (:data:`TURNS`):
    its person matte (0..1) is above 0.5 on at least :data:`TURN_MIN_MATTE` of it."""
    return matte is not None and matte.size > 0 and float(np.mean(matte > 0.5)) >= TURN_MIN_MATTE


def unturn_box(x0: float, y0: float, x1: float, y1: float, turn: int) -> tuple[float, float, float, float]:
    """A box (x0, y0, x1, y1, relative 0..1) found in ``np.rot90(frame, turn)`` as a box of the
    frame itself (relative): turn 1 = the frame turned a quarter turn counter-clockwise, 3 = clockwise."""
    if turn % 4 == 1:  # rot90 k=1: the turned frame's (x', y') is the frame's (1 - y', x')
        return 1.0 - y1, x0, 1.0 - y0, x1
    if turn % 4 == 3:  # k=3: the turned frame's (x', y') is the frame's (y', 1 - x')
        return y0, 1.0 - x1, y1, 1.0 - x0
    if turn % 4 == 2:
        return 1.0 - x1, 1.0 - y1, 1.0 - x0, 1.0 - y0
    return x0, y0, x1, y1
