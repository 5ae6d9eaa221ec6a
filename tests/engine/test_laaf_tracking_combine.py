"""LAAF: KCF tracking with loss reporting, focus reading, the detector combination, steps -> NFTs."""
from __future__ import annotations

import numpy as np
import pytest

from laaf_synth import entering_square, texture
from rvr_addon.laaf.combine import StepDetector, intersect, majority_region, region_min_area
from rvr_addon.laaf.detectors.base import DetectorOutput
from rvr_addon.laaf.focus_reading import read_focus
from rvr_addon.laaf.tracking import SubjectTracker


def moving_sequence(n=30, size=(160, 96), side=24, vx=2.0, vy=1.0, hide=None):
    """Textured square moving with known velocity over a textured background; frames in
    ``hide`` have the square removed (occlusion)."""
    w, h = size
    bg = (texture(h, w, 11) * 0.4 + 50).astype(np.uint8)
    obj = texture(side, side, 12)
    frames, boxes = [], []
    for k in range(n):
        x, y = 20 + vx * k, 30 + vy * k
        f = bg.copy()
        if not (hide and k in hide):
            xi, yi = int(round(x)), int(round(y))
            xe = min(xi + side, w)
            if xi < w:
                f[yi:yi + side, xi:xe] = obj[:, :xe - xi]
        frames.append(f)
        boxes.append((x, y, side, side))
    return frames, boxes


def test_tracker_follows_known_motion():
    frames, boxes = moving_sequence()
    tr = SubjectTracker()
    tr.start(frames[0], boxes[0], 0)
    for k in range(1, len(frames)):
        st = tr.update(frames[k], k)
        assert st.ok
        assert abs(st.box[0] - boxes[k][0]) < 3 and abs(st.box[1] - boxes[k][1]) < 3
    assert not [e for e in tr.events if e.status in ("lost", "left")]


def test_tracker_reports_loss_and_reinitialises():
    frames, boxes = moving_sequence(n=30, vx=1.0, vy=0.0, hide=set(range(10, 14)))
    tr = SubjectTracker()
    tr.start(frames[0], boxes[0], 0)
    states = [tr.update(frames[k], k) for k in range(1, 30)]
    lost = [s.frame for s in states if s.status == "lost"]
    assert lost and min(lost) in (10, 11)  # the occlusion is reported, not tracked through silently
    reinit = [s.frame for s in states if s.status == "reinit"]
    assert reinit and 14 <= min(reinit) <= 16
    final = states[-1]
    assert final.ok and abs(final.box[0] - boxes[29][0]) < 3


def test_subject_leaving_the_frame_is_reported_as_left():
    frames, boxes = moving_sequence(n=50, vx=4.0, vy=0.0)  # exits at the right edge
    tr = SubjectTracker()
    tr.start(frames[0], boxes[0], 0)
    states = [tr.update(frames[k], k) for k in range(1, 50)]
    assert any(s.status == "left" for s in states)
    first_left = next(s.frame for s in states if s.status == "left")
    assert boxes[first_left][0] + boxes[first_left][2] > 150  # at the edge, not earlier


# ------------------------------------------------------------------------------------------ reading

def test_reading_is_foreground_biased_not_the_mean():
    d = np.full((60, 60), 5.0, np.float32)
    d[20:45, 22:40] = 1.0  # the subject covers ~30% of the box
    r = read_focus(d, (10, 10, 40, 40))
    assert r.value == pytest.approx(1.0, abs=0.01) and r.support > 0.3


def test_reading_skips_a_sliver_in_front_and_follows_a_prior():
    d = np.full((60, 60), 5.0, np.float32)
    d[15:50, 20:42] = 2.0  # subject
    d[10:50, 28:30] = -6.0  # a thin branch in front
    assert read_focus(d, (10, 10, 40, 40)).value == pytest.approx(2.0, abs=0.01)
    assert read_focus(d, (10, 10, 40, 40), prior=4.8).value == pytest.approx(5.0, abs=0.01)


# ------------------------------------------------------------------------------------------ combination

def blob(shape, box, value=1.0):
    m = np.zeros(shape, np.float32)
    x, y, w, h = box
    m[y:y + h, x:x + w] = value
    return m


def test_intersection_and_kmeans_majority_pick_the_larger_region():
    shape = (90, 160)
    a = blob(shape, (10, 10, 40, 40)) + blob(shape, (100, 50, 14, 14))
    b = np.ones(shape, np.float32)
    mask, used = intersect({"action": DetectorOutput(a), "saliency": DetectorOutput(b)})
    assert used == ("action", "saliency")
    r = majority_region(mask, min_area=0.001)
    assert 10 <= r.x <= 50 and 10 <= r.y <= 50  # inside the big blob
    assert r.box == (10.0, 10.0, 40.0, 40.0)


