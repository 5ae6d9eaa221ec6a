"""AF-Net training data: the annotation file format, harness ground truth (focus regions, NFTs),
weak labels kept apart, sample drawing (issue 8)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from afnet_synth import BOX_A, annotated_clip, tiny_config, write_harness_clip
from rvr_addon.afnet.annotations import (
    ANNOTATION_FORMAT, AnnotatedClip, Annotation, read_annotations, write_annotations,
)
from rvr_addon.afnet.data import (
    DEPTH_KINDS, TrainingSet, augment_disparity, harness_targets, load_harness_clip, load_training_clips, nft_label,
)
from rvr_addon.afnet.encoding import DISPARITY_CODE_SCALE
from rvr_addon.errors import InputError


def test_annotation_round_trip_keeps_weak_apart(tmp_path):
    editor = annotated_clip(tmp_path / "a", 12, 5, 0)
    weak = AnnotatedClip(editor.clip, [Annotation(7, (1, 2, 3, 4), "weak:action", True, True)], weak=True)
    path = write_annotations(tmp_path / "ann.json", [editor, weak])
    data = json.loads(path.read_text())
    assert data["format"] == ANNOTATION_FORMAT and data["annotations"][0]["clip"] == "a/frames"
    clips = read_annotations(path)
    assert [(c.clip, c.weak) for c in clips] == [(editor.clip, False), (editor.clip, True)]
    assert clips[0].nft_frames == [5] and clips[0].depth == editor.depth
    assert clips[1].records == [Annotation(7, (1.0, 2.0, 3.0, 4.0), "weak:action", True, True)]


@pytest.mark.parametrize("content, match", [
    ({"format": "other/1", "annotations": []}, "format"),
    ({"format": ANNOTATION_FORMAT, "annotations": [{"clip": "c.mp4", "box": [0, 0, 4, 4]}]}, "lacks 'frame'"),
    ({"format": ANNOTATION_FORMAT, "annotations": [{"clip": "c.mp4", "frame": -1, "box": [0, 0, 4, 4]}]}, "frame"),
    ({"format": ANNOTATION_FORMAT, "annotations": [{"clip": "c.mp4", "frame": 1, "box": [0, 0, 0, 4]}]}, "box"),
    ({"format": ANNOTATION_FORMAT, "annotations": [{"clip": "c.mp4", "frame": 1, "box": [0, 0, 4, 4]}] * 2},
     "two NFT records"),
], ids=["format", "no-frame", "negative-frame", "empty-box", "duplicate"])
def test_annotation_errors_name_the_file(tmp_path, content, match):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    with pytest.raises(InputError, match=match) as info:
        read_annotations(path)
    assert "bad.json" in str(info.value)
    with pytest.raises(InputError, match="not found"):
        read_annotations(tmp_path / "missing.json")


def test_harness_ground_truth_focus_regions_and_nfts(tmp_path):
    folder = write_harness_clip(tmp_path / "h", 20, 8, 0)
    manifest = json.loads((folder / "manifest.json").read_text())
    subject, nfts = harness_targets(manifest)
    assert nfts == [8] and subject[:8] == ["ana"] * 8 and subject[8:] == ["bob"] * 12
    cfg = tiny_config()
    clip = load_harness_clip(folder, cfg)
    assert clip.kind == "harness" and not clip.weak and clip.nfts == [8] and clip.frames.shape == (20, 4, 24, 32)
    sx = cfg.width / 48
    np.testing.assert_allclose(clip.boxes[0], [BOX_A[0] * sx, BOX_A[1] * 24 / 32, BOX_A[2] * sx, BOX_A[3] * 24 / 32])
    assert clip.boxes[8, 0] > clip.boxes[7, 0] + 10  # the target moved to the square on the right
    # a clip without events: no NFT, the main subject all along
    quiet = load_harness_clip(write_harness_clip(tmp_path / "q", 12, None, 1), cfg)
    assert quiet.nfts == [] and np.isfinite(quiet.boxes).all()


def test_loading_is_cached_and_reports_kinds(tmp_path):
    write_harness_clip(tmp_path / "ds" / "c1", 12, 6, 0)
    ann = write_annotations(tmp_path / "ann.json", [annotated_clip(tmp_path / "w", 12, 4, 1, weak=True)])
    cfg = tiny_config()
    clips, report = load_training_clips(cfg, [tmp_path / "ds"], [ann], cache_dir=tmp_path / "cache")
    assert sorted(c.kind for c in clips) == ["harness", "weak"]
    assert report.clips == {"harness": 1, "editor": 0, "weak": 1} and report.nfts["weak"] == 1
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2
    again, _ = load_training_clips(cfg, [tmp_path / "ds"], [ann], cache_dir=tmp_path / "cache")
    for a, b in zip(clips, again):
        np.testing.assert_array_equal(a.frames, b.frames)
        assert a.nfts == b.nfts and a.weak == b.weak
    with pytest.raises(InputError, match="no AF-Net training clip"):
        load_training_clips(cfg, [], [])


def test_samples_labels_and_weights(tmp_path):
    cfg = tiny_config()
    write_harness_clip(tmp_path / "ds" / "c1", 30, 12, 0)
    ann = write_annotations(tmp_path / "ann.json", [annotated_clip(tmp_path / "w", 30, 10, 1, weak=True)])
    clips, _ = load_training_clips(cfg, [tmp_path / "ds"], [ann])
    ts = TrainingSet(clips, cfg, pos_fraction=0.5, weak_weight=0.25, tolerance=2.0)
    rng = np.random.default_rng(0)
    samples = [ts.draw(rng) for _ in range(64)]
    s = samples[0]
    assert s.x.shape == (cfg.frames_seen, cfg.channels, cfg.height, cfg.width) and s.x.dtype == np.float32
    assert s.target.shape == (cfg.s, cfg.height // 4, cfg.width // 4)
    for s in samples:
        assert np.allclose(s.target[s.valid].sum(axis=(1, 2)), 1.0, atol=1e-5)
        assert s.weight == (0.25 if s.kind == "weak" else 1.0)
    assert any(s.label > 0.5 for s in samples) and any(s.label == 0 for s in samples)
    assert nft_label(12, [12], 2.0) == 1.0 and nft_label(14, [12], 2.0) == pytest.approx(np.exp(-0.5))
    assert nft_label(30, [12], 2.0) == 0.0 and nft_label(3, [], 2.0) == 0.0


def test_depth_augmentation_gives_every_kind_of_depth_met_at_inference():
    """Issue 23: AF-Net trained on harness depth only fired nothing on flat exact depth; the
    augmentation shows it estimate-like, region-flat and flat maps, normalised as at inference."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:18, 0:32].astype(np.float32)
    ramp = np.clip((xx - 16) / 8, -3, 3)
    disp = np.repeat(ramp[None, None], 9, axis=0)  # (F, 1, H, W), normalised units
    flat = augment_disparity(disp, rng, "flat")
    assert flat.shape == disp.shape and not flat.any()
    regions = augment_disparity(disp, rng, "regions")
    assert 2 <= len(np.unique(regions[0])) <= 3 and np.array_equal(regions[0], regions[-1])
    assert np.corrcoef(regions[0].ravel(), ramp.ravel())[0, 1] > 0.8  # still near = near
    est = augment_disparity(disp, rng, "estimate")
    assert np.corrcoef(est[0].ravel(), ramp.ravel())[0, 1] > 0.8 and not np.allclose(est[0], disp[0])
    for a in (regions, est):  # on the byte code's steps, in its range
        assert np.allclose(a * DISPARITY_CODE_SCALE, np.round(a * DISPARITY_CODE_SCALE), atol=1e-3)
        assert np.abs(a).max() <= 3.0
    assert set(DEPTH_KINDS) == {"estimate", "regions", "flat"}
    with pytest.raises(ValueError):
        augment_disparity(disp, rng, "sky")


def test_training_set_replaces_the_disparity_of_a_share_of_samples(tmp_path):
    cfg = tiny_config()
    write_harness_clip(tmp_path / "ds" / "c1", 30, 12, 0)
    clips, _ = load_training_clips(cfg, [tmp_path / "ds"])
    n_img = 3 if cfg.rgb else 1
    plain = TrainingSet(clips, cfg, depth_augment=0.0)
    aug = TrainingSet(clips, cfg, depth_augment=1.0)
    a = [plain.draw(np.random.default_rng(k)).x[:, n_img:] for k in range(12)]
    b = [aug.draw(np.random.default_rng(k)).x[:, n_img:] for k in range(12)]
    assert sum(not np.allclose(x, y) for x, y in zip(a, b)) >= 6
    with pytest.raises(InputError):
        TrainingSet(clips, cfg, depth_augment=1.5)
