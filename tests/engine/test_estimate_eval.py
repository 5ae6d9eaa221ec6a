"""rvr eval-estimator: metric functions (hand values), the Middlebury loader, the report, weights
errors, and the ablation rows that run the estimator. No trained weights: a randomly
initialised tiny network (the figures are not judged, only computed and written)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from harness_data import write_fake_clip
from rvr_addon.cli import main
from rvr_addon.errors import InputError, OutputError
from rvr_addon.estimate.evaluate import (
    EvalSettings, affine_invariant_error, affine_rms, evaluate, fit_scale_shift, log_radiance_sq_error, motorcycle,
    pearson, saturated_mask, vertical_ramp,
)
from rvr_addon.estimate.train import export_weights
from rvr_addon.estimate.unet import EstimatorConfig, EstimatorNet


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    net = EstimatorNet(EstimatorConfig(widths=(8, 16, 24)))
    return export_weights(net, tmp_path_factory.mktemp("w") / "tiny.pt", iterations=0, wall_time_s=0.0,
                          training={"note": "random init, tests only"})


@pytest.fixture(scope="module")
def heldout(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("heldout") / "data"
    write_fake_clip(root / "clipA", seed=0, frames=2)
    return root


# ------------------------------------------------------------------------------ metrics


def test_scale_shift_fit_and_affine_errors_hand_values():
    gt = np.array([0.0, 1.0, 2.0, 3.0])
    pred = np.array([0.0, 0.0, 1.0, 1.0])
    # s = cov / var = 2 / 1, t = 1.5 - 2 * 0.5 -> fitted [0.5, 0.5, 2.5, 2.5], residuals +-0.5
    assert fit_scale_shift(pred, gt) == pytest.approx((2.0, 0.5))
    assert affine_rms(pred, gt) == pytest.approx(0.5)
    assert affine_invariant_error(pred, gt) == pytest.approx(0.5 / math.sqrt(1.25))  # / std(gt)
    r = pearson(pred, gt)
    assert affine_invariant_error(pred, gt) == pytest.approx(math.sqrt(1 - r * r))
    # exact affine (even with a negative scale) is perfect; a constant scores 1
    assert affine_rms(-3.0 * gt + 7.0, gt) == pytest.approx(0.0, abs=1e-12)
    assert affine_invariant_error(np.ones(4), gt) == pytest.approx(1.0)
    # NaN / masked pixels are left out
    gt_nan = np.array([0.0, 1.0, np.nan, 3.0, 2.0])
    pred_nan = np.array([1.0, 3.0, 100.0, 7.0, 100.0])
    mask = np.array([True, True, True, True, False])
    assert affine_rms(pred_nan, gt_nan, mask) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError):
        fit_scale_shift(np.ones(2), np.full(2, np.nan))


def test_ramp_saturation_and_log_radiance_error():
    ramp = vertical_ramp(3, 2)
    np.testing.assert_array_equal(ramp, [[0, 0], [0.5, 0.5], [1, 1]])
    assert affine_invariant_error(ramp, 4.0 - 2.0 * ramp) == pytest.approx(0.0, abs=1e-9)
    img = np.array([[[254, 0, 0], [253, 253, 253]]], np.uint8)
    np.testing.assert_array_equal(saturated_mask(img), [[True, False]])
    np.testing.assert_array_equal(saturated_mask(img.astype(np.float32) / 255), [[True, False]])
    gt = np.full((1, 2, 3), 20.0, np.float32)
    pred = gt * np.float32(math.e)  # ln error 1 everywhere
    pred[0, 1] = 1e-9  # floored at 1e-3, but not masked in
    assert log_radiance_sq_error(pred, gt, np.array([[True, False]])) == pytest.approx((3.0, 3), rel=1e-6)
    assert log_radiance_sq_error(pred, gt, np.zeros((1, 2), bool)) == (0.0, 0)


def test_middlebury_motorcycle_from_scikit_image():
    left, disp = motorcycle()
    assert left.shape == (500, 741, 3) and left.dtype == np.uint8 and disp.shape == (500, 741)
    valid = np.isfinite(disp)
    assert 0.9 < valid.mean() < 0.95 and float(disp[valid].min()) > 0
    # nearer is larger stereo disparity: the bottom of the frame (the near ground) beats the top
    assert affine_invariant_error(vertical_ramp(500, 741), disp, valid) < 0.9


# ------------------------------------------------------------------------------ the report


def test_eval_report_with_a_random_tiny_network(tiny_weights, heldout, tmp_path):
    report = tmp_path / "report"
    summary = evaluate(EvalSettings(output=report, weights=tiny_weights, data=[heldout], motorcycle=True,
                                    compare_frames=1))
    saved = json.loads((report / "summary.json").read_text())
    assert saved == pytest.approx(summary)
    for key in ("estimate.disparity_rms_px", "estimate.disparity_rms_px_baseline", "estimate.disparity_corr",
                "estimate.hdr_log_mse_saturated", "estimate.hdr_log_mse_saturated_no_recovery",
                "estimate.motorcycle.affine_invariant_error", "estimate.motorcycle.baseline_error"):
        assert isinstance(saved[key], (int, float)) and math.isfinite(saved[key]), key
    assert saved["estimate.frames"] == 2 and saved["estimate.clips"] == 1
    # an affine fit is never worse than a constant; the fake clip's emitters are clipped
    assert saved["estimate.disparity_rms_px"] <= saved["estimate.disparity_rms_px_constant"] + 1e-6
    assert saved["estimate.saturated_values"] > 0 and saved["estimate.hdr_log_mse_saturated_no_recovery"] > 1.0
    assert 0.0 <= saved["estimate.motorcycle.affine_invariant_error"] <= 1.0 + 1e-9
    assert (report / "README.md").read_text().startswith("# Estimator evaluation")
    assert (report / "compare_motorcycle.png").is_file() and len(list(report.glob("compare_clipA_*.png"))) == 1
    with pytest.raises(OutputError, match="--force"):
        evaluate(EvalSettings(output=report, weights=tiny_weights, data=[heldout]))
    evaluate(EvalSettings(output=report, weights=tiny_weights, data=[heldout], force=True, max_frames=1))
    assert json.loads((report / "summary.json").read_text())["estimate.frames"] == 1
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_eval_errors_name_the_weights_and_the_fix(tmp_path, heldout, capsys, monkeypatch):
    with pytest.raises(InputError, match="missing_weights.pt"):
        evaluate(EvalSettings(output=tmp_path / "r", weights=tmp_path / "missing_weights.pt", data=[heldout]))
    from rvr_addon.estimate import infer

    monkeypatch.setattr(infer, "SHIPPED_WEIGHTS", tmp_path / "gone" / "estimator.pt")
    monkeypatch.setattr(infer, "SHIPPED_ONNX", tmp_path / "gone" / "estimator.onnx")  # its export is a fallback
    with pytest.raises(InputError, match="weights file is missing"):
        evaluate(EvalSettings(output=tmp_path / "r", data=[heldout]))
    with pytest.raises(InputError, match="--data"):
        evaluate(EvalSettings(output=tmp_path / "r", weights=tmp_path / "x.pt"))
    bad = tmp_path / "corrupt.pt"
    bad.write_bytes(b"not a torch file")
    assert main(["eval-estimator", "--weights", str(bad), "--data", str(heldout), "-o", str(tmp_path / "r"), "-q"]) == 2
    assert "corrupt.pt" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_cli_eval_estimator(tiny_weights, heldout, tmp_path, capsys):
    assert main(["eval-estimator", "--weights", str(tiny_weights), "--data", str(heldout), "-o",
                 str(tmp_path / "r"), "-q", "--max-frames", "1"]) == 0
    out = capsys.readouterr().out
    assert "estimate.disparity_rms_px" in out and json.loads((tmp_path / "r" / "summary.json").read_text())


# ------------------------------------------------------------------------------ ablation rows


def test_ablation_estimator_rows_unavailable_without_weights_and_run_with_them(tiny_weights, heldout, tmp_path,
                                                                               monkeypatch):
    from rvr_addon.estimate import infer
    from sintel_eval import estimator_inputs
    from sintel_eval.ablate import run_ablation
    from sintel_eval.variants import select

    monkeypatch.setattr(infer, "SHIPPED_WEIGHTS", tmp_path / "gone" / "estimator.pt")
    monkeypatch.setattr(infer, "SHIPPED_ONNX", tmp_path / "gone" / "estimator.onnx")  # its export is a fallback
    estimator_inputs.configure(None)
    rows = select(["estimated_disparity", "estimated_hdr"])
    assert all("no trained estimator weights" in (v.unavailable() or "") for v in rows)
    with pytest.raises(InputError, match="estimated_hdr.*no trained estimator weights"):
        run_ablation(heldout, tmp_path / "a", variants=["estimated_hdr"], max_frames=1, progress=False)
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    estimator_inputs.configure(bad)
    assert "bad.pt" in rows[0].unavailable()
    ab = run_ablation(heldout, tmp_path / "b", variants=["ours_gt,estimated_disparity,estimated_hdr"], max_frames=1,
                      progress=False, compare_frames=1, estimator_weights=tiny_weights)
    s = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert s["ablation.ours_gt.psnr_srgb_db"] == 100.0
    for name in ("estimated_disparity", "estimated_hdr"):
        assert math.isfinite(s[f"ablation.{name}.psnr_srgb_db"]), name
    assert ab is not None and not ab.unavailable
    estimator_inputs.configure(None)


def test_real_picture_with_ground_truth(tiny_weights, tmp_path, capsys):
    """--real IMAGE DISPARITY scores any real view: the keys match the metric computed by hand on
    the estimator's own output, 0 = unknown is left out, a size mismatch names both files."""
    import cv2

    from rvr_addon.estimate.evaluate import pearson, vertical_ramp
    from rvr_addon.estimate.infer import Estimator, load_estimator

    rng = np.random.default_rng(3)
    img = (rng.random((40, 56, 3)) * 255).astype(np.uint8)
    disp = np.tile(np.linspace(10, 60, 40, dtype=np.float32)[:, None], (1, 56))
    disp[:5, :7] = 0  # unknown
    cv2.imwrite(str(tmp_path / "view L.png"), img[..., ::-1])
    np.save(tmp_path / "gt.npy", disp)
    assert main(["eval-estimator", "--weights", str(tiny_weights), "--real", str(tmp_path / "view L.png"),
                 str(tmp_path / "gt.npy"), "-o", str(tmp_path / "r"), "-q"]) == 0
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    d, _ = Estimator(load_estimator(tiny_weights))(img)
    gt = np.where(disp > 0, disp, np.nan)
    valid = np.isfinite(gt)
    assert summary["estimate.real.view_L.affine_invariant_error"] == pytest.approx(affine_invariant_error(d, gt, valid))
    assert summary["estimate.real.view_L.baseline_error"] == pytest.approx(
        affine_invariant_error(vertical_ramp(40, 56), gt, valid))
    assert summary["estimate.real.view_L.baseline_error"] < 1e-3  # this GT *is* a ramp
    assert summary["estimate.real.view_L.corr"] == pytest.approx(pearson(d, gt, valid))
    assert summary["estimate.real.view_L.valid_fraction"] == pytest.approx(1 - 35 / (40 * 56))
    assert (tmp_path / "r" / "compare_real_view_L.png").is_file()
    assert "Real picture `view_L`" in (tmp_path / "r" / "README.md").read_text()
    twice = evaluate(EvalSettings(output=tmp_path / "r3", weights=tiny_weights,
                                  real=[(tmp_path / "view L.png", tmp_path / "gt.npy")] * 2))
    assert twice["estimate.real.view_L_2.corr"] == pytest.approx(twice["estimate.real.view_L.corr"])
    np.save(tmp_path / "small.npy", disp[:20])
    assert main(["eval-estimator", "--weights", str(tiny_weights), "--real", str(tmp_path / "view L.png"),
                 str(tmp_path / "small.npy"), "-o", str(tmp_path / "r2"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "small.npy" in err and "view L.png" in err and not (tmp_path / "r2").exists()
