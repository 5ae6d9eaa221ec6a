"""LAAF and shot cuts (issue 23): one shared detector, tracks and targets restart at a cut, no
pull crosses it, the focus jumps on the cut frame, the cut list is in the focus file and can
be given (``--cuts``) or switched off (``--no-cuts``)."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from laaf_synth import entering_square, texture, write_clip
from rvr_addon.cli import main as rvr_main
from rvr_addon.io.track import load_track
from rvr_addon.laaf.focusfile import write_focus_file
from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings
from rvr_addon.laaf.puller import PullSettings, PullTarget, compose_track
from rvr_addon.temporal.cuts import CutDetector, detect_cuts, parse_cuts

CUT = 40
CLIPS = Path(__file__).resolve().parents[3] / "shared" / "data" / "clips"


def second_shot(n: int = 40, size=(128, 72), enter: int = 15):
    """Another scene: a different texture, everything at disparity 5 until a square at
    disparity 2 slides in from the left at frame ``enter``."""
    w, h = size
    bg = (texture(h, w, 7) * 0.7 + 30).astype(np.uint8)
    obj = texture(20, 20, 8)
    frames, maps = [], []
    for k in range(n):
        f, d = bg.copy(), np.full((h, w), 5.0, np.float32)
        x0 = int(round(-20 + (k - enter + 1) * 3.0)) if k >= enter else -100
        x0 = min(x0, w // 2)
        if x0 > -20:
            xa, xb = max(x0, 0), x0 + 20
            f[10:30, xa:xb] = obj[:, xa - x0:]
            d[10:30, xa:xb] = 2.0
        frames.append(f)
        maps.append(d)
    return frames, maps


@pytest.fixture(scope="module")
def two_shots(tmp_path_factory):
    fa, ma, _ = entering_square(n=CUT, enter=12)
    fb, mb = second_shot()
    return write_clip(tmp_path_factory.mktemp("cut"), fa + fb, ma + mb)


def _run(clip, **kw):
    fdir, ddir = clip
    return AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="action", fps=24, **kw)).run(progress=False)


def _check_respects(r, cut: int) -> None:
    assert r.cuts == [cut]
    # focus jumps exactly on the cut frame, from the first shot's subject to the second shot's
    assert r.focus[cut - 1] == pytest.approx(0.0, abs=0.1)
    assert r.focus[cut] == pytest.approx(5.0, abs=0.1)
    assert np.allclose(r.focus[cut - 8:cut], r.focus[cut - 1], atol=0.05)  # nothing pulls toward shot 2 before
    for p in r.composed.pulls:
        assert not (p.start < cut < p.end), p  # no pull crosses the cut
        t = r.nfts[p.index].t
        if t >= cut:
            assert p.start >= cut - 1 and (p.start >= cut or r.nfts[p.index].t == cut)
    cut_nfts = [n for n in r.nfts if n.t == cut]
    assert len(cut_nfts) == 1 and cut_nfts[0].detail.get("cut")
    for n, boxes in zip(r.nfts, r.boxes):  # no box carried across the cut, either way
        frames = list(boxes)
        if n.t < cut:
            assert all(k < cut for k in frames)
        else:
            assert all(k >= cut for k in frames)
    # the second shot's own subject still gets its pull, after the cut
    later = [n for n in r.nfts if n.t > cut]
    assert later and r.focus[-1] == pytest.approx(2.0, abs=0.3)


@pytest.mark.parametrize("causal", [False, True])
def test_detected_cut_restarts_targets_and_is_never_pulled_across(two_shots, causal):
    r = _run(two_shots, causal=causal)
    _check_respects(r, CUT)
    assert r.settings["cuts"] == [CUT] and r.settings["cuts_source"] == "detected"


def test_given_cuts_and_no_cuts(two_shots):
    given = _run(two_shots, cuts=[CUT], detect_cuts=False)
    _check_respects(given, CUT)
    assert given.settings["cuts_source"] == "given"
    off = _run(two_shots, detect_cuts=False)
    assert off.cuts == [] and off.settings["cuts_source"] == "off"


def test_focus_file_holds_the_cuts_and_the_cli_takes_them(two_shots, tmp_path, capsys):
    fdir, ddir = two_shots
    out = tmp_path / "focus.json"
    assert rvr_main(["autofocus", str(fdir), "--depth", str(ddir), "--fps", "24", "--preset", "action",
                     "--cuts", str(CUT), "-o", str(out), "-q"]) == 0
    doc = json.loads(out.read_text())
    assert doc["cuts"] == [CUT] and doc["settings"]["cuts_source"] == "given"
    assert load_track(out) is not None  # the track reader still reads it
    # a focus file is itself a cut file
    assert parse_cuts(out) == [CUT]
    off = tmp_path / "off.json"
    assert rvr_main(["autofocus", str(fdir), "--depth", str(ddir), "--fps", "24", "--preset", "action",
                     "--no-cuts", "-o", str(off), "-q"]) == 0
    assert json.loads(off.read_text())["cuts"] == []


def test_parse_cuts(tmp_path):
    assert parse_cuts("80, 12") == [12, 80]
    (tmp_path / "c.txt").write_text("5\n9 9\n")
    assert parse_cuts(tmp_path / "c.txt") == [5, 9]
    (tmp_path / "c.json").write_text(json.dumps({"cuts": [3, 1]}))
    assert parse_cuts(tmp_path / "c.json") == [1, 3]
    for bad in ("a,2", "-1", "2.5", tmp_path / "missing.json"):
        with pytest.raises(ValueError):
            parse_cuts(bad)


def test_puller_never_crosses_a_cut():
    n = 60
    a = PullTarget(0, np.zeros(n))
    b = PullTarget(28, np.full(n, 2.0), known_at=25)  # late: its pull would end at 35, after the cut at 30
    d = PullTarget(30, np.full(n, 6.0), at_cut=True)
    e = PullTarget(34, np.full(n, 8.0))  # planned start 19: before its shot
    tr = compose_track([a, b, d, e], n, PullSettings(), cuts=[30])
    for p in tr.pulls:
        assert not (p.start < 30 < p.end)
    assert tr.pulls[0].end == 30 and "cut short" in tr.pulls[0].note
    assert (tr.pulls[1].start, tr.pulls[1].end) == (29, 30)
    assert tr.focus[29] != pytest.approx(6.0) and tr.focus[30] == pytest.approx(6.0)
    assert tr.pulls[-1].start >= 30 and tr.focus[-1] == pytest.approx(8.0)


def test_cut_detector_is_the_stabilizers():
    """The same flow-check test: a still scene has no cut, a different scene is one."""
    fa, _, _ = entering_square(n=10, enter=3)
    fb, _ = second_shot(n=6)
    assert detect_cuts(fa + fb) == [10]
    det = CutDetector()
    for f in fa:
        assert not det.push(f)
    assert det.push(cv2.resize(fb[0], (160, 90)))  # a size change is a cut too


@pytest.mark.skipif(not (CLIPS / "lipnet_grid_lwbsza.mpg").is_file() or not (CLIPS / "kivy_cityCC0.mpg").is_file(),
                    reason="needs ../shared/data/clips")
def test_real_shots_concatenated(tmp_path):
    """A talking head (GRID) cut to a street (kivy): one cut found on the cut frame; focus
    holds the first shot's depth up to the cut and is on the second's from the cut frame."""
    from rvr_addon.io.video import iter_frames

    frames, maps = [], []
    for name, n, level in (("lipnet_grid_lwbsza.mpg", 30, 1.0), ("kivy_cityCC0.mpg", 30, 4.0)):
        for k, f in enumerate(iter_frames(CLIPS / name)):
            if k >= n:
                break
            frames.append(cv2.resize(f, (320, 180), interpolation=cv2.INTER_AREA))
            maps.append(np.full((180, 320), level, np.float32))
    clip = write_clip(tmp_path, frames, maps)
    for preset in ("action", "faces"):
        r = AutofocusJob(AutofocusSettings(input=clip[0], depth=clip[1], preset=preset, fps=25)).run(progress=False)
        assert r.cuts == [30]
        assert np.allclose(r.focus[:30], 1.0, atol=0.05) and np.allclose(r.focus[30:], 4.0, atol=0.05)
        assert all(not (p.start < 30 < p.end) for p in r.composed.pulls)
        for n_, boxes in zip(r.nfts, r.boxes):
            assert all((k < 30) == (n_.t < 30) for k in boxes)
        out = write_focus_file(tmp_path / f"{preset}.json", r)
        assert json.loads(out.read_text())["cuts"] == [30]


def test_focus_file_says_per_frame_where_focus_is(two_shots, tmp_path):
    """focus_on: the governing target, its source, its box and the state of every frame, and the
    same as segments; the old reader still reads the file."""
    r = _run(two_shots)
    doc = json.loads(write_focus_file(tmp_path / "f.json", r).read_text())
    on = doc["focus_on"]
    n = len(r.focus)
    assert len(on["target"]) == len(on["source"]) == len(on["box"]) == len(on["state"]) == n
    assert on["state"][CUT] == "cut" and on["target"][CUT] == next(i for i, x in enumerate(r.nfts) if x.t == CUT)
    assert on["target"][CUT - 1] < on["target"][CUT]
    for k in range(n):
        i = on["target"][k]
        assert on["source"][k] == doc["nfts"][i]["source"]
        if on["box"][k] is not None:  # the box is the governing target's tracked box on that frame
            assert r.boxes[i][k][1]
    assert "pull" in on["state"] and "hold" in on["state"]
    segs = on["segments"]
    assert segs[0]["start"] == 0 and segs[-1]["stop"] == n
    assert all(a["stop"] == b["start"] for a, b in zip(segs, segs[1:]))
    assert any(s["state"] == "cut" and s["start"] == CUT for s in segs)
    track = load_track(tmp_path / "f.json")
    assert len(track.frames) == n


def _still_then_moving(n: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """n frames (128x72) of a textured 20 px object at disparity 2 on a background at 5, still for
    8 frames, then moving right 2 px a frame (what the detectors pick up only once it moves)."""
    w, h = 128, 72
    bg = (texture(h, w, 7) * 0.7 + 30).astype(np.uint8)
    obj = texture(20, 20, 8)
    frames, maps = [], []
    for k in range(n):
        x0 = 30 + max(0, k - 8) * 2
        f, d = bg.copy(), np.full((h, w), 5.0, np.float32)
        f[26:46, x0:x0 + 20] = obj
        d[26:46, x0:x0 + 20] = 2.0
        frames.append(f)
        maps.append(d)
    return frames, maps


def test_lookahead_focuses_the_new_shots_subject_on_the_cut(tmp_path):
    """A subject already in the new shot that the detectors only pick up a few frames later
    (it starts moving at cut + 8) is focused on the cut frame itself (look-ahead), not pulled
    to after it."""
    fa, ma, _ = entering_square(n=CUT, enter=12)
    fb, mb = _still_then_moving(40)
    clip = write_clip(tmp_path, fa + fb, ma + mb)
    la = _run(clip)
    assert la.cuts == [CUT] and la.focus[CUT - 1] == pytest.approx(0.0, abs=0.1)
    assert la.focus[CUT] == pytest.approx(2.0, abs=0.2)
    assert [n.t for n in la.nfts if n.t >= CUT] == [CUT]  # no pull after the cut: the cut found the subject
    assert all(not (p.start < CUT < p.end) for p in la.composed.pulls)


def test_a_cut_frame_is_measured_in_its_own_faces():
    """At a cut off a face-detection frame the analyser detects the new shot's faces afresh and
    measures nothing against the previous shot's frame (the speech detector's mouths were once
    measured in the previous shot's boxes while the face detector re-detected: a crash)."""
    from rvr_addon.laaf.analysis import FrameAnalyser
    from rvr_addon.laaf.detectors.base import AnalysisFrame

    old, new = (20.0, 20.0, 5.0, 5.0), (1.0, 1.0, 5.0, 5.0)

    class Face:
        measures = True

        def detect(self, frame):
            return [new] if frame.t >= 10 else [old]

        def measure(self, frame, prev, faces):
            return self.detect(frame) if frame.t % 6 == 0 else None

    class Speech:
        measures = True

        def measure(self, frame, prev, faces):
            return prev is not None, list(faces)

    analyser = FrameAnalyser({"face": Face(), "speech": Speech()}, ["face", "speech"])
    seen = {}
    for t in range(14):
        g = np.zeros((8, 8), np.uint8)
        features, _ = analyser.measure(AnalysisFrame(t, np.dstack([g] * 3), g, None, 1.0, 25.0), cut=t == 10)
        seen[t] = features["speech"]
    assert seen[9] == (True, [old]) and seen[10] == (False, [new]) and seen[11] == (True, [new])


