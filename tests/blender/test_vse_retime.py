"""Retimed strips (retiming keys, strobe, a movie playing at its own rate): the scene -> clip
frame mapping is Blender's own, Analyze / Auto Focus work in clip frames and key the scene
frames showing them, and a render has one frame per scene frame, each the refocus of the clip
frame shown there. Refused with the fix named: reversed playback, speed transitions, Speed
Control effects, retiming data this Blender stores in an unknown way."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import VSE_FPS, VSE_N, image_folder, retime

bpy = pytest.importorskip("bpy")
cv2 = pytest.importorskip("cv2")

START = 11


@pytest.fixture
def image_strip(registered, factory_scene, tmp_path):
    """VSE_N noise PNGs as image strip 'Images' at START (channel 2), active."""
    folder = image_folder(tmp_path / "frames", VSE_N)
    editor = factory_scene.sequence_editor_create()
    strip = editor.strips.new_image("Images", str(folder / "f_0000.png"), channel=2, frame_start=START)
    for i in range(1, VSE_N):
        strip.elements.append(f"f_{i:04d}.png")
    editor.active_strip = strip
    return strip


def _source(strip):
    from rvr_laaf.operators.source import resolve_source

    return resolve_source(strip.id_data, strip)


def _blender_frames(strip, source) -> list[int]:
    """Blender's own clip frame at each shown scene frame: the image element it shows there."""
    return [int(strip.strip_elem_from_frame(f).filename[2:6]) for f in source.scene_frames]


@pytest.mark.parametrize("percent, trim, strobe", [(200, 0, 1.0), (50, 0, 1.0), (150, 2, 1.0), (50, 3, 3.0),
                                                    (100, 0, 2.0)])
def test_mapping_is_blenders(image_strip, percent, trim, strobe):
    strip = image_strip
    retime(strip, percent)
    strip.frame_offset_start = trim
    strip.strobe = strobe
    source = _source(strip)
    assert list(source.clip_frames) == _blender_frames(strip, source)
    assert source.retimed and source.span.scene_start == START + trim
    assert source.span.clip_start == source.clip_frames[0] and source.span.clip_stop == source.clip_frames[-1] + 1
    assert source.scene_to_clip(START + trim - 1) is None and source.scene_to_clip(source.span.scene_stop) is None
    if (percent, trim, strobe) == (200, 0, 1.0):  # 2x: every other clip frame (4.5 rounds to the last frame)
        assert list(source.clip_frames[:4]) == [0, 2, 4, 6] and source.clip_frames[-1] >= VSE_N - 2
        assert source.clip_to_scene(3) == START + 2  # never shown: where clip frame 4 is
    if (percent, trim, strobe) == (50, 0, 1.0):  # 0.5x: each clip frame on two scene frames
        assert list(source.clip_frames[:7]) == [0, 1, 1, 2, 2, 3, 3]
        assert source.clip_to_scene(2) == START + 3


def test_mapping_follows_several_keys(image_strip):
    strip = image_strip
    scene = strip.id_data
    retime(strip, 200)
    with bpy.context.temp_override(scene=scene):
        assert bpy.ops.sequencer.retiming_key_add(timeline_frame=START + 3) == {"FINISHED"}
    retime(strip, 50, frame=START + 4)  # 2x, then 0.5x from scene frame START + 3
    source = _source(strip)
    assert list(source.clip_frames) == _blender_frames(strip, source)
    assert source.speed_changes == (START + 3,)
    assert list(source.clip_frames[:3]) == [0, 2, 4] and len(set(source.clip_frames[3:])) < len(source.clip_frames[3:])


@pytest.mark.parametrize("percent", [200, 50])
def test_movie_strip_maps_like_an_image_strip(image_strip, vse_clip, percent):
    """A movie of VSE_N frames retimed like an image strip of VSE_N frames shows the same clip frames."""
    editor = image_strip.id_data.sequence_editor
    movie = editor.strips.new_movie("Clip", str(vse_clip), channel=3, frame_start=START)
    retime(image_strip, percent)
    retime(movie, percent)
    assert _source(movie).clip_frames == _source(image_strip).clip_frames


