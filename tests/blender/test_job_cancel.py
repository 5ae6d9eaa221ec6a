"""Issue 22.3: Esc / Cancel on every modal job (Analyze, Track, Auto Focus, Render), before the
first step, mid-way and after the end, through the operator's modal(): the status always goes
back to IDLE (a stuck RUNNING/CANCELLING greys out every RVR operator), and the strip's targets,
F-curves, cache path and the scene's strips are as before. Auto Focus used to crash here
(``'AutofocusJob' object has no attribute 'cancel'``)."""
from __future__ import annotations

import pytest

from conftest import Event, OperatorStub

bpy = pytest.importorskip("bpy")

START = 11  # movie_strip's frame_start
OPERATORS = {"analyze": ("RVR_OT_analyze", {}), "track": ("RVR_OT_track_targets", {}),
             "auto_focus": ("RVR_OT_auto_focus", {"preset": "salient", "lookahead_s": 0.5}),
             "render": ("RVR_OT_render_strip", {})}


@pytest.fixture
def analysed(movie_strip, vse_depth, no_shipped_weights, use_prefs):
    use_prefs()
    movie_strip.rvr.depth_path = str(vse_depth)
    assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
    assert bpy.ops.rvr.add_focus_target(x=50, y=28, w=8, h=8, frame=START + 6) == {"FINISHED"}
    movie_strip.rvr.focus_disparity = 3.0  # focused by hand (Render refuses a strip never focused)
    return movie_strip


def _state(scene):
    from rvr_laaf.operators import fcurves

    out = {"strips": sorted(s.name for s in scene.sequence_editor.strips_all)}
    for strip in scene.sequence_editor.strips_all:
        if not hasattr(strip, "rvr"):
            continue
        keys = {}
        for prop in ("focus_disparity", "aperture"):
            fc = fcurves.find_fcurve(strip, prop)
            keys[prop] = None if fc is None else [(k.co[0], k.co[1], k.type) for k in fc.keyframe_points]
        nfts = [(n.frame, n.x, n.y, n.source, n.keep, len(n.track), n.tracked_start) for n in strip.rvr.nfts]
        out[strip.name] = (strip.rvr.cache_path, strip.rvr.auto_keys, nfts, keys)
    return out


def _start(kind):
    name, props = OPERATORS[kind]
    cls = getattr(bpy.types, name)
    op = OperatorStub(cls, **props)
    op._plan, op._job = cls._prepare_job(op, bpy.context)
    bpy.context.window_manager.rvr_job_status = "RUNNING"
    return op, cls.modal


@pytest.mark.parametrize("how", ["esc_before_first_step", "esc_mid_way", "cancel_operator_mid_way",
                                 "blender_cancel_mid_way", "cancel_after_the_end"])
@pytest.mark.parametrize("kind", list(OPERATORS))
def test_every_modal_job_cancels_and_resets_the_status(registered, analysed, monkeypatch, kind, how):
    monkeypatch.setattr(registered.operators.jobrun, "STEP_BUDGET_S", 0.0)  # one step per timer tick
    scene = analysed.id_data
    wm = bpy.context.window_manager
    before = _state(scene)
    op, modal = _start(kind)
    if how != "esc_before_first_step" and how != "cancel_after_the_end":
        assert modal(op, bpy.context, Event("TIMER")) == {"PASS_THROUGH"}
        assert wm.rvr_job_status == "RUNNING"
    if how.startswith("esc"):
        assert modal(op, bpy.context, Event("ESC")) == {"CANCELLED"}
    elif how == "cancel_operator_mid_way":
        assert bpy.ops.rvr.cancel_job() == {"FINISHED"}
        assert wm.rvr_job_status == "CANCELLING"
        assert modal(op, bpy.context, Event("TIMER")) == {"CANCELLED"}
    elif how == "blender_cancel_mid_way":  # file load, window closed
        op._cls.cancel(op, bpy.context)
    else:
        for _ in range(500):
            result = modal(op, bpy.context, Event("TIMER"))
            if result != {"PASS_THROUGH"}:
                break
        assert result == {"FINISHED"}, op.reports
        op._cls.cancel(op, bpy.context)  # Blender ending the (finished) run changes nothing more
        assert modal(op, bpy.context, Event("ESC")) == {"CANCELLED"}  # a late event: nothing left to run
    assert wm.rvr_job_status == "IDLE" and op._job is None and op._timer is None
    assert not any(level & {"ERROR"} for level, _ in op.reports), op.reports
    if how != "cancel_after_the_end":
        assert _state(scene) == before  # nothing the user made changed
        if not how.startswith("blender"):
            assert any("cancel" in text for _, text in op.reports), op.reports
        assert bpy.ops.rvr.track_targets.poll()  # the operators are usable again


@pytest.mark.parametrize("kind", list(OPERATORS))
def test_a_cancel_or_abort_that_raises_still_resets_the_status(registered, analysed, monkeypatch, kind):
    monkeypatch.setattr(registered.operators.jobrun, "STEP_BUDGET_S", 0.0)
    wm = bpy.context.window_manager
    op, modal = _start(kind)
    assert modal(op, bpy.context, Event("TIMER")) == {"PASS_THROUGH"}
    real_cancel = op._job.cancel

    def broken():
        real_cancel()
        raise RuntimeError("cancel failed")

    op._job.cancel = broken
    with pytest.raises(RuntimeError, match="cancel failed"):
        modal(op, bpy.context, Event("ESC"))
    assert wm.rvr_job_status == "IDLE" and op._job is None
    # a step that fails with a non-RvrError, and an abort that fails as well
    op, modal = _start(kind)
    op._job.step = lambda: (_ for _ in ()).throw(ValueError("step failed"))
    if hasattr(op._job, "abort"):
        op._job.abort = lambda: (_ for _ in ()).throw(OSError("abort failed"))
    else:
        op._job.cancel = lambda: (_ for _ in ()).throw(OSError("abort failed"))
    with pytest.raises((ValueError, OSError)):
        modal(op, bpy.context, Event("TIMER"))
    assert wm.rvr_job_status == "IDLE" and op._job is None


def test_a_job_without_the_job_interface_is_refused_before_it_starts(registered, analysed, monkeypatch):
    ops = registered.operators.ops_render

    class Half:
        text, progress = "", 0.0

        def step(self):
            return False

    monkeypatch.setattr(ops.RVR_OT_render_strip, "_prepare", lambda self, context: (None, Half()))
    op = OperatorStub(bpy.types.RVR_OT_render_strip)
    with pytest.raises(TypeError, match="lacks cancel"):
        bpy.types.RVR_OT_render_strip._prepare_job(op, bpy.context)