def test_lookahead_focuses_the_first_subject_on_the_first_frame(tmp_path):
    """The clip's first frame starts a shot too: a subject there that the detectors pick up only
    a few frames later (it starts moving at frame 8) is the first focus itself in look-ahead
    mode (no pull to it at the start, no change of target); causal mode cannot see it coming."""
    frames, maps = _still_then_moving(40)
    clip = write_clip(tmp_path, frames, maps)
    la = _run(clip)
    assert la.focus[0] == pytest.approx(2.0, abs=0.2) and np.allclose(la.focus[:20], la.focus[0], atol=0.1)
    assert [n.t for n in la.nfts] == [0] and la.nfts[0].detail.get("start")
    assert not la.nfts[0].detail.get("cut")  # frame 0 is no cut
    causal = _run(clip, causal=True)
    assert "subject_from_frame" not in causal.nfts[0].detail  # no hindsight in causal mode


def test_the_first_speaker_keeps_the_first_focus_when_a_second_speaks_within_the_hold(tmp_path, monkeypatch):
    """Look-ahead replaces the clip's first focus by the first speaker (frames 4-17); the second
    speaker (frames 22-36), found within the minimum hold, is a pull after it, not a second
    replacement that would erase the first turn (it once was: focus on the second face from frame 0)."""
    from batch_synth import fake_faces, make_talking_clip
    from rvr_addon.laaf.detectors import face, speech

    clip, depth, audio = make_talking_clip(tmp_path)
    monkeypatch.setattr(face.FaceBackend, "detect", fake_faces)
    monkeypatch.setattr(speech, "analyse_audio", lambda samples, fps, n, **kw: audio)
    la = AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset="conversation",
                                        face_backend="haar")).run(progress=False)
    w = 200  # talking_blobs' frame width: head 0 left of the middle, head 1 right of it
    first, *rest = la.nfts
    assert first.t == 0 and first.detail.get("start") and first.detail.get("subject_from_frame") == 4
    assert first.x < w / 2 and la.focus[4] == pytest.approx(la.focus[0], abs=0.05)
    assert [n.t for n in rest] == [22] and rest[0].x > w / 2 and rest[0].source == "speech"


