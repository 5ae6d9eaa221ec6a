"""Issue 22 (items 1, 2, 6, 7) and issue 21's "cache of another clip": nothing the user made is
lost, and no input is silently misread.

Small synthetic clips (PNG folders and ffmpeg test-pattern MP4s), external depth maps with
``no_hdr`` (no network) except where the network's settings are the point (untrained weights).
"""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.cli import main
from rvr_addon.errors import InputError
from rvr_addon.estimate.cache import ClipCache, check_cache_source, frame_path, recover_swap
from rvr_addon.estimate.infer import EstimateJob, EstimateSettings
from rvr_addon.io.exr import read_exr, write_exr
from rvr_addon.io.maps import open_map_sequence
from rvr_addon.io.paths import check_outputs
from rvr_addon.io.video import ffmpeg_exe, probe_clip
from rvr_addon.pipeline import RenderJob, RenderSettings

W, H, N = 40, 30, 6


def _png_clip(folder: Path, seed: int, n: int = N) -> Path:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        cv2.imwrite(str(folder / f"f{i:03d}.png"), (rng.random((H, W, 3)) * 255).astype(np.uint8))
    return folder


def _maps(folder: Path, value: float, n: int = N) -> Path:
    folder.mkdir(parents=True)
    for i in range(n):
        np.save(folder / f"d_{i:04d}.npy", np.full((H, W), value + i, np.float32))
    return folder


def _mp4(path: Path, seconds: float = 1.0, faststart: bool = False) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    cmd = [ffmpeg_exe(), "-y", "-v", "error", "-f", "lavfi", "-i", f"testsrc2=size=160x96:rate=24:duration={seconds}",
           "-pix_fmt", "yuv420p", "-c:v", "libx264", "-g", "24", "-bf", "0"]
    subprocess.run(cmd + (["-movflags", "+faststart"] if faststart else []) + [str(path)], check=True)
    return path


def _estimate(clip: Path, cache: Path, maps: Path, **kw) -> EstimateJob:
    job = EstimateJob(EstimateSettings(input=clip, output=cache, depth=maps, no_hdr=True, **kw))
    job.run(progress=False)
    return job


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def clip(tmp_path):
    return _png_clip(tmp_path / "clip", 0)


# ------------------------------------------------------------------ 1: outputs never overwrite inputs


def test_render_refuses_to_write_over_its_source_video_also_through_dotdot_and_hard_links(tmp_path):
    video = _mp4(tmp_path / "same" / "clip.mp4", seconds=0.25)
    original = video.read_bytes()
    depth = tmp_path / "d.npy"
    np.save(depth, np.zeros((96, 160), np.float32))
    os.link(video, tmp_path / "link.mp4")
    for out in (video, tmp_path / "same" / ".." / "same" / "clip.mp4", tmp_path / "link.mp4"):
        with pytest.raises(InputError, match="same file") as info:
            RenderJob(RenderSettings(input=video, depth=depth, outputs=[out], aperture=2.0))
        assert str(out) in str(info.value) and str(video) in str(info.value)
    assert main(["render", str(video), "--depth", str(depth), "--hdr", str(depth), "--aperture", "2",
                 "-o", str(tmp_path / "same" / ".." / "same" / "clip.mp4"), "-q"]) == 2
    with pytest.raises(InputError, match="depth"):  # the depth maps are an input too
        RenderJob(RenderSettings(input=video, depth=depth, outputs=[depth.with_suffix(".npy")]))
    assert video.read_bytes() == original and (tmp_path / "link.mp4").read_bytes() == original


def test_estimate_refuses_an_output_that_is_contains_or_lies_in_its_input_folder(clip, tmp_path, capsys):
    maps = _maps(tmp_path / "maps", 1.0)
    before = _snapshot(tmp_path)
    for out in (clip, tmp_path / "clip" / "." , clip / "cache", tmp_path, maps):
        with pytest.raises(InputError, match="rvr estimate: the cache folder"):
            EstimateJob(EstimateSettings(input=clip, output=out, depth=maps, no_hdr=True))
    assert main(["estimate", str(clip), "-o", str(clip), "--depth", str(maps), "--no-hdr", "-q"]) == 2
    assert "same file or folder as the input" in capsys.readouterr().err
    assert _snapshot(tmp_path) == before  # nothing written


