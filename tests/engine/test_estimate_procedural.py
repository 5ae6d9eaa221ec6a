"""Procedural training scenes: exact depth, occlusion, determinism, datasets on disk, scale-free loss."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from rvr_addon.cli import main
from rvr_addon.errors import InputError
from rvr_addon.estimate.data import Augment, SkipReport, TrainingSet, training_sources
from rvr_addon.estimate.losses import LossWeights, supervised_loss
from rvr_addon.estimate.procedural import (
    Camera, Material, Rect, Scene, TexturePool, _box, mip_pyramid, random_frame, texture_paths, trace,
    write_dataset,
)

TINY = ((48, 32), (40, 40))


def grey() -> Material:
    return Material(mip_pyramid(np.full((16, 16, 3), 0.5, np.float32)), 0.05)


def level_camera(height_m: float, w: int = 40, h: int = 30, f: float = 30.0) -> Camera:
    return Camera(np.array([0.0, height_m, 0.0]), np.eye(3), f, w, h, (w / 2, h / 2))


@pytest.fixture(scope="module")
def pool() -> TexturePool:
    return TexturePool.from_paths(texture_paths([]))


def test_floor_depth_is_exact():
    """A level camera 1.5 m above an infinite floor: the row at y px below the centre sees the
    floor at planar depth h f / y."""
    cam = level_camera(1.5)
    floor = Rect(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), (np.inf, np.inf), grey())
    _, depth = trace(Scene(cam, [floor]), ss=1)
    for row in range(16, 30):
        y = row + 0.5 - 15
        assert depth[row, 20] == pytest.approx(1.5 * 30.0 / y, rel=1e-9)
    assert np.all(depth[:15] == 1e4)  # above the horizon: the sky


def test_a_box_occludes_the_wall_behind_it(pool):
    cam = level_camera(1.0)
    wall = Rect(np.array([0, 0, 6.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), (np.inf, np.inf), grey())
    box = _box(np.random.default_rng(0), pool, 0.0, 2.0, 0.6, 0.4, 2.0, 0.0)
    _, depth = trace(Scene(cam, [wall] + box), ss=1)
    assert depth[15, 20] == pytest.approx(1.8)  # the box's front face, z = 2 - 0.4 / 2
    assert depth[15, 1] == pytest.approx(6.0)  # the wall beside it


def test_random_frames_are_deterministic_and_consistent(pool):
    a = random_frame(np.random.default_rng(7), pool, 48, 32)
    b = random_frame(np.random.default_rng(7), pool, 48, 32)
    c = random_frame(np.random.default_rng(8), pool, 48, 32)
    assert np.array_equal(a.image, b.image) and np.array_equal(a.disparity, b.disparity)
    assert not np.array_equal(a.image, c.image)
    assert a.image.shape == (32, 48, 3) and a.disparity.shape == (32, 48) and a.radiance.shape == (32, 48, 3)
    assert np.array_equal(np.round(a.image * 255), a.image * 255) and 0 <= a.image.min() and a.image.max() <= 1
    assert np.isfinite(a.disparity).all()
    # D = K (1/S_ref - 1/S): strictly increasing with depth
    order = np.argsort(a.depth.ravel())
    assert np.all(np.diff(a.disparity.ravel()[order]) >= -1e-5)


def test_dataset_resumes_and_refuses_another_seed(tmp_path, pool):
    out = tmp_path / "proc"
    assert write_dataset(out, 3, seed=4, pool=pool, sizes=TINY) == 3
    first = (out / "input" / "frame_00002.png").read_bytes()
    (out / "done" / "frame_00002.json").unlink()
    assert write_dataset(out, 4, seed=4, pool=pool, sizes=TINY) == 2  # frame 2 again, and the new frame 4
    assert (out / "input" / "frame_00002.png").read_bytes() == first  # same seed: the same frame
    assert json.loads((out / "manifest.json").read_text())["frames"] == 4
    with pytest.raises(InputError, match="seed 4"):
        write_dataset(out, 4, seed=5, pool=pool, sizes=TINY)


def test_procedural_frames_are_scale_free_ground_truth(tmp_path, pool):
    out = tmp_path / "proc"
    write_dataset(out, 2, seed=1, pool=pool, sizes=TINY)
    report = SkipReport()
    sources = training_sources(tmp_path, report)
    assert len(sources) == 2 and report.total == 0
    assert all(s.origin == "procedural" and s.kinds == ("gt",) and s.disparity_invariant for s in sources)
    sample = TrainingSet(sources, Augment(crop=24)).draw(np.random.default_rng(0))
    assert sample.kind == "gt" and sample.disparity_invariant
    assert sample.gt_disparity.shape == sample.image.shape[:2] and np.isfinite(sample.gt_disparity).all()
    assert sample.gt_exponent.shape == sample.image.shape


def test_procedural_share_picks_the_pool(tmp_path, pool):
    from estimate_synth import make_clip

    write_dataset(tmp_path / "proc", 2, seed=1, pool=pool, sizes=TINY)
    make_clip(tmp_path / "clip0", seed=5, frames=2)
    sources = training_sources(tmp_path, SkipReport())
    assert {s.origin for s in sources} == {"procedural", "harness"}
    rng = np.random.default_rng(0)
    for share, origin in ((1.0, "procedural"), (0.0, "harness")):
        data = TrainingSet(sources, Augment(crop=24, procedural_share=share))
        names = {data.draw(rng).name.split("/")[0] for _ in range(12)}
        assert names == ({"proc"} if origin == "procedural" else {"clip0"})


def test_scale_free_loss_ignores_a_positive_scale_and_shift_but_not_inversion():
    gt = torch.linspace(-1, 2, 64).reshape(1, 1, 8, 8)
    e = torch.zeros(1, 3, 8, 8)
    w = LossWeights()
    good = supervised_loss(3 * gt + 1, gt, e, None, None, 1.0, w, scale_free=True)
    assert good.parts["sup_d"] == pytest.approx(0, abs=1e-5) and good.parts["sup_dgrad"] == pytest.approx(0, abs=1e-5)
    flipped = supervised_loss(-gt, gt, e, None, None, 1.0, w, scale_free=True)
    assert flipped.parts["sup_d"] > 1.2 * float((gt - gt.median()).abs().mean())  # worse than a flat map
    invariant = supervised_loss(-gt, gt, e, None, None, 1.0, LossWeights(disparity_invariant=True))
    assert invariant.parts["sup_d"] == pytest.approx(0, abs=1e-5)  # the least-squares fit would flip it
    absolute = supervised_loss(3 * gt + 1, gt, e, None, None, 1.0, w)
    assert absolute.parts["sup_d"] > 1
    pred = (-gt).clone().requires_grad_(True)
    supervised_loss(pred, gt, e, None, None, 1.0, w, scale_free=True).total.backward()
    assert float((pred.grad.ravel() * (gt - gt.mean()).ravel()).sum()) < 0  # a step down the gradient un-inverts


def test_cli_procedural_then_train(tmp_path, capsys):
    data = tmp_path / "proc"
    assert main(["procedural", "-o", str(data), "--frames", "2", "--seed", "3", "-q"]) == 0
    assert "wrote 2 frames" in capsys.readouterr().out
    run = tmp_path / "run"
    assert main(["train", "--data", str(data), "-o", str(run), "--iterations", "2", "--crop", "32",
                 "--checkpoint-every", "1", "-q"]) == 0
    header = json.loads((run / "estimator.json").read_text())
    assert header["training"]["training_data"]["procedural_frames"] == 2
    rows = (run / "loss_log.csv").read_text().splitlines()[1:]
    assert len(rows) == 2 and all(",gt,proc/" in r for r in rows)
    assert main(["procedural", "-o", str(data), "--frames", "0"]) == 2
    assert main(["procedural", "-o", str(tmp_path / "v9"), "--frames", "1", "--generator", "9"]) == 2
    assert "generator version 9" in capsys.readouterr().err
    assert main(["procedural", "-o", str(data), "--frames", "2", "--seed", "9"]) == 2
    assert "seed 3" in capsys.readouterr().err
    assert math.isfinite(float(rows[-1].split(",")[2]))


def test_generator_versions(tmp_path, pool, monkeypatch):
    """Version 3 draws a close-up when its first number is below 1/3; version 2 never does (so its
    datasets rebuild exactly); unknown versions are refused."""
    from rvr_addon.estimate import procedural

    calls = []
    monkeypatch.setattr(procedural, "closeup_scene", lambda rng, *a: calls.append(1) or Scene(level_camera(1.0)))
    for seed in range(12):
        procedural.random_scene(np.random.default_rng([seed]), pool, 48, 32, version=2)
    assert calls == []
    expected = sum(np.random.default_rng([seed]).random() < 1 / 3 for seed in range(12))
    for seed in range(12):
        procedural.random_scene(np.random.default_rng([seed]), pool, 48, 32, version=3)
    assert len(calls) == expected > 0
    monkeypatch.undo()
    # a close-up frames things: more than the floor and the backdrop are in view
    for seed in range(4):
        scene = procedural.closeup_scene(np.random.default_rng(seed), pool, 64, 36)
        _, depth = trace(scene, ss=1)
        planes = {round(float(v), 3) for v in np.unique(np.round(depth, 3))}
        assert len(planes) > 10
    with pytest.raises(InputError, match="generator version 9"):
        write_dataset(tmp_path / "x", 1, seed=1, pool=pool, version=9)
    write_dataset(tmp_path / "v2", 1, seed=1, pool=pool, sizes=TINY, version=2)
    with pytest.raises(InputError, match="--generator 2"):
        write_dataset(tmp_path / "v2", 2, seed=1, pool=pool, sizes=TINY, version=3)


def test_degraded_inputs_keep_their_targets(tmp_path, pool):
    """--degrade changes a ground-truth-only sample's input (8-bit values, blur/noise/JPEG) and
    nothing else: the same draw without it has the same disparity target; rendered kinds never."""
    from rvr_addon.estimate.data import degrade_like_footage

    rng = np.random.default_rng(0)
    img = np.clip(np.random.default_rng(1).random((32, 48, 3)), 0, 1).astype(np.float32)
    out = degrade_like_footage(img, rng)
    assert out.shape == img.shape and out.dtype == np.float32
    assert np.array_equal(np.round(out * 255), out * 255) and 0.005 < float(np.abs(out - img).mean()) < 0.2
    write_dataset(tmp_path / "proc", 2, seed=1, pool=pool, sizes=TINY)
    sources = training_sources(tmp_path, SkipReport())
    plain = TrainingSet(sources, Augment(crop=24)).make(sources[0], np.random.default_rng(5))
    worn = TrainingSet(sources, Augment(crop=24, degrade=1.0)).make(sources[0], np.random.default_rng(5))
    assert not np.array_equal(plain.image, worn.image)
    assert np.array_equal(plain.gt_disparity, worn.gt_disparity)
    lit = TrainingSet(sources, Augment(crop=24, expose=1.0)).make(sources[0], np.random.default_rng(5))
    assert float(lit.image.mean()) > float(plain.image.mean()) and np.array_equal(plain.gt_disparity, lit.gt_disparity)
    from estimate_synth import make_clip

    make_clip(tmp_path / "clips" / "clip0", seed=5, frames=1)
    (src,) = training_sources(tmp_path / "clips", SkipReport())
    a = TrainingSet([src], Augment(crop=24)).make(src, np.random.default_rng(5))
    b = TrainingSet([src], Augment(crop=24, degrade=1.0)).make(src, np.random.default_rng(5))
    assert a.kind != "gt" and np.array_equal(a.image, b.image)


def test_exposure_changes_keep_clipped_pixels_and_the_hdr_target_consistent():
    """--expose: gains >= 1 (at most 1 stop times a 1.25 white-balance ratio) multiply the linear
    input and the true radiance alike, so a clipped pixel stays clipped and the exponent target
    of an unclipped pixel stays 0."""
    from rvr_addon.color import srgb_to_linear
    from rvr_addon.estimate.data import exponent_target, expose_like_footage

    img = np.full((4, 4, 3), 0.2, np.float32)
    img[0, 0] = 1.0
    hdr = srgb_to_linear(img).astype(np.float32)
    hdr[0, 0] = 8.0
    for seed in range(20):
        out, rad = expose_like_footage(img, hdr, np.random.default_rng(seed))
        gains = rad[1, 1] / hdr[1, 1]
        assert np.all(gains >= 1 - 1e-6) and gains.max() <= 2.0 * 1.25 + 1e-5
        assert np.array_equal(np.round(out * 255), out * 255) and np.all(out[0, 0] == 1.0)
        assert np.allclose(srgb_to_linear(out[1, 1]), np.minimum(srgb_to_linear(img[1, 1]) * gains, 1), atol=3e-3)
        e, sat = exponent_target(out, rad)
        assert sat[0, 0] and np.allclose(e[0, 0], np.log(8.0 * gains) / 50, atol=1e-4)
        assert not sat[1, 1] or out[1, 1].max() == 1.0
    assert expose_like_footage(img, None, np.random.default_rng(0))[1] is None


def test_parallel_workers_write_the_same_frames(tmp_path, pool, capsys):
    write_dataset(tmp_path / "one", 4, seed=6, pool=pool, sizes=TINY)
    assert write_dataset(tmp_path / "two", 4, seed=6, pool=pool, sizes=TINY, workers=2) == 4
    for i in range(1, 5):
        for rel in (f"input/frame_{i:05d}.png", f"gt/disparity/frame_{i:05d}.exr", f"done/frame_{i:05d}.json"):
            assert (tmp_path / "one" / rel).read_bytes() == (tmp_path / "two" / rel).read_bytes(), rel
    assert write_dataset(tmp_path / "two", 4, seed=6, pool=pool, sizes=TINY, workers=2) == 0
    assert main(["procedural", "-o", str(tmp_path / "x"), "--frames", "2", "--workers", "0"]) == 2
    assert "--workers" in capsys.readouterr().err


def test_a_failing_worker_is_reported_and_written_frames_stay(tmp_path, pool, monkeypatch):
    from rvr_addon.estimate import procedural

    real = procedural.write_frame

    def flaky(folder, index, *a):
        if index == 2:
            raise OSError("disk full")
        real(folder, index, *a)

    monkeypatch.setattr(procedural, "write_frame", flaky)  # the forked workers inherit it
    with pytest.raises(InputError, match="1 of 2 `rvr procedural` workers failed.*run the command again"):
        write_dataset(tmp_path / "p", 4, seed=6, pool=pool, sizes=TINY, workers=2)
    done = sorted(p.name for p in (tmp_path / "p" / "done").glob("*.json"))
    assert done == ["frame_00001.json", "frame_00003.json"]  # worker 2 stopped at frame 2, before 4
