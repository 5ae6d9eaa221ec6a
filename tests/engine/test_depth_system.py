"""depth.system (plan_depth, DepthStream) through rvr estimate / EstimateJob: the plans of each
--depth-method, the people cue off without mediapipe, the cache key and meta.json record of the
plan, a stale cache when the method changes, bad combinations, and a resumed auto run that equals
an uninterrupted one. The people cue is faked here (tests/engine/test_depth_people.py runs the real
one); the parallax cue runs for real on a ray-cast translating clip."""
from __future__ import annotations

import importlib.util
import json
import logging

import cv2
import numpy as np
import pytest

from rvr_addon.cli import main
from rvr_addon.depth import people as people_mod
from rvr_addon.depth import system
from rvr_addon.depth.cues import CueMap
from rvr_addon.depth.system import DepthPlan, plan_depth
from rvr_addon.errors import InputError
from rvr_addon.estimate.cache import frame_path
from rvr_addon.estimate.infer import EstimateJob, EstimateSettings
from rvr_addon.io.exr import read_exr
from rvr_addon.io.video import iter_frames
from test_depth_parallax import render, translating_clip
from test_estimate_infer import untrained_weights

N_MOVING = 9


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    return untrained_weights(tmp_path_factory.mktemp("w") / "w.pt", 0)


