"""Focus targets on a strip: Add Focus Target (headless x, y, w, h), the list operators, Track,
Auto Focus (kept targets and hand keys survive), keys at the strip's scene frames, and the
render reading the evaluated F-curves."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import VSE_N

bpy = pytest.importorskip("bpy")

START = 11  # movie_strip's frame_start


@pytest.fixture
def analysed(movie_strip, vse_depth, no_shipped_weights, use_prefs):
    use_prefs()
    movie_strip.rvr.depth_path = str(vse_depth)
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    return movie_strip


def _fc(strip, prop="focus_disparity"):
    from rvr_laaf.operators import fcurves

    return fcurves.find_fcurve(strip, prop)


def _keys(fc):
    return [(round(k.co[0], 3), round(k.co[1], 3), k.type) for k in fc.keyframe_points]


def test_add_target_headless_and_list_ops(registered, movie_strip):
    scene = bpy.context.scene
    scene.frame_set(START + 4)
    assert bpy.ops.rvr.add_focus_target(x=11, y=17, w=14, h=14) == {"FINISHED"}
    nft = movie_strip.rvr.nfts[0]
    assert (nft.frame, nft.source, nft.keep) == (4, "manual", True)
    assert tuple(nft.box) == pytest.approx((4, 10, 14, 14))
    # a point only: a default box around it; another frame, inserted in frame order
    assert bpy.ops.rvr.add_focus_target(x=40, y=20, frame=START + 1) == {"FINISHED"}
    assert [n.frame for n in movie_strip.rvr.nfts] == [1, 4]
    assert movie_strip.rvr.nfts[0].box[2] > 0
    # the same frame again replaces the target there
    assert bpy.ops.rvr.add_focus_target(x=42, y=20, frame=START + 1) == {"FINISHED"}
    assert len(movie_strip.rvr.nfts) == 2 and movie_strip.rvr.nfts[0].x == 42
    # outside the strip / outside the picture: clear errors, nothing added
    with pytest.raises(RuntimeError, match="does not show a clip frame"):
        bpy.ops.rvr.add_focus_target(x=5, y=5, frame=START - 3)
    with pytest.raises(RuntimeError, match="outside"):
        bpy.ops.rvr.add_focus_target(x=500, y=500, w=10, h=10)
    assert len(movie_strip.rvr.nfts) == 2
    # jump and delete
    assert bpy.ops.rvr.jump_to_target(index=1) == {"FINISHED"}
    assert scene.frame_current == START + 4 and movie_strip.rvr.nft_index == 1
    assert bpy.ops.rvr.remove_focus_target(index=0) == {"FINISHED"}
    assert [n.frame for n in movie_strip.rvr.nfts] == [4]
    # editing a target by hand marks it kept
    nft = movie_strip.rvr.nfts[0]
    nft.keep = False
    nft.box = (5, 10, 14, 14)
    assert nft.keep


def test_track_writes_boxes_and_generated_keys(registered, analysed):
    strip = analysed
    scene = bpy.context.scene
    # the bright square is near (disparity -2); the background at x=50 is far (~9.5)
    assert bpy.ops.rvr.add_focus_target(x=50, y=28, w=8, h=8, frame=START) == {"FINISHED"}
    assert bpy.ops.rvr.add_focus_target(x=11 + 3 * 8, y=17, w=14, h=14, frame=START + 8) == {"FINISHED"}
    assert bpy.ops.rvr.track_targets("EXEC_DEFAULT") == {"FINISHED"}
    first, second = strip.rvr.nfts
    assert first.tracked_start == 0 and first.tracked_end >= 1
    assert second.tracked_start <= 8 <= second.tracked_end and len(second.track) >= 2
    fc = _fc(strip)
    keys = _keys(fc)
    assert keys and all(t == "GENERATED" for _, _, t in keys)
    assert all(START <= f < START + VSE_N for f, _, _ in keys)  # scene frames of the strip
    # the focus starts far and lands on the square (-2) before frame 8 (lead 5 frames)
    assert fc.evaluate(START) > 5.0
    assert fc.evaluate(START + 8) == pytest.approx(-2.0, abs=0.3)
    assert json.loads(strip.rvr.auto_keys)["focus_disparity"]
    # the animation system drives the property the render samples
    scene.frame_set(START + 8)
    assert strip.rvr.focus_disparity == pytest.approx(fc.evaluate(START + 8), abs=1e-4)


def test_autofocus_keeps_manual_targets_and_hand_keys(registered, analysed):
    strip = analysed
    assert bpy.ops.rvr.add_focus_target(x=50, y=28, w=8, h=8, frame=START + 6) == {"FINISHED"}
    # a key the editor sets by hand, before any automatic one
    from rvr_laaf.operators import fcurves

    fc = fcurves.write_keyframes(strip, "focus_disparity", [(START + 2, 7.5)], interpolation="BEZIER")
    assert bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset="salient", lookahead_s=0.5) == {"FINISHED"}
    frames = {n.frame: (n.source, n.keep) for n in strip.rvr.nfts}
    assert frames[6] == ("manual", True)  # the manual target survived
    fc = _fc(strip)
    keys = _keys(fc)
    assert (START + 2, 7.5, "KEYFRAME") in keys  # the hand key survived, untouched
    assert any(t == "GENERATED" for _, _, t in keys)
    assert fc.keyframe_points[[k[0] for k in keys].index(START + 2)].interpolation == "BEZIER"
    # an automatic target is replaced by the next run, a manual one never
    auto_before = sorted(f for f, (_, keep) in frames.items() if not keep)
    assert auto_before, frames  # the preset proposed at least the initial focus
    assert bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset="salient", lookahead_s=0.5) == {"FINISHED"}
    after = {n.frame: (n.source, n.keep) for n in strip.rvr.nfts}
    assert after[6] == ("manual", True)
    assert sorted(f for f, (_, keep) in after.items() if not keep) == auto_before  # replaced, not duplicated
    # a generated key the editor moved is theirs from then on
    fc = _fc(strip)
    gen = [k for k in fc.keyframe_points if k.type == "GENERATED" and k.co[0] != START + 2][-1]
    gen.co[1] += 1.25
    moved = (round(gen.co[0], 3), round(gen.co[1], 3))
    fc.update()
    assert bpy.ops.rvr.track_targets("EXEC_DEFAULT") == {"FINISHED"}
    assert moved in [(f, v) for f, v, _ in _keys(_fc(strip))]


def test_track_needs_disparity_and_targets(registered, movie_strip, use_prefs):
    use_prefs()
    assert not bpy.ops.rvr.track_targets.poll()  # no targets
    assert bpy.ops.rvr.add_focus_target(x=20, y=20, frame=START) == {"FINISHED"}
    with pytest.raises(RuntimeError, match="Analyze"):
        bpy.ops.rvr.track_targets("EXEC_DEFAULT")
    assert _fc(movie_strip) is None


def test_render_reads_hand_edited_fcurves(registered, analysed, tmp_path):
    """After Track, a hand edit of the focus curve changes the render."""
    import cv2

    strip = analysed
    from rvr_laaf.operators import fcurves

    fcurves.write_keyframes(strip, "focus_disparity", [(START, 12.0)], interpolation="LINEAR")
    strip.rvr.render_size = "1.0"
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    out = tmp_path / "renders" / "Clip.mp4"
    far = _frame(out, 0)
    fcurves.write_keyframes(strip, "focus_disparity", [(START, 0.0)], interpolation="LINEAR")
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    near = _frame(out, 0)
    source = _frame(bpy.path.abspath(strip.filepath), 0)
    right, left = (slice(26, 36), slice(54, 64)), (slice(26, 36), slice(0, 10))

    def off(img, region):  # how far the render is from the clip there (in focus: close)
        return float(np.abs(img[region].astype(np.float32) - source[region].astype(np.float32)).mean())

    # (a Laplacian sharpness compared the two blurred versions of the right's flat texture and
    # flipped with the half-resolution blur of large radii; the distance to the clip does not)
    assert off(far, right) < off(near, right) and off(near, left) < off(far, left)
    result = bpy.context.scene.sequence_editor.strips_all["Clip [RVR]"]
    assert result.channel == strip.channel + 1 and result.frame_final_duration == VSE_N


def _frame(path, index):
    import cv2

    cap = cv2.VideoCapture(str(path))
    for _ in range(index + 1):
        ok, frame = cap.read()
    cap.release()
    assert ok
    return frame


def test_trimmed_strip_analyse_track_render_images(registered, analysed, tmp_path):
    """A cut strip: Analyze covers only the shown frames; Track keys and the image-sequence proxy
    render follow the strip's offsets (frame mapping), and the result spans the cut."""
    strip = analysed
    strip.frame_offset_start = 3
    strip.frame_offset_end = 2
    strip.rvr.cache_path = ""  # analyse the cut again (a partial cache: clip frames 3..9)
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    meta = json.loads((tmp_path / strip.rvr.cache_path[2:] / "meta.json").read_text())
    assert meta["frame_range"] == [0, VSE_N]  # the earlier full analysis is still valid and kept
    assert bpy.ops.rvr.add_focus_target(x=50, y=28, w=8, h=8, frame=START + 4) == {"FINISHED"}
    assert strip.rvr.nfts[0].frame == 4
    with pytest.raises(RuntimeError, match="does not show"):
        bpy.ops.rvr.add_focus_target(x=50, y=28, frame=START + 1)  # cut away
    assert bpy.ops.rvr.track_targets("EXEC_DEFAULT") == {"FINISHED"}
    frames = [k.co[0] for k in _fc(strip).keyframe_points]
    assert min(frames) >= START + 3 and max(frames) <= START + VSE_N - 3
    strip.rvr.render_format = "IMAGES"
    strip.rvr.render_size = "0.5"
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    result = bpy.context.scene.sequence_editor.strips_all["Clip [RVR]"]
    assert result.type == "IMAGE" and len(result.elements) == VSE_N - 5
    assert (result.frame_final_start, result.frame_final_end) == (START + 3, START + VSE_N - 2)
    files = sorted((tmp_path / "renders" / "Clip").iterdir())
    import cv2

    assert len(files) == VSE_N - 5 and cv2.imread(str(files[0])).shape == (18, 32, 3)


