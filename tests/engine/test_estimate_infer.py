"""rvr estimate: the per-clip cache (resume, stale entries), external depth, bad input, weights errors.

The weights here are an untrained network exported for the tests (the cache and the stream
do not care what the network has learnt); the shipped model is not used here.
"""
from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
import torch

from rvr_addon.cli import main
from rvr_addon.errors import InputError
from rvr_addon.estimate.cache import ClipCache, frame_path, split_channels
from rvr_addon.estimate.infer import (
    EstimateJob, EstimateSettings, Estimator, fit_two_points, load_estimator, match_spread, merge_context,
    sample_window,
)
from rvr_addon.estimate.train import export_weights
from rvr_addon.estimate.unet import EstimatorNet
from rvr_addon.io.exr import read_exr


def untrained_weights(path, seed: int):
    torch.manual_seed(seed)
    return export_weights(EstimatorNet(), path, iterations=0, wall_time_s=0.0, training={"note": "test only"})


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    d = tmp_path_factory.mktemp("weights")
    return untrained_weights(d / "a.pt", 0), untrained_weights(d / "b.pt", 1)


@pytest.fixture
def clip(tmp_path):
    """3 frames 40x30: an RGB PNG, a grey PNG and a 16-bit RGBA PNG (bad input handled)."""
    folder = tmp_path / "clip"
    folder.mkdir()
    rng = np.random.default_rng(0)
    rgb = (rng.random((30, 40, 3)) * 255).astype(np.uint8)
    rgb[5:9, 5:9] = 255  # a clipped highlight
    cv2.imwrite(str(folder / "f1.png"), rgb)
    cv2.imwrite(str(folder / "f2.png"), rgb[:, :, 0])
    rgba16 = np.dstack([rgb.astype(np.uint16) * 257, np.full((30, 40), 65535, np.uint16)])
    cv2.imwrite(str(folder / "f3.png"), rgba16)
    return folder


def run(clip, cache, **kw) -> EstimateJob:
    job = EstimateJob(EstimateSettings(input=clip, output=cache, **kw))
    job.run(progress=False)
    return job


def test_cache_layout_and_resume(clip, tmp_path, weights):
    cache = tmp_path / "cache"
    job = run(clip, cache, weights=weights[0])
    assert (job.computed, job.reused) == (3, 0)
    meta = json.loads((cache / "meta.json").read_text())
    for key in ("engine_version", "model_hash", "source", "source_hash", "resolution", "fps", "frame_range"):
        assert key in meta, key
    assert meta["resolution"] == [40, 30] and meta["frame_range"] == [0, 3] and meta["model_hash"] == job.model.model_hash
    ch = read_exr(frame_path(cache, 0))
    assert sorted(ch) == ["D", "E.B", "E.G", "E.R"] and ch["D"].shape == (30, 40)
    e = np.dstack([ch["E.R"], ch["E.G"], ch["E.B"]])
    assert e.min() >= 0.0 and e.max() <= np.log(1000.0) / 50.0 + 1e-6  # 0 <= E <= E_max
    # the same run again reuses everything
    again = run(clip, cache, weights=weights[0])
    assert (again.computed, again.reused) == (0, 3)
    # a truncated EXR and an unreadable one are recomputed, never trusted
    p2 = frame_path(cache, 1)
    p2.write_bytes(p2.read_bytes()[:100])
    third = run(clip, cache, weights=weights[0])
    assert (third.computed, third.reused) == (1, 2)
    # frames on disk but not recorded in meta.json (a killed run) are recomputed
    meta = json.loads((cache / "meta.json").read_text())
    del meta["frames"]["3"]
    (cache / "meta.json").write_text(json.dumps(meta))
    assert run(clip, cache, weights=weights[0]).computed == 1


