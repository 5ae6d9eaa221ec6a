"""rvr eval-estimator on real material (rvr_addon.estimate.evaluate_real): real pictures with
measured depth (a made-up real_depth folder), the flicker warp on synthetic RGB-D sequences with
poses, the aperture fit on a synthetic pair, the CLI's report, and a smoke test on the shared
data (skipped when ../shared/data is absent). Behaviour and tolerance-bounded numbers only."""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from rvr_addon.cli import main
from rvr_addon.errors import InputError
from rvr_addon.estimate import evaluate_real as er
from rvr_addon.estimate.train import export_weights
from rvr_addon.estimate.unet import EstimatorConfig, EstimatorNet

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    net = EstimatorNet(EstimatorConfig(widths=(8, 16, 24)))
    return export_weights(net, tmp_path_factory.mktemp("w") / "tiny.pt", iterations=0, wall_time_s=0.0,
                          training={"note": "random init, tests only"})


# ------------------------------------------------------------------------------ real pictures


def _disparity_scene(h: int, w: int, seed: int) -> np.ndarray:
    """A disparity map (px, 1..60) with a box in front of a tilted wall."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    d = 10 + 20 * x / w + 5 * y / h
    y0, x0 = rng.integers(4, h // 2), rng.integers(4, w // 2)
    d[y0:y0 + h // 3, x0:x0 + w // 3] = 55
    return d


def _encode(d: np.ndarray) -> np.ndarray:
    """An RGB picture whose red channel carries the disparity (the fake network reads it back)."""
    img = np.zeros(d.shape + (3,), np.uint8)
    img[..., 0] = np.clip(d * 4, 0, 255).astype(np.uint8)
    img[..., 1] = 90
    img[..., 2] = 200 - img[..., 0] // 2
    return img


def _fake_network(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """D = a negative affine of the encoded disparity (our D grows away from the camera)."""
    d = -0.5 * image[..., 0].astype(np.float32) + 3.0
    return d, np.zeros(image.shape, np.float32)


def _write_png(path: Path, a: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), a[..., ::-1] if a.ndim == 3 else a)


@pytest.fixture()
def real_set(tmp_path) -> Path:
    root = tmp_path / "real_depth"
    h, w = 48, 64
    for k, scene in enumerate(("Alpha", "Beta")):
        for view, disp in (("view1", "disp1"), ("view5", "disp5")):
            d = _disparity_scene(h, w, 10 * k + len(view))
            d8 = np.rint(d).astype(np.uint8)
            d8[:3, :5] = 0  # unknown pixels
            _write_png(root / "middlebury2006" / scene / f"{view}.png", _encode(d8.astype(np.float64)))
            _write_png(root / "middlebury2006" / scene / f"{disp}.png", d8)
    d = np.rint(_disparity_scene(h, w, 7)).astype(np.uint8)
    _write_png(root / "middlebury2001_2003" / "cones" / "imL.png", _encode(d.astype(np.float64)))
    _write_png(root / "middlebury2001_2003" / "cones" / "groundtruth.png", d * 4)  # x4, as Middlebury
    return root


def test_real_set_keys_and_perfect_depth(real_set, tmp_path):
    nets = er.SceneNetworks(_fake_network, "fake")
    summary, rows, md = er.evaluate_real_set(real_set, nets, "network", folder=tmp_path)
    assert len(rows) == 5
    assert summary["estimate.real.middlebury2006.views"] == 4
    assert summary["estimate.real.middlebury2006.scenes"] == 2
    assert summary["estimate.real.middlebury2001_2003.views"] == 1
    assert summary["estimate.real.middlebury.views"] == 5 and summary["estimate.real.middlebury.scenes"] == 3
    for key in ("middlebury2006", "middlebury2001_2003", "middlebury", "all"):
        # the fake network is an exact negative affine of the truth: error ~0 (uint8 rounding only)
        assert summary[f"estimate.real.{key}.affine_error"] < 0.02
        assert 0.2 < summary[f"estimate.real.{key}.ramp_error"] <= 1.0 + 1e-6
        assert summary[f"estimate.real.{key}.better_than_ramp_share"] == 1.0
    assert all(isinstance(v, (int, float)) and math.isfinite(v) for v in summary.values())
    assert any("middlebury2006/Alpha/view5" in line for line in md)  # per-picture rows
    assert sorted(p.name for p in tmp_path.glob("compare_real_*.png")) == [
        "compare_real_middlebury2001_2003_cones.png", "compare_real_middlebury2006_Alpha.png",
        "compare_real_middlebury2006_Beta.png"]


def test_ramp_like_network_is_not_better_than_ramp(real_set):
    def flat(image):
        h, w = image.shape[:2]
        return np.zeros((h, w), np.float32) + np.random.default_rng(0).normal(size=(h, w)).astype(np.float32), None

    summary, _, _ = er.evaluate_real_set(real_set, er.SceneNetworks(flat, "noise"), "network")
    assert summary["estimate.real.all.affine_error"] > 0.95  # noise explains nothing
    assert summary["estimate.real.all.better_than_ramp_share"] == 0.0


def test_weights_per_scene_loads_each_file_once(real_set, tiny_weights, tmp_path):
    mapping = tmp_path / "folds.json"
    mapping.write_text(json.dumps({"middlebury2006/Alpha": str(tiny_weights), "Beta": str(tiny_weights)}))
    wmap = er.load_weights_map(mapping)
    nets = er.SceneNetworks(_fake_network, "fake", wmap)
    summary, rows, _ = er.evaluate_real_set(real_set, nets, "network")
    assert nets.loads == 1 and summary["estimate.real.fold_models"] == 1
    by = {r["name"]: r["weights"] for r in rows}
    assert by["middlebury2006/Alpha/view1"] == str(tiny_weights) == by["middlebury2006/Beta/view5"]
    assert by["middlebury2001_2003/cones/imL"] == "fake"
    # a missing file is named
    mapping.write_text(json.dumps({"Alpha": "nowhere.pt"}))
    with pytest.raises(InputError, match="nowhere.pt"):
        er.load_weights_map(mapping)
    mapping.write_text("[1, 2]")
    with pytest.raises(InputError, match="mapping"):
        er.load_weights_map(mapping)


def test_cli_real_set_report(real_set, tiny_weights, tmp_path, capsys):
    out = tmp_path / "report"
    rc = main(["eval-estimator", "--weights", str(tiny_weights), "--real-set", str(real_set), "-o", str(out), "-q"])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["estimate.real.middlebury.views"] == 5
    assert all(isinstance(v, (int, float)) for v in summary.values())
    readme = (out / "README.md").read_text()
    assert "Real pictures with measured depth" in readme and "middlebury2006/Beta/view1" in readme
    assert len(json.loads((out / "real_views.json").read_text())) == 5
    # nothing to evaluate / a bad depth method are refused
    assert main(["eval-estimator", "--weights", str(tiny_weights), "-o", str(tmp_path / "r2")]) == 2


def test_picture_depth_auto_without_people_is_the_network(monkeypatch):
    import rvr_addon.depth.system as system

    monkeypatch.setattr(system, "people_available", lambda: (False, "not installed (test)"))
    img = _encode(_disparity_scene(48, 64, 3))
    fn = er.picture_depth("auto", _fake_network)
    d, _ = fn(img)
    np.testing.assert_allclose(d, _fake_network(img)[0])
    with pytest.raises(InputError):
        er.picture_depth("parallax", _fake_network)


# ------------------------------------------------------------------------------ video: warp and flicker

K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
H, W = 48, 64


def _pose(tx: float = 0.0, tz: float = 0.0) -> np.ndarray:
    p = np.eye(4)
    p[0, 3], p[2, 3] = tx, tz
    return p


def _plane_depth(pose: np.ndarray, z0: float = 2.0, slope: float = 0.5) -> np.ndarray:
    """Depth (m) seen by a camera (no rotation) at ``pose`` of the world plane z = z0 + slope * x."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    rx = (x - K[0, 2]) / K[0, 0]
    cx, cz = pose[0, 3], pose[2, 3]
    # camera point (rx z, ., z) + centre lies on the plane: cz + z = z0 + slope (cx + rx z)
    return ((z0 + slope * cx - cz) / (1 - slope * rx)).astype(np.float32)