def test_content_frames_rate_and_strobe(registered):
    """A movie at 24 fps playing at its own rate in a 30 fps scene shows clip frame round(0.8 t)."""
    source = registered.operators.source
    timing = source.Retiming(rate=0.8, length=100)
    assert source.content_frames(np.arange(10), timing).tolist() == [0, 1, 2, 2, 3, 4, 5, 6, 6, 7]
    assert source.content_frames(np.arange(5), source.Retiming(strobe=2.0, length=5)).tolist() == [0, 0, 2, 2, 4]
    assert source.content_frames(np.arange(3), source.Retiming()).tolist() == [0, 1, 2]
    shown = np.array([0, 2, 4, 6])
    assert [source.first_showing(shown, k) for k in (0, 1, 2, 7)] == [0, 1, 1, 3]


def test_playback_rate_of_a_movie_at_its_own_frame_rate(registered):
    """A 24 fps movie of 12 frames in a 30 fps scene: plays at its own rate (0.8 clip frames per
    scene frame) when Blender gave it 15 scene frames or keys it so, else 1:1. Blender's add
    operator sets that up ("Adjust Playback Rate"), which cannot run headless, hence the stubs."""
    from types import SimpleNamespace as NS

    source = registered.operators.source
    scene = NS(render=NS(fps=30, fps_base=1.0))

    def movie(duration):
        return NS(type="MOVIE", fps=24.0, frame_start=11, frame_duration=duration)

    assert source._playback_rate(scene, movie(15), [], lambda: 12) == pytest.approx(0.8)
    assert source._playback_rate(scene, movie(12), [], lambda: 12) == 1.0
    key = registered.operators.compat.RetimingKey
    keys = [key(11, 0.0, 0.0, 0), key(11 + 15, 12.0, 1.0, 0)]  # index 12 at 15 scene frames
    assert source._playback_rate(scene, movie(15), keys, lambda: 12) == pytest.approx(0.8)
    assert source._playback_rate(scene, movie(12), [key(11, 0.0, 0.0, 0), key(23, 12.0, 1.0, 0)],
                                 lambda: 12) == 1.0


def test_refused_time_mappings_name_the_fix(registered, image_strip, monkeypatch):
    errors, compat = registered.rvr_addon.errors, registered.operators.compat
    strip = image_strip
    strip.use_reverse_frames = True
    with pytest.raises(errors.InputError, match="plays reversed.*Reverse Frames"):
        _source(strip)
    strip.use_reverse_frames = False
    editor = strip.id_data.sequence_editor
    speed = editor.strips.new_effect("Speed", "SPEED", channel=3, frame_start=START, input1=strip)
    with pytest.raises(errors.InputError, match="Speed Control strip 'Speed'.*Retiming"):
        _source(strip)
    editor.strips.remove(speed)
    retime(strip, 200)
    real = compat.retiming_keys(strip)
    assert [k.factor for k in real] == [0.0, 1.0] and real[0].index == 0.0
    monkeypatch.setattr(compat, "retiming_keys", lambda s: [real[0]._replace(flags=1), real[1]])
    with pytest.raises(errors.InputError, match="gradual speed transition"):
        _source(strip)
    monkeypatch.setattr(compat, "retiming_keys", lambda s: None)
    with pytest.raises(errors.InputError, match="Retiming > Reset"):
        _source(strip)


@pytest.fixture
def retimed_movie(movie_strip, vse_depth, no_shipped_weights, use_prefs):
    """movie_strip with Disparity maps, not yet analysed (the caller retimes it)."""
    use_prefs()
    movie_strip.rvr.depth_path = str(vse_depth)
    return movie_strip


