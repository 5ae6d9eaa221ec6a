"""AF-Net network: shapes, receptive field, input encoding, streaming inference = the network
on the gathered window, NFT peak picking and regions (issue 8)."""
from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from afnet_synth import frames_of, tiny_config
from rvr_addon.afnet.infer import AFNetStream, check_length, pick_peaks, predict_clip, region_from_map
from rvr_addon.afnet.model import AFNet, AFNetConfig, decode_frames, encode_frame, normalise_disparity


def test_default_config_receptive_field_and_size():
    cfg = AFNetConfig()
    assert cfg.frames_seen == 9 and cfg.sample_step == 5 and cfg.stride == 5
    assert cfg.span == 41 and cfg.half_span == 20
    np.testing.assert_array_equal(cfg.offsets, np.arange(-20, 21, 5))
    np.testing.assert_array_equal(cfg.unit_offsets, [-15, 0, 15])
    model = AFNet(cfg)
    assert 300_000 < model.parameter_count() < 2_000_000  # sized for a 2-core CPU
    assert AFNetConfig.from_dict(cfg.to_dict()) == cfg


@pytest.mark.parametrize("cfg", [tiny_config(), tiny_config(rgb=False, disparity=False),
                                 tiny_config(f_t=1, s=5, sample_step=1)],
                         ids=["rgb+d", "gray", "ft1-s5"])
def test_forward_shapes(cfg):
    model = AFNet(cfg).eval()
    x = torch.zeros(2, cfg.frames_seen, cfg.channels, cfg.height, cfg.width)
    logits, maps = model(x)
    assert logits.shape == (2,)
    assert maps.shape == (2, cfg.s, cfg.height // 4, cfg.width // 4) and cfg.map_size == (cfg.width // 4, cfg.height // 4)
    with pytest.raises(ValueError, match="expected"):
        model(torch.zeros(1, cfg.frames_seen + 1, cfg.channels, cfg.height, cfg.width))


@pytest.mark.parametrize("bad", [dict(width=30), dict(f_t=2), dict(s=0), dict(sample_step=0)],
                         ids=["width", "even-ft", "s0", "step0"])
def test_config_errors_name_the_setting(bad):
    with pytest.raises(ValueError, match="AF-Net"):
        tiny_config(**bad)


def test_encoding_round_trip_and_disparity_invariance():
    cfg = tiny_config()
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    d = rng.normal(2.0, 1.0, (48, 64)).astype(np.float32)
    codes = encode_frame(rgb, d, cfg)
    assert codes.shape == (4, 24, 32) and codes.dtype == np.uint8
    x = decode_frames(codes, cfg)
    assert float(x[:3].min()) >= -0.5 and float(x[:3].max()) <= 0.5
    # offset and scale of a disparity estimate do not matter
    np.testing.assert_array_equal(encode_frame(rgb, 3.0 * d + 7.0, cfg)[3], codes[3])
    assert np.all(encode_frame(rgb, None, cfg)[3] == 128)
    assert np.all(normalise_disparity(np.full((4, 4), np.nan)) == 0)


def _clip_codes(cfg, n, t_enter, seed=1):
    frames, maps, _ = frames_of(n, t_enter, seed)
    return frames, maps, [encode_frame(f, d, cfg) for f, d in zip(frames, maps)]


def test_stream_equals_network_on_the_clamped_window():
    cfg = tiny_config()
    torch.manual_seed(0)
    model = AFNet(cfg).eval()
    n = 23
    _, _, codes = _clip_codes(cfg, n, 9)
    stream = AFNetStream(model, n)
    for c in codes:
        stream.push(c)
    stream.finish()
    assert sorted(stream.probs) == list(range(0, n, cfg.stride))
    for q in (0, 8, 22):
        idx = np.clip(q + cfg.offsets, 0, n - 1)
        x = decode_frames(np.stack([codes[i] for i in idx])[None], cfg)
        with torch.no_grad():
            logit, maps = model(x)
        assert stream.probs[q] == pytest.approx(float(torch.sigmoid(logit)[0]), abs=1e-5)
        prob = torch.softmax(maps[0, (cfg.s - 1) // 2].flatten(), 0).reshape(maps.shape[-2:]).numpy()
        np.testing.assert_allclose(stream.maps[q], prob, atol=1e-6)


def test_receptive_field():
    """P at query q changes with frames inside q +- half_span and not with frames outside."""
    cfg = tiny_config()
    torch.manual_seed(1)
    model = AFNet(cfg).eval()
    n = 40
    frames, maps, _ = frames_of(n, None, 2)
    base = predict_clip(model, frames, maps)
    q = 20
    for k, changes in ((q + cfg.half_span, True), (q - cfg.half_span, True), (q + cfg.half_span + 1, False),
                       (q - cfg.half_span - 1, False)):
        other = [f.copy() for f in frames]
        other[k] = 255 - other[k]
        got = predict_clip(model, other, maps).probs[q]
        assert (abs(got - base.probs[q]) > 1e-7) == changes, k


def test_short_clip_is_padded_with_a_warning(caplog):
    cfg = tiny_config()
    model = AFNet(cfg).eval()
    frames, maps, _ = frames_of(5, None, 3)
    with caplog.at_level(logging.WARNING):
        pred = predict_clip(model, frames, maps)
    assert pred.padded and "receptive field" in caplog.text and "padding" in caplog.text
    assert sorted(pred.probs) == [0, 2, 4]
    assert not check_length(cfg.span, cfg)
    one = predict_clip(model, frames[:1], maps[:1])  # a clip of one frame still runs
    assert list(one.probs) == [0] and one.peaks == []


def test_pick_peaks():
    qs = list(range(0, 50, 5))
    ps = [0.1, 0.2, 0.3, 0.9, 0.6, 0.1, 0.1, 0.55, 0.7, 0.2]
    peaks = pick_peaks(qs, ps, threshold=0.5, min_gap=12)
    assert [p.q for p in peaks] == [15, 40]
    assert 13 <= peaks[0].t <= 16 and peaks[0].p == pytest.approx(0.9)
    # streaming: the second peak is not final until the queries reach 40 + 12
    assert [p.q for p in pick_peaks(qs, ps, 0.5, 12, final_upto=45)] == [15]
    # non-maximum suppression within min_gap; frame 0 is never an NFT
    assert [p.q for p in pick_peaks([0, 5, 10], [0.9, 0.8, 0.7], 0.5, 12)] == []
    assert pick_peaks(qs, [0.4] * 10, 0.5, 12) == []


def test_region_from_map():
    prob = np.zeros((6, 8), np.float32)
    prob[1:3, 5:7] = 1.0
    prob[4, 0] = 0.3  # below half the maximum: not part of the region
    r = region_from_map(prob / prob.sum(), (80, 60))
    assert r.box == pytest.approx((50.0, 10.0, 20.0, 20.0))
    assert (r.x, r.y) == pytest.approx((60.0, 20.0))
    assert r.mask.shape == (60, 80) and r.mask[15, 55] and not r.mask[45, 5]
