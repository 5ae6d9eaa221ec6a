"""`python -m sintel_eval ablate` end to end with every variant, Blender's Defocus node included.

The dataset is tests/harness_data.py's fake clip (64x36, 3 frames, two tracks): its "Cycles"
ground truth is rendered by our own renderer from the clip's inputs, so the expectations are
exact: ours reproduces it (100 dB), naive layers lose in the depth-edge band, HDR off and
Blender's node (8-bit input) lose the bokeh energy, and Blender's node scores below ours.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

pytest.importorskip("bpy")

from harness_data import write_fake_clip  # noqa: E402
from sintel_eval.__main__ import main  # noqa: E402
from sintel_eval.report import METRICS  # noqa: E402
from sintel_eval.variants import VARIANTS as ALL_VARIANTS  # noqa: E402

VARIANTS = [v for v in ALL_VARIANTS if v.unavailable() is None]  # e.g. estimator rows need trained weights
GT_ROWS = ["ours_gt", "naive_gt", "hdr_off", "blender_defocus"]  # rendered from ground-truth disparity

HEADLINE = ("psnr_srgb_db", "psnr_linear_db", "ssim_srgb", "edge_band_psnr_srgb_db", "splotchiness_px", "flicker",
            "bokeh_recall")


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ablate")
    write_fake_clip(root / "dataset" / "clip0", seed=3)
    out = root / "report"
    assert main(["ablate", str(root / "dataset"), "-o", str(out), "-q", "--compare-frames", "2"]) == 0
    return out


def test_summary_has_every_variant_metric_and_clip_key(report):
    s = json.loads((report / "summary.json").read_text())
    names = [v.name for v in VARIANTS]
    assert names[:4] == GT_ROWS and {"temporal_off", "temporal_causal", "temporal_centred"} <= set(names)
    for v in names:
        for metric in HEADLINE:
            assert f"ablation.{v}.{metric}" in s
            assert f"ablation.clip0.{v}.{metric}" in s
            for track in ("constant", "rack"):
                assert f"ablation.clip0.{track}.{v}.{metric}" in s
        assert s[f"ablation.{v}.s_per_frame"] > 0
    assert s["ablation.clips"] == 1 and s["ablation.frames"] == 6


def test_ablation_figures_rank_the_variants(report):
    s = json.loads((report / "summary.json").read_text())
    for track in ("constant", "rack"):
        run = {v.name: {k.rsplit(".", 1)[1]: val for k, val in s.items()
                        if k.startswith(f"ablation.clip0.{track}.{v.name}.")} for v in VARIANTS}
        assert run["ours_gt"]["psnr_srgb_db"] == 100.0 and run["ours_gt"]["ssim_srgb"] == pytest.approx(1.0)
        assert run["ours_gt"]["psnr_srgb_db"] > run["blender_defocus"]["psnr_srgb_db"]
        assert run["naive_gt"]["edge_band_psnr_srgb_db"] < 40.0 < run["ours_gt"]["edge_band_psnr_srgb_db"]
        assert run["hdr_off"]["bokeh_recall"] < 0.5 * run["ours_gt"]["bokeh_recall"]
        assert run["blender_defocus"]["bokeh_recall"] < 0.5
        assert all(run[name]["splotchiness_px"] == 0.0 for name in GT_ROWS)  # all use GT disparity
        assert run["ours_gt"]["flicker"] == 0.0
        # against the exact-input render: ours_gt is that render; the simulated per-frame estimates
        # add flicker, which the temporal filter removes in part
        assert run["ours_gt"]["flicker_exact"] == 0.0 and run["naive_gt"]["flicker_exact"] > 0.0
        assert run["temporal_causal"]["flicker_exact"] < run["temporal_off"]["flicker_exact"]
    assert s["ablation.check.ours_beats_blender_defocus_psnr_srgb"] == 1.0
    assert s["ablation.check.ours_beats_naive_edge_band_psnr_srgb"] == 1.0


def test_markdown_plots_images_and_videos(report):
    readme = (report / "README.md").read_text()
    assert "**100.00**" in readme  # the best PSNR is bold
    for v in VARIANTS:
        assert f"| {v.name} |" in readme
    assert "## Metrics" in readme and "## Dataset" in readme and "| clip0 |" in readme
    plots = sorted((report / "plots").glob("*.png"))
    assert {p.name for p in plots} >= {"metrics_bars.png", "clip0__constant_psnr.png", "clip0__rack_psnr.png"}
    compare = sorted((report / "compare").glob("*.png"))
    assert len(compare) == 2 * 2  # two frames for each track
    img = cv2.imread(str(compare[0]))
    assert img.shape[1] == 64 * (2 + len(VARIANTS))  # input | GT | every variant
    for p in plots + compare:
        assert f"]({p.relative_to(report).as_posix()})" in readme
    videos = sorted((report / "videos").glob("*.mp4"))
    assert [p.name for p in videos] == ["clip0__constant.mp4", "clip0__rack.mp4"]
    assert all(p.stat().st_size > 1000 for p in videos)
    cap = cv2.VideoCapture(str(videos[0]))
    frames = 0
    while cap.read()[0]:
        frames += 1
    assert frames == 3
    assert len(METRICS) >= len(HEADLINE)


def test_existing_report_is_kept_without_force_and_replaced_with_it(report, capsys):
    dataset = report.parent / "dataset"
    (report / "note.txt").write_text("mine")
    assert main(["ablate", str(dataset), "-o", str(report), "-q", "--variants", "ours_gt"]) == 1
    assert "--force" in capsys.readouterr().err and (report / "note.txt").exists()
    assert main(["ablate", str(dataset), "-o", str(report), "-q", "--variants", "ours_gt", "--force",
                 "--max-frames", "1"]) == 0
    s = json.loads((report / "summary.json").read_text())
    assert not (report / "note.txt").exists() and "ablation.blender_defocus.psnr_srgb_db" not in s


def test_ablate_reads_a_clip_from_the_real_generator(tmp_path):
    """Format drift guard: a tiny clip from `generate` (64x36, 2 frames, 2 samples) is read and
    scored without being skipped."""
    from sintel_eval.dataset import GenerateConfig, generate

    generate(tmp_path / "data" / "clip7", GenerateConfig(seed=7, frames=2, width=64, height=36, samples=2,
                                                         dof_samples=2, train_every=0), progress=False)
    out = tmp_path / "report"
    assert main(["ablate", str(tmp_path / "data"), "-o", str(out), "-q", "--variants", "ours_gt,hdr_off",
                 "--compare-frames", "1"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["ablation.clips"] == 1 and s["ablation.clips_skipped"] == 0 and s["ablation.frames"] == 4
    assert 10.0 < s["ablation.ours_gt.psnr_srgb_db"] < 100.0  # a real Cycles render, not our own
    if "ablation.ours_gt.bokeh_recall" in s:  # the clip has defocused highlights
        assert s["ablation.hdr_off.bokeh_recall"] <= s["ablation.ours_gt.bokeh_recall"]
