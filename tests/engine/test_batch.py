"""rvr batch: chunk plans, staging caches, chunked == single-process output, a killed worker,
bad input, re-runs, the missing-weights error; LAAF measured in chunks == one pass, exactly.
Clips are 64x36, 12 frames; the estimator
weights are untrained (exported for the tests only; the shipped model is not used)."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from batch_synth import N, KillOnce, chunked_laaf, laaf_outcome, make_clip, make_depth, untrained_weights
from rvr_addon.batch.chunks import chunk_ranges, stabilize_reads
from rvr_addon.batch.graph import plan_clips, run_batch
from rvr_addon.batch.inputs import clip_names, collect_clips
from rvr_addon.batch.settings import BatchSettings
from rvr_addon.batch.staging import adopt_estimates, seed_staging
from rvr_addon.batch.worker import loads_per_worker
from rvr_addon.cli import main
from rvr_addon.errors import InputError
from rvr_addon.estimate.cache import ClipCache, frame_path
from rvr_addon.io.exr import read_exr
from rvr_addon.temporal.filter import TemporalSettings

CENTRED = TemporalSettings(window="centred")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch")
    return {"root": root, "weights": untrained_weights(root / "w.pt"),
            "a": make_clip(root / "clips" / "a.mp4", seed=0), "b": make_clip(root / "clips" / "b.mp4", seed=1)}


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def reference(data):
    """Clip a through the single-process commands: estimate, stabilize (centred), autofocus, render (EXR)."""
    ref = data["root"] / "ref"
    cache, focus, frames = ref / "cache", ref / "focus.json", ref / "frames"
    a, w = str(data["a"]), str(data["weights"])
    assert main(["estimate", a, "-o", str(cache), "--weights", w, "-q"]) == 0
    assert main(["stabilize", str(cache), "--window", "centred", "-q"]) == 0
    assert main(["autofocus", a, "--cache", str(cache), "--preset", "conversation", "-o", str(focus), "-q"]) == 0
    assert main(["render", a, "--depth", str(cache), "--hdr", str(cache), "--track", str(focus),
                 "-o", str(frames / "frame_%05d.exr"), "-q"]) == 0
    return {"cache": cache, "focus": focus, "frames": frames}


def exr_frames(folder: Path) -> list[np.ndarray]:
    files = sorted(folder.glob("frame_*.exr"))
    return [np.dstack([(ch := read_exr(f))["R"], ch["G"], ch["B"]]) for f in files]


def assert_same_as_reference(out: Path, settings: BatchSettings, reference: dict, name: str = "a") -> None:
    got, want = exr_frames(out / f"{name}_frames"), exr_frames(reference["frames"])
    assert len(got) == len(want) == N
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-5, atol=1e-5)
    focus, ref_focus = json.loads((out / f"{name}.focus.json").read_text()), json.loads(reference["focus"].read_text())
    np.testing.assert_allclose(focus["per_frame"]["focus"], ref_focus["per_frame"]["focus"], atol=1e-6)
    assert focus["keys"] == ref_focus["keys"] and focus["nfts"] == ref_focus["nfts"]  # LAAF measured in chunks
    cache = next(settings.caches.glob(f"{name}-*"))
    for i in range(N):
        g, w = read_exr(frame_path(cache, i)), read_exr(frame_path(reference["cache"], i))
        for ch in ("D", "S.D", "S.E.R", "S.C"):
            np.testing.assert_allclose(g[ch], w[ch], rtol=1e-5, atol=1e-5, err_msg=f"frame {i} channel {ch}")
    # one file per frame and the meta, nothing else (no duplicates, no temp files)
    names = sorted(p.name for p in cache.iterdir())
    assert names == [f"frame_{i:05d}.exr" for i in range(1, N + 1)] + ["meta.json"]
    meta = json.loads((cache / "meta.json").read_text())
    assert meta["frame_count"] == N and not meta["stabilized"]["pending"]


# ------------------------------------------------------------------------------ pure parts


def test_chunks_cover_the_clip_and_the_filter_reads_its_window():
    assert chunk_ranges(12, 4) == [(0, 4), (4, 8), (8, 12)]
    assert chunk_ranges(12, 0) == [(0, 12)] and chunk_ranges(12, 50) == [(0, 12)] and chunk_ranges(0, 4) == []
    assert chunk_ranges(100, 40) == [(0, 40), (40, 80), (80, 100)]
    assert chunk_ranges(81, 40) == [(0, 40), (40, 81)]  # a 1-frame tail joins the chunk before it
    assert stabilize_reads(8, 12, 20, TemporalSettings(window="causal")) == (2, 12)  # causal: M = 6 past frames
    assert TemporalSettings().window == "centred"  # the default: a recorded clip has its future
    assert stabilize_reads(8, 12, 20, CENTRED) == (5, 15)  # centred: 3 past, 3 future
    assert stabilize_reads(0, 4, 5, CENTRED) == (0, 5)


def test_clips_from_folders_and_list_files_get_unique_names(tmp_path, data):
    (tmp_path / "x").mkdir()
    (tmp_path / "y").mkdir()
    a1, a2 = shutil.copy(data["a"], tmp_path / "x" / "take.mp4"), shutil.copy(data["a"], tmp_path / "y" / "take.mp4")
    listing = tmp_path / "clips.txt"
    listing.write_text(f"# two takes\nx/take.mp4\n{a2}\n\nmissing.mov\n")
    clips = collect_clips([tmp_path / "x", listing])
    assert [Path(c).resolve() for c in clips] == [Path(a1).resolve(), Path(a2).resolve(), (tmp_path / "missing.mov")]
    names = clip_names(clips)
    assert len(set(names)) == 3 and names[0].startswith("take-") and names[2] == "missing"
    with pytest.raises(InputError, match="holds no clip"):
        collect_clips([tmp_path / "x" / ".."/ "x" / ".."])  # a folder of folders without clips


def test_staging_adoption_is_atomic_and_repeatable(tmp_path, data):
    """Chunks write staging caches; adopting them is safe to repeat and never re-records a frame twice."""
    from rvr_addon.estimate.infer import EstimateJob, EstimateSettings

    clip_cache, staging = tmp_path / "cache", tmp_path / "staging" / "estimate_000000_000004"
    seed_staging(clip_cache, staging, 0, 4)  # nothing cached yet: an empty staging folder
    EstimateJob(EstimateSettings(input=data["a"], output=staging, depth=make_depth(tmp_path / "d"), no_hdr=True,
                                 start=0, stop=4)).run(progress=False)
    copy = tmp_path / "copy"
    shutil.copytree(staging, copy)
    assert adopt_estimates(clip_cache, staging) == 4 and not staging.exists()
    assert adopt_estimates(clip_cache, staging) == 0  # merged already: nothing to do
    cache = ClipCache.open_existing(clip_cache)
    assert cache.frame_indices() == [0, 1, 2, 3]
    # a re-seeded chunk reuses the cached frames through hard links; adopting them moves nothing
    again = tmp_path / "staging" / "again"
    seed_staging(clip_cache, again, 2, 4)
    assert sorted(p.name for p in again.glob("frame_*")) == ["frame_00003.exr", "frame_00004.exr"]
    assert os.path.samefile(frame_path(again, 2), frame_path(clip_cache, 2))
    assert adopt_estimates(clip_cache, again) == 0
    assert ClipCache.open_existing(clip_cache).frame_indices() == [0, 1, 2, 3]
    assert adopt_estimates(clip_cache, copy) == 4  # other files for the same frames replace them, once each
    assert sorted(p.name for p in clip_cache.iterdir()) == [f"frame_{i:05d}.exr" for i in range(1, 5)] + ["meta.json"]


# ------------------------------------------------------------------------------ on a local cluster


def test_chunked_batch_equals_the_single_process_commands(tmp_path, data, client, reference):
    settings = BatchSettings(output=tmp_path / "out", weights=data["weights"], temporal=CENTRED, format="exr",
                             chunk_frames=4)
    report = run_batch([data["a"]], settings, client=client, progress=False)
    assert [c.status for c in report.clips] == ["done"], report.table()
    assert_same_as_reference(tmp_path / "out", settings, reference)
    assert report.frames_done == N and report.fps > 0
    assert {"estimate", "laaf measure", "autofocus", "render"} <= set(report.stage_seconds_per_frame())
    assert set(loads_per_worker(client).values()) <= {0, 1}  # the model is loaded once per worker process
    assert not (tmp_path / "out" / ".rvr_batch" / "work").exists()  # work folders are cleaned up


def test_a_killed_worker_chunk_is_retried_without_corrupting_the_cache(tmp_path, data, client, reference):
    out = tmp_path / "out"
    settings = BatchSettings(output=out, weights=data["weights"], temporal=CENTRED, format="exr", chunk_frames=4)
    flag = tmp_path / "killed.txt"
    # the fused depth (auto) estimates a clip in one task: killed once it has written its first frame
    plugin = KillOnce(flag, "rvr-estimate-0-", settings.caches / ".staging", "*/estimate_000000_000012/frame_*.exr")
    client.register_plugin(plugin, name=KillOnce.name)
    try:
        before = set(client.nthreads())
        report = run_batch([data["a"]], settings, client=client, progress=False)
    finally:
        client.unregister_worker_plugin(KillOnce.name)
    assert flag.is_file(), "the test plugin did not kill a worker"
    pid = int(flag.read_text().split()[0])
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # that worker process is gone
    client.wait_for_workers(2, timeout=60)
    assert set(client.nthreads()) != before  # the nanny started a new worker in its place
    assert [c.status for c in report.clips] == ["done"], report.table()
    assert_same_as_reference(out, settings, reference)


def test_cli_bad_clips_fail_alone_and_a_rerun_skips_finished_clips(tmp_path, data, capsys):
    """External depth without weights; a corrupt and a missing clip; PNG frames; then the re-run."""
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"not a video")
    depth = tmp_path / "depth"
    make_depth(depth / "a")
    make_depth(depth / "broken")
    out = tmp_path / "out"
    args = ["batch", str(data["a"]), str(bad), str(tmp_path / "missing.mp4"), "-o", str(out), "--depth-root",
            str(depth), "--no-hdr", "--format", "png", "--chunk-frames", "5", "--workers", "1", "--no-dashboard", "-q"]
    assert main(args) == 1
    table = capsys.readouterr().out
    assert "clips done 1, skipped (already finished) 0, failed 2" in table
    assert "broken.mp4: probe: Cannot open video" in table and "missing.mp4' not found" in table
    assert len(list((out / "a_frames").glob("frame_*.png"))) == N and (out / "a.focus.json").is_file()
    assert main(args) == 1
    assert "clips done 0, skipped (already finished) 1, failed 2" in capsys.readouterr().out


def test_missing_weights_name_the_file_before_any_cluster_starts(tmp_path, data, monkeypatch, capsys):
    import rvr_addon.estimate.infer as infer

    monkeypatch.setattr(infer, "SHIPPED_WEIGHTS", tmp_path / "weights" / "estimator.pt")
    monkeypatch.setattr(infer, "SHIPPED_ONNX", tmp_path / "weights" / "estimator.onnx")  # its export is a fallback
    with pytest.raises(InputError, match=r"weights/estimator\.pt"):
        run_batch([data["a"]], BatchSettings(output=tmp_path / "out"), progress=False)
    assert main(["batch", str(data["a"]), "-o", str(tmp_path / "out"), "--weights", str(tmp_path / "nope.pt")]) == 2
    assert "nope.pt' not found" in capsys.readouterr().err
    assert main(["batch", str(data["a"]), "-o", str(tmp_path / "out"), "--preset", "learned", "--afnet-weights",
                 str(tmp_path / "no_afnet.pt")]) == 2
    assert "AF-Net weights" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_learned_preset_settings_reach_autofocus_and_the_fingerprint(tmp_path):
    from rvr_addon.afnet.infer import DEFAULT_WEIGHTS
    from rvr_addon.batch.graph import afnet_id
    from rvr_addon.batch.stages import autofocus_settings

    s = BatchSettings(output=tmp_path, preset="learned", afnet_weights=DEFAULT_WEIGHTS, afnet_threshold=0.4,
                      afnet_speaker=False)
    plan = plan_clips([tmp_path / "clips" / "a.mp4"], s, "f" * 16)[0]  # not OUT/a.mp4: that is its output
    a = autofocus_settings(plan, s)
    assert (a.preset, a.afnet_weights, a.afnet_threshold, a.afnet_speaker) == ("learned", DEFAULT_WEIGHTS, 0.4, False)
    assert len(afnet_id(s)) == 16 and afnet_id(BatchSettings(output=tmp_path)) == ""
    import hashlib  # the id is the file's hash, as before: earlier batches' fingerprints still match

    assert afnet_id(s) == hashlib.sha256(DEFAULT_WEIGHTS.read_bytes()).hexdigest()[:16]
    assert s.fingerprint("x") != BatchSettings(output=tmp_path, preset="learned", afnet_weights=DEFAULT_WEIGHTS,
                                               afnet_threshold=0.4).fingerprint("x")


# ------------------------------------------------------------------------------ LAAF in chunks


def test_analysis_chunks_read_the_frame_before_and_the_last_face_detection():
    from rvr_addon.laaf.analysis import analysis_start

    assert analysis_start(0, 6) == 0 and analysis_start(1, 6) == 0
    assert analysis_start(7, 6) == 6 and analysis_start(12, 6) == 11 and analysis_start(17, 6) == 12
    assert analysis_start(17, None) == 16  # no face detector: only the frame before


def test_laaf_measured_in_chunks_equals_one_pass_action(tmp_path):
    """Action + saliency (optical flow, decaying motion memory) on a PNG sequence, chunks of 7."""
    from laaf_synth import entering_square, write_clip
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    frames, maps, _ = entering_square(n=40, enter=20)
    fdir, ddir = write_clip(tmp_path, frames, maps)
    settings = AutofocusSettings(input=fdir, depth=ddir, preset="action", fps=24)
    one = AutofocusJob(settings).run(progress=False)
    chunked = chunked_laaf(settings, tmp_path / "work", 40, 7)
    assert len(one.nfts) >= 2 and one.detectors["action"]["homography_failures"] >= 0
    assert laaf_outcome(chunked) == laaf_outcome(one)


def test_laaf_measured_in_chunks_equals_one_pass_conversation(tmp_path, monkeypatch):
    """Face tracks (detected every 6 frames: chunk starts 7, 14, ... fall between detections),
    mouth motion and audio-visual synchrony of the speech detector, on an MP4 with audio."""
    from batch_synth import fake_faces, make_talking_clip
    from rvr_addon.laaf.detectors import face, speech
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

    clip, depth, audio = make_talking_clip(tmp_path)
    monkeypatch.setattr(face.FaceBackend, "detect", fake_faces)
    monkeypatch.setattr(speech, "analyse_audio", lambda samples, fps, n, **kw: audio)
    settings = AutofocusSettings(input=clip, depth=depth, preset="conversation", face_backend="haar")
    one = AutofocusJob(settings).run(progress=False)
    m = one.detectors
    assert m["speech"]["available"] and m["speech"]["speaker_frames"] > 0 and m["face"]["face_tracks"] >= 2
    assert one.settings["preset_used"] == "conversation" and len(one.nfts) >= 2
    chunked = chunked_laaf(settings, tmp_path / "work", 40, 7)
    assert laaf_outcome(chunked) == laaf_outcome(one)


# ------------------------------------------------------------------------------ the depth method


def test_depth_method_reaches_the_estimate_and_the_fingerprint(tmp_path, data, monkeypatch):
    """Fused depth (auto, parallax, people) is one estimate task per clip; network and external are
    chunked; the method is part of the fingerprint (network keeps the formula of earlier batches, with
    LAAF's decision version since that changed)."""
    import dataclasses
    import hashlib

    from rvr_addon import __version__
    from rvr_addon.batch import stages
    from rvr_addon.batch.chunks import estimate_ranges
    from rvr_addon.batch.graph import check_settings
    from rvr_addon.laaf.presets import DECISION_VERSION

    auto = BatchSettings(output=tmp_path / "out", weights=data["weights"], chunk_frames=4)
    network = dataclasses.replace(auto, depth_method="network")
    external = dataclasses.replace(auto, depth_root=tmp_path, no_hdr=True)
    assert auto.clip_wide_estimate and not network.clip_wide_estimate and not external.clip_wide_estimate
    assert estimate_ranges(N, 4, auto.clip_wide_estimate) == [(0, N)]
    assert estimate_ranges(N, 4, network.clip_wide_estimate) == chunk_ranges(N, 4) == [(0, 4), (4, 8), (8, 12)]
    fingerprints = {auto.fingerprint("w"), network.fingerprint("w"), dataclasses.replace(auto, hfov_deg=50.0)
                    .fingerprint("w"), dataclasses.replace(auto, depth_method="parallax").fingerprint("w")}
    assert len(fingerprints) == 4
    record = dataclasses.asdict(network)  # the fingerprint of a batch made before the depth system
    for k in ("output", "cache_root", "chunk_frames", "force", "retries", "keep_cache", "depth_method", "hfov_deg"):
        record.pop(k)
    record.update(engine_version=__version__, weights="w", laaf_decision=DECISION_VERSION)
    old = hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()[:16]
    assert network.fingerprint("w") == old  # (since LAAF's decision version 2 with it: focus in seconds)
    # bad combinations fail before any cluster starts
    with pytest.raises(InputError, match="--depth-method external needs --depth-root"):
        check_settings(dataclasses.replace(auto, depth_method="external"))
    with pytest.raises(InputError, match="--depth-method parallax"):
        check_settings(dataclasses.replace(external, depth_method="parallax"))
    with pytest.raises(InputError, match="--hfov"):
        check_settings(dataclasses.replace(auto, hfov_deg=0.5))
    from rvr_addon.depth import system

    monkeypatch.setattr(system, "people_available", lambda: (False, "mediapipe is not installed; pip install it"))
    with pytest.raises(InputError, match="--depth-method people: mediapipe"):
        check_settings(dataclasses.replace(auto, depth_method="people"))
    monkeypatch.undo()
    # the estimate task runs EstimateJob with the method and the field of view
    plan = plan_clips([data["a"]], auto, "f" * 16)[0].probed(frames=N)
    for settings, want in ((network, "network"), (dataclasses.replace(network, depth_method="auto", hfov_deg=50.0),
                                                  "auto")):
        r = stages.estimate(plan, settings, data["weights"], 0, N)
        assert r["computed"] == N
        staging = stages.staging_root(plan) / f"estimate_000000_{N:06d}"
        meta = json.loads((staging / "meta.json").read_text())
        assert meta["depth_plan"]["method"] == want
        if want == "network":
            assert meta["depth"] == "network"
        else:
            assert meta["depth"]["method"] == "auto" and meta["depth_cues"]["used"]["frames"] == N
            assert meta["depth"].get("hfov_deg", 50.0) == 50.0
        shutil.rmtree(staging)


def test_cli_batch_depth_method_and_hfov_reach_the_settings(monkeypatch, tmp_path, data):
    import rvr_addon.batch.graph as graph

    seen = {}

    def fake_run_batch(clips, settings, cluster, progress=True):
        seen["settings"] = settings
        raise InputError("stop here")

    monkeypatch.setattr(graph, "run_batch", fake_run_batch)
    assert main(["batch", str(data["a"]), "-o", str(tmp_path / "out"), "--depth-method", "parallax", "--hfov", "72",
                 "--no-dashboard", "-q"]) == 2
    assert seen["settings"].depth_method == "parallax" and seen["settings"].hfov_deg == 72.0
    assert main(["batch", str(data["a"]), "-o", str(tmp_path / "out"), "--no-dashboard", "-q"]) == 2
    assert seen["settings"].depth_method == "auto" and seen["settings"].hfov_deg is None


def test_calm_cuts_and_the_default_preset_reach_each_clips_autofocus(tmp_path):
    from rvr_addon.batch.settings import ClipPlan
    from rvr_addon.batch.stages import autofocus_settings
    from rvr_addon.laaf.presets import DEFAULT_PRESET

    plan = ClipPlan(index=0, source=tmp_path / "a.mp4", name="a", cache=tmp_path / "c", work=tmp_path / "w")
    s = autofocus_settings(plan, BatchSettings(output=tmp_path / "out", calm=0.2, detect_cuts=False))
    assert (s.calm, s.detect_cuts, s.preset) == (0.2, False, DEFAULT_PRESET)
    assert main(["batch", str(tmp_path / "a.mp4"), "-o", str(tmp_path / "out"), "--calm", "1.5"]) == 2


def test_a_variable_frame_rate_clip_keeps_sound_and_picture_in_sync(tmp_path, data, client, ffmpeg_run):
    """As in rvr refocus: the probe task makes the clip's constant-rate copy (work folder) and every
    stage reads it, so the rendered flash is where its beep is (decode order put it 0.3 s early)."""
    from vfr_synth import assert_in_sync, flash_clip

    clip = flash_clip(ffmpeg_run, tmp_path / "vfr.mp4")
    settings = BatchSettings(output=tmp_path / "out", weights=data["weights"], depth_method="network",
                             chunk_frames=40)
    report = run_batch([clip], settings, client=client, progress=False)
    assert [c.status for c in report.clips] == ["done"], report.table()
    out = tmp_path / "out" / "vfr.mp4"
    assert_in_sync(out)
    assert report.clips[0].source == clip  # the report names the user's clip, not the copy
