"""Registration round trip of the extension, the compat helpers, and a smoke draw of the panel."""
from __future__ import annotations

import pytest

from conftest import color_strip
from layout_recorder import LayoutRecorder

bpy = pytest.importorskip("bpy")

OPERATORS = {"render_strip": "RVR_OT_render_strip", "cancel_job": "RVR_OT_cancel_job",
             "keyframe_toggle": "RVR_OT_keyframe_toggle"}
WM_PROPS = ("rvr_job_status", "rvr_job_text", "rvr_job_progress")


def _registered_state() -> dict:
    return {
        "ops": {name: hasattr(bpy.ops.rvr, name) and hasattr(bpy.types, cls) for name, cls in OPERATORS.items()},
        "panel": hasattr(bpy.types, "RVR_PT_focus"),
        "strip_prop": hasattr(bpy.types.Strip, "rvr"),
        "wm_props": {p: hasattr(bpy.types.WindowManager, p) for p in WM_PROPS},
    }


def _all(state: dict, value: bool) -> bool:
    flat = [state["panel"], state["strip_prop"], *state["ops"].values(), *state["wm_props"].values()]
    return all(v is value for v in flat)


def test_register_round_trip_twice(addon_package, factory_scene):
    assert _all(_registered_state(), False)
    load_handlers = len(bpy.app.handlers.load_post)
    for _ in range(2):
        addon_package.register()
        try:
            assert len(bpy.app.handlers.load_post) == load_handlers + 1
            assert addon_package._cli_handle is not None
            state = _registered_state()
            assert _all(state, True), state
            panel = bpy.types.RVR_PT_focus
            assert panel.bl_space_type == "SEQUENCE_EDITOR"
            assert panel.bl_region_type == "UI"
            assert panel.bl_category == "Refocus"
            assert bpy.types.RVR_OT_render_strip.bl_idname == "rvr.render_strip"
            assert {"REGISTER", "UNDO"} <= set(bpy.types.RVR_OT_render_strip.bl_options)
            wm = bpy.context.window_manager
            assert wm.rvr_job_status == "IDLE" and wm.rvr_job_progress == 0.0
        finally:
            addon_package.unregister()
        assert _all(_registered_state(), False), _registered_state()
        assert len(bpy.app.handlers.load_post) == load_handlers and addon_package._cli_handle is None


def test_strip_properties_defaults(registered, factory_scene, tmp_path):
    editor = factory_scene.sequence_editor_create()
    strip = color_strip(editor.strips, "Color", 1, 1, 5)
    rvr = strip.rvr
    assert rvr.aperture == 1.0 and rvr.aperture_shape == "DISK" and rvr.output_dir == "//rvr_renders/"
    props = type(rvr).bl_rna.properties
    assert props["focus_disparity"].is_animatable and props["aperture"].is_animatable
    assert props["aperture"].hard_min == 0.0
    assert props["depth_path"].subtype == "FILE_PATH" and props["output_dir"].subtype == "DIR_PATH"
    assert [i.identifier for i in props["aperture_shape"].enum_items] == ["DISK", "POLYGON", "ANAMORPHIC"]
    from rvr_addon.laaf.nft import SOURCES

    item = rvr.nfts.add()
    sources = [i.identifier for i in type(item).bl_rna.properties["source"].enum_items]
    assert sources == list(SOURCES)  # every source the engine writes can be kept on a strip


def test_poll_explains_itself(registered, factory_scene):
    assert not bpy.ops.rvr.render_strip.poll()
    assert not bpy.ops.rvr.cancel_job.poll()
    editor = factory_scene.sequence_editor_create()
    editor.active_strip = color_strip(editor.strips, "Color", 1, 1, 5)
    assert not bpy.ops.rvr.render_strip.poll()  # not a movie/image strip
    with pytest.raises(RuntimeError, match="not a movie or image strip"):
        bpy.ops.rvr.render_strip()


