"""Engine support for the VSE tool (issue 7): per-target pull length and lead, partial caches
read by clip frame number, LAAF reading the stabilized disparity of a cache."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rvr_addon.errors import InputError
from rvr_addon.estimate.cache import ClipCache
from rvr_addon.io.maps import open_map_sequence
from rvr_addon.laaf.nft import NFT, nft_from_dict
from rvr_addon.laaf.puller import PullSettings, PullTarget, compose_track, schedule_pulls


def _targets(pull=None, lead=None):
    return [PullTarget(0, np.zeros(60)), PullTarget(30, np.full(60, 4.0), pull_frames=pull, lead_frames=lead)]


def test_per_target_pull_and_lead_override_the_defaults():
    settings = PullSettings(pull_frames=10, lead_frames=5)
    (default,) = schedule_pulls(_targets(), settings)
    assert (default.start, default.end) == (15, 25)
    (own,) = schedule_pulls(_targets(pull=4, lead=0), settings)
    assert (own.start, own.end) == (26, 30)
    track = compose_track(_targets(pull=4, lead=0), 60, settings)
    assert track.focus[26] == 0.0 and track.focus[30] == pytest.approx(4.0)
    with pytest.raises(ValueError, match="pull_frames=0"):
        schedule_pulls(_targets(pull=0), settings)


def test_nft_json_carries_pull_settings():
    n = nft_from_dict({"t": 3, "x": 5, "y": 6, "pull_frames": 8, "lead_frames": 0}, 0, "test")
    assert (n.pull_frames, n.lead_frames) == (8, 0)
    assert n.to_json()["pull_frames"] == 8
    assert "pull_frames" not in NFT(1, 1, 0, (0, 0, 2, 2)).to_json()
    with pytest.raises(InputError, match="lead_frames"):
        nft_from_dict({"t": 3, "x": 5, "y": 6, "lead_frames": -1}, 0, "test")


def _cache(folder, frames, key_extra=None):
    key = {"format": "rvr-laaf-cache/1", "engine_version": "t", "model_hash": "none", "source_hash": "x",
           "resolution": [8, 4], "depth": "test"}
    cache = ClipCache(folder, key)
    for i in frames:
        cache.write(i, np.full((4, 8), float(i), np.float32), np.zeros((4, 8, 3), np.float32))
    cache.flush()
    return cache


def test_partial_cache_is_read_by_clip_frame(tmp_path):
    _cache(tmp_path / "c", [3, 4, 5])
    seq = open_map_sequence(tmp_path / "c", kind="disparity")
    assert len(seq) == 6
    assert seq.get(4)[0, 0] == 4.0 and seq.get(3)[0, 0] == 3.0
    with pytest.raises(InputError, match="lacks frame 1"):
        seq.get(1)


def test_laaf_depth_prefers_complete_stabilized_channel(tmp_path):
    from rvr_addon.laaf.depth import DisparitySource

    cache = _cache(tmp_path / "c", [0, 1])
    cache.begin_stabilized({"test": 1})
    for i in (0, 1):
        cache.write_stabilized(i, np.full((4, 8), 10.0 + i, np.float32), np.zeros((4, 8, 3), np.float32),
                               np.ones((4, 8), np.float32))
    cache.flush()
    assert json.loads((tmp_path / "c" / "meta.json").read_text())["stabilized"]["frames"]
    src = DisparitySource(cache=tmp_path / "c")
    assert src.get(1, (8, 4))[0, 0] == 11.0 and src.channel == "S.D"


def test_remap_point_lists_longer_than_opencv_allows():
    """The temporal filter fuses E at point lists (N, 1, 2); N may exceed OpenCV's SHRT_MAX rows."""
    from rvr_addon.temporal.flow import remap

    rng = np.random.default_rng(0)
    image = rng.random((360, 640)).astype(np.float32)
    pts = np.stack([rng.uniform(0, 639, 70000), rng.uniform(0, 359, 70000)], -1).astype(np.float32)[:, None, :]
    out = remap(image, pts, nearest=True)
    assert out.shape == (70000, 1)
    idx = np.rint(pts[:, 0]).astype(int)
    np.testing.assert_array_equal(out[:, 0], image[idx[:, 1], idx[:, 0]])