def test_empty_detector_empties_the_intersection_and_tiny_regions_are_ignored():
    shape = (90, 160)
    mask, _ = intersect({"speech": DetectorOutput(None), "face": DetectorOutput(blob(shape, (5, 5, 20, 20)))})
    assert mask is None
    assert majority_region(blob(shape, (0, 0, 3, 3)) > 0, min_area=0.01) is None


def test_unavailable_detector_is_dropped_and_primary_is_not_vetoed():
    shape = (90, 160)
    face = DetectorOutput(blob(shape, (5, 5, 20, 20)))
    mask, used = intersect({"speech": DetectorOutput(None, available=False), "face": face})
    assert used == ("face",) and mask.sum() == 400
    act = DetectorOutput(blob(shape, (100, 20, 30, 40)))
    sal = DetectorOutput(blob(shape, (0, 0, 50, 90)))
    mask, used = intersect({"action": act, "saliency": sal}, primary="action", min_area=0.01)
    assert used == ("action",) and mask.sum() == 1200


def test_a_small_speaking_face_is_a_region_where_a_speck_of_motion_is_not():
    """A speaker in a wide shot: an 11 px face box in a 320x160 analysis frame (0.24 % of it, under
    the 1 % floor that keeps specks of the pixel maps out) is still the focus region of the
    conversation preset; the same speck from the action or saliency map is not."""
    shape = (160, 320)
    face = blob(shape, (180, 117, 11, 11))
    outputs = {"speech": DetectorOutput(face), "face": DetectorOutput(face + blob(shape, (120, 130, 22, 22)))}
    mask, used = intersect(outputs, primary="speech", min_area=0.01)
    assert used == ("speech", "face") and mask.sum() == 121
    assert region_min_area(used, 0.01) == 0.0
    r = majority_region(mask, region_min_area(used, 0.01))
    assert r is not None and r.box == (180.0, 117.0, 11.0, 11.0)
    mask, used = intersect({"speech": DetectorOutput(face), "face": DetectorOutput(None)}, primary="speech",
                           min_area=0.01)  # the face detector missed it on this frame: speech's box alone
    assert used == ("speech",) and mask.sum() == 121
    for used in (("action", "saliency"), ("action",), ("face",), ("saliency",)):
        assert region_min_area(used, 0.01) == 0.01
        assert majority_region(face > 0, region_min_area(used, 0.01)) is None


def _steps(levels, causal):
    det = StepDetector(min_step=0.5, r=3, min_gap=5, causal=causal)
    found = []
    for i, v in enumerate(levels):
        for st in det.push(v):
            found.append((st.frame, i))  # (step frame, frame at which it became certain)
    found += [(st.frame, len(levels)) for st in det.finish()]
    return found


def test_step_detector_finds_the_discontinuity_frame():
    rng = np.random.default_rng(0)
    levels = np.r_[np.full(20, 1.0), np.full(20, 3.0)] + rng.normal(0, 0.05, 40)
    levels[5] = np.nan  # empty intersection: held
    ((frame, known),) = _steps(levels, causal=False)
    assert frame == 20 and 20 < known <= 20 + StepDetector(causal=False).delay
    ((frame_c, known_c),) = _steps(levels, causal=True)
    assert frame_c == 20 and 20 <= known_c <= 20 + StepDetector(causal=True).delay
    assert known_c < known


def test_a_one_frame_blip_then_nothing_is_no_target():
    levels = np.r_[np.full(20, 1.0), [4.0], np.full(20, np.nan)]
    assert _steps(levels, causal=False) == [] and _steps(levels, causal=True) == []


def test_gradual_change_below_min_step_is_no_target():
    levels = np.linspace(1.0, 1.4, 40)
    assert _steps(levels, causal=False) == []


def test_synthetic_entering_square_is_consistent():
    frames, maps, boxes = entering_square()
    assert len(frames) == 40 and maps[25][36, 120] == 0.0 and maps[0][36, 100] == 3.0