def test_a_first_speaker_named_within_the_look_ahead_replaces_the_first_guess(tmp_path, monkeypatch):
    """The clip's first focus names nobody (here the largest face, head 1): the first speaker, head 0,
    whose turn starts at frame 44 (1.8 s), later than the minimum hold (1 s) and than the frames the
    look-ahead buffer still holds, but within the look-ahead (2 s), is the first focus from frame 0
    (his face track is on every frame since: his level is held back to it), not a pull to him after
    1.2 s (the interview at half size began on the presenter and pulled to the guest at frame 36).
    Causal mode cannot see him coming: a pull."""
    from batch_synth import fake_faces, make_talking_clip
    from rvr_addon.laaf.detectors import face, speech

    clip, depth, audio = make_talking_clip(tmp_path, frames=100, turns=((44, 90, 0),), pan=0.0)
    monkeypatch.setattr(face.FaceBackend, "detect", fake_faces)
    monkeypatch.setattr(speech, "analyse_audio", lambda samples, fps, n, **kw: audio)
    w = 200  # talking_blobs' frame width: head 0 left of the middle
    runs = {causal: AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset="conversation", face_backend="haar",
                                                   causal=causal)).run(progress=False) for causal in (False, True)}
    la = runs[False]
    assert len(la.nfts) == 1
    first = la.nfts[0]
    assert first.t == 0 and first.detail.get("start") and first.detail.get("subject_from_frame") == 44
    assert first.x < w / 2 and first.source == "speech"
    assert np.allclose(la.focus[:100], la.focus[60], atol=0.05)  # on him from frame 0, no pull
    assert runs[True].nfts[0].x > w / 2 and [n.x < w / 2 for n in runs[True].nfts[1:]] == [True]


