"""`rvr stabilize CACHE`: the stabilized channels in the per-clip cache, resuming, settings,
the renderer's choice of channels, and bad input. Estimates are SIMULATED (no trained weights)."""
from __future__ import annotations

import json
import logging
import shutil

import cv2
import numpy as np
import pytest

from rvr_addon import __version__
from rvr_addon.cli import main
from rvr_addon.errors import InputError
from rvr_addon.estimate.cache import CACHE_FORMAT, ClipCache, frame_path, source_fingerprint
from rvr_addon.io.exr import read_exr
from rvr_addon.io.maps import open_map_sequence
from rvr_addon.temporal.filter import TemporalSettings, stabilize_stream
from rvr_addon.temporal.job import StabilizeJob, StabilizeSettings, segments
from rvr_addon.temporal.simulate import simulate_estimates, synthetic_clip

N = 10


CAUSAL = TemporalSettings(window="causal")
"""The paper's window (P = 6 past frames): the resume tests count its warm-up frames."""

def make_cache(root, n=N, indices=None):
    """An image-sequence clip (synthetic, known motion) and a cache of simulated estimates."""
    frames = root / "frames"
    frames.mkdir(parents=True)
    clip = list(synthetic_clip(96, 64, n, seed=1))
    for f in clip:
        cv2.imwrite(str(frames / f"f_{f.index:04d}.png"), f.image[:, :, ::-1])
    src = source_fingerprint(frames)
    key = {"format": CACHE_FORMAT, "engine_version": __version__, "model_hash": "simulated",
           "source_hash": src["hash"], "resolution": [96, 64], "depth": "simulated"}
    cache = ClipCache(root / "cache", key, {"source": src, "fps": 24.0})
    for f in clip:
        if indices is None or f.index in indices:
            cache.write(f.index, *simulate_estimates(f.disparity, f.exponent, f.index, seed=2))
    cache.flush()
    return root / "cache", frames, clip


def channels(cache, n=N):
    return [read_exr(frame_path(cache, i)) for i in range(n)]


@pytest.fixture
def made(tmp_path):
    return make_cache(tmp_path)


def test_cli_adds_stabilized_channels_and_keeps_the_raw_ones(made, capsys):
    cache, frames, clip = made
    before = channels(cache)
    assert main(["stabilize", str(cache), "-q"]) == 0
    assert "stabilized 10 frames" in capsys.readouterr().out
    after = channels(cache)
    expected = list(stabilize_stream((f.image for f in clip), ((b["D"], np.dstack([b["E.R"], b["E.G"], b["E.B"]]))
                                                              for b in before), TemporalSettings()))
    for b, a, (i, d, e, c) in zip(before, after, expected):
        assert set(a) == {"D", "E.R", "E.G", "E.B", "S.D", "S.E.R", "S.E.G", "S.E.B", "S.C"}
        for name in ("D", "E.R", "E.G", "E.B"):
            np.testing.assert_array_equal(a[name], b[name])  # raw estimates are never lost
        np.testing.assert_array_equal(a["S.D"], d)  # the job equals the streaming filter
        np.testing.assert_array_equal(a["S.E.G"], e[..., 1])
        np.testing.assert_array_equal(a["S.C"], c)
    meta = json.loads((cache / "meta.json").read_text())
    assert len(meta["stabilized"]["frames"]) == N and meta["stabilized"]["settings"]["window"] == "centred"
    assert meta["stabilized"]["frames"] == meta["frames"]  # sizes recorded for the rewritten files
    # the estimator still trusts every raw frame (same key, recorded sizes)
    reopened = ClipCache(cache, {k: meta[k] for k in ("format", "engine_version", "model_hash", "source_hash",
                                                      "resolution", "depth")})
    assert all(reopened.is_valid(i, (96, 64)) for i in range(N))
    assert reopened.stabilized is not None  # and keeps the record


def test_interrupted_run_resumes_to_the_same_result(made, tmp_path):
    cache, frames, _ = made
    other = tmp_path / "copy"
    shutil.copytree(cache, other)
    StabilizeJob(StabilizeSettings(cache=other, temporal=CAUSAL)).run(progress=False)  # uninterrupted
    job = StabilizeJob(StabilizeSettings(cache=cache, temporal=CAUSAL))
    for _ in range(5):
        job.step()
    job.cancel()
    assert job.written == 5
    resumed = StabilizeJob(StabilizeSettings(cache=cache, temporal=CAUSAL))
    assert resumed.todo == set(range(5, N)) and resumed.plan == [(0, N)]  # warm-up from frame max(0, 5 - 6)
    resumed.run(progress=False)
    assert resumed.written == N - 5
    for a, b in zip(channels(cache), channels(other)):
        for name in ("S.D", "S.E.R", "S.C"):
            np.testing.assert_array_equal(a[name], b[name])


def test_resume_warms_up_on_the_window_only(tmp_path):
    cache, frames, _ = make_cache(tmp_path, n=14)
    other = tmp_path / "copy"
    shutil.copytree(cache, other)
    StabilizeJob(StabilizeSettings(cache=other, temporal=CAUSAL)).run(progress=False)
    job = StabilizeJob(StabilizeSettings(cache=cache, temporal=CAUSAL))
    while job.written < 10:
        job.step()
    job.cancel()  # the write in flight (written behind the filter) completes: 10 or 11 frames stored
    assert job.written in (10, 11)
    resumed = StabilizeJob(StabilizeSettings(cache=cache, temporal=CAUSAL))
    assert resumed.plan == [(job.written - 6, 14)]  # P = 6 frames of warm-up before the first frame left
    resumed.run(progress=False)
    for a, b in zip(channels(cache, 14), channels(other, 14)):
        np.testing.assert_array_equal(a["S.D"], b["S.D"])