def test_every_command_checks_its_outputs_with_the_one_helper(clip, tmp_path):
    from rvr_addon.batch.graph import plan_clips
    from rvr_addon.batch.settings import BatchSettings
    from rvr_addon.temporal.job import StabilizeJob, StabilizeSettings

    # batch: a clip already named like the output of another clip
    out = tmp_path / "out"
    video = _mp4(out / "a.mp4", seconds=0.25)
    with pytest.raises(InputError, match="rvr batch: the output of clip 'a'"):
        plan_clips([video], BatchSettings(output=out), "f" * 16)
    # autofocus: the focus file over the manual targets
    targets = tmp_path / "t.json"
    targets.write_text("[]")
    assert main(["autofocus", str(clip), "--depth", str(tmp_path), "--targets", str(targets), "-o", str(targets),
                 "-q"]) == 2
    assert targets.read_text() == "[]"
    # stabilize: a cache inside the clip's folder
    with pytest.raises(InputError, match="rvr stabilize"):
        StabilizeJob(StabilizeSettings(cache=clip / "cache", input=clip))
    check_outputs("x", [("output", tmp_path / "new.mp4")], [("input", video), ("none", None)])  # fine


# ------------------------------------------------------------------ 2: another key builds beside the old cache


def test_other_settings_build_beside_the_cache_which_stays_usable_until_complete(clip, tmp_path):
    cache = tmp_path / "cache"
    first, second = _maps(tmp_path / "a", 1.0), _maps(tmp_path / "b", 100.0)
    _estimate(clip, cache, first)
    before = _snapshot(cache)
    job = EstimateJob(EstimateSettings(input=clip, output=cache, depth=second, no_hdr=True))
    assert job.step() and job.step()  # two frames of the new settings, then Ctrl-C / Esc
    job.cancel()
    assert "unchanged" in job.text and job.cache.rebuilding
    assert _snapshot(cache) == before  # the old cache, every frame and meta.json, as it was
    assert open_map_sequence(cache).get(3)[0, 0] == 1.0 + 3  # and still readable
    beside = list(tmp_path.glob(".cache.rebuild-*"))
    assert len(beside) == 1 and len(json.loads((beside[0] / "meta.json").read_text())["frames"]) == 2
    # the same new settings again: resumes beside, swaps in at the end
    job = _estimate(clip, cache, second)
    assert (job.computed, job.reused) == (N - 2, 2)
    meta = json.loads((cache / "meta.json").read_text())
    assert meta["depth"]["path"] == str(second) and meta["frame_count"] == N and "committing" not in meta
    assert open_map_sequence(cache).get(3)[0, 0] == 100.0 + 3
    assert not list(tmp_path.glob(".cache.*rebuild-*")) and not list(tmp_path.glob(".cache.*.old"))
    # the same settings once more: the cache is reused in place
    assert _estimate(clip, cache, second).reused == N


def test_a_crash_in_the_middle_of_the_swap_is_finished_by_the_next_open(clip, tmp_path):
    cache = tmp_path / "cache"
    first, second = _maps(tmp_path / "a", 1.0), _maps(tmp_path / "b", 100.0)
    _estimate(clip, cache, first)
    job = EstimateJob(EstimateSettings(input=clip, output=cache, depth=second, no_hdr=True, defer_commit=True))
    job.run(progress=False)
    rebuilt = job.cache.folder
    assert rebuilt != cache and json.loads((cache / "meta.json").read_text())["depth"]["path"] == str(first)
    meta = json.loads((rebuilt / "meta.json").read_text())
    (rebuilt / "meta.json").write_text(json.dumps({**meta, "committing": True}))
    cache.replace(tmp_path / ".cache.0badf00d.old")  # killed between the two renames
    recover_swap(cache)
    assert json.loads((cache / "meta.json").read_text())["depth"]["path"] == str(second)
    assert not rebuilt.exists() and not (tmp_path / ".cache.0badf00d.old").exists()