def test_partial_cache_render_after_cut(registered, movie_strip, vse_depth, no_shipped_weights, use_prefs, tmp_path):
    """Only the shown frames are analysed (clip frames 3..9); the render reads them by frame number."""
    use_prefs()
    strip = movie_strip
    strip.rvr.depth_path = str(vse_depth)
    strip.frame_offset_start = 3
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    strip.rvr.depth_path = ""  # the render must use the cache
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    assert bpy.context.scene.sequence_editor.strips_all["Clip [RVR]"].frame_final_duration == VSE_N - 3


def test_learned_preset_with_missing_weights_names_them_and_changes_nothing(registered, analysed, use_prefs,
                                                                             tmp_path):
    """Auto Focus > Learned (AF-Net) with a weights path that does not exist: a clear error, and the
    strip keeps its targets and keys."""
    strip = analysed
    use_prefs(afnet_weights_path=str(tmp_path / "nowhere" / "afnet.pt"))
    assert bpy.ops.rvr.add_focus_target(x=50, y=28, w=8, h=8, frame=START + 6) == {"FINISHED"}
    before = [(n.frame, n.source, n.keep) for n in strip.rvr.nfts]
    with pytest.raises(RuntimeError, match="AF-Net weights"):
        bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset="learned", lookahead_s=0.5)
    assert [(n.frame, n.source, n.keep) for n in strip.rvr.nfts] == before
    assert _fc(strip) is None


