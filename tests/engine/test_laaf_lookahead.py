"""LAAF end to end on synthetic clips: look-ahead vs causal, manual NFTs, the focus file and
``rvr render --track``, bad input (no audio, no faces), and ``rvr eval-focus`` metrics."""
from __future__ import annotations

import json
import logging

import cv2
import numpy as np
import pytest

from laaf_synth import entering_square, write_clip
from rvr_addon.cli import main as rvr_main
from rvr_addon.errors import InputError
from rvr_addon.io.track import load_track, resolve_track
from rvr_addon.laaf.evaluate import ground_truth, match_nfts
from rvr_addon.laaf.focusfile import write_focus_file
from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings
from rvr_addon.laaf.nft import NFT
from rvr_addon.laaf.puller import PullSettings

ENTER = 20


@pytest.fixture(scope="module")
def square_clip(tmp_path_factory):
    frames, maps, boxes = entering_square(n=40, enter=ENTER)
    fdir, ddir = write_clip(tmp_path_factory.mktemp("square"), frames, maps)
    return fdir, ddir, boxes


@pytest.fixture(scope="module")
def runs(square_clip):
    fdir, ddir, _ = square_clip
    out = {}
    for causal in (False, True):
        out[causal] = AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="action", causal=causal,
                                                     fps=24)).run(progress=False)
    return out


def test_lookahead_pull_lands_before_the_subject_enters(runs):
    r = runs[False]
    assert r.focus[0] == pytest.approx(3.0, abs=0.1)  # the background before anything happens
    acts = [n for n in r.nfts[1:] if n.source == "action"]
    # the square is found once enough of it moves inside the border band (the flow there is unreliable)
    assert acts and 0 <= acts[0].act_at - ENTER <= 8
    lead = r.settings["lead_frames"]
    assert r.focus[acts[0].t - lead] == pytest.approx(0.0, abs=0.05)  # arrived lead frames early
    assert r.focus[acts[0].t - lead - 1] > 0.05
    assert r.focus[-1] == pytest.approx(0.0, abs=0.3)


def test_causal_mode_is_late_and_lookahead_is_not(runs):
    la, ca = runs[False], runs[True]
    t_la = [n.act_at for n in la.nfts[1:]][0]
    t_ca = [n.act_at for n in ca.nfts[1:]][0]
    assert t_ca > t_la
    assert ca.nfts[1].known_at > ca.nfts[1].t - 1 and la.nfts[1].known_at < la.nfts[1].t
    # at the NFT the causal focus is still on the background; look-ahead is on the subject
    t = la.nfts[1].t
    assert abs(float(ca.focus[t]) - 0.0) > 2.0 > 0.05 > abs(float(la.focus[t]) - 0.0)
    arrived = [int(np.argmax(np.abs(r.focus) <= 0.05)) for r in (la, ca)]
    assert arrived[0] <= t - la.settings["lead_frames"] and arrived[1] >= t + la.settings["pull_frames"]


def test_at_twice_the_frame_rate_the_pull_takes_as_long_in_seconds(tmp_path):
    frames, maps, _ = entering_square(n=80, enter=50)
    fdir, ddir = write_clip(tmp_path, frames, maps)
    runs = {fps: AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="action", fps=fps)).run(progress=False)
            for fps in (24, 48)}
    assert [(r.settings["pull_frames"], r.settings["lead_frames"], r.settings["hold_frames"])
            for r in runs.values()] == [(10, 5, 12), (19, 10, 23)]
    for fps, (pull, lead) in ((24, (10, 5)), (48, (19, 10))):
        r = runs[fps]
        p = r.composed.pulls[0]
        assert (p.start, p.end) == (r.nfts[1].t - lead - pull, r.nfts[1].t - lead), p
        assert r.focus[p.end] == pytest.approx(0.0, abs=0.05) and r.focus[p.start] == pytest.approx(3.0, abs=0.05)
    faces = [AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="faces", fps=fps)).detectors["face"].every
             for fps in (24, 48)]
    assert faces == [6, 12]  # the face detector's stride: 0.24 s


def test_keys_reproduce_and_render_reads_the_focus_file(runs, square_clip, tmp_path):
    fdir, ddir, _ = square_clip
    r = runs[False]
    path = write_focus_file(tmp_path / "focus.json", r)
    doc = json.loads(path.read_text())
    assert doc["interpolation"] == "LINEAR" and doc["nfts"][0]["t"] == 0
    f, _ = resolve_track(load_track(path), len(r.focus))
    np.testing.assert_allclose(f, r.focus, atol=1e-4)
    keys_only = dict(doc)
    del keys_only["per_frame"]
    (tmp_path / "keys.json").write_text(json.dumps(keys_only))
    f2, _ = resolve_track(load_track(tmp_path / "keys.json"), len(r.focus))
    assert np.max(np.abs(f2 - r.focus)) <= 0.05
    out = tmp_path / "out"
    assert rvr_main(["render", str(fdir), "--depth", str(ddir), "--track", str(path), "-o", str(out), "-q"]) == 0
    assert len(list(out.glob("*.png"))) == 40