# ------------------------------------------------------------------ 6: one writer; readers never read a mix

_HOLDER = """
import sys, time
from rvr_addon.io.lock import acquire
lock = acquire(sys.argv[1], "the cache")
print("locked", flush=True)
time.sleep(60)
"""


def test_a_second_writer_and_readers_are_refused_while_another_process_writes(clip, tmp_path):
    cache = tmp_path / "cache"
    maps = _maps(tmp_path / "a", 1.0)
    _estimate(clip, cache, maps)
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(cache)], stdout=subprocess.PIPE, text=True,
                              cwd=Path(__file__).resolve().parents[2])
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(InputError, match=rf"being written by another process \(pid {holder.pid}"):
            _estimate(clip, cache, _maps(tmp_path / "b", 5.0))
        with pytest.raises(InputError, match="being written by another process"):
            open_map_sequence(cache)
        with pytest.raises(InputError, match="being written"):
            RenderJob(RenderSettings(input=clip, depth=cache, outputs=[tmp_path / "r.mp4"]))
    finally:
        holder.kill()
        holder.wait()
    assert open_map_sequence(cache).get(0)[0, 0] == 1.0  # the lock went with the process
    assert _estimate(clip, cache, maps).reused == N


def test_a_reader_refuses_a_frame_rewritten_after_it_read_meta_json(clip, tmp_path):
    cache = tmp_path / "cache"
    _estimate(clip, cache, _maps(tmp_path / "a", 1.0))
    seq = open_map_sequence(cache)
    seq.get(0)
    ch = read_exr(frame_path(cache, 1))
    write_exr(frame_path(cache, 1), {**ch, "D": ch["D"] + 7})  # another writer's frame, atomically renamed
    with pytest.raises(InputError, match="rewritten while it was being read"):
        seq.get(1)


# ------------------------------------------------------------------ 7: silent wrong results


def test_max_pixels_is_part_of_the_cache_key(clip, tmp_path):
    import torch

    from rvr_addon.estimate.train import export_weights
    from rvr_addon.estimate.unet import EstimatorNet

    torch.manual_seed(0)
    weights = export_weights(EstimatorNet(), tmp_path / "w.pt", iterations=0, wall_time_s=0.0, training={})
    cache = tmp_path / "cache"
    full = EstimateJob(EstimateSettings(input=clip, output=cache, weights=weights, depth_method="network"))
    full.run(progress=False)
    small = EstimateJob(EstimateSettings(input=clip, output=cache, weights=weights, depth_method="network",
                                         max_pixels=300))
    small.run(progress=False)
    assert (small.computed, small.reused) == (N, 0)
    assert json.loads((cache / "meta.json").read_text())["max_pixels"] == 300
    again = EstimateJob(EstimateSettings(input=clip, output=cache, weights=weights, depth_method="network",
                                         max_pixels=300))
    again.run(progress=False)
    assert again.reused == N


def test_a_cache_made_before_the_context_pass_recomputes(clip, tmp_path):
    """D's layout pass (infer.CONTEXT_PIXELS) is in the key: a meta.json without it (an older
    rvr's cache) is not reused."""
    import torch

    from rvr_addon.estimate.infer import CONTEXT_PIXELS
    from rvr_addon.estimate.train import export_weights
    from rvr_addon.estimate.unet import EstimatorNet

    torch.manual_seed(0)
    weights = export_weights(EstimatorNet(), tmp_path / "w.pt", iterations=0, wall_time_s=0.0, training={})
    cache = tmp_path / "cache"
    settings = EstimateSettings(input=clip, output=cache, weights=weights, depth_method="network")
    EstimateJob(settings).run(progress=False)
    meta = json.loads((cache / "meta.json").read_text())
    assert meta["context_pixels"] == CONTEXT_PIXELS
    del meta["context_pixels"]
    (cache / "meta.json").write_text(json.dumps(meta))
    again = EstimateJob(settings)
    again.run(progress=False)
    assert (again.computed, again.reused) == (N, 0)


