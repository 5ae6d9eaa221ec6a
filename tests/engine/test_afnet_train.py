"""``rvr train-afnet`` and AF-Net in the LAAF engine: a short run learns an obvious NFT (a bright
square appears), resume equals an uninterrupted run, preset ``learned`` in ``rvr autofocus`` and
``rvr eval-focus``, and a missing weights file (issue 8)."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from afnet_synth import one_thread  # noqa: F401 - autouse fixture
from afnet_synth import frames_of, tiny_config, write_annotated_dataset, write_harness_clip, write_sequence
from rvr_addon.afnet.infer import load_afnet, predict_clip
from rvr_addon.afnet.train import AFNetTrainer, AFNetTrainSettings
from rvr_addon.errors import InputError

ENTERS = [8, 11, 14, 17, 20, 23, None, 10]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("afnet")
    ann = write_annotated_dataset(root / "data", ENTERS, n=30)
    run = root / "run"
    trainer = AFNetTrainer(AFNetTrainSettings(run_dir=run, annotations=[ann], iterations=60, lr=3e-3, batch=8,
                                              checkpoint_every=30, model=tiny_config()))
    trainer.run(progress=False)
    return run, ann


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_short_run_reduces_the_loss_and_finds_the_new_focus_target(trained):
    run, _ = trained
    for name in ("afnet.pt", "afnet.json", "checkpoint.pt", "loss_log.csv", "loss.png", "run.json"):
        assert (run / name).is_file(), name
    rows = _rows(run / "loss_log.csv")
    assert [int(r["iteration"]) for r in rows] == list(range(1, 61))
    total = np.array([float(r["total"]) for r in rows])
    assert total[-10:].mean() < 0.8 * total[:10].mean()
    model, header = load_afnet(run / "afnet.pt")
    assert header["config"] == tiny_config().to_dict() and header["iterations"] == 60
    assert header["parameters"] == model.parameter_count() and header["receptive_field_frames"] == 17
    assert header["training"]["training_data"]["clips"]["editor"] == len(ENTERS)
    frames, maps, box_b = frames_of(30, 15, seed=99)
    pred = predict_clip(model, frames, maps, min_gap=6)
    assert len(pred.peaks) == 1 and abs(pred.peaks[0].t - 15) <= 3, pred.probs
    x, y, w, h = pred.regions[0].box
    assert x < box_b[0] + box_b[2] and box_b[0] < x + w and y < box_b[1] + box_b[3] and box_b[1] < y + h
    frames, maps, _ = frames_of(30, None, seed=98)
    assert predict_clip(model, frames, maps, min_gap=6).peaks == []


def test_resume_equals_an_uninterrupted_run(tmp_path):
    ann = write_annotated_dataset(tmp_path / "data", [6, None], n=16)

    def settings(run, resume=False):
        return AFNetTrainSettings(run_dir=run, annotations=[ann], iterations=6, batch=2, checkpoint_every=3,
                                  resume=resume, model=tiny_config(), seed=3)

    straight = AFNetTrainer(settings(tmp_path / "a"))
    straight.run(progress=False)
    first = AFNetTrainer(settings(tmp_path / "b"))
    for _ in range(3):
        first.step()
    first.cancel()  # Ctrl-C: checkpoint at iteration 3
    resumed = AFNetTrainer(settings(tmp_path / "b", resume=True))
    assert resumed.iteration == 3
    resumed.run(progress=False)
    a, b = straight.model.state_dict(), resumed.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    ra, rb = _rows(tmp_path / "a" / "loss_log.csv"), _rows(tmp_path / "b" / "loss_log.csv")
    assert [r["total"] for r in ra] == [r["total"] for r in rb]
    with pytest.raises(InputError, match="--resume"):
        AFNetTrainer(settings(tmp_path / "a"))
    with pytest.raises(InputError, match="does not exist"):
        AFNetTrainer(settings(tmp_path / "c", resume=True))
    with pytest.raises(InputError, match="no AF-Net training data"):
        AFNetTrainer(AFNetTrainSettings(run_dir=tmp_path / "d"))


def _sequence(tmp_path, t_enter):
    frames, maps, _ = frames_of(30, t_enter, seed=77)
    return write_sequence(tmp_path / "clip", frames, maps)


def test_autofocus_preset_learned(tmp_path, trained):
    from rvr_addon.cli import main
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    run, _ = trained
    fdir, ddir = _sequence(tmp_path, 16)
    result = AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="learned",
                                            afnet_weights=run / "afnet.pt")).run(progress=False)
    learned = [n for n in result.nfts[1:] if n.source == "afnet"]
    assert len(learned) == 1 and abs(learned[0].act_at - 16) <= 3 and learned[0].known_at <= learned[0].t
    assert result.focus[-1] == pytest.approx(0.0, abs=0.3)  # ends on the square that appeared (D = 0)
    assert result.detectors["afnet"]["receptive_field_frames"] == 17
    out = tmp_path / "focus.json"
    assert main(["autofocus", str(fdir), "--depth", str(ddir), "--preset", "learned", "--afnet-weights",
                 str(run / "afnet.pt"), "--afnet-region", "map", "-o", str(out), "-q"]) == 0
    assert any(n["source"] == "afnet" for n in json.loads(out.read_text())["nfts"])


def test_at_twice_the_frame_rate_afnet_sees_every_other_frame_and_finds_the_same_moment(tmp_path, trained):
    """AF-Net's windows are frames of the 24-25 fps clips it learned on: a faster clip is read at
    25 frames a second (a 50 fps clip, each frame twice, at every other frame), and its NFT comes
    back in the clip's frames."""
    from rvr_addon.laaf.detectors.afnet import frame_ratio, stream_frames
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    assert [frame_ratio(f) for f in (24, 25, 30, 50, None)] == [1.0, 1.0, 1.2, 2.0, 1.0]
    assert stream_frames(12, 1.2) == [0, 1, 2, 4, 5, 6, 7, 8, 10, 11]  # 30 fps: every 6th frame skipped
    assert stream_frames(7, 2.0) == [0, 2, 4, 6] and stream_frames(5, 1.0) == [0, 1, 2, 3, 4]
    run, _ = trained
    frames, maps, _ = frames_of(30, 16, seed=77)
    fdir, ddir = write_sequence(tmp_path / "clip50", [f for f in frames for _ in (0, 1)],
                                [d for d in maps for _ in (0, 1)])
    result = AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="learned", fps=50,
                                            afnet_weights=run / "afnet.pt")).run(progress=False)
    assert result.detectors["afnet"]["frame_ratio"] == 2.0 and result.detectors["afnet"]["frames"] == 30
    learned = [n for n in result.nfts[1:] if n.source == "afnet"]
    assert len(learned) == 1 and abs(learned[0].act_at - 32) <= 6 and learned[0].known_at <= learned[0].t
    assert result.focus[-1] == pytest.approx(0.0, abs=0.3)