def test_warp_fronto_parallel_plane_shift():
    z = np.full((H, W), 2.0, np.float32)
    ys, xs, x2, y2 = er.warp_to_next(z, _pose(0.0), z, _pose(0.1), K)
    # the camera moves +0.1 m in x: the plane 2 m away moves by -f tx / z = -3 px
    np.testing.assert_allclose(x2 - xs, -3.0, atol=1e-4)
    np.testing.assert_allclose(y2, ys, atol=1e-4)
    assert len(xs) == H * (W - 3)  # the three columns that leave the frame are dropped
    # a depth that disagrees (a moving object) is rejected
    z_u = z.copy()
    z_u[:, :20] = 3.0
    ys2, xs2, x22, _ = er.warp_to_next(z, _pose(0.0), z_u, _pose(0.1), K)
    assert np.all(x22 >= 19.5) and len(xs2) < len(xs)


def test_still_camera_constant_d_gives_zero_flicker():
    z = _plane_depth(_pose())
    m = er.warp_to_next(z, _pose(), z, _pose(), K)
    assert len(m[0]) == H * W
    d = np.random.default_rng(1).normal(size=(H, W)).astype(np.float32)
    p = er.flicker_pair(d, d, 1 / z, 1 / z, m)
    assert er.flicker_figures([p], float(d.std()))[0] == pytest.approx(0.0, abs=1e-6)


