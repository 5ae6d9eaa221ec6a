"""Face-free speaker localisation by audio-visual synchrony (speech detector without faces)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from laaf_synth import talking_blobs
from rvr_addon.laaf.audio import AudioTrack
from rvr_addon.laaf.combine import intersect
from rvr_addon.laaf.detectors.base import AnalysisFrame, DetectorOutput
from rvr_addon.laaf.detectors.speech import SpeechDetector
from rvr_addon.laaf.detectors.synchrony import pearson_map

FPS = 25.0
TURNS = ((8, 27, 0), (36, 55, 1))


class NoFaces:
    """A face detector that never finds a face (the speaker must be found without one)."""

    def faces_at(self, t):
        return []

    def seen_before(self, t, frames):
        return False


@pytest.fixture(scope="module")
def blobs():
    return talking_blobs(turns=TURNS, fps=FPS)


def _run(frames, env, voiced, causal):
    audio = AudioTrack(voiced, env, voiced.astype(np.float32), FPS)
    det = SpeechDetector(NoFaces(), FPS, len(frames), audio=audio, causal=causal)
    for t, f in enumerate(frames):
        det.process(t, AnalysisFrame(t, f, cv2.cvtColor(f, cv2.COLOR_RGB2GRAY), None, 1.0, FPS))
    det.flush()
    return det


def _hits(det, centres, a, b, who):
    hits = 0
    for t in range(a, b + 1):
        box, _, tid = det.decide(t)
        if box is None:
            continue
        assert tid is None  # no face track involved
        cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
        hits += np.hypot(cx - centres[t][who][0], cy - centres[t][who][1]) <= 20
    return hits


@pytest.mark.parametrize("causal", [False, True], ids=["lookahead", "causal"])
def test_synchrony_finds_the_speaking_blob_in_each_turn_without_faces(blobs, causal):
    frames, env, voiced, centres = blobs
    det = _run(frames, env, voiced, causal)
    for a, b, who in TURNS:
        lo = a + (8 if causal else 0)  # causal: the evidence has to build up first
        assert _hits(det, centres, lo, b, who) >= 0.9 * (b - lo + 1), f"turn {a}-{b} of speaker {who}"
    assert all(det.decide(t)[0] is None for t in (3, 31, 60))  # silence: nobody is localised
    out = det.output(20)
    assert out.heat is not None and out.heat.shape == frames[0].shape[:2] and out.heat.max() == 1.0
    assert det.metrics()["synchrony_frames"] >= 1


def test_sound_that_no_mouth_follows_localises_nobody(blobs):
    frames, env, voiced, _ = blobs
    rng = np.random.default_rng(1)
    other = np.zeros_like(env)
    other[voiced] = rng.uniform(0.2, 1.0, int(voiced.sum()))  # an off-screen voice
    still = [frames[0]] * len(frames)  # nobody moves at all
    det = _run(still, other, voiced, causal=False)
    assert all(det.decide(t)[0] is None for t in range(len(frames)))


def test_synchrony_can_be_switched_off(blobs):
    frames, env, voiced, _ = blobs
    audio = AudioTrack(voiced, env, voiced.astype(np.float32), FPS)
    det = SpeechDetector(NoFaces(), FPS, len(frames), audio=audio, sync=False)
    for t, f in enumerate(frames[:30]):
        det.process(t, AnalysisFrame(t, f, cv2.cvtColor(f, cv2.COLOR_RGB2GRAY), None, 1.0, FPS))
    det.flush()
    assert det.decide(15)[0] is None


def test_no_audio_track_keeps_the_synchrony_off(clip_silent):
    det = SpeechDetector(NoFaces(), 24.0, 12, media=clip_silent)
    f = np.zeros((48, 64, 3), np.uint8)
    for t in range(3):
        det.process(t, AnalysisFrame(t, f, f[..., 0], None, 1.0, 24.0))
    assert det.available is False and det.output(1).available is False
    assert det.metrics()["synchrony_frames"] == 0


def test_pearson_map_matches_numpy():
    rng = np.random.default_rng(0)
    s, f = rng.normal(size=(20, 3, 4)), rng.normal(size=20)
    ref = np.array([[np.corrcoef(s[:, i, j], f)[0, 1] for j in range(4)] for i in range(3)])
    assert np.allclose(pearson_map(s, f), ref, atol=1e-5)
    assert not pearson_map(np.ones((5, 2, 2)), np.arange(5.0)).any()  # flat cells: 0


def test_speech_region_is_used_alone_when_no_face_is_found():
    shape = (90, 160)
    heat = np.zeros(shape, np.float32)
    heat[20:40, 30:50] = 1.0
    mask, used = intersect({"speech": DetectorOutput(heat), "face": DetectorOutput(None)}, primary="speech",
                           min_area=0.01)
    assert used == ("speech",) and mask.sum() == 400
    mask, _ = intersect({"speech": DetectorOutput(None), "face": DetectorOutput(heat)}, primary="speech")
    assert mask is None  # nobody speaks: nothing, as before