def test_the_first_speakers_level_is_held_back_over_a_reading_that_jumps(tmp_path, monkeypatch):
    """As above, with the first speaker named early (his turn at frame 14, within the hold) but his
    depth reading 1.5 units off on frames 0-3 (estimated depth on the real interview at its own
    size: the guest's reading jumped at frame 2): tracking him back stops at the jump, and the
    replacement used to fail there, so the clip began with a pull to him over its first frames. His
    face track is on every frame since the start, so his level is held back to frame 0."""
    from batch_synth import fake_faces, make_talking_clip
    from rvr_addon.laaf.detectors import face, speech

    clip, depth, audio = make_talking_clip(tmp_path, frames=60, turns=((14, 50, 0),), pan=0.0)
    ramp = np.load(depth)
    stack = np.repeat(ramp[None], 60, axis=0)
    h, w = ramp.shape
    stack[:4, :, : w // 2] += 1.5  # head 0's half reads 1.5 units further on the first frames
    np.save(depth, stack)
    monkeypatch.setattr(face.FaceBackend, "detect", fake_faces)
    monkeypatch.setattr(speech, "analyse_audio", lambda samples, fps, n, **kw: audio)
    la = AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset="conversation",
                                        face_backend="haar")).run(progress=False)
    first = la.nfts[0]
    assert len(la.nfts) == 1 and first.t == 0 and first.x < w / 2 and first.detail.get("subject_from_frame") == 14
    assert np.allclose(la.focus[:40], la.focus[20], atol=0.05)  # his level from frame 0: no pull
    assert any(e.get("status") == "held_back" for e in la.tracking)


