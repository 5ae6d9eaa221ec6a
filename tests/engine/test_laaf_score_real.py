"""Real-clip scoring of LAAF (rvr_addon/laaf/score_real.py; ``rvr eval-focus --real``)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from batch_synth import N, make_clip, make_depth
from rvr_addon.cli import main
from rvr_addon.laaf.score_real import load_annotation, score_focus, turns_from_sides

ROOT = Path(__file__).resolve().parents[2]
INTERVIEW_ANN = ROOT / "tests" / "data" / "interview_speakers.json"
INTERVIEW = ROOT.parent / "shared" / "data" / "clips" / "visualvoice_interview.mp4"

L, R = [0, 0, 50, 100], [50, 0, 50, 100]
BL, BR, FAR = [10, 10, 20, 20], [60, 10, 20, 20], [200, 200, 10, 10]


def synthetic_doc() -> dict:
    """100 frames at 10 fps: t0 left 0-24, pull to t1 right 25-27, t1 28-57, t2 (nobody) 58-69,
    t3 right 70-84, pull to t4 left 85-86, t4 87-99."""
    runs = [(0, 25, 0, BL, "hold"), (25, 28, 1, BR, "pull"), (28, 58, 1, BR, "hold"), (58, 70, 2, FAR, "hold"),
            (70, 85, 3, BR, "hold"), (85, 87, 4, BL, "pull"), (87, 100, 4, BL, "hold")]
    target, box, state = [], [], []
    for a, b, t, bx, st in runs:
        for _ in range(a, b):
            target.append(t)
            box.append(list(bx))
            state.append(st)
    return {"focus_on": {"start": 0, "target": target, "box": box, "state": state,
                         "source": ["face"] * 100}, "cuts": []}


ANNOTATION = {"fps": 10.0, "cuts": [70, 86], "turns": [
    {"start_s": 0.0, "end_s": 2.0, "box": L},
    {"start_s": 3.0, "end_s": 3.8, "box": R},
    {"start_s": 4.2, "end_s": 4.9, "box": R},
    {"start_s": 8.0, "end_s": 9.0, "box": L}]}


def test_score_focus_known_answers():
    s = score_focus(synthetic_doc(), ANNOTATION)
    assert [t["changes_speaker"] for t in s["turns"]] == [False, True, False, True]
    assert [t["lead_frames"] for t in s["turns"]] == [None, -5, None, 5]  # pull to t1 at 25 (turn at 30); t4 at 85
    assert [t["lead_landed_frames"] for t in s["turns"]] == [None, -2, None, 7]  # landed at 28 and 87
    assert [t["on_frames"] for t in s["turns"]] == [20, 8, 7, 5]
    assert s["turns_changed"] == 2 and s["turns_led"] == 1 and s["turns_led_landed"] == 1 and s["turns_missed"] == 0
    assert s["lead_frames_mean"] == 0.0
    assert s["speaking_frames"] == 45 and s["speaking_share"] == round(40 / 45, 4)
    assert s["target_changes"] == 4  # 25, 58, 70, 85
    assert s["spurious_changes"] == [58]  # 25 and 85 are near turn starts, 70 is a cut
    assert s["spurious_per_min"] == 6.0  # 1 in 10 s
    assert s["cuts_annotated"] == 2 and s["pulls_across_cuts"] == 1  # the pull 85-86 crosses the cut at 86


def test_score_focus_missed_turn_and_no_cuts():
    doc = synthetic_doc()
    ann = {"fps": 10.0, "turns": [{"start_s": 0.0, "end_s": 1.0, "box": R}, {"start_s": 6.0, "end_s": 6.5, "box": [0, 50, 50, 50]}]}
    s = score_focus(doc, ann)  # frames 10-64 never on the lower left: missed
    assert s["turns"][1]["lead_frames"] is None and s["turns_missed"] == 1 and s["turns_led"] == 0
    assert s["lead_frames_mean"] is None and s["cuts_annotated"] == 0 and s["pulls_across_cuts"] == 0
    assert s["speaking_share"] == 0.0  # 0-9 on the left while R speaks, 60-64 on nobody


def test_interview_converter():
    raw = json.loads(INTERVIEW_ANN.read_text())
    ann = turns_from_sides(raw)
    assert ann["fps"] == 25.0 and len(ann["turns"]) == len(raw["stretches"]) == 6
    assert ann["turns"][0]["box"] == [0, 0, 640, 720] and ann["turns"][2]["box"] == [640, 0, 640, 720]
    assert ann["turns"][2]["start_s"] == 8.48 and ann["turns"][2]["speaker"] == "right"
    assert load_annotation(INTERVIEW_ANN)["turns"] == ann["turns"]
    # a focus document always on the right half: on the speaker in the right turns only
    n = 18 * 25
    doc = {"focus_on": {"start": 0, "target": [0] * n, "box": [[700, 100, 200, 200]] * n, "state": ["hold"] * n},
           "cuts": []}
    s = score_focus(doc, raw)
    assert s["turns_changed"] == 2 and s["turns_led"] == 1  # left->right already there; right->left never
    right = sum(round(t["end_s"] * 25) - round(t["start_s"] * 25) for t in ann["turns"] if t["speaker"] == "right")
    assert s["speaking_share"] == round(right / s["speaking_frames"], 4)
    with pytest.raises(ValueError):
        turns_from_sides({"fps": 25, "stretches": [{"speaker": "middle", "start_s": 0, "end_s": 1}]})


def test_cli_real_writes_summary(tmp_path, capsys):
    clip = make_clip(tmp_path / "clip.mp4")
    depth = make_depth(tmp_path / "d")
    ann = tmp_path / "ann.json"
    ann.write_text(json.dumps({"fps": 24.0, "turns": [{"start_s": 0.0, "end_s": N / 24.0, "box": [0, 0, 64, 36]}]}))
    out = tmp_path / "rep"
    assert main(["eval-focus", "--real", str(clip), "--annotations", str(ann), "--depth", str(depth),
                 "--preset", "action", "--causal-too", "-o", str(out), "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    for k in ("speaking_share", "turns_led", "spurious_per_min", "lead_frames_mean", "pulls_across_cuts"):
        assert f"focus.real.clip.action.{k}" in summary and f"focus.real.clip.action.causal.{k}" in summary
    assert 0.0 <= summary["focus.real.clip.action.speaking_share"] <= 1.0
    assert (out / "focus" / "clip.action.json").is_file() and (out / "focus" / "clip.action.causal.json").is_file()
    assert "action look-ahead" in capsys.readouterr().out


def test_cli_real_needs_depth_and_annotations(tmp_path):
    clip = make_clip(tmp_path / "clip.mp4")
    ann = tmp_path / "ann.json"
    ann.write_text(json.dumps({"fps": 24.0, "turns": [{"start_s": 0.0, "end_s": 0.2, "box": [0, 0, 64, 36]}]}))
    out = tmp_path / "rep"
    assert main(["eval-focus", "--real", str(clip), "--annotations", str(ann), "-o", str(out)]) == 2  # no depth
    assert main(["eval-focus", "--real", str(clip), "--depth", str(tmp_path), "-o", str(out)]) == 2  # no annotations
    assert main(["eval-focus", "-o", str(out)]) == 2  # neither DATASET nor --real
    assert not (out / "summary.json").exists()


@pytest.mark.skipif(not INTERVIEW.is_file(), reason="../shared/data/clips/visualvoice_interview.mp4 not here")
def test_interview_annotation_matches_clip():
    from rvr_addon.io.video import probe_clip

    info = probe_clip(INTERVIEW)
    ann = load_annotation(INTERVIEW_ANN)
    assert (info.width, info.height) == (1280, 720)
    assert abs(info.fps - ann["fps"]) < 0.01
    assert max(t["end_s"] for t in ann["turns"]) * ann["fps"] <= info.frame_count and info.has_audio


def test_offscreen_figures():
    """Off-screen speech: target changes inside the segment (but not within 1 s before the next
    turn) and the share of its frames whose focus left the panel it was on."""
    doc = synthetic_doc()  # t1 on the right 28-57, t2 far away (nobody) from 58, t3 right from 70
    ann = {"fps": 10.0, "panels": [{"box": L}, {"box": R}, {"box": [150, 150, 100, 100]}],
           "turns": [{"start_s": 3.0, "end_s": 4.0, "box": R}, {"start_s": 8.0, "end_s": 9.0, "box": L}],
           "offscreen": [{"start_s": 5.0, "end_s": 7.5}]}
    s = score_focus(doc, ann)
    # frames 50-74 (before 8.0 s - 1 s = frame 70): the change at 58 counts, the one at 70 does not
    assert s["offscreen_changes"] == 1
    assert s["offscreen_moved_share"] == round(12 / 20, 4)  # 58-69 on the far box, off the right panel
    assert score_focus(doc, {k: v for k, v in ann.items() if k != "offscreen"})["offscreen_changes"] is None


def test_shot_figures():
    """Edited clips (``shots``): per cut the frames until focus is on the new shot's subject, and
    off-screen frames judged against the subject of the shot each belongs to; the lead exception
    of an off-screen segment does not reach over a cut."""
    doc = synthetic_doc()  # left 0-24, right 25-57, far 58-69, right 70-84, pull left 85-86, left 87-99
    ann = {"fps": 10.0, "cuts": [58, 87],
           "shots": [{"first": 0, "box": L}, {"first": 58, "box": R}, {"first": 87, "box": L}],
           "turns": [{"start_s": 0.0, "end_s": 2.0, "box": L}, {"start_s": 8.0, "end_s": 9.0, "box": L}],
           "offscreen": [{"start_s": 5.0, "end_s": 7.5}]}
    s = score_focus(doc, ann)
    assert s["cut_lag_frames"] == [12, 0]  # the shot from 58 is on its subject (right) from 70; the one from 87 at once
    assert s["cuts_on_subject"] == 1 and s["cut_lag_frames_max"] == 12
    # frames 50-74: the turn at 80 is in another shot (cut 58 between): no lead exception; the changes at 58
    # and 70 count; home (frame 50, on the right while the shot's subject is left): no; 70-74 on the subject
    assert s["offscreen_changes"] == 2 and s["offscreen_moved_share"] == round(5 / 25, 4)
    assert score_focus(doc, {k: v for k, v in ann.items() if k != "shots"})["cuts_on_subject"] is None