def test_manual_nfts_are_tracked_and_pulled_on_time(square_clip, tmp_path):
    fdir, ddir, boxes = square_clip
    targets = tmp_path / "nfts.json"
    targets.write_text(json.dumps([{"t": 30, "box": list(boxes[30])}, {"t": 0, "box": [4, 4, 30, 30]}]))
    job = AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset=None, targets=targets, fps=24,
                                         pull=PullSettings(pull_frames=8, lead_frames=4)))
    r = job.run(progress=False)
    assert [n.t for n in r.nfts] == [0, 30]  # sorted
    assert r.focus[0] == pytest.approx(3.0, abs=0.05)
    assert r.focus[26] == pytest.approx(0.0, abs=0.05) and r.focus[25] > 0.05  # lands at 30 - 4
    assert r.focus[18] == pytest.approx(3.0, abs=0.05)  # starts at 30 - 4 - 8


def test_nft_outside_the_clip_is_an_error(square_clip, tmp_path):
    fdir, ddir, _ = square_clip
    targets = tmp_path / "late.json"
    targets.write_text(json.dumps([{"t": 99, "x": 10, "y": 10}]))
    with pytest.raises(InputError, match=r"frame 99 is outside the clip \(frames 0..39\)"):
        AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset=None, targets=targets))
    assert rvr_main(["autofocus", str(fdir), "--depth", str(ddir), "--targets", str(targets), "-o",
                     str(tmp_path / "f.json"), "-q"]) == 2


def test_no_audio_speech_says_so_and_conversation_falls_back(clip_silent, tmp_path, caplog):
    depth = tmp_path / "d.npy"
    np.save(depth, np.linspace(0, 2, 64 * 48, dtype=np.float32).reshape(48, 64))
    with caplog.at_level(logging.WARNING):
        r = AutofocusJob(AutofocusSettings(input=clip_silent, depth=depth, preset="conversation")).run(progress=False)
    assert "no audio" in caplog.text
    assert r.settings["preset_used"] == "faces" and "fell back" in r.settings["fallback"]
    assert r.detectors["speech"]["available"] is False
    assert len(r.focus) == 12 and np.isfinite(r.focus).all()


def test_no_faces_still_gives_a_track(square_clip, caplog):
    fdir, ddir, _ = square_clip
    with caplog.at_level(logging.WARNING):
        r = AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="faces", stop=12)).run(progress=False)
    assert "no face was found" in caplog.text
    assert r.nfts[0].source in ("saliency", "initial") and np.isfinite(r.focus).all()


def test_cli_autofocus_writes_focus_file_and_plot(square_clip, tmp_path, capsys):
    fdir, ddir, _ = square_clip
    out = tmp_path / "focus.json"
    code = rvr_main(["autofocus", str(fdir), "--depth", str(ddir), "--preset", "action", "--fps", "24",
                     "--stop", "30", "-o", str(out), "--plot", str(tmp_path / "focus.png"), "-q"])
    assert code == 0 and out.is_file() and (tmp_path / "focus.png").is_file()
    assert "NFTs at" in capsys.readouterr().out


# ------------------------------------------------------------------------------------------ evaluation

def fake_manifest(n=30):
    per = lambda d: [{"disparity": d + 0.01 * k} for k in range(n)]  # noqa: E731
    return {"config": {"frames": n, "fps": 24, "script": "conversation"}, "scene": {"main": "ana"},
            "subjects": {"ana": {"per_frame": per(0.0)}, "ben": {"per_frame": per(2.0)}},
            "events": [{"index": 3, "subject": "ana", "type": "speech_start"},
                       {"index": 20, "subject": "ben", "type": "speech_start"}]}


def test_ground_truth_track_skips_events_on_the_subject_in_focus():
    gt = ground_truth(fake_manifest(), PullSettings(pull_frames=10, lead_frames=5))
    assert gt.nfts == [(20, "ben")]
    assert gt.focus[0] == pytest.approx(0.0) and gt.focus[15] == pytest.approx(2.15)
    assert gt.focus[5] == pytest.approx(0.05)


def test_nft_matching_is_one_to_one_with_misses_and_false_targets():
    dt, misses, false = match_nfts([19, 21, 40], [20, 30], max_dt=5)
    assert sorted(dt) == [1.0, 5.0] and misses == 1 and false == 2
