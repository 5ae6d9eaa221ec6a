"""The ONNX exports of the shipped networks (what the Blender extension runs without torch):
their outputs match torch, they come from the shipped weights (a fresh export gives the same
outputs: weights and .onnx never drift apart), and the loaders pick the backend as documented.

Tolerances below (float32 on both sides; measured 2026-12-02: estimator D 1e-5 px at 640x360 for a
D range of 16 px, E 3e-8; AF-Net features and map logits 1e-5, NFT logit 2e-6).
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
torch = pytest.importorskip("torch")

from rvr_addon import onnxrun  # noqa: E402
from rvr_addon.afnet.infer import DEFAULT_WEIGHTS as AFNET_PT, load_afnet, onnx_paths, predict_clip, runner_of  # noqa: E402
from rvr_addon.estimate.infer import SHIPPED_ONNX, SHIPPED_WEIGHTS, Estimator, load_estimator  # noqa: E402

D_TOL_PX = 1e-4
"""Max abs difference of D (px of blur at aperture 1), ONNX vs torch."""
E_TOL = 1e-6
"""Max abs difference of the HDR exponent E (E_max is 0.138)."""
AFNET_TOL = 1e-4
"""Max abs difference of AF-Net's features, map logits and NFT logits."""


@pytest.fixture(scope="module")
def estimators():
    return load_estimator(SHIPPED_WEIGHTS, backend="torch"), load_estimator(SHIPPED_WEIGHTS, backend="onnx")


@pytest.fixture(scope="module")
def afnets():
    return load_afnet(AFNET_PT, backend="torch")[0], load_afnet(AFNET_PT, backend="onnx")[0]


