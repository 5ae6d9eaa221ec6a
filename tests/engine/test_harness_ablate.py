"""`python -m sintel_eval ablate` without Blender: the variants that need no bpy, bad datasets,
report-folder safety. The dataset is tests/harness_data.py's fake clip, whose ground truth is
rendered by our own renderer, so ``ours_gt`` must reproduce it exactly."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from harness_data import write_fake_clip
from rvr_addon.errors import InputError, OutputError
from sintel_eval import ablate as ablate_mod
from sintel_eval.__main__ import main
from sintel_eval.ablate import run_ablation
from sintel_eval.reader import ClipReader, find_clips

NO_BPY = ["--variants", "ours_gt,naive_gt,hdr_off"]


@pytest.fixture(scope="session")
def fake_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("harness") / "dataset"
    write_fake_clip(root / "clipA", seed=0)
    write_fake_clip(root / "clipB", seed=1)
    return root


@pytest.fixture
def dataset(tmp_path, fake_dataset) -> Path:
    """A private copy of the fake dataset that a test may break."""
    return Path(shutil.copytree(fake_dataset, tmp_path / "dataset"))


def _ablate(dataset: Path, report: Path, *extra: str) -> int:
    return main(["ablate", str(dataset), "-o", str(report), "-q", *NO_BPY, *extra])


def test_reader_streams_a_complete_clip(fake_dataset):
    clips = find_clips(fake_dataset)
    assert [c.name for c in clips] == ["clipA", "clipB"]
    assert find_clips(clips[0]) == [clips[0]]  # a clip folder is a dataset of one clip
    reader = ClipReader(clips[0])
    assert reader.tracks == ["constant", "rack"]
    reader.check_complete(reader.tracks)
    frames = list(reader.iter_frames("rack"))
    assert [f.frame for f in frames] == [1, 2, 3]
    assert [f.focus for f in frames] == [0.0, 2.0, 4.0] and frames[0].aperture == 1.0
    assert frames[0].disparity.shape == (36, 64) and frames[0].dof_linear.shape == (36, 64, 3)
    assert frames[0].radiance.max() > 10  # HDR kept in gt/hdr


def test_ablate_end_to_end_without_blender(dataset, tmp_path, capsys):
    report = tmp_path / "report"
    assert _ablate(dataset, report, "--max-frames", "2") == 0
    assert "ours_gt" in capsys.readouterr().out
    s = json.loads((report / "summary.json").read_text())
    assert s["ablation.frames"] == 2 * 2 * 2  # frames x tracks x clips, per variant
    assert s["ablation.clips"] == 2 and s["ablation.clips_skipped"] == 0
    assert s["ablation.ours_gt.psnr_srgb_db"] == 100.0  # bit-exact reproduction of the fake GT
    assert s["ablation.clipA.rack.ours_gt.flicker"] == 0.0
    assert s["ablation.naive_gt.edge_band_psnr_srgb_db"] < 40.0
    assert s["ablation.hdr_off.bokeh_recall"] < 0.5 < s["ablation.ours_gt.bokeh_recall"] == 1.0
    assert s["ablation.check.ours_beats_naive_edge_band_psnr_srgb"] == 1.0
    assert "ablation.check.ours_beats_blender_defocus_psnr_srgb" not in s  # that variant did not run
    assert not any(k.startswith("ablation.blender_defocus") for k in s)
    assert all(isinstance(v, float) for v in s.values())
    assert not (report / "_frames").exists()
    assert [p.name for p in report.parent.iterdir() if p.name.startswith(".")] == []


def test_not_a_dataset_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert _ablate(tmp_path / "empty", tmp_path / "r") == 1
    assert "not a harness dataset" in capsys.readouterr().err
    assert _ablate(tmp_path / "nowhere", tmp_path / "r") == 1
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_missing_frame_skips_the_clip_and_reports_it(dataset, tmp_path):
    (dataset / "clipB" / "done" / "frame_00002.json").unlink()
    report = tmp_path / "report"
    assert _ablate(dataset, report) == 0
    s = json.loads((report / "summary.json").read_text())
    assert s["ablation.clips"] == 1 and s["ablation.clips_skipped"] == 1
    assert not any(k.startswith("ablation.clipB") for k in s)
    readme = (report / "README.md").read_text()
    assert "## Skipped clips" in readme and "clipB/done/frame_00002.json" in readme


def test_truncated_file_is_caught_by_the_done_marker(dataset, tmp_path):
    exr = dataset / "clipA" / "gt" / "hdr" / "frame_00003.exr"
    exr.write_bytes(exr.read_bytes()[:100])
    ab = run_ablation(dataset, tmp_path / "report", variants=["ours_gt"], progress=False, compare_frames=1)
    assert [name for name, _ in ab.skipped] == ["clipA"]
    assert str(exr) in ab.skipped[0][1] and "truncated" in ab.skipped[0][1]


def test_corrupt_exr_of_the_right_size_skips_the_clip(dataset, tmp_path):
    exr = dataset / "clipA" / "gt" / "disparity" / "frame_00002.exr"
    exr.write_bytes(b"\0" * exr.stat().st_size)  # passes the size check, fails to decode
    ab = run_ablation(dataset, tmp_path / "report", variants=["ours_gt"], progress=False, compare_frames=1)
    assert [name for name, _ in ab.skipped] == ["clipA"] and [c["clip"] for c in ab.clips] == ["clipB"]
    assert str(exr) in ab.skipped[0][1]
    assert str(exr) in (tmp_path / "report" / "README.md").read_text()


def test_no_usable_clip_fails_naming_every_file(dataset, tmp_path, capsys):
    for clip in ("clipA", "clipB"):
        (dataset / clip / "input" / "frame_00001.png").unlink()
    assert _ablate(dataset, tmp_path / "report") == 1
    err = capsys.readouterr().err
    assert "clipA/input/frame_00001.png" in err and "clipB/input/frame_00001.png" in err
    assert not (tmp_path / "report").exists()


def test_existing_report_needs_force(dataset, tmp_path, capsys):
    report = tmp_path / "report"
    assert _ablate(dataset, report, "--max-frames", "1") == 0
    (report / "old_marker.txt").write_text("from the first run")
    assert _ablate(dataset, report, "--max-frames", "1") == 1
    assert "--force" in capsys.readouterr().err
    assert (report / "old_marker.txt").exists()  # untouched
    assert _ablate(dataset, report, "--max-frames", "1", "--force") == 0
    assert not (report / "old_marker.txt").exists() and (report / "summary.json").exists()


def test_force_never_replaces_a_folder_that_is_not_a_report(dataset, tmp_path):
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "thesis.txt").write_text("keep me")
    with pytest.raises(OutputError, match="not an ablation report"):
        run_ablation(dataset, precious, variants=["ours_gt"], force=True, progress=False)
    assert (precious / "thesis.txt").read_text() == "keep me"


def test_interrupted_run_leaves_no_report(dataset, tmp_path, monkeypatch):
    real = ablate_mod.run_variant
    calls = []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(ablate_mod, "run_variant", flaky)
    with pytest.raises(KeyboardInterrupt):
        run_ablation(dataset, tmp_path / "out" / "report", variants=["ours_gt"], progress=False)
    assert list((tmp_path / "out").iterdir()) == []  # neither the report nor its temp folder


def test_unknown_variant_names_the_known_ones(dataset, tmp_path, capsys):
    assert main(["ablate", str(dataset), "-o", str(tmp_path / "r"), "-q", "--variants", "ours_gt,magic"]) == 1
    err = capsys.readouterr().err
    assert "magic" in err and "naive_gt" in err
    with pytest.raises(InputError):
        run_ablation(dataset, tmp_path / "r", variants=["nope"], progress=False)
