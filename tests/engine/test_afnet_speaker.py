"""Preset ``learned`` takes an AF-Net NFT's region from the speaker where someone speaks
(``afnet_speaker``; issue 8).

AF-Net itself is scripted here (its interface, one NFT at the second turn whose map sits on
the wrong head): what is tested is what the engine does with it. The speech detector is the
real one, on a real MP4 with sound (``batch_synth.make_talking_clip``: two drawn heads whose
mouths open with their own turns, 8-27 the left one, 36-55 the right one; a depth ramp from
-2 on the left to 6 on the right)."""
from __future__ import annotations

import numpy as np
import pytest

from rvr_addon.laaf.combine import Region
from rvr_addon.laaf.detectors.base import DetectorOutput, FocusDetector

N, NFT_AT, PAN = 64, 36, 1.0
TURNS = ((8, 27, 0), (36, 55, 1))


def head_box(i: int, k: int, w: int = 200, h: int = 120) -> tuple[float, float, float, float]:
    """Box (x, y, w, h) of head i at frame k in ``laaf_synth.talking_blobs`` (n = N, pan 1 px/frame)."""
    cx = int(w * (0.28, 0.72)[i]) - round(PAN * k) + round(PAN * N / 2)
    return (cx - 15.0, h / 2 - 18.0, 30.0, 36.0)


def ramp_at(box) -> float:
    """The depth ramp's disparity under a box's centre."""
    return -2.0 + 8.0 * (box[0] + box[2] / 2) / 199.0


def _region(box, shape) -> Region:
    x, y, w, h = box
    mask = np.zeros(shape, bool)
    mask[int(y):int(y + h), int(x):int(x + w)] = True
    return Region(x + w / 2, y + h / 2, box, mask, float(mask.mean()), ("afnet",))


class ScriptedAFNet(FocusDetector):
    """AF-Net's detector interface with a fixed answer: its map is on head 0 in every frame and
    it proposes one NFT at frame ``at`` (NFT_AT: the right head starts to speak) with that map's region."""

    name = "afnet"
    lookahead_frames = 16
    at = NFT_AT

    def __init__(self, weights, n_frames, fps, threshold=None, min_gap=None, media=None, start_frame=0):
        self.shape = None
        self.pushed = 0
        self.proposed = False

    def process(self, t, frame):
        self.shape = frame.gray.shape
        self.pushed = t + 1

    def output(self, t):
        heat = np.zeros(self.shape, np.float32)
        x, y, w, h = (int(v) for v in head_box(0, t))
        heat[y:y + h, x:x + w] = 1.0
        return DetectorOutput(heat)

    def take_nfts(self):
        if self.proposed or self.pushed < min(self.at + self.lookahead_frames, N):
            return []
        self.proposed = True
        return [(self.at, self.at + 2, 0.9, _region(head_box(0, self.at + 2), self.shape))]


@pytest.fixture()
def talking(tmp_path, monkeypatch):
    from batch_synth import make_talking_clip
    from rvr_addon.laaf.detectors import afnet, face, speech

    clip, depth, audio = make_talking_clip(tmp_path, frames=N, turns=TURNS)
    monkeypatch.setattr(face.FaceBackend, "detect", lambda self, gray: [])  # drawn heads: synchrony finds them
    monkeypatch.setattr(speech, "analyse_audio", lambda samples, fps, n, **kw: audio)
    monkeypatch.setattr(afnet, "AFNetDetector", ScriptedAFNet)
    return clip, depth


def _run(clip, depth, speaker: bool):
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    return AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset="learned", face_backend="haar",
                                          afnet_speaker=speaker)).run(progress=False)


def test_the_nft_focuses_the_speaker_the_speech_detector_localises(talking):
    result = _run(*talking, speaker=True)
    assert result.detectors["speech"]["available"]
    assert [n.t for n in result.nfts] == [0, NFT_AT]
    nft = result.nfts[1]
    assert nft.source == "afnet_speech" and nft.subject is None  # no face track: synchrony found it
    frame = nft.detail["region_frame"]
    assert NFT_AT <= frame <= NFT_AT + 10 and nft.detail["speech_corr"] >= 0.3  # synchrony's own bar
    assert nft.detail["voice_turn"][0] == pytest.approx(TURNS[1][0], abs=2)  # the right head's turn
    right = head_box(1, frame)
    cx, cy = nft.box[0] + nft.box[2] / 2, nft.box[1] + nft.box[3] / 2
    assert abs(cx - (right[0] + 15)) <= 20 and abs(cy - (right[1] + 18)) <= 20
    assert result.focus[0] == pytest.approx(ramp_at(head_box(0, 0)), abs=0.5)  # the map's head first
    assert result.focus[-1] == pytest.approx(ramp_at(head_box(1, N - 1)), abs=0.5)  # then the speaker


def test_an_nft_far_from_a_voice_onset_keeps_the_map_region(talking, monkeypatch):
    monkeypatch.setattr(ScriptedAFNet, "at", 46)  # ten frames into the right head's turn
    result = _run(*talking, speaker=True)
    assert [(n.t, n.source) for n in result.nfts] == [(0, "afnet"), (46, "afnet")]


def test_map_only_keeps_the_map_region(talking):
    result = _run(*talking, speaker=False)
    assert "speech" not in result.detectors and "face" not in result.detectors
    assert [(n.t, n.source) for n in result.nfts] == [(0, "afnet"), (NFT_AT, "afnet")]
    head0 = np.array([ramp_at(head_box(0, k)) for k in range(N)])
    assert np.abs(result.focus - head0).max() <= 0.5  # head 0 all along, tracked as the camera pans


def test_measured_in_chunks_equals_one_pass(talking, tmp_path):
    """``rvr batch`` measures faces, mouths and synchrony in chunks (of 9 frames here) and decides
    in one job: the speaker's NFT comes out the same."""
    from batch_synth import chunked_laaf, laaf_outcome
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    settings = AutofocusSettings(input=talking[0], depth=talking[1], preset="learned", face_backend="haar")
    one = AutofocusJob(settings).run(progress=False)
    assert [n.source for n in one.nfts[1:]] == ["afnet_speech"]
    (tmp_path / "work").mkdir()
    chunked = chunked_laaf(settings, tmp_path / "work", N, 9)
    assert laaf_outcome(chunked) == laaf_outcome(one)