def test_compat_helpers(registered, factory_scene):
    compat = registered.operators.compat
    assert compat.strips_all(factory_scene) == []
    editor = factory_scene.sequence_editor_create()
    a = color_strip(editor.strips, "A", 1, 1, 5)
    meta = editor.strips.new_meta("Meta", channel=3, frame_start=1)
    b = color_strip(meta.strips, "B", 1, 1, 5)
    assert {s.name for s in compat.strips_all(factory_scene)} == {"A", "Meta", "B"}
    assert compat.strip_type(a) == "COLOR"
    assert compat.strip_container(factory_scene, b) == meta.strips
    assert compat.strip_container(factory_scene, a) == editor.strips
    editor.active_strip = a
    assert compat.active_strip(bpy.context) == a
    workspace = bpy.context.workspace
    if hasattr(workspace, "sequencer_scene"):  # 5.0: the Sequencer edits the workspace's scene
        workspace.sequencer_scene = bpy.data.scenes.new("Edit")
        assert compat.sequencer_scene(bpy.context).name == "Edit" and compat.active_strip(bpy.context) is None
        workspace.sequencer_scene = None
    assert compat.sequencer_scene(bpy.context) == factory_scene
    # a property group on a strip: path built from the strip (5.0 cannot make it directly)
    path = compat.prop_data_path(editor.strips_all["A"].rvr, "aperture")
    assert path == 'sequence_editor.strips_all["A"].rvr.aperture'
    assert factory_scene.path_resolve(path) == 1.0
    assert compat.fcurve_find(factory_scene, path) is None
    fc = compat.fcurve_ensure(factory_scene, path)
    assert compat.fcurve_ensure(factory_scene, path) == fc
    assert compat.fcurve_find(factory_scene, path) == fc
    assert compat.fcurves_all(factory_scene) == [fc]
    compat.fcurve_remove(factory_scene, fc)
    assert compat.fcurve_find(factory_scene, path) is None


def test_panel_draw_smoke(registered, factory_scene, tmp_path):
    import cv2
    import numpy as np

    png = tmp_path / "f_0000.png"
    cv2.imwrite(str(png), np.zeros((4, 4, 3), np.uint8))
    editor = factory_scene.sequence_editor_create()
    strip = editor.strips.new_image("Clip", str(png), channel=1, frame_start=1)
    editor.active_strip = strip
    strip.rvr.aperture_shape = "POLYGON"
    registered.operators.fcurves.write_keyframes(strip, "focus_disparity", [(1, 0.5)])
    panel = bpy.types.RVR_PT_focus
    recorder = LayoutRecorder()
    panel.draw(type("P", (), {"layout": recorder})(), bpy.context)
    drawn = {c[1] for c in recorder.calls}
    assert {"focus_disparity", "aperture", "aperture_shape", "blades", "rotation", "depth_path", "hdr_path",
            "output_dir", "rvr.render_strip", "rvr.keyframe_toggle"} <= drawn
    keys = [c for c in recorder.calls if c[:2] == ("operator", "rvr.keyframe_toggle")]
    assert [c[2] for c in keys] == ["DECORATE_KEYFRAME", "DECORATE"]
    wm = bpy.context.window_manager
    wm.rvr_job_status, wm.rvr_job_progress, wm.rvr_job_text = "RUNNING", 50.0, "4/8 frames"
    try:
        recorder = LayoutRecorder()
        panel.draw(type("P", (), {"layout": recorder})(), bpy.context)
        assert ("progress", 0.5) in recorder.calls and ("operator", "rvr.cancel_job", "CANCEL") in recorder.calls
        assert bpy.ops.rvr.cancel_job.poll() and not bpy.ops.rvr.render_strip.poll()
        bpy.ops.rvr.cancel_job()
        assert wm.rvr_job_status == "CANCELLING"
    finally:
        wm.rvr_job_status = "IDLE"


def test_keyframe_toggle_operator(registered, factory_scene, tmp_path):
    fcurves = registered.operators.fcurves
    editor = factory_scene.sequence_editor_create()
    strip = color_strip(editor.strips, "A", 1, 1, 10)
    editor.active_strip = strip
    factory_scene.frame_set(3)
    strip.rvr.focus_disparity = 2.5
    assert bpy.ops.rvr.keyframe_toggle(prop="focus_disparity") == {"FINISHED"}
    assert fcurves.key_at(strip, "focus_disparity", 3)
    assert fcurves.find_fcurve(strip, "focus_disparity").evaluate(3) == pytest.approx(2.5)
    bpy.ops.rvr.keyframe_toggle(prop="focus_disparity")  # same frame: deletes the key (and the empty curve)
    assert fcurves.find_fcurve(strip, "focus_disparity") is None


def test_cli_command_runs_engine(addon_package, capsys):
    assert addon_package._cli(["--version"]) == 0
    assert "rvr" in capsys.readouterr().out
    assert addon_package._cli(["render"]) == 2  # no input: an RvrError turned into exit status 2
