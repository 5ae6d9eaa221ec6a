"""rvr.analyze on a movie strip: the cache next to the .blend, reuse, trimmed strips, the modal
run and its cancel, and the bad input of issue 7 (no weights, no strip, sound strip, moved file,
unsaved file)."""
from __future__ import annotations

import json
import shutil

import pytest

from conftest import VSE_N, Event, OperatorStub

bpy = pytest.importorskip("bpy")


def _meta(strip):
    return json.loads((_cache(strip) / "meta.json").read_text())


def _cache(strip):
    from pathlib import Path

    return Path(bpy.path.abspath(strip.rvr.cache_path))


def test_analyze_without_weights_or_maps_names_the_file(movie_strip, no_shipped_weights, use_prefs):
    use_prefs()
    with pytest.raises(RuntimeError, match="estimator.pt") as info:
        bpy.ops.rvr.analyze("EXEC_DEFAULT")
    assert str(no_shipped_weights) in str(info.value) and "Disparity maps" in str(info.value)
    assert movie_strip.rvr.cache_path == ""


def test_analyze_depth_from_maps_then_reuse(movie_strip, vse_depth, no_shipped_weights, use_prefs, saved_blend):
    use_prefs()
    movie_strip.rvr.depth_path = str(vse_depth)
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    assert movie_strip.rvr.cache_path.startswith("//rvr_cache/")  # next to the .blend, relative
    cache = _cache(movie_strip)
    assert cache.parent == saved_blend.parent / "rvr_cache"
    meta = _meta(movie_strip)
    assert meta["frame_count"] == VSE_N and meta["model_hash"] == "none"
    assert meta["stabilized"]["frames"] and not meta["stabilized"]["pending"]
    stamps = {p.name: p.stat().st_mtime_ns for p in cache.glob("frame_*.exr")}
    # again: everything reused, nothing rewritten
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    assert bpy.types.RVR_OT_analyze.execute(op, bpy.context) == {"FINISHED"}
    assert f"reused {VSE_N}" in op.reports[-1][1] and "estimated 0 frames" in op.reports[-1][1]
    assert stamps == {p.name: p.stat().st_mtime_ns for p in cache.glob("frame_*.exr")}


def test_analyze_with_weights_follows_trimmed_strip(movie_strip, vse_weights, use_prefs):
    use_prefs(weights_path=str(vse_weights))
    movie_strip.frame_offset_start = 3
    movie_strip.frame_offset_end = 2
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    meta = _meta(movie_strip)
    assert meta["frame_range"] == [3, VSE_N - 2]  # only the frames the strip shows
    assert meta["model_hash"] != "none"


def test_analyze_modal_cancel_keeps_finished_frames(movie_strip, vse_depth, no_shipped_weights, use_prefs,
                                                    monkeypatch, registered):
    use_prefs()
    movie_strip.rvr.depth_path = str(vse_depth)
    monkeypatch.setattr(registered.operators.jobrun, "STEP_BUDGET_S", 0.0)  # one frame per timer tick
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    op._plan, op._job = op._prepare(bpy.context)
    bpy.context.window_manager.rvr_job_status = "RUNNING"
    modal = bpy.types.RVR_OT_analyze.modal
    assert modal(op, bpy.context, Event("MOUSEMOVE")) == {"PASS_THROUGH"}
    for _ in range(3):
        assert modal(op, bpy.context, Event("TIMER")) == {"PASS_THROUGH"}
    assert 0 < bpy.context.window_manager.rvr_job_progress < 100
    cache = op._plan.cache
    assert modal(op, bpy.context, Event("ESC")) == {"CANCELLED"}
    assert bpy.context.window_manager.rvr_job_status == "IDLE"
    assert "cancelled" in bpy.context.window_manager.rvr_job_text
    assert movie_strip.rvr.cache_path == ""  # nothing recorded on the strip
    meta = json.loads((cache / "meta.json").read_text())
    assert meta["frame_count"] == 3  # the finished frames stay valid
    # the next run continues from there
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    assert bpy.types.RVR_OT_analyze.execute(op, bpy.context) == {"FINISHED"}
    assert "reused 3" in op.reports[-1][1]