@pytest.mark.parametrize("percent", [200, 50])
def test_analyze_and_autofocus_on_retimed_strip(registered, retimed_movie, tmp_path, monkeypatch, percent):
    strip = retimed_movie
    retime(strip, percent)
    source = _source(strip)
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    meta = json.loads((tmp_path / strip.rvr.cache_path[2:] / "meta.json").read_text())
    assert meta["frame_range"][0] <= source.span.clip_start and meta["frame_range"][1] >= source.span.clip_stop
    # a target added at a scene frame lands on the clip frame shown there
    frame = START + 3
    assert bpy.ops.rvr.add_focus_target(x=50, y=28, w=8, h=8, frame=frame) == {"FINISHED"}
    assert strip.rvr.nfts[0].frame == source.scene_to_clip(frame)
    ops_focus = registered.operators.ops_focus
    seen = []
    real_apply = ops_focus.apply_focus_result
    monkeypatch.setattr(ops_focus, "apply_focus_result", lambda plan, result: seen.append(result)
                        or real_apply(plan, result))
    assert bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset="salient", lookahead_s=0.5) == {"FINISHED"}
    (result,) = seen
    clip_keys = np.array([k.frame + result.start for k in result.keys], float)
    focus = np.array([k.focus for k in result.keys], float)
    assert (result.start, result.start + len(result.focus)) == (source.span.clip_start, source.span.clip_stop)
    fc = registered.operators.fcurves.find_fcurve(strip, "focus_disparity")
    keys = {k.co[0]: k.co[1] for k in fc.keyframe_points if k.type == "GENERATED"}
    shown = np.array(source.clip_frames)
    for k in clip_keys:  # each engine key is keyed where its clip frame (or the next one shown) shows first
        scene_frame = START + int(np.searchsorted(shown, k))
        assert scene_frame in keys, (k, sorted(keys))
    for scene_frame, value in keys.items():  # whole scene frames of the span, valued at the clip frame shown
        assert scene_frame == int(scene_frame) and source.scene_to_clip(scene_frame) is not None
        assert value == pytest.approx(np.interp(source.scene_to_clip(scene_frame), clip_keys, focus), abs=1e-3)


def _direct_render(registered, clip, depth, clip_frame, focus, aperture, out):
    """The engine rendering one clip frame with a constant focus (PNG, exact)."""
    pipeline = registered.rvr_addon.pipeline
    settings = pipeline.RenderSettings(input=clip, depth=depth, outputs=[out], focus=focus, aperture=aperture,
                                       start=clip_frame, stop=clip_frame + 1)
    pipeline.RenderJob(settings).run(progress=False)
    (png,) = sorted(out.iterdir())
    return cv2.imread(str(png))


@pytest.mark.parametrize("percent", [200, 50])
def test_render_frame_n_is_the_clip_frame_shown_at_scene_frame_n(registered, retimed_movie, vse_clip, vse_depth,
                                                                 tmp_path, percent):
    strip = retimed_movie
    retime(strip, percent)
    source = _source(strip)
    fcurves = registered.operators.fcurves
    last = source.span.scene_stop - 1
    fcurves.write_keyframes(strip, "focus_disparity", [(START, 12.0), (last, -2.0)], interpolation="LINEAR")
    strip.rvr.aperture = 1.5
    strip.rvr.render_format = "IMAGES"
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    result = strip.id_data.sequence_editor.strips_all["Clip [RVR]"]
    assert (result.frame_final_start, result.frame_final_end) == (strip.frame_final_start, strip.frame_final_end)
    assert len(result.elements) == source.span.count  # one frame per scene frame, no retiming of its own
    files = sorted((tmp_path / "renders" / "Clip").iterdir())
    assert len(files) == source.span.count
    step = 1 if percent > 100 else 3  # 0.5x: a sample of the 24 frames, repeats included
    for n in list(range(0, source.span.count, step)) + [1]:
        focus = fcurves.find_fcurve(strip, "focus_disparity").evaluate(START + n)
        direct = _direct_render(registered, vse_clip, vse_depth, source.clip_frames[n], focus, 1.5,
                                tmp_path / f"direct_{n}")
        np.testing.assert_array_equal(cv2.imread(str(files[n])), direct, err_msg=f"output frame {n}")


def test_retimed_movie_render_plays_at_scene_rate(registered, retimed_movie, tmp_path, ffmpeg):
    """0.5x in a 25 fps scene (the clip is 24 fps): the MP4 has one frame per scene frame at 25 fps,
    no audio, and its strip lines up with the source."""
    from tests.conftest import stream_kinds

    strip = retimed_movie
    strip.id_data.render.fps = 25
    retime(strip, 50)
    count = _source(strip).span.count
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    result = strip.id_data.sequence_editor.strips_all["Clip [RVR]"]
    assert result.frame_duration == count and result.fps == pytest.approx(25.0) and VSE_FPS != 25
    assert (result.frame_final_start, result.frame_final_end) == (strip.frame_final_start, strip.frame_final_end)
    assert "Audio:" not in stream_kinds(ffmpeg, tmp_path / "renders" / "Clip.mp4")