@pytest.mark.parametrize("region, speaker", [("SPEAKER", True), ("MAP", False)])
def test_learned_focus_region_preference_reaches_the_engine(registered, analysed, use_prefs, region, speaker):
    """Preferences > Learned Focus Region: the speaker where a voice starts (default) or AF-Net's map."""
    import importlib

    from conftest import PACKAGE

    ops_focus = importlib.import_module(f"{PACKAGE}.operators.ops_focus")
    use_prefs(afnet_region=region)
    plan = ops_focus.plan_focus(bpy.context.scene, analysed, "learned", 0.5)
    assert plan.settings.preset == "learned" and plan.settings.afnet_speaker is speaker


def test_auto_focus_learned_with_the_shipped_weights(registered, analysed, use_prefs):
    """Auto Focus > Learned (AF-Net, the shipped weights; the 12-frame clip is shorter than its
    receptive field and is padded): keys are written and every target names its source."""
    strip = analysed
    use_prefs()
    assert bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset="learned", lookahead_s=0.5) == {"FINISHED"}
    assert _fc(strip) is not None and len(_fc(strip).keyframe_points) >= 2
    assert strip.rvr.nfts and {n.source for n in strip.rvr.nfts} <= {"afnet", "afnet_speech", "face", "saliency",
                                                                       "initial"}


def test_calm_knob_and_auto_preset_reach_the_engine(registered, analysed):
    """Issue 23: the strip's Calm (default the engine's) and the Auto preset (the default) go to AutofocusSettings."""
    import importlib

    from conftest import PACKAGE

    ops_focus = importlib.import_module(f"{PACKAGE}.operators.ops_focus")
    presets = importlib.import_module(f"{PACKAGE}.rvr_addon.laaf.presets")
    assert analysed.rvr.autofocus_preset == presets.DEFAULT_PRESET == "auto"
    assert analysed.rvr.focus_calm == pytest.approx(presets.DEFAULT_CALM)
    analysed.rvr.focus_calm = 0.9
    plan = ops_focus.plan_focus(bpy.context.scene, analysed, analysed.rvr.autofocus_preset, 0.5)
    assert plan.settings.preset == "auto" and plan.settings.calm == pytest.approx(0.9)