def test_analyze_bad_input(registered, factory_scene, vse_clip, vse_depth, tmp_path, use_prefs, no_shipped_weights):
    use_prefs()
    assert not bpy.ops.rvr.analyze.poll()  # no strip
    editor = factory_scene.sequence_editor_create()
    sound = editor.strips.new_sound("Sound", str(vse_clip), channel=1, frame_start=1)
    editor.active_strip = sound
    assert not bpy.ops.rvr.analyze.poll()
    with pytest.raises(RuntimeError, match="not a movie or image strip"):
        bpy.ops.rvr.analyze()
    moved = tmp_path / "moved.mp4"
    shutil.copy(vse_clip, moved)
    strip = editor.strips.new_movie("Moved", str(moved), channel=2, frame_start=1)
    strip.rvr.depth_path = str(vse_depth)
    editor.active_strip = strip
    # never saved: the default cache location (next to the .blend) does not exist yet
    with pytest.raises(RuntimeError, match="never saved"):
        bpy.ops.rvr.analyze("EXEC_DEFAULT")
    use_prefs(cache_dir=str(tmp_path / "cache"))
    moved.unlink()
    with pytest.raises(RuntimeError, match="moved.mp4.*not found"):
        bpy.ops.rvr.analyze("EXEC_DEFAULT")
    assert strip.rvr.cache_path == "" and not (tmp_path / "cache").exists()