def test_translating_camera_over_tilted_plane_warps_correctly():
    p0, p1 = _pose(0.0), _pose(0.08)
    z0, z1 = _plane_depth(p0), _plane_depth(p1)
    d0, d1 = (-1.0 / z0).astype(np.float32), (-1.0 / z1).astype(np.float32)  # exact D of the points
    m = er.warp_to_next(z0, p0, z1, p1, K)
    assert len(m[0]) > 0.8 * H * W
    std = float(np.std(np.concatenate([d0.ravel(), d1.ravel()])))
    good = er.flicker_figures([er.flicker_pair(d0, d1, 1 / z0, 1 / z1, m)], std)[0]
    ys, xs = np.mgrid[0:H, 0:W]
    ident = (ys.ravel(), xs.ravel(), xs.ravel().astype(np.float32), ys.ravel().astype(np.float32))
    bad = er.flicker_figures([er.flicker_pair(d0, d1, 1 / z0, 1 / z1, ident)], std)[0]
    assert good < 0.01  # bilinear sampling error only
    assert bad > 10 * good and bad > 0.05


def _write_hololens(root: Path, frames: int = 4, step: float = 0.05) -> None:
    (root / "images").mkdir(parents=True)
    (root / "depth").mkdir()
    poses = []
    y, x = np.mgrid[0:H, 0:W]
    for i in range(frames):
        p = _pose(step * i)
        z = _plane_depth(p)
        tex = ((np.sin(x / 3.0 + i * 0.2) + 1) * 100 + y).clip(0, 255).astype(np.uint8)
        _write_png(root / "images" / f"{i:05d}.png", np.stack([tex, tex, 255 - tex], -1))
        cv2.imwrite(str(root / "depth" / f"{i:05d}.png"), np.rint(z * 1000).astype(np.uint16))
        poses.append(p.ravel())
    np.savetxt(root / "poses.txt", np.array(poses))
    np.savetxt(root / "K.txt", K)


def test_video_clip_figures_with_a_fixed_network(tmp_path):
    root = tmp_path / "hololens_synth"
    _write_hololens(root, frames=4)
    const = np.random.default_rng(2).normal(size=(H, W)).astype(np.float32)

    def same_map(frame):
        return const, np.zeros(frame.shape, np.float32)

    summary, md = er.evaluate_video_clip(root, ["network"], same_map, folder=tmp_path)
    k = "estimate.video.hololens"
    assert summary[f"{k}.frames"] == 4
    assert summary[f"{k}.matched_share"] > 0.8
    assert summary[f"{k}.gt_flicker"] < 0.05  # the plane's own 1/z barely changes along x motion
    assert 0.9 < summary[f"{k}.network.affine_error"] < 1.1  # noise: no better than a constant
    assert summary[f"{k}.network.flicker"] > 0.3  # the map stays put while the scene moves
    assert (tmp_path / "video_hololens.png").is_file()
    assert any("Real video" in line for line in md)

    def true_depth(frame, _state={"i": 0}):
        i = _state["i"]
        _state["i"] += 1
        return (-1.0 / _plane_depth(_pose(0.05 * i))).astype(np.float32), None

    summary, _ = er.evaluate_video_clip(root, ["network"], true_depth)
    assert summary[f"{k}.network.affine_error"] < 0.01  # mm rounding of the GT depth only
    assert summary[f"{k}.network.clip_affine_error"] < 0.01
    assert summary[f"{k}.network.flicker"] < 0.02
    assert summary[f"{k}.network.flicker_geometry_corrected"] < 0.02
    with pytest.raises(InputError):
        er.evaluate_video_clip(tmp_path / "nothing", ["network"], true_depth)