def test_a_cache_made_before_the_layout_head_recomputes(clip, tmp_path):
    """The layout head that gives D's layout (infer.SHIPPED_LAYOUT, 2026-12-08) is in the key by its
    hash, and meta.json's model record names it: a cache without it (the context pass's) recomputes."""
    from rvr_addon.estimate.infer import SHIPPED_LAYOUT
    from rvr_addon.onnxrun import file_hash, has_onnxruntime

    if not (SHIPPED_LAYOUT.is_file() and has_onnxruntime()):
        pytest.skip("the layout head or onnxruntime is not here")
    cache = tmp_path / "cache"
    settings = EstimateSettings(input=clip, output=cache, depth_method="network")
    EstimateJob(settings).run(progress=False)
    meta = json.loads((cache / "meta.json").read_text())
    assert meta["layout"] == file_hash(SHIPPED_LAYOUT)
    assert meta["model"]["layout"]["hash"] == file_hash(SHIPPED_LAYOUT)
    del meta["layout"]
    (cache / "meta.json").write_text(json.dumps(meta))
    again = EstimateJob(settings)
    again.run(progress=False)
    assert (again.computed, again.reused) == (N, 0)


def test_an_npy_stack_is_read_as_one_map_per_frame(tmp_path):
    stack = np.arange(5 * H * W, dtype=np.float32).reshape(5, H, W)
    np.save(tmp_path / "stack.npy", stack)
    seq = open_map_sequence(tmp_path / "stack.npy")
    assert len(seq) == 5 and not seq.static
    assert np.array_equal(seq.get(3), stack[3]) and seq.get(4, size=(W, H)).shape == (H, W)
    np.savez(tmp_path / "hdr.npz", E=np.ones((4, H, W, 3), np.float32))
    assert len(open_map_sequence(tmp_path / "hdr.npz", kind="hdr")) == 4
    np.save(tmp_path / "one.npy", np.ones((H, W, 1), np.float32))  # one map with a channel axis
    assert open_map_sequence(tmp_path / "one.npy").static
    with pytest.raises(InputError, match="5 maps"):
        seq.get(5)


def test_a_truncated_faststart_mp4_is_reported(tmp_path, caplog):
    whole = _mp4(tmp_path / "whole.mp4", faststart=True)
    cut = tmp_path / "cut.mp4"
    data = whole.read_bytes()
    cut.write_bytes(data[:int(len(data) * 0.4)])
    with caplog.at_level(logging.WARNING):
        assert probe_clip(whole).frame_count == 24
        assert not caplog.records
        count = probe_clip(cut).frame_count
    assert 0 < count < 24
    assert any(str(cut) in r.getMessage() and "declares 24 frames" in r.getMessage() for r in caplog.records)
    depth = tmp_path / "d.npy"
    np.save(depth, np.zeros((96, 160), np.float32))
    with pytest.raises(InputError, match="may be truncated") as info:  # frames past the cut are not invented
        _estimate(cut, tmp_path / "cache", depth)
    assert str(cut) in str(info.value)


def test_track_keys_beyond_the_clip_and_extra_depth_maps_are_reported(clip, tmp_path, caplog):
    track = tmp_path / "track.json"
    track.write_text(json.dumps({"keys": [{"frame": 0, "focus": 1, "aperture": 1},
                                          {"frame": 100, "focus": 2, "aperture": 1}]}))
    maps = _maps(tmp_path / "maps", 1.0, n=N + 4)
    with caplog.at_level(logging.WARNING):
        RenderJob(RenderSettings(input=clip, depth=maps, track=track, outputs=[tmp_path / "r.mp4"]))
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert str(track) in text and f"of {N} frames" in text and "100" in text
    assert f"has {N + 4} maps but the clip '{clip}' has {N} frames" in text


