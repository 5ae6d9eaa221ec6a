"""LAAF speech detector: who speaks (audio-visual synchrony), voice activity on a real clip."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from laaf_synth import face_image
from rvr_addon.laaf.audio import AudioTrack, NoAudio, analyse_audio, decode_audio
from rvr_addon.laaf.detectors.base import AnalysisFrame
from rvr_addon.laaf.detectors.face import FaceDetector
from rvr_addon.laaf.detectors.speech import SpeechDetector

LIPNET = Path(__file__).resolve().parents[3] / "shared" / "data" / "clips" / "lipnet_grid_lwbsza.mpg"


class FixedFaces(FaceDetector):
    """A face detector stub with known face tracks (the drawn faces are not dlib's business)."""

    def __init__(self, boxes):
        self.boxes = boxes

    def faces_at(self, t):
        return [(b, 1.0, tid) for tid, b in self.boxes.items()]


def two_face_clip(n=60, fps=25.0, speaker="A", seed=0):
    """Frames of two drawn faces; the audio envelope drives the speaker's mouth, the other
    mouth moves with an independent pattern (a listener who chews)."""
    rng = np.random.default_rng(seed)
    syll = np.abs(np.sin(np.arange(n) * 2 * np.pi * 4.3 / fps + rng.uniform(0, 6)))
    env = syll * (rng.uniform(0.5, 1.0, n))
    env[:8] = 0.0
    other = np.abs(np.sin(np.arange(n) * 2 * np.pi * 1.7 / fps + 1.0)) * rng.uniform(0.3, 1.0, n)
    faces = {"A": (50, 60, 22), "B": (150, 60, 22)}
    frames = []
    for k in range(n):
        mouths = {"A": env[k] if speaker == "A" else other[k], "B": env[k] if speaker == "B" else other[k]}
        frames.append(face_image(120, 200, [(x, y, r, mouths[name]) for name, (x, y, r) in faces.items()]))
    boxes = {name: (float(x - r), float(y - r), 2.0 * r, 2.0 * r) for name, (x, y, r) in faces.items()}
    voiced = env > 0.05
    voiced[8:] = True
    return frames, AudioTrack(voiced, env.astype(np.float32), voiced.astype(np.float32), fps), boxes


@pytest.mark.parametrize("speaker", ["A", "B"])
@pytest.mark.parametrize("causal", [False, True], ids=["lookahead", "causal"])
def test_the_face_whose_mouth_follows_the_voice_is_the_speaker(speaker, causal):
    frames, audio, boxes = two_face_clip(speaker=speaker)
    det = SpeechDetector(FixedFaces(boxes), 25.0, len(frames), audio=audio, causal=causal)
    for t, f in enumerate(frames):
        det.process(t, AnalysisFrame(t, f, cv2.cvtColor(f, cv2.COLOR_RGB2GRAY), None, 1.0, 25.0))
    det.flush()
    decided = [det.decide(t)[2] for t in range(20, 60)]
    assert decided.count(speaker) >= 0.9 * len(decided)
    assert det.decide(3)[0] is None  # silence: nobody speaks
    out = det.output(30)
    assert out.heat is not None and out.boxes[0][2] == speaker


def test_no_audio_track_is_reported(clip_silent):
    with pytest.raises(NoAudio, match="silent.mp4"):
        decode_audio(clip_silent)
    det = SpeechDetector(FixedFaces({}), 24.0, 12, media=clip_silent)
    assert det.available is False and "no audio" in det.unavailable_reason
    assert det.output(0).available is False


@pytest.mark.skipif(not LIPNET.is_file(), reason="../shared/data/clips/lipnet_grid_lwbsza.mpg is not here")
def test_voice_activity_on_a_real_clip_finds_the_sentence():
    fps = 25.0
    samples = decode_audio(LIPNET)
    track = analyse_audio(samples, fps, 75)
    segs = track.segments()
    assert segs, "no speech found"
    start, end = segs[0][0] / fps, segs[-1][1] / fps
    assert abs(start - 0.7) <= 0.25 and abs(end - 2.4) <= 0.3  # speech about 0.7-2.4 s
    voiced_s = track.voiced.sum() / fps
    assert 1.0 <= voiced_s <= 2.0


def test_the_speech_cues_are_the_same_seconds_at_any_frame_rate():
    """A frame's envelope is the RMS of at least 40 ms centred on it (at 25 fps its own span, as
    before; at 50 fps not its 20 ms alone, whose noise weakened the speaker's 1 s correlation), and
    the chain's change costs count frames at 25 fps: a 50 fps clip pays twice the frames, so a
    change of speaker takes the same seconds of evidence."""
    from rvr_addon.laaf.audio import ENVELOPE_MIN_S, SAMPLE_RATE
    from rvr_addon.laaf.detectors.speech import COST_REFERENCE_FPS

    rng = np.random.default_rng(4)
    samples = (rng.standard_normal(SAMPLE_RATE * 2) * np.repeat(rng.uniform(0.01, 0.5, 100), SAMPLE_RATE // 50)
               ).astype(np.float32)
    at25, at50 = analyse_audio(samples, 25.0, 50), analyse_audio(samples, 50.0, 100)
    for k in (3, 20, 40):  # 25 fps: the frame's own 40 ms, exactly as before
        seg = samples[k * 640:(k + 1) * 640]
        assert at25.envelope[k] == pytest.approx(float(np.sqrt(np.mean(seg * seg))), rel=1e-5)
    for k in (7, 40, 81):  # 50 fps: 40 ms centred on the frame's 20 ms
        c = int((k + 0.5) / 50 * SAMPLE_RATE)
        seg = samples[c - int(ENVELOPE_MIN_S / 2 * SAMPLE_RATE):c + int(ENVELOPE_MIN_S / 2 * SAMPLE_RATE)]
        assert at50.envelope[k] == pytest.approx(float(np.sqrt(np.mean(seg * seg))), rel=1e-5)
    assert COST_REFERENCE_FPS == 25.0
    a = SpeechDetector(None, 25.0, 10, audio=at25, sync=False, mouth="motion")
    b = SpeechDetector(None, 50.0, 10, audio=at50, sync=False, mouth="motion")
    assert (b.switch_cost, b.pause_cost) == pytest.approx((2 * a.switch_cost, 2 * a.pause_cost))
    assert (a.switch_cost, a.pause_cost) == pytest.approx((8.0, 2.5))  # the defaults, at 25 fps unchanged
    from rvr_addon.laaf.detectors.speech import motion_smooth_frames

    assert [motion_smooth_frames(f) for f in (24, 25, 30, 50, 60, 0)] == [3, 3, 5, 7, 7, 3]
