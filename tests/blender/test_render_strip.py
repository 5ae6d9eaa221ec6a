"""rvr.render_strip on a generated image-sequence strip: result strip, video, focus track, and
that a failure leaves the scene and the disk as they were."""
from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
cv2 = pytest.importorskip("cv2")

W, H, N = 64, 36, 8
START = 11  # scene frame of the strip's first frame
KEYS = [(START + 1, 2.0), (START + 6, 12.0)]  # (scene frame, focus disparity)


@pytest.fixture
def clip(tmp_path):
    """8 frames of 64x36 PNG (noise) and one .npy disparity map per frame (left-right ramp 0..16)."""
    frames, depth = tmp_path / "frames", tmp_path / "depth"
    frames.mkdir()
    depth.mkdir()
    rng = np.random.default_rng(0)
    ramp = np.tile(np.linspace(0.0, 16.0, W, dtype=np.float32), (H, 1))
    for i in range(N):
        cv2.imwrite(str(frames / f"f_{i:04d}.png"), rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        np.save(depth / f"d_{i:04d}.npy", ramp)
    return frames, depth


@pytest.fixture
def image_strip(registered, factory_scene, clip, tmp_path):
    frames, depth = clip
    editor = factory_scene.sequence_editor_create()
    strip = editor.strips.new_image("Clip", str(frames / "f_0000.png"), channel=2, frame_start=START)
    for i in range(1, N):
        strip.elements.append(f"f_{i:04d}.png")
    editor.active_strip = strip
    strip.rvr.depth_path = str(depth)
    strip.rvr.output_dir = str(tmp_path / "renders")
    strip.rvr.focus_disparity = 0.0  # set by hand: Render refuses a strip whose focus nobody set
    return strip


def _strip_state(scene):
    return sorted((s.name, s.type, s.channel, s.frame_final_start, s.frame_final_end)
                  for s in scene.sequence_editor.strips_all)


def _keys(fcurve):
    return [tuple(k.co) for k in fcurve.keyframe_points]


def _OperatorStub():
    """Stands in for the operator instance to call execute()/modal() directly and see its reports."""
    from rvr_laaf.operators.ops_render import RVR_OT_render_strip

    from conftest import OperatorStub

    return OperatorStub(RVR_OT_render_strip)


def _decode(path):
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames


def test_render_strip_adds_result_strip(registered, factory_scene, image_strip, tmp_path):
    fcurves = registered.operators.fcurves
    compat = registered.operators.compat
    strip = image_strip
    fc = fcurves.write_keyframes(strip, "focus_disparity", KEYS, interpolation="LINEAR")

    path = 'sequence_editor.strips_all["Clip"].rvr.focus_disparity'
    assert fc.data_path == path
    assert fcurves.data_path(strip, "focus_disparity") == path
    assert compat.fcurve_find(factory_scene, path) == fc
    assert fcurves.find_fcurve(strip, "aperture") is None
    keys_before = _keys(fc)
    assert keys_before == [(float(f), float(v)) for f, v in KEYS]

    # the sampled track: linear between the keys, held outside; the static aperture
    scene_frames = np.arange(START, START + N)
    track = fcurves.sample_track(strip, scene_frames, np.arange(N))
    expected = np.interp(scene_frames, [k[0] for k in KEYS], [k[1] for k in KEYS])
    np.testing.assert_allclose(track.focus, expected, atol=1e-5)
    np.testing.assert_array_equal(track.frames, np.arange(N))
    np.testing.assert_allclose(track.aperture, 1.0)
    # and the animation system agrees with the sampling
    factory_scene.frame_set(START + 3)
    assert strip.rvr.focus_disparity == pytest.approx(expected[3], abs=1e-5)

    state_before = _strip_state(factory_scene)
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}

    result = factory_scene.sequence_editor.strips_all["Clip [RVR]"]
    assert result.type == "MOVIE"
    assert result.channel == strip.channel + 1
    assert (result.frame_final_start, result.frame_final_end) == (strip.frame_final_start, strip.frame_final_end)
    assert result.frame_duration == N
    assert not [s for s in factory_scene.sequence_editor.strips_all if s.type == "SOUND"]
    out = tmp_path / "renders" / "Clip.mp4"
    assert bpy.path.abspath(result.filepath) == str(out)
    frames = _decode(out)
    assert len(frames) == N and frames[0].shape == (H, W, 3)
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no temp files left
    # the focus track was used: the far right (D = 16) is blurred with r = 14 px at the first
    # frame (focus 2) and with r = 4 px at the last (focus 12), so it keeps more detail there
    right = (slice(8, H - 8), slice(W - 8, W))
    detail = [float(cv2.Laplacian(f[right].astype(np.float32), cv2.CV_32F).var()) for f in (frames[0], frames[-1])]
    assert detail[1] > 2.0 * detail[0], detail

    # the source strip and its F-curve are unchanged
    assert [s for s in _strip_state(factory_scene) if s[0] != "Clip [RVR]"] == state_before
    fc = fcurves.find_fcurve(factory_scene.sequence_editor.strips_all["Clip"], "focus_disparity")
    assert _keys(fc) == keys_before

    # rendering again replaces the result strip (same name, same place), no duplicate
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    results = [s for s in factory_scene.sequence_editor.strips_all if s.name.startswith("Clip [RVR]")]
    assert [(s.name, s.channel) for s in results] == [("Clip [RVR]", strip.channel + 1)]