def test_the_action_detector_sees_the_same_speed_in_px_a_second_at_any_frame_rate():
    """Its threshold (1.2 px a frame) and memory (0.4 a frame) are set at 25 fps: a subject moving
    30 px a second is as hot at 50 fps (0.6 px a frame) and its heat fades as fast in seconds."""
    from rvr_addon.laaf.detectors.action import ActionDetector
    from rvr_addon.laaf.detectors.base import AnalysisFrame

    def heats(fps: float, px_per_frame: float, frames: int) -> list[float]:
        det = ActionDetector()
        gray = np.zeros((18, 32), np.uint8)
        out = []
        for t in range(frames):
            res = np.full((18, 32), px_per_frame if t == 0 else 0.0, np.float32)
            det.ingest(t, AnalysisFrame(t, np.zeros((18, 32, 3), np.uint8), gray, None, 1.0, fps), (res, False))
            out.append(float(det.output(t).heat.max()))
        return out

    h25, h50 = heats(25.0, 1.2, 3), heats(50.0, 0.6, 5)
    assert h25[0] == pytest.approx(0.5) and h50[0] == pytest.approx(0.5)
    assert h50[2] == pytest.approx(h25[1], rel=1e-5) and h50[4] == pytest.approx(h25[2], rel=1e-5)  # 40, 80 ms on


@pytest.mark.parametrize("causal", [False, True])
def test_a_young_target_read_on_a_depth_glitch_takes_the_level_its_next_frames_agree_on(causal):
    """A speaker's target read at -7 on its first frame (a frame where the depth map lost him), then
    at -3 on every frame after: each later reading jumps by more than max_jump and is refused as a
    slip of the box, until REANCHOR_FRAMES of them agree; then the target takes -3 (look-ahead: from
    its first frame on, so the pull lands there; causal: from the run on). A target tracked longer
    keeps refusing such jumps (its box sliding onto the background)."""
    from rvr_addon.laaf.lookahead import REANCHOR_FRAMES, AutofocusJob, TargetState

    job = object.__new__(AutofocusJob)
    job.reanchor_frames, job.max_jump, job.causal = REANCHOR_FRAMES, 0.5, causal
    tg = TargetState(None, np.full(40, np.nan, np.float32), (0, 0, 10, 10), first_read=10)
    tg.level[10] = -7.0
    for k in range(11, 11 + REANCHOR_FRAMES):
        tg.jumped.append((k, -3.0 + 0.05 * (k % 2)))
        job._reanchor(tg)
    assert not tg.jumped and tg.events[-1]["status"] == "reanchor"
    last = 10 + REANCHOR_FRAMES
    assert tg.level[last] == pytest.approx(-3.0, abs=0.06)
    if causal:  # the frames before the one it decided on are not changed
        assert tg.level[10] == -7.0 and np.isnan(tg.level[11:last]).all()
    else:
        assert np.allclose(tg.level[10:last + 1], -3.0, atol=0.06)
    old = TargetState(None, np.full(80, np.nan, np.float32), (0, 0, 10, 10), first_read=10)
    old.level[10:50] = -7.0
    for k in range(50, 50 + REANCHOR_FRAMES):
        old.jumped.append((k, -3.0))
        job._reanchor(old)
    assert len(old.jumped) == REANCHOR_FRAMES and np.isnan(old.level[50:]).all()  # still refused


def test_a_change_of_speaker_the_chain_takes_back_withdraws_its_target():
    """The speech chain named the presenter at frame 380 (a pull there), then, with more of the
    evidence, the guest again from 381: instead of a pull to the presenter and straight back, the
    presenter's target is withdrawn and the guest's resumes. A change to a third face, or one more
    than a pull after the target, is a new target as before; causal mode never withdraws."""
    from types import SimpleNamespace

    from rvr_addon.laaf.combine import Step
    from rvr_addon.laaf.lookahead import AutofocusJob, TargetState
    from rvr_addon.laaf.nft import NFT

    def target(t, subject):
        tg = TargetState(NFT(0.0, 0.0, t, (0, 0, 10, 10), "speech", known_at=t - 20, subject=subject),
                         np.full(500, np.nan, np.float32), (0, 0, 10, 10), first_read=t)
        tg.tracker = SimpleNamespace(state=SimpleNamespace(frame=400))  # tracked up to the newest frame
        return tg

    def job(causal=False):
        j = object.__new__(AutofocusJob)
        j.causal, j.cuts, j.pull, j.detectors = causal, [], SimpleNamespace(pull_frames=10), {}
        j.targets = [target(48, "face1"), target(380, "face0")]
        j.targets[0].active = False  # retired when the presenter's target came
        return j

    j = job()
    guest = j.targets[0]
    assert j._withdraw_taken_back(Step(381, 1.0, 3.0, speaker="face1", region_frame=390), ingest=400)
    assert j.targets == [guest] and guest.active and guest.events[-1]["status"] == "resumed"
    for step, causal in ((Step(381, 1.0, 3.0, speaker="face2"), False),  # a third face: a change of speaker
                         (Step(395, 1.0, 3.0, speaker="face1"), False),  # more than a pull after it: a turn back
                         (Step(381, 1.0, 3.0, speaker="face1"), True)):
        j = job(causal)
        assert not j._withdraw_taken_back(step, ingest=400) and len(j.targets) == 2