def test_missing_weights_name_the_path_and_presets_still_work(tmp_path, capsys):
    from rvr_addon.cli import main
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    fdir, ddir = _sequence(tmp_path, 16)
    missing = tmp_path / "nowhere" / "afnet.pt"
    with pytest.raises(InputError) as info:
        AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="learned", afnet_weights=missing))
    assert str(missing) in str(info.value) and "rvr train-afnet" in str(info.value)
    assert main(["autofocus", str(fdir), "--depth", str(ddir), "--preset", "learned", "--afnet-weights",
                 str(missing), "-o", str(tmp_path / "f.json"), "-q"]) == 2
    assert "rvr train-afnet" in capsys.readouterr().err and not (tmp_path / "f.json").exists()
    result = AutofocusJob(AutofocusSettings(input=fdir, depth=ddir, preset="salient")).run(progress=False)
    assert len(result.focus) == 30
    with pytest.raises(InputError, match="not an AF-Net weights file"):
        bad = tmp_path / "bad.pt"
        torch.save({"format": "something-else"}, bad)
        load_afnet(bad)


def test_eval_focus_compares_learned_with_the_presets(tmp_path, trained):
    from rvr_addon.laaf.evaluate import evaluate

    run, _ = trained
    write_harness_clip(tmp_path / "ds" / "clip_a", 30, 14, seed=50)
    write_harness_clip(tmp_path / "ds" / "clip_b", 30, None, seed=51, script="random")
    with pytest.raises(InputError, match="rvr train-afnet"):
        evaluate(tmp_path / "ds", tmp_path / "never", ["learned-map"], afnet_weights=tmp_path / "none.pt",
                 progress=False)
    assert not (tmp_path / "never" / "summary.json").exists()
    summary = evaluate(tmp_path / "ds", tmp_path / "report", ["learned", "learned-map", "salient"],
                       afnet_weights=run / "afnet.pt", progress=False)
    # no sound in these clips: AF-Net's map either way
    assert summary["focus.learned-map.mean_dd"] == summary["focus.learned.mean_dd"]
    assert summary["focus.learned.clips"] == 2 and summary["focus.learned.gt_nfts"] == 1
    assert summary["focus.learned.mean_dt_frames"] <= 6
    assert "focus.learned.clip_b.mean_dd" in summary and "focus.learned.clip_b.mean_dt_frames" not in summary
    assert "focus.salient.all.mean_dd" in summary and "focus.learned.causal.mean_dd" in summary
    report = (tmp_path / "report" / "report.md").read_text()
    assert "All clips" in report and "| learned |" in report
