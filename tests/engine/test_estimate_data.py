"""Training data: harness sidecars, drawing samples, bracketed photos and their ECC alignment."""
from __future__ import annotations

import json
import logging

import cv2
import numpy as np
import pytest
import torch

from estimate_synth import MEMBERS, input_srgb, make_clip, true_exponent
from rvr_addon.errors import InputError
from rvr_addon.estimate.align import AlignmentError, ecc_align, inner_rectangle, warp_to_reference
from rvr_addon.estimate.data import (
    Augment, SkipReport, TrainingSet, find_harness_clips, find_photo_shots, harness_sources, photo_sources,
    read_srgb,
)
from rvr_addon.estimate.losses import render_member, to_display
from rvr_addon.render.model import hdr_radiance
from rvr_addon.color import srgb_to_linear


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("harness")
    truth = make_clip(root / "nested" / "clipA", seed=1, frames=2, width=48, height=40)
    make_clip(root / "clipB", seed=2, frames=2, complete=False)
    (root / "not_a_clip").mkdir()
    (root / "not_a_clip" / "manifest.json").write_text(json.dumps({"format": "something-else/1"}))
    return root, truth


def test_harness_clips_and_incomplete_frames(dataset):
    root, _ = dataset
    assert sorted(p.name for p in find_harness_clips(root)) == ["clipA", "clipB"]
    report = SkipReport()
    sources = harness_sources(root, report)
    assert sorted(s.name for s in sources) == ["clipA/frame_00001", "clipA/frame_00002", "clipB/frame_00001"]
    assert report.counts == {"incomplete frame": 1}
    assert "skipped 1: 1 incomplete frame" == report.summary()
    src = next(s for s in sources if s.name == "clipA/frame_00001")
    assert src.kinds == ("pair", "aperture", "focal")
    assert src.third == {"aperture": ("mid", "small"), "focal": ("focusB",)}
    assert src.native_width == 48
    f, a = MEMBERS["focusB"][1:]
    assert (src.members["focusB"].alpha, src.members["focusB"].beta) == (a, -a * f)


def test_harness_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        harness_sources(tmp_path / "missing", SkipReport())
    with pytest.raises(InputError, match="no harness clip"):
        harness_sources(tmp_path, SkipReport())
    with pytest.raises(InputError, match="no usable training samples"):
        TrainingSet([])


def test_drawn_samples_scale_beta_with_the_resize(dataset):
    root, _ = dataset
    sources = [s for s in harness_sources(root, SkipReport()) if s.name.startswith("clipA")]
    data = TrainingSet(sources, Augment(crop=24, scale_range=(0.6, 1.0)))
    rng = np.random.default_rng(0)
    kinds = set()
    for _ in range(30):
        s = data.draw(rng)
        kinds.add(s.kind)
        assert s.image.shape == s.target.shape == (24, 24, 3) and s.image.dtype == np.float32
        scale = s.frame_width / 48
        assert 0.6 - 1e-6 <= scale <= 1.0 + 1e-6
        assert s.alpha == 1.0 and s.beta == 0.0  # the large member is focused at 0 with a = 1
        if s.kind == "focal":
            third, alpha, beta = s.adjusted
            assert alpha == 1.0 and beta == pytest.approx(-3.0 * scale)
        elif s.kind == "aperture":
            assert s.adjusted[1] in (MEMBERS["mid"][2], MEMBERS["small"][2]) and s.adjusted[2] == 0.0
        else:
            assert s.adjusted is None
    assert kinds == {"pair", "aperture", "focal"}


def test_ground_truth_reproduces_the_targets(dataset):
    """Input PNG + true E + true D through render_member == the member PNGs (8-bit rounding)."""
    root, truth = dataset
    radiance, disparity = truth[1]
    clip = root / "nested" / "clipA"
    img = read_srgb(clip / "input" / "frame_00001.png")
    np.testing.assert_allclose(img, input_srgb(radiance), atol=1e-6)
    e = torch.from_numpy(true_exponent(radiance)).permute(2, 0, 1)[None]
    rad = hdr_radiance(srgb_to_linear(torch.from_numpy(img).permute(2, 0, 1)[None]), e)
    d = torch.from_numpy(disparity)[None, None]
    sidecar = json.loads((clip / "train" / "frame_00001.json").read_text())
    for name, m in sidecar["members"].items():
        got = to_display(render_member(rad, d, m["alpha"], m["beta"]))[0].permute(1, 2, 0).numpy()
        want = read_srgb(clip / m["png"])
        assert np.abs(got - want).mean() < 2e-3, name


# ------------------------------------------------------------------------------ photos