def test_same_settings_skip_other_settings_recompute(made):
    cache, _, _ = made
    StabilizeJob(StabilizeSettings(cache=cache)).run(progress=False)
    again = StabilizeJob(StabilizeSettings(cache=cache))
    assert again.todo == set() and again.total == 0
    again.run(progress=False)
    causal = StabilizeJob(StabilizeSettings(cache=cache, temporal=CAUSAL))
    assert causal.todo == set(range(N))
    causal.run(progress=False)
    assert json.loads((cache / "meta.json").read_text())["stabilized"]["settings"]["window"] == "causal"
    forced = StabilizeJob(StabilizeSettings(cache=cache, temporal=CAUSAL, force=True))
    assert forced.todo == set(range(N))


def test_render_reads_stabilized_channels_only_when_complete(made, caplog):
    cache, _, clip = made
    with caplog.at_level(logging.INFO, logger="rvr_addon.io.maps"):
        assert open_map_sequence(cache, "disparity").prefix == ""
    assert "per-frame depth channels (D)" in caplog.text and "rvr stabilize" in caplog.text
    StabilizeJob(StabilizeSettings(cache=cache)).run(progress=False)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="rvr_addon.io.maps"):
        depth = open_map_sequence(cache, "disparity")
        hdr = open_map_sequence(cache, "hdr")
    assert depth.prefix == hdr.prefix == "S." and "temporally stabilized" in caplog.text
    ch = read_exr(frame_path(cache, 3))
    np.testing.assert_array_equal(depth.get(3), ch["S.D"])
    np.testing.assert_array_equal(hdr.get(3)[..., 2], ch["S.E.B"])
    # re-estimating one frame makes the stabilized channels stale: the renderer goes back to raw
    meta = json.loads((cache / "meta.json").read_text())
    est = ClipCache(cache, {k: meta[k] for k in ("format", "engine_version", "model_hash", "source_hash",
                                                 "resolution", "depth")})
    est.write(3, clip[3].disparity, clip[3].exponent)
    est.flush()
    est.close()
    assert "stabilized" not in json.loads((cache / "meta.json").read_text())
    assert open_map_sequence(cache, "disparity").prefix == ""


def test_a_killed_rewrite_leaves_the_raw_frame_valid(made):
    cache, _, _ = made
    job = StabilizeJob(StabilizeSettings(cache=cache))
    job.cache.flush_every = 1000  # never flushed after the rename: as if killed right then
    while job._writes.submitted < 1:  # frame 0 handed to the writer (it writes behind the filter)
        job.step()
    job._writes.wait()  # frame 0 renamed, no other write started
    assert job.written == 1
    meta = json.loads((cache / "meta.json").read_text())
    assert meta["stabilized"]["pending"] == {"1": frame_path(cache, 0).stat().st_size}
    assert meta["frames"]["1"] != frame_path(cache, 0).stat().st_size
    reopened = ClipCache.open_existing(cache)
    assert reopened.is_valid(0, (96, 64)) and not reopened.has_stabilized(0)
    resumed = StabilizeJob(StabilizeSettings(cache=cache))
    assert 0 in resumed.todo
    resumed.run(progress=False)
    assert json.loads((cache / "meta.json").read_text())["stabilized"]["pending"] == {}


def test_gaps_in_the_cache_are_separate_segments(tmp_path):
    assert segments([0, 1, 2, 5, 6, 9]) == [(0, 3), (5, 7), (9, 10)]
    cache, _, _ = make_cache(tmp_path, indices={0, 1, 2, 3, 6, 7, 8})
    job = StabilizeJob(StabilizeSettings(cache=cache))
    assert job.plan == [(0, 4), (6, 9)]
    job.run(progress=False)
    assert job.written == 7


def test_bad_input_names_the_file_and_the_fix(made, tmp_path, capsys):
    cache, frames, _ = made
    assert main(["stabilize", str(tmp_path / "nowhere"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "nowhere" in err and "rvr estimate" in err
    # the recorded source is gone
    moved = tmp_path / "moved"
    frames.rename(moved)
    assert main(["stabilize", str(cache), "-q"]) == 2
    err = capsys.readouterr().err
    assert str(frames) in err and "--input" in err
    # --input works instead (with a warning that it is not the recorded file)
    short = tmp_path / "short"
    short.mkdir()
    for p in sorted(moved.iterdir())[:4]:
        shutil.copy(p, short / p.name)
    assert main(["stabilize", str(cache), "--input", str(short), "-q"]) == 2
    err = capsys.readouterr().err
    assert "only 4 frames" in err and "--input" in err
    # a corrupt frame of the cache is named
    frame_path(cache, 2).write_bytes(b"not an exr")
    assert main(["stabilize", str(cache), "--input", str(moved), "-q"]) == 2
    err = capsys.readouterr().err
    assert "frame_00003.exr" in err and "rvr estimate" in err
    with pytest.raises(InputError, match="not an estimation cache"):
        ClipCache.open_existing(frames if frames.exists() else moved)
    assert main(["stabilize", str(cache), "--window", "centred", "-M", "0", "-q"]) == 2
    assert "M=0" in capsys.readouterr().err
