"""The people depth cue (rvr_addon.depth.people) on real clips of ../shared/data/clips (skipped
when absent) and on synthetic frames: person mattes, the split between people, distance from
face size, the mouth opening, the CueMap's units, bad input and a missing mediapipe."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.depth import face_check
from rvr_addon.depth import people as people_mod
from rvr_addon.depth.cues import focal_px
from rvr_addon.depth.people import FACE_WIDTH_M, PeopleDetector, PeopleFrame, PeopleModelError
from rvr_addon.errors import InputError
from rvr_addon.io.video import iter_frames

ROOT = Path(__file__).resolve().parents[2]
CLIPS = ROOT.parent / "shared" / "data" / "clips"
INTERVIEW = CLIPS / "visualvoice_interview.mp4"
LIPNET = CLIPS / "lipnet_grid_lwbsza.mpg"
HAS_MEDIAPIPE = __import__("importlib").util.find_spec("mediapipe") is not None
needs_mediapipe = pytest.mark.skipif(not HAS_MEDIAPIPE, reason="mediapipe is not installed (scripts/setup.sh)")


def clip_frame(path: Path, index: int) -> np.ndarray:
    if not path.is_file():
        pytest.skip(f"{path} is absent (the shared real clips)")
    return next(iter_frames(path, index, index + 1))


@pytest.fixture(scope="module")
def detector():
    if not HAS_MEDIAPIPE:
        pytest.skip("mediapipe is not installed (scripts/setup.sh)")
    with PeopleDetector() as det:
        yield det


def check_cue(result: PeopleFrame, shape: tuple[int, int]) -> None:
    """The CueMap contract: metric, shift-free, NaN exactly where confidence is 0."""
    cue = result.cue
    assert cue.name == "people" and cue.metric and cue.shift_free
    assert cue.inverse_depth.shape == cue.confidence.shape == shape
    assert cue.inverse_depth.dtype == cue.confidence.dtype == np.float32
    assert cue.confidence.min() >= 0 and cue.confidence.max() <= 1
    assert np.array_equal(np.isnan(cue.inverse_depth), cue.confidence == 0)
    assert cue.info["people"] == len(result.persons)


@needs_mediapipe
def test_interview_two_people_one_per_half(detector):
    frame = clip_frame(INTERVIEW, 100)
    h, w = frame.shape[:2]
    result = detector(frame)
    check_cue(result, (h, w))
    assert len(result.persons) == 2
    centres = sorted(((p.face_box[0] + p.face_box[2]) / 2, p) for p in result.persons)
    assert centres[0][0] < w / 2 < centres[1][0]
    for side, (cx, person) in enumerate(centres):
        assert person.mask.shape == (h, w) and person.mask.dtype == np.float32
        assert 0 <= person.mask.min() and person.mask.max() <= 1
        x0, y0, x1, y1 = (int(c) for c in person.face_box)
        fw = x1 - x0
        assert person.mask[y0:y1, x0:x1].mean() > 0.8  # the face
        # the body: below the face, a face width either side of its centre, to the frame's bottom
        assert person.mask[y1 + fw // 4:, max(0, int(cx) - fw):int(cx) + fw].mean() > 0.8
        # hair: the band just above the face box is person too
        assert person.mask[max(0, y0 - fw // 5):y0, x0 + fw // 4:x1 - fw // 4].mean() > 0.5
        own = person.mask[:, :w // 2] if side == 0 else person.mask[:, w // 2:]
        assert own.sum() > 0.9 * person.mask.sum()  # the split follows the split screen
        assert 0.3 < person.distance_m < 2.0 and person.mouth_open is not None
        assert person.face_width_px == pytest.approx(focal_px(w) * FACE_WIDTH_M / person.distance_m, rel=1e-6)
        # inverse depth: 1/distance at the face, the rest of the person a few cm behind it
        q = result.cue.inverse_depth[person.mask > 0.5]
        q = q[np.isfinite(q)]
        assert np.nanmax(q) == pytest.approx(1 / person.distance_m, rel=0.03)
        assert np.percentile(q, 5) > 1 / (person.distance_m + 0.12)
    assert result.persons[0].distance_m <= result.persons[1].distance_m  # nearest first


@needs_mediapipe
def test_lipnet_mouth_opens_while_speaking(detector):
    if not LIPNET.is_file():
        pytest.skip(f"{LIPNET} is absent (the shared real clips)")
    mouth, fps = [], 25.0
    for frame in iter_frames(LIPNET, 0, 75):
        result = detector(frame)
        assert len(result.persons) == 1
        mouth.append(result.persons[0].mouth_open)
    assert all(m is not None for m in mouth)
    t = np.arange(len(mouth)) / fps
    mouth = np.array(mouth, float)
    speaking = mouth[(t >= 0.7) & (t <= 2.4)].mean()
    silent = mouth[(t <= 0.5) | ((t >= 2.6) & (t <= 3.0))].mean()
    assert speaking > 1.4 * silent and 0 < silent < 0.3 and speaking < 0.6


@needs_mediapipe
@pytest.mark.parametrize("turn", [1, 3])
def test_a_face_turned_a_quarter_turn_is_still_a_person(turn):
    """A frame turned 90 degrees (a person lying down, a phone held sideways): MediaPipe's face
    detector finds no face in it, so the cue searches the frame turned back; the person is found
    with the face where it is in the turned frame and about the distance of the upright frame."""
    frame = clip_frame(LIPNET, 30)
    with PeopleDetector() as det:
        upright = det(frame)
    turned_frame = np.ascontiguousarray(np.rot90(frame, turn))
    with PeopleDetector() as det:
        assert det._faces(det._load(), turned_frame, turned_frame) == []  # the detector alone misses it
        turned = det(turned_frame)
    check_cue(turned, turned_frame.shape[:2])
    assert len(upright.persons) == len(turned.persons) == 1
    h, w = frame.shape[:2]
    x0, y0, x1, y1 = upright.persons[0].face_box
    expected = face_check.unturn_box(x0 / w, y0 / h, x1 / w, y1 / h, 4 - turn)  # where it went when turned
    th, tw = turned_frame.shape[:2]
    got = turned.persons[0].face_box
    assert np.allclose(got, np.array(expected) * [tw, th, tw, th], atol=0.12 * (x1 - x0))
    assert turned.persons[0].distance_m == pytest.approx(upright.persons[0].distance_m, rel=0.2)


@needs_mediapipe
def test_the_turned_search_runs_one_frame_in_four_while_it_finds_nothing(monkeypatch):
    """A person whose face is not visible (the restaurant man's face blurred away): the matte says
    someone is there, no face is found upright or turned, so in a clip the turned search runs on
    one frame in TURN_RETRY_FRAMES; on a turned face it runs on every frame (and finds it)."""
    face = clip_frame(CLIPS / "visualvoice_noisy_restaurant.mp4", 100)
    with PeopleDetector() as det:
        x0, y0, x1, y1 = (int(v) for v in det(face).persons[0].face_box)
    hidden = face.copy()
    box = (slice(max(0, y0 - 20), y1 + 20), slice(max(0, x0 - 20), x1 + 20))
    hidden[box] = cv2.GaussianBlur(face, (0, 0), 25)[box]
    calls = []
    real = PeopleDetector._faces
    monkeypatch.setattr(PeopleDetector, "_faces", lambda self, m, s, f, rotated=False:
                        calls.append(rotated) or real(self, m, s, f, rotated=rotated))
    with PeopleDetector() as det:
        for _ in range(9):
            assert det(hidden).persons == []
    assert calls.count(True) == 3 and calls.count(False) == 9  # frames 0, 4 and 8
    calls.clear()
    with PeopleDetector() as det:
        turned = np.ascontiguousarray(np.rot90(clip_frame(LIPNET, 30)))
        assert all(len(det(turned).persons) == 1 for _ in range(3))
    assert calls.count(True) == 3


def test_unturn_box_maps_a_box_back_from_each_quarter_turn():
    a = np.zeros((40, 60))
    a[5:15, 30:50] = 1  # x 30..50, y 5..15 of a 60 x 40 frame
    for turn in range(4):
        r = np.rot90(a, turn)
        ys, xs = np.nonzero(r)
        th, tw = r.shape
        box = face_check.unturn_box(xs.min() / tw, ys.min() / th, (xs.max() + 1) / tw, (ys.max() + 1) / th, turn)
        assert np.allclose(np.array(box) * [60, 40, 60, 40], [30, 5, 50, 15])


@needs_mediapipe
def test_no_people_all_nan(detector):
    sky = np.zeros((360, 640, 3), np.uint8)
    sky[...] = np.linspace([90, 140, 230], [200, 220, 250], 360)[:, None, :].astype(np.uint8)
    for frame in (sky, np.full((240, 320, 3), 128, np.uint8)):
        result = detector(frame)
        assert result.persons == []
        check_cue(result, frame.shape[:2])
        assert np.isnan(result.cue.inverse_depth).all() and not result.cue.confidence.any()


@needs_mediapipe
def test_4k_frame_same_people_at_full_size(detector):
    frame = clip_frame(INTERVIEW, 100)
    big = cv2.resize(frame, (3840, 2160), interpolation=cv2.INTER_CUBIC)
    small, large = detector(frame), detector(big)
    assert len(large.persons) == 2 and large.persons[0].mask.shape == (2160, 3840)
    check_cue(large, (2160, 3840))
    for a, b in zip(small.persons, large.persons):
        assert b.distance_m == pytest.approx(a.distance_m, rel=0.05)  # face size scales with the width
        assert np.allclose(np.array(b.face_box) / 3, a.face_box, atol=6)
        assert float(b.mask.mean()) == pytest.approx(float(a.mask.mean()), abs=0.01)


@needs_mediapipe
def test_without_face_mesh_distance_from_the_box(detector):
    frame = clip_frame(INTERVIEW, 100)
    with PeopleDetector(face_mesh=False) as boxes_only:
        plain = boxes_only(frame)
    meshed = detector(frame)
    assert len(plain.persons) == 2 and all(p.mouth_open is None for p in plain.persons)
    left_to_right = lambda persons: sorted(persons, key=lambda p: p.face_box[0])  # noqa: E731
    for a, b in zip(left_to_right(meshed.persons), left_to_right(plain.persons)):
        assert b.distance_m == pytest.approx(a.distance_m, rel=0.2)


@needs_mediapipe
def test_tiny_frame_has_no_people(detector):
    result = detector(np.zeros((1, 1, 3), np.uint8))
    assert result.persons == [] and result.cue.inverse_depth.shape == (1, 1)
    assert np.isnan(result.cue.inverse_depth).all() and result.cue.confidence.max() == 0


@pytest.mark.parametrize("frame, words", [
    (np.zeros((48, 64), np.uint8), "grey"),
    (np.zeros((48, 64, 1), np.uint8), "grey"),
    (np.zeros((48, 64, 4), np.uint8), "RGBA"),
    (np.zeros((48, 64, 3), np.float32), "uint8"),
    (np.zeros((2, 48, 64, 3), np.uint8), "(H, W, 3)"),
])
def test_bad_frames_rejected(frame, words):
    with pytest.raises(InputError, match=words.replace("(", r"\(").replace(")", r"\)")):
        PeopleDetector()(frame)  # rejected before any model loads


def test_missing_mediapipe_names_the_fix(monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # import mediapipe -> ImportError
    with pytest.raises(PeopleModelError) as err, PeopleDetector() as det:
        det(np.zeros((64, 64, 3), np.uint8))
    message = str(err.value)
    assert "mediapipe==0.10.14" in message and "scripts/setup.sh" in message and "--no-deps" in message
    assert isinstance(err.value, InputError)


def test_model_that_fails_to_load_names_the_fix(monkeypatch):
    class Broken:
        def __init__(self, *args, **kwargs):
            raise RuntimeError("ValidatedGraphConfig Initialization failed")

    fake = type(sys)("mediapipe")
    fake.solutions = type(sys)("solutions")
    for name in ("selfie_segmentation", "face_detection", "face_mesh"):
        module = type(sys)(name)
        module.SelfieSegmentation = module.FaceDetection = module.FaceMesh = Broken
        setattr(fake.solutions, name, module)
    monkeypatch.setitem(sys.modules, "mediapipe", fake)
    with pytest.raises(PeopleModelError, match="bundled models.*ValidatedGraphConfig.*mediapipe==0.10.14"):
        PeopleDetector()(np.zeros((64, 64, 3), np.uint8))


def test_module_imports_without_mediapipe():
    """`import rvr_addon.depth.people` needs no mediapipe; with mediapipe but no matplotlib (Blender's
    Python) the detector still works and leaves no stand-in matplotlib behind."""
    code = textwrap.dedent("""
        import importlib.abc, sys
        blocked = set(sys.argv[1].split(","))
        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path, target=None):
                if name.split(".")[0] in blocked:
                    raise ImportError("blocked " + name)
        sys.meta_path.insert(0, Block())
        import numpy as np
        from rvr_addon.depth.people import PeopleDetector, PeopleModelError
        try:
            with PeopleDetector() as det:
                print("people", len(det(np.zeros((64, 96, 3), np.uint8)).persons))
        except PeopleModelError as exc:
            print("error", exc)
        print("matplotlib" in sys.modules)
    """)
    run = lambda blocked: subprocess.run([sys.executable, "-c", code, blocked], capture_output=True, text=True,
                                         cwd=ROOT, timeout=120)
    done = run("mediapipe")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[0].startswith("error") and "mediapipe==0.10.14" in done.stdout
    if HAS_MEDIAPIPE:
        done = run("matplotlib")
        assert done.returncode == 0, done.stderr
        assert done.stdout.splitlines() == ["people 0", "False"]


def test_grow_labels_splits_along_the_mask():
    """Two seeds in a U-shaped mask: each arm goes to its own seed, though the other seed is
    nearer in a straight line across the gap."""
    core = np.zeros((40, 40), bool)
    core[:, 2:12] = core[:, 28:38] = core[30:, 2:38] = True
    seeds = np.zeros((40, 40), np.uint8)
    seeds[2, 7], seeds[2, 33] = 1, 2
    labels = people_mod.grow_labels(core, seeds, [1, 1])
    assert (labels[:25, 2:12] == 1).all() and (labels[:25, 28:38] == 2).all()
    assert (labels[~core] == 0).all() and (labels[core] > 0).all()


def test_overlapping_people_the_nearer_wins():
    """Two people whose mattes overlap: the nearer one's inverse depth wherever its matte is
    solid, the far one's only where the near matte is faint; NaN and confidence 0 outside both."""
    h, w = 60, 80
    far_mask, near_mask = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    far_mask[10:50, 10:50] = 1.0
    near_mask[20:60, 30:70] = 0.9
    near_mask[20:60, 30:34] = 0.1  # a faint fringe over the far person
    layers = []
    for mask, dist in ((near_mask, 1.0), (far_mask, 2.0)):
        person = people_mod.Person(mask=mask, face_box=(0, 0, 1, 1), face_width_px=10.0, distance_m=dist,
                                   mouth_open=None, score=1.0)
        layers.append(people_mod._Layer(person, mask, np.full((h, w), 1 / dist, np.float32)))
    result = PeopleDetector._answer(layers, h, w, {"people": 2})
    q, conf = result.cue.inverse_depth, result.cue.confidence
    assert [p.distance_m for p in result.persons] == [1.0, 2.0]
    assert np.allclose(q[30:50, 40:50], 1.0) and np.allclose(conf[30:50, 40:50], 0.9)  # overlap: near
    assert np.allclose(q[30:50, 30:34], 0.5) and np.allclose(conf[30:50, 30:34], 1.0)  # faint near fringe
    assert np.allclose(q[12:18, 12:48], 0.5)  # far alone
    assert np.isnan(q[:10]).all() and not conf[:10].any()
    check_cue(result, (h, w))