def texture(seed: int, width: int = 240, height: int = 180) -> np.ndarray:
    """A photo-like RGB uint8 texture with structure at several scales."""
    rng = np.random.default_rng(seed)
    img = np.zeros((height, width, 3), np.float32)
    for cells in (4, 12, 40):
        img += cv2.resize(rng.random((cells, cells, 3)).astype(np.float32), (width, height),
                          interpolation=cv2.INTER_CUBIC) / 3
    for _ in range(8):
        x, y = int(rng.integers(0, width - 30)), int(rng.integers(0, height - 30))
        img[y:y + int(rng.integers(8, 30)), x:x + int(rng.integers(8, 30))] = rng.random(3)
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def similarity(angle_deg: float, shift: tuple[float, float], center: tuple[float, float], scale: float = 1.0):
    m = cv2.getRotationMatrix2D(center, angle_deg, scale)
    m[:, 2] += shift
    return np.vstack([m, [0, 0, 1]])


def test_ecc_recovers_a_rotation_and_shift():
    ref = texture(0)
    h, w = ref.shape[:2]
    true = similarity(1.5, (5.0, -3.0), (w / 2, h / 2))  # moving(x) = ref(true^-1 x): warp maps ref -> moving
    moving = cv2.warpPerspective(ref, true, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    moving = cv2.GaussianBlur(moving, (0, 0), 1.2)  # the large aperture is softer
    al = ecc_align(ref, moving, motion="homography")
    corners = np.array([[0, 0, 1], [w, 0, 1], [0, h, 1], [w, h, 1]], float).T
    got, want = al.warp @ corners, true @ corners
    assert np.abs(got[:2] / got[2] - want[:2] / want[2]).max() < 0.5  # px
    aligned, valid = warp_to_reference(moving, al, (w, h))
    y0, y1, x0, x1 = inner_rectangle(valid)
    assert valid[y0:y1, x0:x1].all() and (y1 - y0) * (x1 - x0) > 0.8 * w * h
    blurred_ref = cv2.GaussianBlur(ref, (0, 0), 1.2).astype(np.float32)
    err = np.abs(aligned[y0:y1, x0:x1].astype(np.float32) - blurred_ref[y0:y1, x0:x1]).mean()
    assert err < 3.0  # 8-bit levels
    affine = ecc_align(ref, moving, motion="affine")
    assert np.abs(affine.warp - al.warp).max() < 0.05


def test_ecc_rejects_unrelated_images():
    with pytest.raises(AlignmentError):
        ecc_align(texture(1), texture(2))


def _save(path, rgb, f_number=None):
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    img = Image.fromarray(rgb)
    if f_number is None:
        img.save(path)
    else:
        exif = Image.Exif()
        exif.get_ifd(0x8769)[0x829D] = f_number
        img.save(path, exif=exif, quality=95)


def test_photo_folder_pairs_triplets_and_skips(tmp_path, caplog):
    photos = tmp_path / "photos"
    ref = texture(3)
    h, w = ref.shape[:2]
    warp = similarity(-1.0, (3.0, 2.0), (w / 2, h / 2))
    moved = cv2.warpPerspective(cv2.GaussianBlur(ref, (0, 0), 2.0), warp, (w, h), borderMode=cv2.BORDER_REFLECT)
    medium = cv2.warpPerspective(cv2.GaussianBlur(ref, (0, 0), 0.7), similarity(0.5, (-2.0, 1.0), (w / 2, h / 2)),
                                 (w, h), borderMode=cv2.BORDER_REFLECT)
    # a flat-named aperture triplet with EXIF f-numbers
    _save(photos / "tree_small.jpg", ref, 22.0)
    _save(photos / "tree_large.jpg", moved, 2.0)
    _save(photos / "tree_medium.jpg", medium, 8.0)
    # a shot in its own folder, f-numbers from its JSON, a focal triplet member with its shift
    _save(photos / "cup" / "small.png", ref)
    _save(photos / "cup" / "large.png", moved)
    _save(photos / "cup" / "focusB.png", moved)
    (photos / "cup" / "shot.json").write_text(json.dumps({"focusB": {"beta": -4.0}}))
    # broken shots: a missing partner, an unrelated "large" image
    _save(photos / "lonely_small.jpg", ref)
    _save(photos / "wrong_small.png", texture(4))
    _save(photos / "wrong_large.png", texture(5))
    (photos / "notes.txt").write_text("not a photo")
    report = SkipReport()
    with caplog.at_level(logging.WARNING):
        sources = photo_sources(photos, tmp_path / "cache", report, max_side=200)
    assert sorted(s.name for s in sources) == ["photos/cup", "photos/tree"]
    assert report.counts == {"missing partner": 1, "alignment failed": 1}
    assert "lonely" in caplog.text and "wrong" in caplog.text
    tree = next(s for s in sources if s.name == "photos/tree")
    assert tree.kinds == ("pair", "aperture")
    assert tree.members["large"].alpha == 1.0 and tree.members["large"].beta == 0.0
    assert tree.members["medium"].alpha == pytest.approx(2.0 / 8.0)  # N_large / N_medium
    cup = next(s for s in sources if s.name == "photos/cup")
    assert cup.kinds == ("pair", "focal")
    assert cup.members["focusB"].beta == pytest.approx(-4.0 * 200 / 240)  # px at the stored width
    small, large = read_srgb(tree.input), read_srgb(tree.members["large"].path)
    assert small.shape == large.shape and max(small.shape[:2]) <= 200
    expect = cv2.GaussianBlur(small, (0, 0), 2.0 * 200 / 240)
    assert np.abs(large - expect)[5:-5, 5:-5].mean() < 0.03  # aligned to the small-aperture shot
    # the aligned shots are cached: a second pass reuses them without re-aligning
    again = photo_sources(photos, tmp_path / "cache", SkipReport(), max_side=200)
    assert sorted(s.name for s in again) == ["photos/cup", "photos/tree"]
    data = TrainingSet(sources, Augment(crop=64))
    s = data.draw(np.random.default_rng(0))
    assert s.image.shape == (64, 64, 3)


def test_photo_medium_without_f_numbers_becomes_a_pair(tmp_path):
    ref = texture(6)
    _save(tmp_path / "a_small.png", ref)
    _save(tmp_path / "a_large.png", cv2.GaussianBlur(ref, (0, 0), 1.5))
    _save(tmp_path / "a_medium.png", cv2.GaussianBlur(ref, (0, 0), 0.8))
    report = SkipReport()
    (src,) = photo_sources(tmp_path, tmp_path / "cache", report, max_side=160)
    assert src.kinds == ("pair",) and report.counts == {"medium without f-numbers": 1}


def test_photo_folder_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        find_photo_shots(tmp_path / "nope", SkipReport())
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no bracketed photos"):
        find_photo_shots(tmp_path / "empty", SkipReport())


# ------------------------------------------------------------------------------ ground truth (supervised terms)


def test_samples_carry_ground_truth_resized_like_the_images(dataset):
    from rvr_addon.estimate.data import SATURATED

    root, truth = dataset
    sources = [s for s in harness_sources(root, SkipReport()) if s.name.startswith("clipA")]
    assert all(s.gt_disparity is not None and s.gt_hdr is not None for s in sources)
    # at scale 1 without flip the crop of D is the truth itself and E reproduces the radiance
    data = TrainingSet(sources, Augment(crop=48, scale_range=(1.0, 1.0), flip=False))
    s = data.make(sources[0], np.random.default_rng(0))
    radiance, disparity = truth[int(sources[0].name[-1])]
    np.testing.assert_array_equal(s.gt_disparity, disparity)
    sat = s.saturated
    assert sat.any() and (~sat).any()
    np.testing.assert_array_equal(sat, s.image.max(axis=-1) >= SATURATED)
    rebuilt = srgb_to_linear(s.image) * np.exp(50.0 * s.gt_exponent)
    np.testing.assert_allclose(rebuilt[sat], np.maximum(radiance[sat], srgb_to_linear(s.image)[sat]), rtol=1e-4)
    assert float(s.gt_exponent[~sat].max()) < 0.01  # nothing clipped: gain ~1 (8-bit rounding)
    # resized + flipped: D is scaled by the width ratio, nearest-neighbour (only values of the truth)
    data = TrainingSet(sources, Augment(crop=20, scale_range=(0.5, 0.7), flip=True))
    rng = np.random.default_rng(3)
    for _ in range(10):
        s = data.draw(rng)
        scale = s.frame_width / 48
        assert s.gt_disparity.shape == s.image.shape[:2] == s.saturated.shape
        assert s.gt_exponent.shape == s.image.shape and s.native_width == 48
        values = {round(float(v), 4) for v in np.unique(np.concatenate([d.ravel() for d, _ in
                                                                          (truth[1][::-1], truth[2][::-1])]))}
        got = {round(float(v) / scale, 4) for v in np.unique(s.gt_disparity)}
        assert got <= values


def test_whole_frame_samples_and_photos_without_ground_truth(dataset, tmp_path):
    root, _ = dataset
    sources = [s for s in harness_sources(root, SkipReport()) if s.name.startswith("clipA")]
    data = TrainingSet(sources, Augment(crop=24, whole_frame=1.0))
    s = data.draw(np.random.default_rng(0))
    h, w = s.image.shape[:2]
    assert w == round(s.frame_width) and 0.5 * 24**2 * 0.8 <= h * w <= 24**2 * 1.1  # the whole frame, ~crop^2 px
    assert w / h == pytest.approx(48 / 40, rel=0.1)
    # a clip without ground truth (like photos) gives samples without it
    make_clip(tmp_path / "nogt", seed=9, frames=1, gt=False)
    (src,) = harness_sources(tmp_path / "nogt", SkipReport())
    assert src.gt_disparity is None and src.gt_hdr is None
    s = TrainingSet([src], Augment(crop=16)).draw(np.random.default_rng(0))
    assert s.gt_disparity is None and s.gt_exponent is None and s.saturated is None


def test_ground_truth_only_clips_train_the_supervised_terms(tmp_path):
    """A clip without training sidecars (generate --no-dof) gives kind-``gt`` samples: the input and
    its ground truth, no shallow-DOF image; the loss is the supervised terms alone, and draws take
    them with probability gt_share when rendered samples exist too."""
    import shutil

    import torch

    from rvr_addon.estimate.losses import LossWeights
    from rvr_addon.estimate.train import sample_loss
    from rvr_addon.estimate.unet import EstimatorNet

    make_clip(tmp_path / "deep", seed=3, frames=3, width=48, height=40)
    shutil.rmtree(tmp_path / "deep" / "train")  # what generate --no-dof writes: no training passes
    for marker in (tmp_path / "deep" / "done").glob("*.json"):
        rec = json.loads(marker.read_text())
        rec["files"] = {k: v for k, v in rec["files"].items() if not k.startswith("train/")}
        marker.write_text(json.dumps(rec))
    make_clip(tmp_path / "full", seed=4, frames=2, width=48, height=40)
    report = SkipReport()
    sources = harness_sources(tmp_path, report)
    deep = [s for s in sources if s.name.startswith("deep/")]
    assert len(deep) == 3 and all(s.kinds == ("gt",) and not s.members for s in deep)
    assert report.total == 0
    data = TrainingSet(sources, Augment(crop=32, gt_share=0.75))
    rng = np.random.default_rng(0)
    kinds = [data.draw(rng).kind for _ in range(400)]
    assert 0.68 < kinds.count("gt") / len(kinds) < 0.82
    sample = next(s for s in (data.draw(rng) for _ in range(50)) if s.kind == "gt")
    assert sample.gt_disparity is not None and sample.gt_exponent is not None and sample.adjusted is None
    torch.manual_seed(0)
    res = sample_loss(EstimatorNet(), sample, LossWeights(supervised=1.0))
    assert np.isfinite(res.total.item()) and res.total.item() > 0
    assert "rend" not in res.parts and "sup_d" in res.parts and "d_rms_px" in res.parts
    with pytest.raises(InputError, match="--supervised-weight"):
        sample_loss(EstimatorNet(), sample, LossWeights(supervised=0.0))


def test_ignore_prints_leaves_the_photo_prints_unsupervised(tmp_path):
    """--ignore-prints: billboards and poster panels (by ID) are NaN in the disparity target."""
    from dataclasses import replace

    from rvr_addon.estimate.data import print_ids, read_gt_disparity
    from rvr_addon.io.exr import write_exr

    manifest = {"object_ids": {"0": "set", "1": "ben", "24": "panel_3", "42": "billboards", "43": "lamps",
                               "25": "panelled_wall"}}
    assert print_ids(manifest) == (24, 42)
    assert print_ids({}) == ()
    d = np.arange(48 * 40, dtype=np.float32).reshape(40, 48)
    ids = np.zeros((40, 48), np.float32)
    ids[:, :10] = 42
    ids[:5] = 24
    ids[-3:, -3:] = 1
    exr = tmp_path / "d.exr"
    write_exr(exr, {"D": d, "ID": ids})
    got = read_gt_disparity(exr, (48, 40), (24, 42))
    assert np.isnan(got[:, :10]).all() and np.isnan(got[:5]).all()
    np.testing.assert_array_equal(got[5:, 10:], d[5:, 10:])
    np.testing.assert_array_equal(read_gt_disparity(exr, (48, 40)), d)  # without: all supervised
    write_exr(tmp_path / "noid.exr", {"D": d})
    with pytest.raises(InputError, match="no channel ID.*--ignore-prints"):
        read_gt_disparity(tmp_path / "noid.exr", (48, 40), (42,))

    make_clip(tmp_path / "clipP", seed=3, frames=1, width=48, height=40)
    path = tmp_path / "clipP" / "manifest.json"
    m = json.loads(path.read_text())
    m["object_ids"] = manifest["object_ids"]
    path.write_text(json.dumps(m))
    (src,) = harness_sources(tmp_path / "clipP", SkipReport(), ignore_prints=True)
    assert src.unsupervised_ids == (24, 42)
    assert harness_sources(tmp_path / "clipP", SkipReport())[0].unsupervised_ids == ()
    src = replace(src, gt_disparity=exr)
    sample = TrainingSet([src], Augment(crop=48, scale_range=(1.0, 1.0), flip=False)).make(src, np.random.default_rng(0))
    assert np.isnan(sample.gt_disparity[:, :10]).all() and np.isfinite(sample.gt_disparity[5:, 10:]).all()