def _frame(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    frame[: max(h // 3, 1), : max(w // 2, 1)] = 252  # a clipped area: E is gated on
    return frame


@pytest.mark.parametrize("h, w, max_pixels", [
    pytest.param(37, 53, None, id="odd-37x53"), pytest.param(100, 129, None, id="odd-100x129"),
    pytest.param(180, 320, None, id="320x180"), pytest.param(121, 203, 5000, id="shrunk-trunk"),
    pytest.param(1, 1, None, id="1x1")])
def test_estimator_onnx_matches_torch(estimators, h, w, max_pixels):
    torch_model, onnx_model = estimators
    assert (torch_model.backend, onnx_model.backend) == ("torch", "onnx")
    assert onnx_model.model_hash == torch_model.model_hash  # one cache key for both backends
    frame = _frame(h, w, h * w)
    d_t, e_t = Estimator(torch_model, max_pixels)(frame)
    d_o, e_o = Estimator(onnx_model, max_pixels)(frame)
    assert d_o.shape == d_t.shape == (h, w) and e_o.shape == e_t.shape == (h, w, 3)
    assert d_o.dtype == e_o.dtype == np.float32
    assert float(np.abs(d_o - d_t).max()) < D_TOL_PX
    assert float(np.abs(e_o - e_t).max()) < E_TOL


def test_afnet_onnx_matches_torch(afnets):
    torch_model, onnx_model = afnets
    cfg = torch_model.config
    rt, ro = runner_of(torch_model), runner_of(onnx_model)
    rng = np.random.default_rng(3)
    for n in (1, 3):
        codes = rng.integers(0, 256, (n, cfg.f_t, cfg.channels, cfg.height, cfg.width), dtype=np.uint8)
        for audio in (rng.standard_normal((n, cfg.f_t, cfg.audio)).astype(np.float32), None):
            (f_t, m_t), (f_o, m_o) = rt.unit(codes, audio), ro.unit(codes, audio)
            assert float(np.abs(f_t - f_o).max()) < AFNET_TOL and float(np.abs(m_t - m_o).max()) < AFNET_TOL
        feats = rng.standard_normal((n, cfg.s, cfg.widths1[3], cfg.height // 8, cfg.width // 8)).astype(np.float32)
        for audio in (rng.standard_normal((n, cfg.audio, cfg.span)).astype(np.float32), None):
            assert float(np.abs(rt.head(feats, audio) - ro.head(feats, audio)).max()) < AFNET_TOL
    frames = [_frame(72, 128, i) for i in range(45)]
    maps = [np.tile(np.linspace(0, 5, 128, dtype=np.float32), (72, 1)) for _ in frames]
    p_t, p_o = predict_clip(torch_model, frames, maps), predict_clip(onnx_model, frames, maps)
    assert p_t.probs.keys() == p_o.probs.keys()
    assert max(abs(p_t.probs[q] - p_o.probs[q]) for q in p_t.probs) < AFNET_TOL
    assert [p.t for p in p_t.peaks] == [p.t for p in p_o.peaks]


EXPORT_TOLERANCE = 2e-5
"""A fresh export against the committed file, relative to the output's magnitude (at least 1)."""


def test_committed_onnx_files_come_from_the_shipped_weights(tmp_path, estimators, afnets):
    """A fresh export (scripts/export_onnx.py) gives the committed files' outputs, and each file
    records the hash of the .pt beside it: retrained weights without a new export fail here."""
    assert onnxrun.read_metadata(SHIPPED_ONNX)["rvr_source_hash"] == onnxrun.file_hash(SHIPPED_WEIGHTS)
    for path in onnx_paths(AFNET_PT):
        assert onnxrun.read_metadata(path)["rvr_source_hash"] == onnxrun.file_hash(AFNET_PT)
    pytest.importorskip("onnx")  # the exporter's (scripts/setup.sh installs it)
    from rvr_addon.onnx_export import export_all

    fresh = {p.name: p for p in export_all(tmp_path)}
    frame = _frame(90, 161, 7)
    committed = Estimator(estimators[1])(frame)
    regenerated = Estimator(load_estimator(fresh["estimator.onnx"]))(frame)
    # float32 ULPs: constant folding at export runs on this machine's CPU (AVX2 / AVX-512 paths differ),
    # so a fresh export matches the committed one to ~1e-6 of the output's scale, not bit for bit; a
    # retrained network differs by orders of magnitude more
    for a, b in zip(committed, regenerated):
        assert float(np.abs(a - b).max()) <= EXPORT_TOLERANCE * max(1.0, float(np.abs(a).max()))
    cfg = afnets[1].config
    codes = np.random.default_rng(5).integers(0, 256, (2, cfg.f_t, cfg.channels, cfg.height, cfg.width), np.uint8)
    new_model, header = load_afnet(fresh["afnet_unit.onnx"])
    assert header["file_id"] == onnxrun.file_hash(AFNET_PT)
    for a, b in zip(runner_of(afnets[1]).unit(codes, None), runner_of(new_model).unit(codes, None)):
        assert float(np.abs(a - b).max()) <= EXPORT_TOLERANCE * max(1.0, float(np.abs(a).max()))


def test_backend_choice(monkeypatch, tmp_path):
    assert load_estimator(SHIPPED_WEIGHTS).backend == "torch"  # auto with torch: the faster one here
    assert type(load_afnet()[0]).__name__ == "OnnxAFNet"  # auto with onnxruntime: faster for AF-Net
    monkeypatch.setenv("RVR_INFERENCE", "onnx")
    assert load_estimator(SHIPPED_WEIGHTS).backend == "onnx"
    monkeypatch.setenv("RVR_INFERENCE", "torch")
    assert type(load_afnet()[0]).__name__ == "AFNet"
    monkeypatch.setenv("RVR_INFERENCE", "cuda")
    with pytest.raises(onnxrun.InputError, match="not one of"):
        load_estimator(SHIPPED_WEIGHTS)
    monkeypatch.delenv("RVR_INFERENCE")
    missing = tmp_path / "estimator.pt"
    with pytest.raises(onnxrun.InputError, match="export_onnx"):
        load_estimator(missing, backend="onnx")


def test_no_torch_uses_the_exports(monkeypatch):
    """Without torch (as in Blender), both networks run from their exports; a .pt whose export is
    stale is refused with the fix."""
    monkeypatch.setattr(onnxrun, "has_torch", lambda: False)
    assert load_estimator(SHIPPED_WEIGHTS).backend == "onnx"
    assert type(load_afnet()[0]).__name__ == "OnnxAFNet"


def test_neither_runtime_names_the_fix(monkeypatch):
    """No torch and no onnxruntime: an InputError naming what to install, never an ImportError."""
    monkeypatch.setattr(onnxrun, "has_torch", lambda: False)
    monkeypatch.setattr(onnxrun, "has_onnxruntime", lambda: False)
    with pytest.raises(onnxrun.InputError, match="onnxruntime"):
        load_estimator(SHIPPED_WEIGHTS)
    with pytest.raises(onnxrun.InputError, match="onnxruntime"):
        load_afnet()
    from rvr_addon.estimate.infer import estimator_unavailable

    assert "onnxruntime" in estimator_unavailable(SHIPPED_WEIGHTS)
    monkeypatch.undo()
    assert estimator_unavailable(SHIPPED_WEIGHTS) == "" and estimator_unavailable(SHIPPED_ONNX) == ""


def test_row_prior_estimator_exports(tmp_path):
    """Weights with the row prior export too: the row column of the grid head travels in the metadata
    and is added in numpy (the graph sees only the padded frame); ONNX matches torch, odd sizes too."""
    from rvr_addon.estimate.train import export_weights
    from rvr_addon.estimate.unet import EstimatorConfig, EstimatorNet
    from rvr_addon.onnx_export import export_estimator

    torch.manual_seed(0)
    net = EstimatorNet(EstimatorConfig(widths=(8, 16, 16, 16), row_prior=True))
    with torch.no_grad():
        net.grid_head.weight[:, -1] = torch.linspace(-0.2, 0.3, net.grid_head.weight.shape[0])[:, None, None]
    pt = export_weights(net, tmp_path / "estimator.pt", iterations=0, wall_time_s=0.0, training={})
    (tmp_path / "estimator.onnx").write_bytes(export_estimator(pt))
    torch_model = load_estimator(pt, backend="torch")
    onnx_model = load_estimator(tmp_path / "estimator.onnx", backend="onnx")
    for h, w, max_pixels in ((37, 53, None), (100, 129, None), (121, 203, 5000)):
        frame = _frame(h, w, h + w)
        d_t, e_t = Estimator(torch_model, max_pixels)(frame)
        d_o, e_o = Estimator(onnx_model, max_pixels)(frame)
        assert float(np.abs(d_o - d_t).max()) < D_TOL_PX
        assert float(np.abs(e_o - e_t).max()) < E_TOL
    rows = np.abs(np.diff(d_t, axis=0)).mean()
    assert rows > 0  # the row term is there