def test_truncated_exr_and_cache_frames_name_the_file_and_the_fix(clip, tmp_path):
    exr = tmp_path / "x.exr"
    write_exr(exr, {"D": np.random.default_rng(0).random((64, 80)).astype(np.float32)})
    exr.write_bytes(exr.read_bytes()[: exr.stat().st_size // 2])
    with pytest.raises(InputError, match="truncated or damaged") as info:
        read_exr(exr)
    assert str(exr) in str(info.value)
    cache = tmp_path / "cache"
    _estimate(clip, cache, _maps(tmp_path / "a", 1.0))
    path = frame_path(cache, 2)
    path.write_bytes(path.read_bytes()[:200])
    seq = open_map_sequence(cache)
    with pytest.raises(InputError, match="truncated") as info:
        seq.get(2)
    assert str(path) in str(info.value) and f"rvr estimate {clip} -o {cache}" in str(info.value)
    frame_path(cache, 3).unlink()
    with pytest.raises(InputError, match="rvr estimate"):
        seq.get(3)


# ------------------------------------------------------------------ issue 21: a cache of another clip


def test_a_cache_of_another_clip_is_refused_and_rvr_estimate_recomputes_it(clip, tmp_path, capsys):
    import shutil

    cache = tmp_path / "cache"
    _estimate(clip, cache, _maps(tmp_path / "a", 1.0))
    other = _png_clip(tmp_path / "other", 1)
    with pytest.raises(InputError, match="was made from") as info:
        RenderJob(RenderSettings(input=other, depth=cache, hdr=cache, outputs=[tmp_path / "r.mp4"]))
    assert str(clip) in str(info.value) and f"rvr estimate {other} -o {cache}" in str(info.value)
    for source in ("--cache", "--depth"):
        assert main(["autofocus", str(other), source, str(cache), "-o", str(tmp_path / "f.json"), "-q"]) == 2
        assert "rvr autofocus: the cache" in capsys.readouterr().err and not (tmp_path / "f.json").exists()
    # a copy of the clip (new times, new place) is the same clip
    copy = tmp_path / "copy"
    shutil.copytree(clip, copy)
    time.sleep(0.01)
    os.utime(copy / "f000.png")
    check_cache_source(cache, copy)
    # the clip edited in place: refused, saying so
    cv2.imwrite(str(clip / "f000.png"), np.zeros((H, W, 3), np.uint8))
    with pytest.raises(InputError, match="changed or replaced"):
        check_cache_source(cache, clip)
    # rvr estimate itself recomputes for the other clip
    job = _estimate(other, cache, _maps(tmp_path / "b", 3.0))
    assert job.computed == N
    assert json.loads((cache / "meta.json").read_text())["source"]["path"] == str(other)
    check_cache_source(cache, other)


def test_stabilizing_with_other_settings_keeps_the_stabilized_cache_until_complete(clip, tmp_path):
    from rvr_addon.estimate.cache import stabilized_complete
    from rvr_addon.temporal.filter import TemporalSettings
    from rvr_addon.temporal.job import StabilizeJob, StabilizeSettings

    cache = tmp_path / "cache"
    _estimate(clip, cache, _maps(tmp_path / "a", 1.0))
    StabilizeJob(StabilizeSettings(cache=cache)).run(progress=False)
    before = _snapshot(cache)
    assert stabilized_complete(json.loads(before["meta.json"]))
    other = StabilizeSettings(cache=cache, temporal=TemporalSettings(m=2))
    job = StabilizeJob(other)
    for _ in range(4):
        job.step()
    job.cancel()
    assert _snapshot(cache) == before  # still complete and stabilized with the first settings
    assert open_map_sequence(cache).prefix == "S."
    job = StabilizeJob(other)
    job.run(progress=False)
    meta = json.loads((cache / "meta.json").read_text())
    assert stabilized_complete(meta) and meta["stabilized"]["settings"]["m"] == 2 and job.reused > 0
    assert not list(tmp_path.glob(".cache.rebuild-*"))
    assert StabilizeJob(other).text.startswith("all")  # in place now: nothing to do