def test_render_strip_trimmed_strip(registered, factory_scene, image_strip, tmp_path):
    """Trimmed handles: only the visible frames are rendered and the result spans them."""
    strip = image_strip
    strip.frame_offset_start = 2
    strip.frame_offset_end = 1
    span = registered.operators.ops_render.plan_render(factory_scene, strip).span
    assert (span.scene_start, span.scene_stop, span.clip_start) == (START + 2, START + N - 1, 2)
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
    result = factory_scene.sequence_editor.strips_all["Clip [RVR]"]
    assert (result.frame_final_start, result.frame_final_end) == (START + 2, START + N - 1)
    assert len(_decode(tmp_path / "renders" / "Clip.mp4")) == N - 3


def test_render_strip_bad_depth_changes_nothing(registered, factory_scene, image_strip, tmp_path):
    fcurves = registered.operators.fcurves
    strip = image_strip
    fc = fcurves.write_keyframes(strip, "focus_disparity", KEYS, interpolation="LINEAR")
    keys_before = _keys(fc)
    state_before = _strip_state(factory_scene)
    strip.rvr.depth_path = str(tmp_path / "no_such_depth")

    # a script sees the operator's ERROR report as a RuntimeError naming the path
    with pytest.raises(RuntimeError, match="no_such_depth"):
        bpy.ops.rvr.render_strip("EXEC_DEFAULT")
    # ... because execute() reported it and returned CANCELLED
    stub = _OperatorStub()
    assert registered.operators.ops_render.RVR_OT_render_strip.execute(stub, bpy.context) == {"CANCELLED"}
    assert [level for level, _ in stub.reports] == [{"ERROR"}] and "no_such_depth" in stub.reports[0][1]

    assert _strip_state(factory_scene) == state_before
    assert "Clip [RVR]" not in factory_scene.sequence_editor.strips_all
    assert _keys(fcurves.find_fcurve(strip, "focus_disparity")) == keys_before
    renders = tmp_path / "renders"
    assert not renders.exists() or not any(renders.iterdir())


def test_frame_span_and_channel_helpers(registered):
    ops = registered.operators.ops_render
    # holds on both sides: only the content frames are rendered, the span keeps the holds
    span = ops.frame_span(frame_start=10, final_start=8, final_end=20, duration=8, content_offset=3)
    assert (span.scene_start, span.scene_stop, span.clip_start, span.count) == (10, 18, 3, 8)
    assert (span.final_start, span.final_end) == (8, 20)
    with pytest.raises(registered.rvr_addon.errors.InputError):
        ops.frame_span(frame_start=10, final_start=18, final_end=20, duration=8, content_offset=0)
    occupied = [(3, 0, 10), (4, 5, 15), (5, 20, 30)]
    assert ops.first_free_channel(occupied, above=2, start=0, end=10) == 5
    assert ops.first_free_channel(occupied, above=2, start=10, end=12) == 3
    assert ops.safe_file_name("a/b:c") == "a_b_c"