def test_analyze_without_torch_names_what_the_weights_need(movie_strip, vse_weights, vse_depth, use_prefs,
                                                          monkeypatch):
    """A trained .pt without an ONNX export needs torch (the shipped weights run from their export:
    test_vse_install)."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "torch" else real(name, *a))
    use_prefs(weights_path=str(vse_weights))
    with pytest.raises(RuntimeError, match=f"{vse_weights.name}' needs torch"):
        bpy.ops.rvr.analyze("EXEC_DEFAULT")
    assert movie_strip.rvr.cache_path == ""
    movie_strip.rvr.depth_path = str(vse_depth)  # with maps: analysed from them, without HDR recovery
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    assert _meta(movie_strip)["model_hash"] == "none"


def _panel_labels():
    from layout_recorder import LayoutRecorder

    rec = LayoutRecorder()
    bpy.types.RVR_PT_focus.draw(type("P", (), {"layout": rec})(), bpy.context)
    return rec


def test_analyze_auto_records_the_cues_and_the_panel_shows_them(movie_strip, vse_weights, use_prefs, registered,
                                                               monkeypatch):
    import importlib.util

    use_prefs(weights_path=str(vse_weights))
    assert movie_strip.rvr.depth_method == "AUTO" and movie_strip.rvr.hfov_deg == 0.0
    assert ("prop", "depth_method") in _panel_labels().calls
    has_mediapipe = importlib.util.find_spec("mediapipe") is not None
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    assert bpy.types.RVR_OT_analyze.execute(op, bpy.context) == {"FINISHED"}
    meta = _meta(movie_strip)
    cues = ["people", "network"] if has_mediapipe else ["network"]  # a still camera, 64x36 px: no parallax
    assert meta["depth_plan"]["method"] == "auto" and meta["depth_plan"]["cues"] == cues
    assert meta["depth_plan"]["reasons"]["parallax"]  # why not
    if has_mediapipe:
        assert meta["depth"]["method"] == "auto" and meta["depth"]["cues"] == cues  # the cache key
        assert meta["depth_cues"]["used"]["frames"] == VSE_N
    line = registered.operators.ops_analyze.depth_line(_cache(movie_strip))
    assert line.startswith("Depth (auto): ") and ("people 0/12" in line if has_mediapipe else "people off" in line)
    assert ("label", line) in _panel_labels().calls  # one line under the cache
    assert "depth: " + " + ".join(cues) in op.reports[-1][1]
    # Network: another key, the cache is recomputed, the line follows
    movie_strip.rvr.depth_method = "NETWORK"
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    assert bpy.types.RVR_OT_analyze.execute(op, bpy.context) == {"FINISHED"}
    assert f"estimated {VSE_N} frames" in op.reports[-1][1] and _meta(movie_strip)["depth"] == "network"
    assert registered.operators.ops_analyze.depth_line(_cache(movie_strip)) == "Depth (network): network"
    # without mediapipe: Auto goes on without the people cue and says so; People is an error naming the fix
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a, **k: None if name.split(".")[0] == "mediapipe" else real(name, *a, **k))
    movie_strip.rvr.depth_method = "AUTO"
    movie_strip.rvr.hfov_deg = 70.0
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    assert bpy.types.RVR_OT_analyze.execute(op, bpy.context) == {"FINISHED"}
    assert "people off" in op.reports[-1][1] and "mediapipe" in op.reports[-1][1]
    assert "people off" in registered.operators.ops_analyze.depth_line(_cache(movie_strip))
    movie_strip.rvr.depth_method = "PEOPLE"
    with pytest.raises(RuntimeError, match="mediapipe.*pip install") as info:
        bpy.ops.rvr.analyze("EXEC_DEFAULT")
    assert "Traceback" not in str(info.value)
    # the maps are the depth: another Depth than Auto is a clear error
    movie_strip.rvr.depth_path = str(movie_strip.rvr.cache_path)
    with pytest.raises(RuntimeError, match="clear the Disparity maps, or set Depth to Auto"):
        bpy.ops.rvr.analyze("EXEC_DEFAULT")


def test_analyze_with_other_maps_then_esc_keeps_the_old_cache_intact(movie_strip, vse_depth, no_shipped_weights,
                                                                     use_prefs, monkeypatch, registered, tmp_path):
    """Issue 22 item 2: new settings build beside the strip's cache; Esc leaves it as it was."""
    import numpy as np

    use_prefs(cache_dir=str(tmp_path / "caches"))
    movie_strip.rvr.depth_path = str(vse_depth)
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    cache, recorded = _cache(movie_strip), movie_strip.rvr.cache_path
    before = (cache / "meta.json").read_text()
    stamps = {p.name: p.stat().st_mtime_ns for p in cache.glob("frame_*.exr")}
    other = tmp_path / "other_maps"
    other.mkdir()
    for p in sorted(vse_depth.glob("*.npy")):
        np.save(other / p.name, np.load(p) * 2.0)
    movie_strip.rvr.depth_path = str(other)
    monkeypatch.setattr(registered.operators.jobrun, "STEP_BUDGET_S", 0.0)  # one frame per timer tick
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    op._plan, op._job = op._prepare(bpy.context)
    bpy.context.window_manager.rvr_job_status = "RUNNING"
    for _ in range(3):
        bpy.types.RVR_OT_analyze.modal(op, bpy.context, Event("TIMER"))
    assert bpy.types.RVR_OT_analyze.modal(op, bpy.context, Event("ESC")) == {"CANCELLED"}
    assert "unchanged" in bpy.context.window_manager.rvr_job_text
    assert movie_strip.rvr.cache_path == recorded
    assert (cache / "meta.json").read_text() == before  # the old cache, complete and stabilized
    assert stamps == {p.name: p.stat().st_mtime_ns for p in cache.glob("frame_*.exr")}
    assert json.loads(before)["stabilized"]["frames"]
    # a complete run with the new maps replaces it (and continues the frames built beside it)
    op = OperatorStub(bpy.types.RVR_OT_analyze)
    assert bpy.types.RVR_OT_analyze.execute(op, bpy.context) == {"FINISHED"}
    assert "reused 3" in op.reports[-1][1]
    meta = _meta(movie_strip)
    assert meta["depth"]["path"] == str(other) and meta["frame_count"] == VSE_N and meta["stabilized"]["frames"]
    assert not list(cache.parent.glob(f".{cache.name}.rebuild-*"))
