"""Undo of the VSE tool, headless (the bpy module has a window manager and a memfile undo stack):
every operator that changes the file declares REGISTER and UNDO, and with one undo step per call
(as the UI pushes; a script asks for it with ``bpy.ops.rvr.x("EXEC_DEFAULT", True)``) Blender's
undo and redo restore the cache path, the targets, the focus keys and the result strip."""
from __future__ import annotations

import pytest

bpy = pytest.importorskip("bpy")

START = 11  # movie_strip's frame_start


def test_every_operator_declares_undo(registered):
    ops = registered.operators
    classes = [c for m in (ops.fcurves, ops.ops_render, ops.ops_analyze, ops.ops_focus) for c in m.classes]
    assert {c.__name__ for c in classes} == {n for n in dir(bpy.types) if n.startswith("RVR_OT_")}
    for cls in classes:
        options = set(cls.bl_options)
        assert "REGISTER" in options, cls.__name__
        if cls.__name__ == "RVR_OT_cancel_job":  # only the job status on the WindowManager (never saved)
            assert not options & {"UNDO", "UNDO_GROUPED"}
        elif cls.__name__ == "RVR_OT_jump_to_target":  # a frame change, grouped as Blender's own jumps
            assert "UNDO_GROUPED" in options and cls.bl_undo_group == "Frame Change"
        else:
            assert "UNDO" in options, cls.__name__


def _state() -> tuple:
    scene = bpy.context.scene
    strips = scene.sequence_editor.strips_all
    strip = strips["Clip"]
    from rvr_laaf.operators import fcurves

    fc = fcurves.find_fcurve(strip, "focus_disparity")
    return (strip.rvr.cache_path, tuple(n.frame for n in strip.rvr.nfts), len(fc.keyframe_points) if fc else 0,
            "Clip [RVR]" in strips, scene.frame_current)


def test_undo_and_redo_every_step(registered, movie_strip, vse_depth, no_shipped_weights, use_prefs):
    use_prefs()
    movie_strip.rvr.depth_path = str(vse_depth)
    movie_strip.rvr.render_size = "0.5"
    bpy.ops.ed.undo_push(message="start")
    steps = [(bpy.ops.rvr.analyze, {}),
             (bpy.ops.rvr.add_focus_target, dict(x=50, y=28, w=8, h=8, frame=START + 2)),
             (bpy.ops.rvr.track_targets, {}),
             (bpy.ops.rvr.jump_to_target, dict(index=0)),
             (bpy.ops.rvr.keyframe_toggle, dict(prop="focus_disparity")),
             (bpy.ops.rvr.render_strip, {}),
             (bpy.ops.rvr.remove_focus_target, dict(index=0))]
    states = [_state()]
    for op, kw in steps:
        assert op("EXEC_DEFAULT", True, **kw) == {"FINISHED"}  # True: push an undo step, as the UI does
        states.append(_state())
    assert len(set(states)) == len(states), states  # every step changed something
    for expected in reversed(states[:-1]):
        bpy.ops.ed.undo()
        assert _state() == expected
    for expected in states[1:]:
        bpy.ops.ed.redo()
        assert _state() == expected
