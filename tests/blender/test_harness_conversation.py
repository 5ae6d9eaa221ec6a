"""The "conversation" script: espeak-ng speech, turns timed from the audio, mouths driven by each
speaker's envelope, the speech muxed into input.mp4, and speech_start events."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if shutil.which("espeak-ng") is None:
    pytest.skip("espeak-ng is not installed (scripts/setup.sh installs it with apt-get as root); the "
                "conversation script needs it for its speech track", allow_module_level=True)

from rvr_addon.io.video import probe_clip  # noqa: E402
from sintel_eval.dataset import GenerateConfig, generate  # noqa: E402
from sintel_eval.speech import SAMPLE_RATE, read_wav, voice_activity  # noqa: E402

FRAMES = 48


@pytest.fixture(scope="module")
def talk(tmp_path_factory):
    out = tmp_path_factory.mktemp("talk") / "conversation"
    cfg = GenerateConfig(seed=4, frames=FRAMES, width=48, height=27, script="conversation", samples=1,
                         dof_samples=1, train_every=0)
    generate(out, cfg, progress=False)
    return out, json.loads((out / "manifest.json").read_text())


def test_speech_track_is_muxed_and_timed(talk, stream_info):
    out, manifest = talk
    mix, rate = read_wav(out / "audio" / "speech.wav")
    assert rate == SAMPLE_RATE and len(mix) == FRAMES * SAMPLE_RATE // 24
    assert np.abs(mix).max() > 0.3  # real speech, not silence
    info = probe_clip(out / "input.mp4")
    assert info.has_audio and info.frame_count == FRAMES
    assert "Audio:" in stream_info(out / "input.mp4") and "aac" in stream_info(out / "input.mp4")
    speech = manifest["speech"]
    assert speech["tool"] == "espeak-ng" and len(set(speech["voices"].values())) == len(speech["voices"]) >= 2


def test_turns_alternate_and_mouths_follow_the_audio(talk):
    out, manifest = talk
    turns = manifest["speech"]["turns"]
    assert len(turns) >= 2
    speakers = [t["speaker"] for t in turns]
    assert all(a != b for a, b in zip(speakers, speakers[1:])), speakers
    for a, b in zip(turns, turns[1:]):
        assert a["end_s"] <= b["start_s"]  # no overlap: a turn ends before the next starts
    for t in turns:
        # The turn is where that speaker's own track is voiced (timed from the audio).
        track, _ = read_wav(out / "audio" / f"{t['speaker']}.wav")
        seg = voice_activity(track)
        assert any(abs(s - t["start_s"]) < 0.03 and abs(e - t["end_s"]) < 0.03 for s, e in seg)
        mouth = np.array(manifest["subjects"][t["speaker"]]["mouth_open"])
        inside = mouth[t["start_frame"] - 1:t["end_frame"]]
        assert inside.max() > 0.8  # opens while speaking
        others = [u for u in turns if u["speaker"] != t["speaker"]]
        for u in others:  # and is shut while the other one speaks
            assert mouth[u["start_frame"]:u["end_frame"] - 1].max() == 0.0


def test_speech_events_point_at_the_speaker(talk):
    out, manifest = talk
    events = [e for e in manifest["events"] if e["type"] == "speech_start"]
    turns = manifest["speech"]["turns"]
    assert [(e["frame"], e["subject"]) for e in events] == [(t["start_frame"], t["speaker"]) for t in turns]
    for e in events:
        x, y, w, h = e["box"]
        px, py = e["point"]
        assert x <= px <= x + w and y <= py <= y + h
        assert e["detail"]["text"]
    rack = manifest["focus_tracks"]["rack"]
    assert (rack["from"], rack["to"]) == (turns[0]["speaker"], turns[1]["speaker"])


def test_conversation_lens_and_camera_match_the_plan(talk):
    """The conversation's longer lens reaches Blender, and the bpy-free camera model that keeps
    strands and plants off the speakers (sintel_eval.framing) is Blender's camera."""
    from sintel_eval.scripts_events import CONVERSATION_FOCAL_MM, SCRIPT_VERSIONS, make_plan

    out, manifest = talk
    assert manifest["camera"]["focal_mm"] == CONVERSATION_FOCAL_MM
    assert manifest["script_version"] == SCRIPT_VERSIONS["conversation"]
    plan = make_plan(4, "conversation", FRAMES, 24)
    for cam in manifest["camera_per_frame"]:
        np.testing.assert_allclose(plan.camera.world_to_camera(cam["frame"]), np.array(cam["world_to_camera"]),
                                   atol=1e-5)