def test_a_method_after_the_temporal_filter(tmp_path):
    """``network+centred``: the network's D after rvr stabilize's filter (what the renderer gets);
    the filter averages the noise maps over the window, so the flicker drops; unknown names fail."""
    root = tmp_path / "hololens_synth"
    _write_hololens(root, frames=6)
    rng = np.random.default_rng(5)

    def noise(frame, _state={"i": 0}):  # the true D with 5 % noise, new every frame
        d = -1.0 / _plane_depth(_pose(0.05 * (_state["i"] % 6)))  # each method runs the 6 frames again
        _state["i"] += 1
        return (d * (1.0 + 0.05 * rng.normal(size=d.shape))).astype(np.float32), np.zeros(frame.shape, np.float32)

    summary, md = er.evaluate_video_clip(root, ["network", "network+centred"], noise)
    k = "estimate.video.hololens"
    assert summary[f"{k}.network+centred.flicker"] < 0.8 * summary[f"{k}.network.flicker"]
    assert any("network+centred" in line for line in md)
    for bad in ("network+sideways", "nothing+centred"):
        with pytest.raises(InputError, match="depth-methods"):
            er.evaluate_video_clip(root, [bad], noise)


# ------------------------------------------------------------------------------ aperture


def test_aperture_fit_recovers_a_rendered_photo(tmp_path):
    from rvr_addon.render.fast import FastRenderer

    rng = np.random.default_rng(3)
    h, w = 64, 96
    img = cv2.resize(rng.integers(0, 255, (16, 24, 3)).astype(np.uint8), (w, h), interpolation=cv2.INTER_CUBIC)
    img[20:44, 30:66] = (rng.integers(0, 255, (24, 36, 3)) // 2 + 100).astype(np.uint8)
    d = np.full((h, w), 4.0, np.float32)
    d[20:44, 30:66] = 0.0  # subject in focus, background blurred by 4 px
    target = FastRenderer(threads=1).render_srgb(img, d, 0.0, 1.0)
    scene = tmp_path / "aperture" / "synth_1"
    _write_png(scene / "input.png", img)
    _write_png(scene / "target.png", (np.clip(target, 0, 1) * 255 + 0.5).astype(np.uint8))

    def oracle(image):
        return d, np.zeros(image.shape, np.float32)

    summary, md = er.evaluate_aperture(tmp_path / "aperture", oracle, long_side=96, folder=tmp_path)
    k = "estimate.aperture.synth_1"
    assert summary[f"{k}.psnr_ours_db"] > 38  # 8-bit rounding of the target only
    assert summary[f"{k}.psnr_ours_db"] > summary[f"{k}.psnr_gauss_db"] + 3
    assert summary["estimate.aperture.mean_margin_db"] > 3
    assert summary[f"{k}.aperture_scale"] == pytest.approx(1.0, rel=0.15)
    assert summary[f"{k}.focus"] == pytest.approx(0.0, abs=0.3)
    assert (tmp_path / "aperture_synth_1.png").is_file()
    with pytest.raises(InputError):
        er.aperture_scenes(tmp_path / "empty_nothing")


# ------------------------------------------------------------------------------ the shared data


@pytest.mark.skipif(not (SHARED / "real_depth" / "middlebury2001_2003").is_dir()
                    or not (SHARED / "real_video_depth" / "tum_fr1_rpy_window").is_dir(),
                    reason="../shared/data (real_depth, real_video_depth) absent")
def test_shared_real_data_smoke():
    from rvr_addon.estimate.infer import Estimator, default_weights, load_estimator

    torch.set_num_threads(1)
    est = Estimator(load_estimator(default_weights()))
    summary, rows, _ = er.evaluate_real_set(SHARED / "real_depth" / "middlebury2001_2003",
                                            er.SceneNetworks(est, "shipped"), "network")
    assert len(rows) == 4
    assert 0.0 < summary["estimate.real.middlebury2001_2003.affine_error"] <= 1.0 + 1e-6
    assert 0.3 < summary["estimate.real.middlebury2001_2003.ramp_error"] <= 1.0 + 1e-6
    video, _ = er.evaluate_video_clip(SHARED / "real_video_depth" / "tum_fr1_rpy_window", ["network"], est,
                                      max_frames=3)
    assert video["estimate.video.tum.frames"] == 3
    assert video["estimate.video.tum.matched_share"] > 0.3  # real poses + depth agree between frames
    assert video["estimate.video.tum.gt_flicker"] < 0.2
    assert 0.0 < video["estimate.video.tum.network.affine_error"] <= 1.0 + 1e-6