def test_look_ahead_lands_every_change_of_speaker_before_the_voice_even_in_quick_turns(tmp_path, monkeypatch):
    """Three turns, the middle one (frames 36-52, 0.7 s) shorter than the minimum hold (1 s at the
    default calm): in look-ahead mode each change of speaker is a target at the new speaker's voice
    onset whose pull has landed before it (the speech chain's own cost of a change is its
    hysteresis; the hold once deferred the answer at frame 56 past its start, to frame 76). Causal
    mode starts its pulls only after the evidence, after the onsets."""
    from batch_synth import fake_faces, make_talking_clip
    from rvr_addon.laaf.detectors import face, speech

    turns = ((6, 30, 0), (36, 52, 1), (56, 90, 0))
    clip, depth, audio = make_talking_clip(tmp_path, frames=100, turns=turns, pan=0.0)
    monkeypatch.setattr(face.FaceBackend, "detect", fake_faces)
    monkeypatch.setattr(speech, "analyse_audio", lambda samples, fps, n, **kw: audio)
    w = 200  # talking_blobs' frame width: head 0 left of the middle, head 1 right of it

    def run(causal):
        return AutofocusJob(AutofocusSettings(input=clip, depth=depth, preset="conversation", face_backend="haar",
                                              causal=causal)).run(progress=False)

    la = run(False)
    first, *rest = la.nfts
    assert first.t == 0 and first.x < w / 2
    assert [n.x > w / 2 for n in rest] == [True, False]
    for nft, (onset, _, _) in zip(rest, turns[1:]):
        assert onset - 2 <= nft.t <= onset and nft.source == "speech"
    ends = [p.end for p in la.composed.pulls]
    assert len(ends) == 2 and all(end < onset for end, (onset, _, _) in zip(ends, turns[1:]))
    causal = run(True)
    starts = [p.start for p in causal.composed.pulls][-2:]  # (the first is to the first speaker: no hindsight)
    assert all(s > onset for s, (onset, _, _) in zip(starts, turns[1:]))