class _Event:
    def __init__(self, kind):
        self.type = kind
        self.value = "NOTHING"


def _modal_stub(registered, context):
    """An operator stand-in prepared as invoke() would (without the window timer)."""
    ops = registered.operators.ops_render
    stub = _OperatorStub()
    stub._timer = None
    stub._plan, stub._job = ops.RVR_OT_render_strip._prepare(stub, context)
    context.window_manager.rvr_job_status = "RUNNING"
    return stub, ops.RVR_OT_render_strip.modal


def test_modal_steps_on_timer_and_finishes(registered, factory_scene, image_strip, tmp_path):
    stub, modal = _modal_stub(registered, bpy.context)
    wm = bpy.context.window_manager
    assert modal(stub, bpy.context, _Event("MOUSEMOVE")) == {"PASS_THROUGH"}
    assert stub._job.done == 0  # only timer events step the job
    results = []
    for _ in range(100):
        results.append(modal(stub, bpy.context, _Event("TIMER")))
        if results[-1] != {"PASS_THROUGH"}:
            break
        assert wm.rvr_job_status == "RUNNING" and 0.0 < wm.rvr_job_progress <= 100.0
    assert results[-1] == {"FINISHED"}
    assert wm.rvr_job_status == "IDLE" and stub._job is None
    assert "Clip [RVR]" in factory_scene.sequence_editor.strips_all
    assert len(_decode(tmp_path / "renders" / "Clip.mp4")) == N


@pytest.mark.parametrize("how", ["esc", "cancel_operator"])
def test_modal_cancel_changes_nothing(registered, factory_scene, image_strip, tmp_path, how, monkeypatch):
    monkeypatch.setattr(registered.operators.jobrun, "STEP_BUDGET_S", 0.0)  # one frame per timer tick
    out = tmp_path / "renders" / "Clip.mp4"
    out.parent.mkdir()
    out.write_bytes(b"earlier render")
    state_before = _strip_state(factory_scene)
    stub, modal = _modal_stub(registered, bpy.context)
    assert modal(stub, bpy.context, _Event("TIMER")) == {"PASS_THROUGH"}
    assert stub._job.done == 1
    if how == "esc":
        result = modal(stub, bpy.context, _Event("ESC"))
    else:
        assert bpy.ops.rvr.cancel_job() == {"FINISHED"}
        result = modal(stub, bpy.context, _Event("TIMER"))
    assert result == {"CANCELLED"}
    assert bpy.context.window_manager.rvr_job_status == "IDLE"
    assert "cancelled" in bpy.context.window_manager.rvr_job_text
    assert _strip_state(factory_scene) == state_before
    assert out.read_bytes() == b"earlier render"  # the earlier result survives
    assert [p.name for p in out.parent.iterdir()] == ["Clip.mp4"]  # no temp file left


def test_invoke_in_background_runs_blocking(registered, factory_scene, image_strip):
    assert bpy.ops.rvr.render_strip("INVOKE_DEFAULT") == {"FINISHED"}
    assert "Clip [RVR]" in factory_scene.sequence_editor.strips_all


def test_a_strip_never_focused_is_refused_naming_auto_focus(registered, factory_scene, image_strip, tmp_path):
    """Render never guesses focus 0: no focus keys and a Focus nobody set -> an error naming the
    fix, nothing written, no strip added; keyed or set focus renders."""
    strip = image_strip
    strip.rvr.property_unset("focus_disparity")
    before = _strip_state(factory_scene)
    with pytest.raises(RuntimeError, match="has no focus yet: run Auto Focus"):
        bpy.ops.rvr.render_strip("EXEC_DEFAULT")
    assert _strip_state(factory_scene) == before and not (tmp_path / "renders").exists()
    strip.rvr.focus_disparity = 0.0  # the user's own choice, even the default value
    assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