def write_pngs(folder, frames):
    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f_{i:04d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    return folder


@pytest.fixture(scope="module")
def still_clip(tmp_path_factory):
    """6 identical frames of the ray-cast planes: a camera that does not move."""
    frame, _ = render(np.zeros(3))
    return write_pngs(tmp_path_factory.mktemp("still") / "clip", [frame] * 6)


@pytest.fixture(scope="module")
def moving_clip(tmp_path_factory):
    """N_MOVING frames of a camera translating past planes at 2, 3.5 and 7 m (320x240)."""
    frames, _ = translating_clip(n=N_MOVING)
    return write_pngs(tmp_path_factory.mktemp("moving") / "clip", frames)


class FakePeople:
    """Stands in for PeopleDetector: one 'person' on the 2 m plane's pixels, at a distance that
    depends on the frame's content (deterministic), so the fused clip state depends on it."""

    instances = 0

    def __init__(self, hfov_deg=66.0, **kw):
        FakePeople.instances += 1

    def __call__(self, frame):
        h, w = frame.shape[:2]
        q = np.full((h, w), np.nan, np.float32)
        c = np.zeros((h, w), np.float32)
        y0, y1, x0, x1 = h // 4, 3 * h // 4, w // 3, w // 2
        q[y0:y1, x0:x1] = 0.5 + 0.002 * (float(frame.mean()) % 5.0)
        c[y0:y1, x0:x1] = 1.0

        class Result:
            persons = []  # the auto probe masks people's tracks; this fake's person has no matte
            cue = CueMap("people", q, c, metric=True, shift_free=True, info={"people": 1})

        return Result()

    def close(self):
        pass


@pytest.fixture
def fake_people(monkeypatch):
    monkeypatch.setattr(system, "people_available", lambda: (True, "fake"))
    monkeypatch.setattr(people_mod, "PeopleDetector", FakePeople)


@pytest.fixture
def no_mediapipe(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a, **k: None if name.split(".")[0] == "mediapipe" else real(name, *a, **k))


def meta(cache):
    return json.loads((cache / "meta.json").read_text())


def frames_d(cache, n):
    return [read_exr(frame_path(cache, i))["D"] for i in range(n)]


# ------------------------------------------------------------------------------ plan_depth


def test_network_and_external_plans():
    for method in ("network", "external"):
        plan = plan_depth(method, None)
        assert plan.cues == (method,) and plan.reasons == {}
        assert plan.key() == {"method": method, "cues": [method]}
    with pytest.raises(InputError, match="choose one of"):
        plan_depth("lidar", None)
    with pytest.raises(InputError, match="--hfov"):
        plan_depth("auto", None, hfov_deg=200.0)


def test_auto_on_a_still_clip_has_no_parallax_and_says_why(still_clip, fake_people):
    plan = plan_depth("auto", lambda: iter_frames(still_clip))
    assert plan.cues == ("people", "network")
    assert "parallax" in plan.reasons and "still" in plan.reasons["parallax"]
    key = plan.key()
    assert key["method"] == "auto" and key["cues"] == ["people", "network"] and "fusion" in key
    assert "still" in plan.summary()


def test_auto_without_mediapipe_warns_and_uses_the_others(still_clip, no_mediapipe, caplog):
    assert not system.people_available()[0]
    with caplog.at_level(logging.WARNING):
        plan = plan_depth("auto", lambda: iter_frames(still_clip))
    assert plan.cues == ("network",)
    assert plan.reasons["people"].startswith("off") and "mediapipe" in plan.reasons["people"]
    assert any("people cue is off" in r.getMessage() for r in caplog.records)
    with pytest.raises(InputError, match=r"--depth-method people.*mediapipe==.*pip install"):
        plan_depth("people", None)


def test_parallax_plan_is_forced(moving_clip):
    plan = plan_depth("parallax", None)
    assert plan.cues == ("parallax", "network") and plan.reasons == {"parallax": "asked for"}
    auto = plan_depth("auto", lambda: iter_frames(moving_clip))
    assert auto.cues[0] == "parallax", auto.reasons


# ------------------------------------------------------------------------------ EstimateJob


def run(clip, cache, **kw) -> EstimateJob:
    job = EstimateJob(EstimateSettings(input=clip, output=cache, **kw))
    job.run(progress=False)
    return job


def test_network_keeps_the_old_key_and_auto_records_the_plan(still_clip, tmp_path, weights, fake_people):
    cache = tmp_path / "cache"
    job = run(still_clip, cache, weights=weights, depth_method="network")
    m = meta(cache)
    assert m["depth"] == "network"  # the key earlier caches were written under: they stay valid
    assert m["depth_plan"]["cues"] == ["network"] and "depth_cues" not in m and job.stream is None
    net_d = frames_d(cache, 6)
    # auto (people + network here): another key, so the cache is stale and recomputed
    job = run(still_clip, cache, weights=weights)
    assert (job.computed, job.reused) == (6, 0)
    m = meta(cache)
    assert m["depth"]["method"] == "auto" and m["depth"]["cues"] == ["people", "network"]
    assert m["depth_plan"] == {"method": "auto", "cues": ["people", "network"], "reasons": job.plan.reasons,
                               "probe_start": 0, "hfov_asked": None}
    used = m["depth_cues"]["used"]
    assert used["frames"] == 6 and used["people"] == 6 and used["parallax"] == 0
    assert "people on 6 of 6 frames" in job.text
    assert not np.array_equal(frames_d(cache, 6)[0], net_d[0])
    # the same again reuses everything and keeps the record of the cues, without probing the clip again
    def no_probe(*a, **k):
        raise AssertionError("the recorded plan should have been reused")

    real_plan = system.plan_depth
    system.plan_depth = no_probe
    try:
        again = run(still_clip, cache, weights=weights)
    finally:
        system.plan_depth = real_plan
    assert again.plan.cues == ("people", "network") and again.plan.reasons == job.plan.reasons
    assert (again.computed, again.reused) == (0, 6)
    assert meta(cache)["depth_cues"]["used"] == used
    # back to network: stale again, recomputed to the network's own D
    back = run(still_clip, cache, weights=weights, depth_method="network")
    assert back.computed == 6 and meta(cache)["depth"] == "network"
    np.testing.assert_array_equal(frames_d(cache, 6)[3], net_d[3])


def test_auto_without_people_is_the_network_cache(still_clip, tmp_path, weights, no_mediapipe):
    """auto that decides the network alone gives the network's cache (same key, same frames)."""
    cache = tmp_path / "cache"
    run(still_clip, cache, weights=weights, depth_method="network")
    job = run(still_clip, cache, weights=weights)
    assert job.plan.cues == ("network",) and (job.computed, job.reused) == (0, 6)
    assert meta(cache)["depth_plan"]["reasons"]["people"].startswith("off")


def test_bad_combinations(still_clip, tmp_path, weights, no_mediapipe, capsys):
    maps = tmp_path / "maps"
    maps.mkdir()
    for i in range(6):
        np.save(maps / f"d{i}.npy", np.zeros((240, 320), np.float32))
    for method in ("parallax", "people", "network"):
        with pytest.raises(InputError, match=f"--depth-method {method}"):
            EstimateJob(EstimateSettings(input=still_clip, output=tmp_path / "c", depth=maps, depth_method=method,
                                         no_hdr=True))
    with pytest.raises(InputError, match="needs --depth"):
        EstimateJob(EstimateSettings(input=still_clip, output=tmp_path / "c", depth_method="external", weights=weights))
    # people without mediapipe: the fix is named, through the CLI too
    assert main(["estimate", str(still_clip), "-o", str(tmp_path / "c"), "--weights", str(weights),
                 "--depth-method", "people", "-q"]) == 2
    err = capsys.readouterr().err
    assert "--depth-method people" in err and "pip install" in err
    assert main(["estimate", str(still_clip), "-o", str(tmp_path / "c"), "--weights", str(weights),
                 "--hfov", "0", "-q"]) == 2
    assert "--hfov" in capsys.readouterr().err
    # external maps with auto: external
    job = EstimateJob(EstimateSettings(input=still_clip, output=tmp_path / "c2", depth=maps, no_hdr=True))
    assert job.plan.cues == ("external",) and job.stream is None


def test_a_resumed_auto_run_equals_an_uninterrupted_one(moving_clip, tmp_path, weights, fake_people):
    whole = tmp_path / "whole"
    job = run(moving_clip, whole, weights=weights, hfov_deg=60.0)
    assert job.plan.cues == ("parallax", "people", "network")
    used = meta(whole)["depth_cues"]["used"]
    assert used["frames"] == N_MOVING and used["parallax"] > 0 and used["people"] == N_MOVING
    assert meta(whole)["depth"]["hfov_deg"] == 60.0
    # interrupted after k frames, then run again
    k = 4
    part = tmp_path / "part"
    job = EstimateJob(EstimateSettings(input=moving_clip, output=part, weights=weights, hfov_deg=60.0))
    for _ in range(k):
        assert job.step()
    job.cancel()
    assert meta(part)["frame_count"] == k
    stamps = {i: frame_path(part, i).stat().st_mtime_ns for i in range(k)}
    resumed = run(moving_clip, part, weights=weights, hfov_deg=60.0)
    assert (resumed.computed, resumed.reused) == (N_MOVING - k, k)
    assert stamps == {i: frame_path(part, i).stat().st_mtime_ns for i in range(k)}  # not rewritten
    for i, (a, b) in enumerate(zip(frames_d(whole, N_MOVING), frames_d(part, N_MOVING))):
        np.testing.assert_array_equal(a, b, err_msg=f"frame {i}")
    assert meta(part)["depth_cues"]["used"] == used
    # another field of view is another plan: stale
    assert run(moving_clip, part, weights=weights, hfov_deg=70.0).computed == N_MOVING


def test_plan_key_of_one_cue_has_no_fusion_settings():
    assert "fusion" not in DepthPlan("network", ("network",)).key()
    assert "fusion" in DepthPlan("auto", ("people", "network")).key()


def test_plan_key_names_the_parallax_check_only_with_parallax():
    """Caches made before the parallax cue's photometric check (2026-12-07) recompute; a still
    camera's cache (people + network) is not invalidated by it."""
    assert "parallax_check" in DepthPlan("auto", ("parallax", "network")).key()
    assert "parallax_check" not in DepthPlan("auto", ("people", "network")).key()


def test_a_reused_auto_run_reads_each_frame_once_and_decodes_none(still_clip, tmp_path, weights, fake_people,
                                                                   monkeypatch):
    """Editors re-run often: with every frame of the cache intact, an auto run checks each
    frame file once (not once in the up-front check and again when counting it), by its header
    alone (its pixels are read by whoever uses them), and neither decodes the clip nor runs a cue."""
    from collections import Counter

    import rvr_addon.estimate.cache as cache_mod
    import rvr_addon.io.video as video

    cache = tmp_path / "cache"
    run(still_clip, cache, weights=weights)
    reads: Counter = Counter()
    headers: Counter = Counter()
    real, real_header = cache_mod.read_exr, cache_mod.read_exr_header

    def counting(path):
        reads[path.name] += 1
        return real(path)

    def counting_headers(path):
        headers[path.name] += 1
        return real_header(path)

    def no_decode(*a, **k):
        raise AssertionError("a fully cached run decoded the clip")
        yield  # pragma: no cover

    monkeypatch.setattr(cache_mod, "read_exr", counting)
    monkeypatch.setattr(cache_mod, "read_exr_header", counting_headers)
    monkeypatch.setattr(video, "iter_frames", no_decode)
    again = run(still_clip, cache, weights=weights)
    assert (again.computed, again.reused) == (0, 6)
    assert sorted(headers.values()) == [1] * 6 and not reads, (headers, reads)


class FailingPeople(FakePeople):
    """The fake people cue whose model fails on its third frame (as a broken install would)."""

    def __init__(self, hfov_deg=66.0, **kw):
        super().__init__(hfov_deg, **kw)
        self.calls = 0

    def __call__(self, frame):
        self.calls += 1
        if self.calls == 3:
            raise people_mod.PeopleModelError("the fake model broke")
        return super().__call__(frame)


@pytest.mark.parametrize("people", [FakePeople, FailingPeople])
def test_the_cues_run_ahead_on_a_worker_and_give_the_same_depth(monkeypatch, people):
    """With the parallax cue on, the network and the people cue of the next frames run on a worker
    thread (``overlap``): every frame's D, E and cue use are those of running them in turn, a
    people model that fails is switched off for the frames after it with one note, and at most
    AHEAD_FRAMES frames wait with their answers (besides the refine_lag frames the refinement holds)."""
    frames, _ = translating_clip(n=N_MOVING)
    monkeypatch.setattr(people_mod, "PeopleDetector", people)
    plan = DepthPlan("auto", ("parallax", "people", "network"), hfov_deg=60.0, hfov_given=True)
    yielded, ahead = [0], []

    def network(frame):
        ahead.append(len(ahead) - yielded[0])  # earlier frames asked for and not yet handed out
        d = np.full(frame.shape[:2], 1.0 + float(frame.mean()) / 255.0, np.float32)
        return d, np.repeat(d[..., None], 3, 2)

    runs = {}
    for overlap in (False, True):
        stream = system.DepthStream(plan, (frames[0].shape[1], frames[0].shape[0]), network, overlap=overlap)
        out, yielded[0] = [], 0
        ahead.clear()
        for f, d, e, fused in stream.frames(iter(frames)):
            out.append((d, e))
            yielded[0] += 1
        runs[overlap] = (out, stream.usage(), list(stream.notes))
        stream.close()
        # the frame being fused + AHEAD_FRAMES, and the frames the refinement holds back
        lag = plan.fusion.refine_lag
        assert max(ahead) <= (system.AHEAD_FRAMES if overlap else 0) + lag
    (a, used_a, notes_a), (b, used_b, notes_b) = runs[False], runs[True]
    assert len(a) == len(b) == N_MOVING and used_a == used_b and notes_a == notes_b
    for i, ((da, ea), (db, eb)) in enumerate(zip(a, b)):
        np.testing.assert_array_equal(da, db, err_msg=f"frame {i}")
        np.testing.assert_array_equal(ea, eb, err_msg=f"frame {i}")
    if people is FailingPeople:
        assert used_b["people"] == 2 and len(notes_b) == 1 and "the fake model broke" in notes_b[0]
    else:
        assert used_b["people"] == N_MOVING and not notes_b
    assert used_b["parallax"] > 0