def test_other_model_or_source_recomputes(clip, tmp_path, weights):
    cache = tmp_path / "cache"
    first = run(clip, cache, weights=weights[0])
    d0 = read_exr(frame_path(cache, 0))["D"]
    other = run(clip, cache, weights=weights[1])
    assert (other.computed, other.reused) == (3, 0)
    assert json.loads((cache / "meta.json").read_text())["model_hash"] == other.model.model_hash != first.model.model_hash
    assert not np.array_equal(read_exr(frame_path(cache, 0))["D"], d0)
    st = (clip / "f1.png").stat()
    os.utime(clip / "f1.png", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # the source changed
    assert run(clip, cache, weights=weights[1]).computed == 3
    (cache / "meta.json").write_text("{broken")
    assert run(clip, cache, weights=weights[1]).computed == 3


def test_partial_range_and_stale_frames_removed(clip, tmp_path, weights):
    cache = tmp_path / "cache"
    job = run(clip, cache, weights=weights[0], start=1, stop=3)
    assert job.computed == 2 and not frame_path(cache, 0).exists()
    run(clip, cache, weights=weights[1], start=2)
    assert not frame_path(cache, 1).exists()  # written by another model: removed, not left to be trusted
    assert frame_path(cache, 2).exists()


def test_estimator_core_shapes_tiny_frames_and_downscaled_trunk(weights):
    model = load_estimator(weights[0])
    for h, w in ((1, 1), (2, 3), (31, 17)):
        d, e = Estimator(model)(np.full((h, w, 3), 128, np.uint8))
        assert d.shape == (h, w) and e.shape == (h, w, 3) and d.dtype == np.float32
    frame = cv2.resize((np.random.default_rng(1).random((12, 16, 3)) * 255).astype(np.uint8), (128, 96),
                       interpolation=cv2.INTER_CUBIC)
    full_d, full_e = Estimator(model)(frame)
    half_d, half_e = Estimator(model, max_pixels=64 * 48)(frame)
    assert half_d.shape == full_d.shape and half_e.shape == full_e.shape
    # D is in px at the frame's width: a net running on a half-size copy returns the same units
    assert abs(float(half_d.mean()) - float(full_d.mean())) < 0.2 * abs(float(full_d.mean())) + 0.05


def test_merge_context_takes_the_layout_of_one_and_the_detail_of_the_other():
    """merge_context: low frequencies from the context map (at the main map's low-frequency median
    and spread), high frequencies from the main one at their own amplitude."""
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    layout = 4.0 * yy / h                                   # "nearer toward the bottom", smooth
    detail = np.where((xx // 8 + yy // 8) % 2 == 0, 0.5, -0.5).astype(np.float32)  # an 8 px checker
    main_d = detail + 4.0 * xx / w                          # right detail, a wrong layout of the same range
    context = 0.5 * layout + 7.0                            # the right layout, at another magnitude
    merged = merge_context(main_d, context, sigma_px=0.1 * w)
    inner = (slice(30, 90), slice(40, 120))                 # away from the borders' reflection
    assert np.allclose(merged[inner] - detail[inner], layout[inner], atol=0.25)
    assert merged.dtype == np.float32 and merged.shape == (h, w)
    # the context map at its own, smaller size gives the same layout
    small = cv2.resize(context, (40, 30), interpolation=cv2.INTER_AREA)
    assert np.allclose(merge_context(main_d, small, sigma_px=0.1 * w)[inner] - detail[inner], layout[inner], atol=0.3)
    # the detail keeps its amplitude whatever the context's magnitude
    hp = lambda a: a - cv2.GaussianBlur(a, (0, 0), 4.0)
    assert np.allclose(hp(merge_context(main_d, 10 * context, 0.1 * w))[inner], hp(main_d)[inner], atol=0.05)
    # equal maps: nothing changes; tiny frames and sigmas below a pixel work
    assert np.allclose(merge_context(main_d, main_d, 0.1 * w), main_d, atol=1e-4)
    assert merge_context(np.ones((1, 1), np.float32), np.zeros((1, 1), np.float32), 0.02).shape == (1, 1)


def test_match_spread_keeps_the_layout_and_takes_the_reference_magnitude():
    rng = np.random.default_rng(3)
    layout = rng.normal(size=(40, 60)).astype(np.float32)
    reference = (5.0 + 3.0 * rng.normal(size=(40, 60))).astype(np.float32)
    out = match_spread(layout - 2.0, reference)  # a scale of 3 (bounded to [1/4, 4])
    assert np.corrcoef(out.ravel(), layout.ravel())[0, 1] > 0.999
    assert abs(float(np.median(out[::4, ::4])) - float(np.median(reference[::4, ::4]))) < 1e-4  # read on a 1/4 grid
    spread = lambda a: float(np.subtract(*np.percentile(a[::4, ::4], (95, 5))))
    assert spread(out) == pytest.approx(spread(reference), rel=1e-4)
    flat = match_spread(np.full((8, 8), 2.0, np.float32), reference)
    assert np.allclose(flat, np.median(reference[::4, ::4]))


def test_context_pass_changes_d_only_and_can_be_turned_off(weights):
    """Estimator's context pass (CONTEXT_PIXELS): D differs, E is the main pass's exactly;
    context_pixels=0, or a frame no larger than the context, is one pass."""
    model = load_estimator(weights[0])
    frame = cv2.resize((np.random.default_rng(2).random((12, 16, 3)) * 255).astype(np.uint8), (256, 192),
                       interpolation=cv2.INTER_CUBIC)
    d_on, e_on = Estimator(model, context_pixels=64 * 48)(frame)
    d_off, e_off = Estimator(model, context_pixels=0)(frame)
    assert np.array_equal(e_on, e_off)
    assert not np.allclose(d_on, d_off)
    small = frame[:40, :50]
    assert np.array_equal(Estimator(model, context_pixels=64 * 48)(small)[0], Estimator(model, context_pixels=0)(small)[0])


def test_weights_errors_name_the_file(tmp_path, clip):
    bad = tmp_path / "corrupt_weights.pt"
    bad.write_bytes(b"\x00not torch")
    with pytest.raises(InputError, match="corrupt_weights.pt"):
        load_estimator(bad)
    with pytest.raises(InputError, match="missing.pt"):
        load_estimator(tmp_path / "missing.pt")
    other = tmp_path / "state_dict.pt"
    torch.save({"conv.weight": torch.zeros(1)}, other)
    with pytest.raises(InputError, match="state_dict.pt"):
        load_estimator(other)

def test_missing_shipped_weights_name_the_file_and_the_fix(tmp_path, clip, monkeypatch):
    from rvr_addon.estimate import infer

    monkeypatch.setattr(infer, "SHIPPED_WEIGHTS", tmp_path / "gone" / "estimator.pt")
    monkeypatch.setattr(infer, "SHIPPED_ONNX", tmp_path / "gone" / "estimator.onnx")  # its export is a fallback
    with pytest.raises(InputError, match="weights file is missing.*gone/estimator.pt"):
        EstimateJob(EstimateSettings(input=clip, output=tmp_path / "c"))


def test_external_depth_affine_points_and_distance(clip, tmp_path, weights):
    maps = tmp_path / "depth"
    maps.mkdir()
    yy, xx = np.mgrid[:30, :40].astype(np.float32)
    for i in range(3):
        np.save(maps / f"d{i}.npy", (1.0 + xx / 10.0).astype(np.float32))  # distance 1..4.9 m
    cache = tmp_path / "c1"
    run(clip, cache, depth=maps, depth_scale=2.0, depth_offset=-1.0, no_hdr=True)
    ch = read_exr(frame_path(cache, 2))
    np.testing.assert_allclose(ch["D"], 2.0 * (1.0 + xx / 10.0) - 1.0, rtol=1e-6)
    assert float(np.abs(ch["E.R"]).max()) == 0.0
    # distances: a near plane (1 m, x < 10) and a far one (4 m, x >= 25); the two points say the
    # near plane is at disparity -3 (in front of focus) and the far one at +1
    steps = np.select([xx < 10, xx < 25], [1.0, 2.0], 4.0).astype(np.float32)
    for i in range(3):
        np.save(maps / f"d{i}.npy", steps)
    cache2 = tmp_path / "c2"
    job = run(clip, cache2, depth=maps, depth_points=[(3.0, 10.0, -3.0), (30.0, 10.0, 1.0)],
              depth_is_distance=True, weights=weights[0])
    d = read_exr(frame_path(cache2, 0))["D"]
    assert d[0, 0] == pytest.approx(-3.0, abs=1e-5) and d[29, 39] == pytest.approx(1.0, abs=1e-5)
    # disparity is affine in 1/distance: the 2 m plane sits at 1/2 between 1/1 and 1/4 -> D = -3 + 4 (1 - 1/2) / (3/4)
    assert d[10, 15] == pytest.approx(-3.0 + 4.0 * (1 - 0.5) / 0.75, abs=1e-5)
    assert job.depth.scale < 0  # nearer (larger 1/distance) = more negative disparity
    e = read_exr(frame_path(cache2, 0))["E.R"]
    assert e.shape == (30, 40)  # E from the network
    with pytest.raises(InputError, match="same map value"):
        fit_two_points([2.0, 2.0], [0.0, 1.0])
    with pytest.raises(InputError, match="outside"):
        EstimateJob(EstimateSettings(input=clip, output=tmp_path / "c3", depth=maps, no_hdr=True,
                                     depth_points=[(0.0, 0.0, 0.0), (99.0, 0.0, 1.0)]))
    assert sample_window(np.arange(25.0).reshape(5, 5), 2.0, 2.0) == 12.0


def test_cli_estimate_then_render_from_the_cache(clip, tmp_path, weights, capsys, monkeypatch):
    cache = tmp_path / "cache"
    assert main(["estimate", str(clip), "-o", str(cache), "--weights", str(weights[0]), "-q"]) == 0
    out = tmp_path / "render"
    assert main(["render", str(clip), "--depth", str(cache), "--hdr", str(cache), "--focus", "0",
                 "-o", str(out), "-q"]) == 0
    assert len(list(out.glob("*.png"))) == 3
    capsys.readouterr()
    from rvr_addon.estimate import infer

    monkeypatch.setattr(infer, "SHIPPED_WEIGHTS", tmp_path / "gone" / "estimator.pt")
    monkeypatch.setattr(infer, "SHIPPED_ONNX", tmp_path / "gone" / "estimator.onnx")  # its export is a fallback
    assert main(["estimate", str(clip), "-o", str(tmp_path / "c2"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "weights file is missing" in err and "rvr train" in err


def test_clip_cache_rejects_a_file_path(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    from rvr_addon.errors import OutputError

    with pytest.raises(OutputError, match="is a file"):
        ClipCache(f, {"format": 1, "engine_version": 1, "model_hash": 1, "source_hash": 1, "resolution": 1,
                      "depth": 1})


def test_cache_frames_are_rle_lossless_and_read_valid_reads_once(tmp_path):
    import OpenEXR

    key = {"format": "rvr-laaf-cache/1", "engine_version": "t", "model_hash": "m", "source_hash": "s",
           "resolution": [5, 4], "depth": "network"}
    cache = ClipCache(tmp_path / "c", key)
    rng = np.random.default_rng(1)
    d, e = rng.random((4, 5)).astype(np.float32), rng.normal(size=(4, 5, 3)).astype(np.float32)
    cache.write(0, d, e)
    cache.flush()
    assert OpenEXR.File(str(frame_path(cache.folder, 0))).header()["compression"] == OpenEXR.RLE_COMPRESSION
    got = split_channels(cache.read_valid(0, (5, 4)))
    np.testing.assert_array_equal(got[0], d)
    np.testing.assert_array_equal(got[1], e)
    assert cache.is_valid(0, (5, 4)) and cache.read_valid(0, (4, 5)) is None  # wrong size
    assert not cache.is_valid(0, (4, 5))  # the header alone says so
    assert cache.read_valid(1, (5, 4)) is None  # not recorded
    path = frame_path(cache.folder, 0)
    path.write_bytes(path.read_bytes()[:60])  # truncated: the recorded size no longer matches
    assert cache.read_valid(0, (5, 4)) is None and not cache.is_valid(0, (5, 4))


def test_tiny_frames_through_the_job(tmp_path, weights):
    folder = tmp_path / "tiny"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.full((2, 3), 200, np.uint8))  # grey, 3x2 px
    job = run(folder, tmp_path / "cache", weights=weights[0])
    assert job.computed == 1
    ch = read_exr(frame_path(tmp_path / "cache", 0))
    assert ch["D"].shape == (2, 3) and np.isfinite(ch["D"]).all()


def test_more_bad_input_16bit_grey_grey_alpha_and_a_corrupt_frame(tmp_path, weights, capsys):
    from PIL import Image

    folder = tmp_path / "odd"
    folder.mkdir()
    rng = np.random.default_rng(2)
    cv2.imwrite(str(folder / "a1.png"), (rng.random((30, 40)) * 65535).astype(np.uint16))  # 16-bit grey
    Image.fromarray(np.dstack([(rng.random((30, 40)) * 255).astype(np.uint8)] * 2), "LA").save(folder / "a2.png")
    cache = tmp_path / "cache"
    assert run(folder, cache, weights=weights[0]).computed == 2
    (folder / "a3.png").write_bytes((folder / "a1.png").read_bytes()[:200])  # truncated
    assert main(["estimate", str(folder), "-o", str(cache), "--weights", str(weights[0]), "-q"]) == 2
    assert "a3.png" in capsys.readouterr().err
    assert frame_path(cache, 1).is_file()  # the good frames stay cached


def test_cache_from_another_engine_version_is_recomputed_and_corrupt_weights_fail_clearly(clip, tmp_path, weights,
                                                                                           capsys):
    cache = tmp_path / "cache"
    run(clip, cache, weights=weights[0])
    meta = json.loads((cache / "meta.json").read_text())
    meta["engine_version"] = "0.0.0-older"
    (cache / "meta.json").write_text(json.dumps(meta))
    assert run(clip, cache, weights=weights[0]).computed == 3
    bad = tmp_path / "broken_estimator.pt"
    bad.write_bytes(open(weights[0], "rb").read()[:1000])  # a truncated download
    assert main(["estimate", str(clip), "-o", str(tmp_path / "c2"), "--weights", str(bad), "-q"]) == 2
    err = capsys.readouterr().err
    assert "broken_estimator.pt" in err and "corrupt" in err


def test_the_shipped_weights_brighten_only_pixels_near_clipping():
    """E (HDR) of the shipped weights is 0 on a bright surface that is not clipped (code value 240:
    a white wall, a sky; the gate starts at 0.96 = 245) and the same as with the old gate (from
    0.90) on clipped pixels (255), where the gate is 1 either way."""
    import dataclasses

    from rvr_addon.estimate.infer import SHIPPED_WEIGHTS

    model = load_estimator(SHIPPED_WEIGHTS, backend="torch")
    assert (model.net.config.gate_lo, model.net.config.gate_hi) == (0.96, 0.98)
    rng = np.random.default_rng(0)
    frame = np.clip(rng.normal(90, 20, (96, 160, 3)), 0, 255).astype(np.uint8)
    frame[20:50, 20:80] = 240  # bright, not clipped
    frame[60:70, 100:110] = 255  # a clipped light
    _d, e = Estimator(model, context_pixels=0)(frame)
    assert float(np.abs(e[22:48, 22:78]).max()) == 0.0
    old = dataclasses.replace(model.net.config, gate_lo=0.90)
    model.net.config = old
    _d, e_old = Estimator(model, context_pixels=0)(frame)
    assert float(e_old[22:48, 22:78].max()) > 0.0  # the old gate brightened the wall
    np.testing.assert_array_equal(e[60:70, 100:110], e_old[60:70, 100:110])


def test_a_portrait_frame_gets_the_blur_of_a_landscape_one(weights, tmp_path):
    """D_rel is a share of the frame's long side: a phone held upright gives D in px scaled by its
    height, not its (short) width, so the same scene is not blurred 0.56x as much in portrait; the
    cache key says so for portrait clips only (landscape caches stay valid)."""
    from rvr_addon.estimate.unet import disparity_to_px

    model = load_estimator(weights[0])
    rng = np.random.default_rng(3)
    portrait = cv2.resize((rng.random((12, 8, 3)) * 255).astype(np.uint8), (64, 96), interpolation=cv2.INTER_CUBIC)
    d, _e = Estimator(model, context_pixels=0)(portrait)
    x = torch.from_numpy(portrait.astype(np.float32) / 255.0).permute(2, 0, 1)[None]
    with torch.inference_mode():
        rel = model.net(x).disparity_rel
    assert np.allclose(d, disparity_to_px(rel, 96.0)[0, 0].numpy(), atol=1e-4)
    assert not np.allclose(d, disparity_to_px(rel, 64.0)[0, 0].numpy(), atol=1e-3)
    for name, (h, w) in (("portrait", (40, 30)), ("landscape", (30, 40))):
        folder = tmp_path / name
        folder.mkdir()
        cv2.imwrite(str(folder / "f.png"), cv2.resize(portrait, (w, h)))
        job = run(folder, tmp_path / f"cache_{name}", weights=weights[0], depth_method="network")
        meta = json.loads((tmp_path / f"cache_{name}" / "meta.json").read_text())
        assert (meta.get("blur_span") == "long side") == (name == "portrait")
        assert job.computed == 1
