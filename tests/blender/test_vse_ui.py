"""The VSE tool's UI side, headless: registration of every operator/panel/list/preferences,
the Focus Targets panel, the preview geometry and overlay shapes, the preview picture."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import VSE_H, VSE_W
from layout_recorder import LayoutRecorder

bpy = pytest.importorskip("bpy")

NEW_OPERATORS = ("analyze", "add_focus_target", "remove_focus_target", "jump_to_target", "track_targets",
                 "auto_focus")
NEW_TYPES = ("RVR_OT_analyze", "RVR_OT_track_targets", "RVR_OT_auto_focus", "RVR_UL_nfts", "RVR_PT_targets")


def test_register_round_trip_includes_the_vse_tool(addon_package, factory_scene):
    for _ in range(2):
        addon_package.register()
        try:
            assert all(hasattr(bpy.ops.rvr, op) and bpy.ops.rvr.__getattr__(op).poll is not None
                       for op in NEW_OPERATORS)
            assert all(hasattr(bpy.types, t) for t in NEW_TYPES)
            for cls in ("RVR_OT_analyze", "RVR_OT_track_targets", "RVR_OT_auto_focus", "RVR_OT_add_focus_target"):
                assert {"REGISTER", "UNDO"} <= set(getattr(bpy.types, cls).bl_options)
            ops = addon_package.operators
            assert ops.prefs.RVR_AP_preferences.is_registered and ops.props.RVR_PG_nft.is_registered
            assert ops.prefs.RVR_AP_preferences.bl_idname == "rvr_laaf"
            assert "nfts" in bpy.types.Strip.bl_rna.properties["rvr"].fixed_type.bl_rna.properties
            assert addon_package.panels.overlay._handle is None  # no draw handler in background mode
        finally:
            addon_package.unregister()
        assert not any(hasattr(bpy.types, t) for t in NEW_TYPES)
        assert not addon_package.operators.props.RVR_PG_nft.is_registered


def test_panels_draw(registered, movie_strip):
    bpy.ops.rvr.add_focus_target(x=20, y=20, frame=11)
    rec = LayoutRecorder()
    bpy.types.RVR_PT_focus.draw(type("P", (), {"layout": rec})(), bpy.context)
    names = {c[1] for c in rec.calls}
    assert {"rvr.analyze", "rvr.render_strip", "preview_mode", "render_format", "render_size"} <= names
    rec = LayoutRecorder()
    assert bpy.types.RVR_PT_targets.poll(bpy.context)
    bpy.types.RVR_PT_targets.draw(type("P", (), {"layout": rec})(), bpy.context)
    names = {c[1] for c in rec.calls}
    assert {"RVR_UL_nfts", "rvr.add_focus_target", "rvr.track_targets", "rvr.auto_focus", "pull_frames",
            "lead_frames", "pull_profile", "autofocus_preset", "focus_calm", "lookahead_s", "box", "keep"} <= names
    fps = movie_strip.fps  # the strip's defaults are durations, shown in frames of its clip
    assert ("label", f"Automatic at {fps:g} fps: pull {round(0.4 * fps)}, lead {round(0.2 * fps)}, hold "
                     f"{round(0.48 * fps)} frames") in rec.calls
    movie_strip.rvr.pull_frames, movie_strip.rvr.lead_frames, movie_strip.rvr.hold_frames = 8, 2, 0
    rec = LayoutRecorder()
    bpy.types.RVR_PT_targets.draw(type("P", (), {"layout": rec})(), bpy.context)
    assert not [c for c in rec.calls if c[0] == "label" and c[1].startswith("Automatic")]
    rec = LayoutRecorder()
    item = movie_strip.rvr.nfts[0]
    bpy.types.RVR_UL_nfts.draw_item(None, bpy.context, rec, movie_strip.rvr, item, 0, None, "", 0)
    assert ("label", "not tracked") in rec.calls


@pytest.mark.parametrize("rotation", [0.0, 0.3])
def test_preview_geometry_round_trip(registered, rotation):
    preview = registered.operators.preview
    p = preview.Placement(64, 36, scale_x=2.0, scale_y=1.5, offset_x=10, offset_y=-4, rotation=rotation)
    for x, y in [(0, 0), (64, 36), (10.5, 30.25)]:
        vx, vy = preview.clip_to_view(p, x, y)
        assert preview.view_to_clip(p, vx, vy) == pytest.approx((x, y), abs=1e-9)
    if rotation == 0.0:  # centred, y up, scaled, offset
        assert preview.clip_to_view(p, 32, 18) == pytest.approx((10, -4))
        assert preview.clip_to_view(p, 0, 0) == pytest.approx((-64 + 10, 27 - 4))
    else:  # the picture's centre stays at the offset when rotating about the centre
        assert preview.clip_to_view(p, 32, 18) == pytest.approx((10, -4))
        vx, vy = preview.clip_to_view(p, 64, 18)
        assert math.atan2(vy + 4, vx - 10) == pytest.approx(rotation)


def test_overlay_shapes_follow_the_tracked_box(registered, movie_strip):
    overlay = registered.panels.overlay
    scene = bpy.context.scene
    strip = movie_strip
    bpy.ops.rvr.add_focus_target(x=11, y=17, w=14, h=14, frame=11)
    nft = strip.rvr.nfts[0]
    entry = nft.track.add()
    entry.frame, entry.box, entry.ok = 2, (10, 10, 14, 14), True
    scene.frame_set(13)  # clip frame 2
    shapes = overlay.overlay_shapes(scene, strip)
    (corners, color), = shapes["boxes"]
    assert corners[0] == pytest.approx((10 - VSE_W / 2, VSE_H / 2 - 10))
    assert shapes["focus"] == pytest.approx((17 - VSE_W / 2, VSE_H / 2 - 17))
    assert shapes["picture_rect"] == pytest.approx((-VSE_W / 2, -VSE_H / 2, VSE_W / 2, VSE_H / 2))
    scene.frame_set(18)  # clip frame 7: no box known there
    assert overlay.overlay_shapes(scene, strip)["boxes"] == []
    strip.rvr.show_targets = False
    scene.frame_set(13)
    assert overlay.overlay_shapes(scene, strip)["boxes"] == []


def test_preview_picture_refocus_and_disparity(registered, movie_strip, vse_depth, no_shipped_weights, use_prefs):
    preview = registered.operators.preview
    scene = bpy.context.scene
    strip = movie_strip
    assert preview.preview_picture(scene, strip, "REFOCUS") is None  # not analysed yet
    use_prefs()
    strip.rvr.depth_path = str(vse_depth)
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    scene.frame_set(12)
    sharp = preview.preview_picture(scene, strip, "REFOCUS")
    assert sharp.shape == (VSE_H, VSE_W, 4) and sharp.dtype == np.float32
    strip.rvr.focus_disparity = 12.0
    strip.rvr.aperture = 2.0
    blurred = preview.preview_picture(scene, strip, "REFOCUS")
    assert not np.allclose(sharp, blurred)
    disp = preview.preview_picture(scene, strip, "DISPARITY")
    # rows are bottom-up: the left column (near, warm) is redder than the right (far, cool)
    assert disp[VSE_H // 2, 0, 0] > disp[VSE_H // 2, -1, 0]
    scene.frame_set(1)  # before the strip
    assert preview.preview_picture(scene, strip, "REFOCUS") is None


def test_preferences_weights(registered, tmp_path, no_shipped_weights):
    prefs = registered.operators.prefs
    defaults = prefs.get()
    assert (defaults.cache_dir, defaults.threads, defaults.weights_path) == ("//rvr_cache/", 0, "")
    with pytest.raises(registered.rvr_addon.errors.InputError, match="Estimator Weights"):
        prefs.weights_file(defaults)
    with pytest.raises(registered.rvr_addon.errors.InputError, match="nope.pt"):
        prefs.weights_file(prefs.Defaults(weights_path=str(tmp_path / "nope.pt")))
    (tmp_path / "w.pt").write_bytes(b"x")
    assert prefs.weights_file(prefs.Defaults(weights_path=str(tmp_path / "w.pt"))) == tmp_path / "w.pt"
