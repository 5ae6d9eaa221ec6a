"""Real pictures with measured depth: reading (estimate.real_data) and training on them (rvr train --real)."""
from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.errors import InputError
from rvr_addon.estimate.data import Augment, SkipReport, TrainingSet, real_sources, real_target
from rvr_addon.estimate.real_data import find_real_pictures, read_inverse_depth, scene_folds

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real_depth"


def _write_scene(root: Path, name: str, seed: int, size=(64, 48)) -> None:
    """A Middlebury-2006-like scene: two views, a near square on a far backdrop (disparity px)."""
    rng = np.random.default_rng(seed)
    d = root / "middlebury2006" / name
    d.mkdir(parents=True)
    w, h = size
    for view, disp in (("view1", "disp1"), ("view5", "disp5")):
        img = (rng.random((h, w, 3)) * 255).astype(np.uint8)
        gt = np.full((h, w), 20, np.uint8)
        gt[10:30, 20:44] = 80
        gt[0, :] = 0  # unknown
        cv2.imwrite(str(d / f"{view}.png"), img)
        cv2.imwrite(str(d / f"{disp}.png"), gt)


@pytest.fixture
def real_root(tmp_path: Path) -> Path:
    root = tmp_path / "real_depth"
    for i, name in enumerate(("Alpha", "Beta", "Gamma")):
        _write_scene(root, name, i)
    kin = root / "kinect"
    kin.mkdir()
    cv2.imwrite(str(kin / "ch7_1.png"), np.full((48, 64, 3), 90, np.uint8))
    depth = np.full((48, 64), 10000, np.uint16)  # 2 m
    depth[:, :32] = 5000  # 1 m: nearer
    depth[0, 0] = 0
    cv2.imwrite(str(kin / "ch7_1_depth.png"), depth)
    return root


def test_listing_and_inverse_depth(real_root: Path):
    pics = find_real_pictures(real_root)
    assert [p.name for p in pics][:2] == ["kinect/ch7_1", "middlebury2006/Alpha/view1"]
    assert len(pics) == 7 and len({p.scene for p in pics}) == 4
    kin = pics[0]
    q = read_inverse_depth(kin)
    assert np.isnan(q[0, 0])
    assert q[5, 5] == pytest.approx(2 * q[5, 40])  # 1 m is twice the inverse depth of 2 m
    mid = read_inverse_depth(pics[1])
    assert np.isnan(mid[0]).all() and mid[20, 30] == 80 and mid[40, 5] == 20


def test_sun_and_nyu_conventions(tmp_path: Path):
    kin = tmp_path / "kinect"
    kin.mkdir()
    cv2.imwrite(str(kin / "RGBD_other_formats_SUN_color.jpg"), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(kin / "RGBD_other_formats_NYU_color.ppm"), np.zeros((8, 8, 3), np.uint8))
    sun = np.full((8, 8), 2000, np.uint16)  # mm
    sun[:, 4:] = 4000
    cv2.imwrite(str(kin / "RGBD_other_formats_SUN_depth.png"), ((sun << 3) | (sun >> 13)).astype(np.uint16))
    nyu = np.full((8, 8), 900, np.uint16)
    nyu[:, 4:] = 1000  # farther (1092.5 - raw smaller)
    cv2.imwrite(str(kin / "RGBD_other_formats_NYU_depth.pgm"), nyu.byteswap())
    pics = {p.name: p for p in find_real_pictures(kin)}
    q_sun = read_inverse_depth(pics["kinect/RGBD_other_formats_SUN"])
    assert q_sun[0, 0] == pytest.approx(2 * q_sun[0, 6])
    q_nyu = read_inverse_depth(pics["kinect/RGBD_other_formats_NYU"])
    assert q_nyu[0, 0] == pytest.approx(1092.5 - 900) and q_nyu[0, 6] == pytest.approx(1092.5 - 1000)


def test_exclusion_and_folds(real_root: Path):
    report = SkipReport()
    all_src = real_sources(real_root, report)
    assert len(all_src) == 7 and all(s.origin == "real" and s.disparity_invariant for s in all_src)
    kept = real_sources(real_root, report, exclude=["Alpha", "middlebury2006/Beta"])
    assert sorted({s.name.split("/")[1] for s in kept if s.name.startswith("middlebury")}) == ["Gamma"]
    with pytest.raises(InputError, match="no such scene"):
        real_sources(real_root, report, exclude=["Motorbike"])
    folds = scene_folds(find_real_pictures(real_root), 2)
    assert sorted(sum(folds, [])) == sorted({p.scene for p in find_real_pictures(real_root)})
    assert not set(folds[0]) & set(folds[1])


