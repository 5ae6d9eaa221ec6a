"""Small faces (``rvr_addon.depth.face_tiles``): MediaPipe's face detector sees every picture at
192 x 192 px, so the faces of a wide shot are missed in the whole frame; LAAF's face backend also
runs it on overlapping tiles of the native frame. The tiling is checked with a stand-in detector,
then the real detector on a real face made small: a frame of the GRID clip scaled down and pasted
on a plain frame, as a wide shot would show her."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.depth.face_tiles import (MAX_BOX_FRAC, around_boxes, MIN_TILE_PX, TILE_OVERLAP, iou, merge_boxes, new_boxes,
                                        tile_grid, tile_sides, tiled_boxes)

ROOT = Path(__file__).resolve().parents[2]
GRID = ROOT.parent / "shared" / "data" / "clips" / "lipnet_grid_lwbsza.mpg"
HAVE_MP = importlib.util.find_spec("mediapipe") is not None


@pytest.mark.parametrize("h, w, side", [(720, 1280, 720), (720, 1280, 360), (1080, 1920, 540), (480, 960, 480),
                                        (1280, 720, 360), (300, 300, 320)])
def test_the_tiles_cover_the_frame_and_neighbours_overlap_by_a_third(h, w, side):
    corners = tile_grid(h, w, side)
    covered = np.zeros((h, w), np.int32)
    for x0, y0 in corners:
        covered[y0:y0 + side, x0:x0 + side] += 1
    assert covered.min() >= 1  # every pixel is in a tile
    xs, ys = sorted({x for x, _ in corners}), sorted({y for _, y in corners})
    for starts in (xs, ys):
        gaps = np.diff(starts)
        assert len(gaps) == 0 or gaps.max() <= side * (1 - TILE_OVERLAP) + 1  # neighbours share >= a third


def test_tile_sides_halve_the_short_side_down_to_the_smallest_useful_tile():
    assert tile_sides(720, 1280) == [720, 360]
    assert tile_sides(1080, 1920) == [1080, 540]
    assert tile_sides(360, 640) == [360]  # 180 px tiles would find faces too small to read
    assert tile_sides(480, 960) == [480, 320]  # half is too small: the smallest useful tile instead
    assert tile_sides(400, 720) == [400]  # 320 is not small enough to find what 400 misses
    assert tile_sides(200, 300) == [] and MIN_TILE_PX == 320


def _fake_detector(faces):
    """A detector that finds the faces (x, y, w, h, in the frame) that lie whole in the picture it is
    given, when they are at least 1/12 of its long side (the real model's limit, roughly), at the
    picture's own coordinates: it must be called with tiles cut from ``frame``."""
    calls = []

    def detect(tile):
        calls.append(tile.shape[:2])
        # find where this tile sits in the frame through its marker pixels
        y0, x0 = int(tile[0, 0, 0]), int(tile[0, 0, 1])
        th, tw = tile.shape[:2]
        out = []
        for x, y, bw, bh in faces:
            lx, ly = x - x0, y - y0
            whole = lx >= 0 and ly >= 0 and lx + bw <= tw and ly + bh <= th
            cut = lx < tw and ly < th and lx + bw > 0 and ly + bh > 0 and not whole
            if whole and bw >= max(th, tw) / 12:
                out.append(((float(lx), float(ly), float(bw), float(bh)), 0.9))
            elif cut:  # a face cut by the tile's edge: a partial box at the edge
                cx0, cy0 = max(lx, 0), max(ly, 0)
                out.append(((float(cx0), float(cy0), float(min(lx + bw, tw) - cx0), float(min(ly + bh, th) - cy0)), 0.6))
        return out

    return detect, calls


def _marked_frame(h, w):
    """A frame whose every pixel holds its own (y, x), so a tile knows its place."""
    yy, xx = np.mgrid[0:h, 0:w]
    return np.dstack([yy, xx]).astype(np.int32)


def test_a_small_face_is_found_in_a_tile_at_its_place_in_the_frame_and_a_cut_one_is_not_kept():
    h, w = 720, 1280
    frame = _marked_frame(h, w)
    face = (600.0, 400.0, 40.0, 40.0)  # 1/32 of the width: too small for the whole frame, found in a 360 px tile
    detect, calls = _fake_detector([face])
    assert detect(frame) == []  # the whole frame misses it (the stand-in's limit, like the model's)
    found = tiled_boxes(detect, frame)
    assert [b for b, _ in found] == [face]  # once, at its place, never the partial boxes of the tiles that cut it
    assert len(calls) == 1 + len(tile_grid(h, w, 720)) + len(tile_grid(h, w, 360)) == 19  # the whole frame, 3 + 15 tiles


def test_a_small_face_found_before_is_followed_with_one_tile_around_it():
    h, w = 720, 1280
    frame = _marked_frame(h, w)
    face = (1230.0, 660.0, 40.0, 40.0)  # in the corner: the tile is moved inside the frame
    detect, calls = _fake_detector([face])
    assert [b for b, _ in around_boxes(detect, frame, [(1220.0, 650.0, 38.0, 38.0)])] == [face]
    assert len(calls) == 1 and calls[0] == (MIN_TILE_PX, MIN_TILE_PX)
    assert around_boxes(detect, frame, []) == []


def test_a_box_the_coarser_pass_would_have_found_is_not_taken_from_a_tile():
    """Hands on a restaurant table passed the detector in a tile: a box larger than a sixth of the
    coarser pass's side is dropped (the coarser pass finds faces that large itself)."""
    h, w = 720, 1280
    big = (500.0, 300.0, 240.0, 240.0)  # > 1280 / 6 = 213 px

    def detect(tile):
        return [((10.0, 10.0, 240.0, 240.0), 0.8)] if tile.shape[0] >= 720 else []

    assert big[2] > w * MAX_BOX_FRAC and tiled_boxes(detect, _marked_frame(h, w)) == []


def test_a_face_found_at_two_levels_keeps_the_finer_levels_box():
    """A 480 px tile's box of a small face (a poorly placed, oversized box that scores higher) and a
    320 px tile's box of the same face: the finer tile saw it larger, its box is kept."""
    h, w = 480, 960

    def detect(tile):
        y0, x0 = int(tile[0, 0, 0]), int(tile[0, 0, 1])
        face = (576.0, 266.0, 57.0, 57.0) if tile.shape[0] == 320 else (573.0, 238.0, 92.0, 92.0)
        lx, ly = face[0] - x0, face[1] - y0
        whole = lx >= 0 and ly >= 0 and lx + face[2] <= tile.shape[1] and ly + face[3] <= tile.shape[0]
        return [((lx, ly, face[2], face[3]), 0.72 if tile.shape[0] == 320 else 0.9)] if whole else []

    assert tiled_boxes(detect, _marked_frame(h, w)) == [((576.0, 266.0, 57.0, 57.0), 0.72)]


def test_a_small_face_of_the_whole_frame_takes_its_tiles_box():
    from rvr_addon.depth.face_tiles import tile_box

    whole = (573.0, 238.0, 92.0, 92.0)  # the whole frame's box of a small face: 27 px above the head
    found = [((576.0, 266.0, 57.0, 57.0), 0.7), ((100.0, 100.0, 40.0, 40.0), 0.9)]
    assert tile_box(whole, found, (480, 960, 3)) == (576.0, 266.0, 57.0, 57.0)
    assert tile_box((200.0, 200.0, 170.0, 170.0), found, (480, 960, 3)) is None  # a face the whole frame sees well
    assert tile_box(whole, [((300.0, 300.0, 40.0, 40.0), 0.9)], (480, 960, 3)) is None  # no tile found it


def test_overlapping_boxes_are_one_face_and_known_faces_are_not_new():
    a, b, c = (10.0, 10.0, 50.0, 50.0), (14.0, 12.0, 50.0, 48.0), (200.0, 10.0, 40.0, 40.0)
    assert iou(a, a) == pytest.approx(1.0) and iou(a, c) == 0.0
    assert merge_boxes([(a, 0.6), (b, 0.9), (c, 0.7)]) == [(b, 0.9), (c, 0.7)]
    assert new_boxes([(a, 0.9), (c, 0.8)], [b]) == [(c, 0.8)]
    small_inside = (30.0, 30.0, 8.0, 8.0)  # its centre inside a known face: the same face
    assert new_boxes([(small_inside, 0.9)], [a]) == []


def _wide_shot(scale: float) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """A 1280x720 street-like frame with the GRID speaker's frame 40 scaled by ``scale`` and pasted at
    the bottom centre; and the region (x, y, w, h) px she occupies."""
    from rvr_addon.io.video import iter_frames

    frames = iter_frames(GRID)
    for _ in range(40):
        person = next(frames)
    canvas = np.full((720, 1280, 3), 90, np.uint8)
    canvas[:, :, 1] = np.linspace(60, 140, 1280, dtype=np.uint8)[None, :]  # a plain gradient "street"
    ph, pw = int(person.shape[0] * scale * 720 / 288), int(person.shape[1] * scale * 720 / 288)
    small = cv2.resize(person, (pw, ph), interpolation=cv2.INTER_AREA)
    x0, y0 = (1280 - pw) // 2, 720 - ph
    canvas[y0:, x0:x0 + pw] = small
    return canvas, (float(x0), float(y0), float(pw), float(ph))


@pytest.mark.skipif(not HAVE_MP, reason="mediapipe is not installed (scripts/setup.sh)")
@pytest.mark.skipif(not GRID.is_file(), reason="the real clips of ../shared/data/clips are not here")
def test_laaf_finds_the_face_of_a_wide_shot_that_the_whole_frame_misses():
    """The GRID speaker small in a 720p frame (a face of ~40 px): the whole-frame detector
    finds nothing, at the analysis size as at the native size; with the tiles of the native frame
    LAAF's face backend finds her, once, inside her region, in analysis px."""
    from rvr_addon.laaf.detectors.mediapipe_face import MediaPipeFaces

    frame, (px, py, pw, ph) = _wide_shot(0.12)
    small = cv2.resize(frame, (320, 180), interpolation=cv2.INTER_AREA)
    whole = MediaPipeFaces(mesh=False, tiles=False)
    assert whole.detect(small) == [] and whole.detect(frame) == []
    found = MediaPipeFaces(mesh=False).detect(small, frame)
    assert len(found) == 1
    (x, y, w, h), score = found[0]
    k = 320 / 1280
    cx, cy = (x + w / 2) / k, (y + h / 2) / k
    assert px <= cx <= px + pw and py <= cy <= py + ph * 0.6  # on her head, in the upper part of her region
    assert 25 <= w / k <= 60 and score >= 0.5


@pytest.mark.skipif(not HAVE_MP, reason="mediapipe is not installed (scripts/setup.sh)")
@pytest.mark.skipif(not GRID.is_file(), reason="the real clips of ../shared/data/clips are not here")
def test_the_people_depth_cue_gives_the_person_of_a_wide_shot_a_layer_on_every_frame():
    """The people cue tiles the whole frame on one frame in TILE_EVERY and follows the small faces it
    found with one tile each on the frames between: the small GRID speaker is a person layer on each
    of 2 x TILE_EVERY frames, at a distance her face's size gives (about 5 m for a 40 px face at a
    phone's field of view), on her, and nowhere without the tiles."""
    from rvr_addon.depth.people import TILE_EVERY, PeopleDetector

    frame, (px, py, pw, ph) = _wide_shot(0.12)
    with PeopleDetector(tiles=False) as det:
        assert det(frame).persons == []
    with PeopleDetector() as det:
        answers = [det(frame) for _ in range(2 * TILE_EVERY)]
    for answer in answers:
        assert len(answer.persons) == 1
        person = answer.persons[0]
        x0, y0, x1, y1 = person.face_box
        assert px <= (x0 + x1) / 2 <= px + pw and 2.5 <= person.distance_m <= 8.0
        covered = answer.cue.confidence > 0.5
        assert covered[int(py):, int(px):int(px + pw)].sum() > 0.8 * covered.sum() > 0  # the layer is on her


@pytest.mark.skipif(not HAVE_MP, reason="mediapipe is not installed (scripts/setup.sh)")
@pytest.mark.skipif(not GRID.is_file(), reason="the real clips of ../shared/data/clips are not here")
def test_a_followed_face_its_tile_misses_stays_while_the_face_mesh_reads_it(monkeypatch):
    """Between two whole tilings a small face is followed with one tile around it; where that tile's
    detection misses it (a 58 px face of a wide shot at 32 model px, now and then), the face mesh
    still reading a face in its box keeps it, so its person layer does not vanish for those frames
    (on the x0.5 wide copy of the GRID + restaurant composite the man lacked one on 23 of 200)."""
    from rvr_addon.depth import face_tiles as T
    from rvr_addon.depth.people import TILE_EVERY, PeopleDetector

    frame, (px, py, pw, ph) = _wide_shot(0.12)
    real = T.around_boxes
    monkeypatch.setattr(T, "around_boxes", lambda detect, image, boxes, **kw: [])  # every follow-up tile misses
    with PeopleDetector() as det:
        answers = [det(frame) for _ in range(TILE_EVERY)]
    assert [len(a.persons) for a in answers] == [1] * TILE_EVERY
    monkeypatch.setattr(T, "around_boxes", real)
    blank = np.full_like(frame, 90)  # she is gone: the mesh reads nothing there, and nothing holds her
    with PeopleDetector() as det:
        assert len(det(frame).persons) == 1 and det(blank).persons == []