def test_target_sign_and_scale(real_root: Path):
    src = next(s for s in real_sources(real_root, SkipReport()) if s.name.endswith("Alpha/view1"))
    t = real_target(src.gt_disparity, src.truth_kind, src.truth_scale, (64, 48))
    assert np.isnan(t[0]).all()
    # nearer (larger disparity) -> smaller D; in px of stereo disparity (Middlebury 2006: as stored)
    assert t[20, 30] == -80 and t[40, 5] == -20
    kin = next(s for s in real_sources(real_root, SkipReport()) if s.name == "kinect/ch7_1")
    tk = real_target(kin.gt_disparity, kin.truth_kind, kin.truth_scale, (64, 48))
    # a Kinect's own stereo disparity: 525 px * (64 / 640) * 0.075 m / z
    assert tk[5, 5] == pytest.approx(-525 * 0.1 * 0.075 / 1.0, rel=1e-4)
    assert tk[5, 40] == pytest.approx(-525 * 0.1 * 0.075 / 2.0, rel=1e-4)
    ts = TrainingSet(real_sources(real_root, SkipReport()), Augment(crop=32))
    sample = ts.draw(np.random.default_rng(0))
    assert sample.kind == "gt" and sample.disparity_invariant and sample.gt_exponent is None
    assert sample.gt_disparity.shape == sample.image.shape[:2]


def test_train_on_real_keeps_hdr_of_teacher(real_root: Path, tmp_path: Path):
    """`rvr train --real` from weights: D is supervised up to scale, E is kept near the start's."""
    import torch

    from rvr_addon.estimate.train import Trainer, TrainSettings, export_weights
    from rvr_addon.estimate.unet import EstimatorConfig, EstimatorNet

    torch.manual_seed(0)
    start = tmp_path / "start.pt"
    net = EstimatorNet(EstimatorConfig(widths=(8, 16, 16, 16)))
    export_weights(net, start, iterations=0, wall_time_s=0.0, training={})
    run = tmp_path / "run"
    trainer = Trainer(TrainSettings(run_dir=run, real=[real_root], real_exclude=("Gamma",), iterations=3, batch=2,
                                    crop=32, init_from=start, checkpoint_every=10))
    assert trainer.teacher is not None
    assert trainer.data.summary()["real_pictures"] == 5
    while trainer.step():
        pass
    trainer.finish()
    rows = list(csv.DictReader((run / "loss_log.csv").open()))
    assert len(rows) == 3
    assert all(float(r["sup_keep"]) >= 0 and float(r["sup_d"]) > 0 for r in rows)
    assert all("Gamma" not in r["sample"] for r in rows)
    assert (run / "estimator.pt").is_file()


def test_train_needs_some_data(tmp_path: Path):
    from rvr_addon.estimate.train import Trainer, TrainSettings

    with pytest.raises(InputError, match="--real DIR"):
        Trainer(TrainSettings(run_dir=tmp_path / "run"))


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data/real_depth is absent")
def test_shared_real_depth_listing():
    pics = find_real_pictures(SHARED)
    scenes = {p.scene for p in pics}
    assert len([p for p in pics if p.set == "middlebury2006"]) == 42
    assert len([s for s in scenes if s.startswith("middlebury")]) == 25
    for p in pics:
        q = read_inverse_depth(p)
        ok = np.isfinite(q)
        assert ok.mean() > 0.5 and (q[ok] > 0).all(), p.name


def _tiny_start(tmp_path: Path) -> Path:
    import torch

    from rvr_addon.estimate.train import export_weights
    from rvr_addon.estimate.unet import EstimatorConfig, EstimatorNet

    torch.manual_seed(0)
    start = tmp_path / "start.pt"
    export_weights(EstimatorNet(EstimatorConfig(widths=(8, 16, 16, 16))), start, iterations=0, wall_time_s=0.0,
                   training={}, inference_max_pixels=1200)
    return start


def test_train_only_disparity_head_leaves_e_and_the_trunk_alone(real_root: Path, tmp_path: Path):
    """train_only="disparity-head": the grid head learns, every other parameter (E's path) stays."""
    import torch

    from rvr_addon.estimate.infer import load_estimator
    from rvr_addon.estimate.train import Trainer, TrainSettings

    start = _tiny_start(tmp_path)
    trainer = Trainer(TrainSettings(run_dir=tmp_path / "run", real=[real_root], iterations=3, batch=2, crop=32,
                                    init_from=start, checkpoint_every=10, lr=1e-2, train_only="disparity-head"))
    assert trainer.teacher is None
    while trainer.step():
        pass
    trainer.finish()
    before = load_estimator(start).net.state_dict()
    after = load_estimator(tmp_path / "run" / "estimator.pt").net.state_dict()
    for name, value in after.items():
        same = torch.equal(value, before[name])
        assert same != name.startswith("grid_head."), name
    with pytest.raises(InputError, match="train-only"):
        Trainer(TrainSettings(run_dir=tmp_path / "run2", real=[real_root], init_from=start, train_only="trunk"))


def test_cli_train_only_choices_are_the_trainers():
    """`rvr train --train-only` (the torch-free CLI spells its choices out) offers exactly train.TRAIN_ONLY."""
    from rvr_addon.cli import build_parser
    from rvr_addon.estimate.train import TRAIN_ONLY

    parser = build_parser()
    train = next(a for a in parser._subparsers._group_actions[0].choices["train"]._actions
                 if a.dest == "train_only")
    assert set(train.choices) == set(TRAIN_ONLY)
    assert train.default in TRAIN_ONLY


def test_head_fit_cv_and_export(real_root: Path, tmp_path: Path):
    """python -m rvr_addon.estimate.head_fit: leave-scene-out rows per held-out view, exported weights
    whose E is bit-identical to the start's and whose D differs."""
    import json

    import torch

    from rvr_addon.estimate import head_fit
    from rvr_addon.estimate.infer import load_estimator

    start = _tiny_start(tmp_path)
    out = tmp_path / "fit"
    assert head_fit.main(["--real", str(real_root), "--init-from", str(start), "-o", str(out), "--cv", "3",
                          "--iterations", "5", "--row-prior", "--lr", "1e-2"]) == 0
    rep = json.loads((out / "head_fit.json").read_text())
    assert {r["fold"] for r in rep["cv_rows"]} == {0, 1, 2}
    assert len([r for r in rep["cv_rows"] if r["name"].startswith("middlebury")]) == 6
    assert 0.0 <= rep["cv"]["better_than_ramp_share"] <= 1.0
    old, new = load_estimator(start), load_estimator(out / "estimator.pt")
    assert new.net.config.row_prior and new.header["inference_max_pixels"] == 1200
    img = torch.rand(1, 3, 40, 56)
    img[:, :, 5:15, 5:25] = 1.0  # clipped: E is non-zero there
    with torch.no_grad():
        a, b = old.net(img), new.net(img)
    assert torch.equal(a.exponent, b.exponent) and float(a.exponent.max()) > 0
    assert not torch.equal(a.disparity_rel, b.disparity_rel)


def test_head_fit_mixes_procedural_frames(real_root: Path, tmp_path: Path):
    """head_fit --procedural: the frames of an `rvr procedural` dataset are prepared with their exact D
    (larger = farther, the real targets' orientation), each batch draws its share from them (a share of
    0 never reads them, so the fit equals the real-only one), and the settings are recorded."""
    import json

    import torch

    from rvr_addon.cli import main as rvr
    from rvr_addon.estimate import head_fit
    from rvr_addon.estimate.infer import load_estimator

    data = tmp_path / "proc"
    assert rvr(["procedural", "-o", str(data), "--frames", "2", "--seed", "3", "-q"]) == 0
    start = _tiny_start(tmp_path)
    net, _ = head_fit._load(start, False)
    frames = head_fit.prepare_procedural(net, [data], 1200)
    assert len(frames) == 2 and all(len(v) == 2 for v in frames.values())  # + the flipped copy
    f = next(iter(frames.values()))[0]
    assert f.scene == "procedural" and torch.isfinite(f.train_target).any()
    assert np.allclose(f.q, -f.target[0, 0].numpy(), equal_nan=True)

    fits = {}
    for name, share in (("real", None), ("zero", "0"), ("mixed", "1")):
        args = ["--real", str(real_root), "--init-from", str(start), "-o", str(tmp_path / name),
                "--iterations", "3", "--lr", "1e-2"]
        if share is not None:
            args += ["--procedural", str(data), "--procedural-share", share]
        assert head_fit.main(args) == 0
        fits[name] = load_estimator(tmp_path / name / "estimator.pt").net.grid_head.weight.detach()
    assert torch.equal(fits["real"], fits["zero"])
    assert not torch.equal(fits["real"], fits["mixed"])
    rep = json.loads((tmp_path / "mixed" / "head_fit.json").read_text())
    assert rep["settings"]["procedural"] == [str(data)] and rep["settings"]["procedural_share"] == 1.0
