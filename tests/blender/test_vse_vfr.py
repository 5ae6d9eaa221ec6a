"""A variable-frame-rate movie (phones) in the sequencer: Blender shows it on a constant-rate
timeline at its nominal rate, and the engine reads the same frames (``io.video.video_timeline``),
so the depth, the focus and the render of strip frame n are those of the picture Blender shows."""
from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")


def _blender_frame(scene, frame: int, path) -> np.ndarray:
    """The sequencer's picture at scene frame ``frame`` (RGB uint8), rendered to ``path``."""
    import cv2

    scene.frame_set(frame)
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return cv2.imread(str(path), cv2.IMREAD_COLOR)[:, :, ::-1]


def test_blender_and_the_engine_count_and_show_the_same_frames(registered, factory_scene, tmp_path, ffmpeg_run):
    from rvr_laaf.operators.source import resolve_source
    from rvr_laaf.rvr_addon.io.video import iter_frames, probe_clip
    from vfr_synth import flash_clip

    clip = flash_clip(ffmpeg_run, tmp_path / "vfr.mp4")  # the flash at 2.5 s; 85 frames decoded
    scene = factory_scene
    scene.render.fps, scene.render.fps_base = 30, 1.0
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 320, 180, 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.view_settings.view_transform = "Standard"  # the movie's own code values
    editor = scene.sequence_editor_create()
    strip = editor.strips.new_movie("Phone", str(clip), channel=1, frame_start=1)
    info = probe_clip(clip)
    assert strip.frame_final_duration == info.frame_count == 105 and strip.fps == pytest.approx(info.fps)
    source = resolve_source(scene, strip)
    assert source.span.count == 105 and list(source.clip_frames[:3]) == [0, 1, 2]
    ours = list(iter_frames(clip))
    flash = [k for k, f in enumerate(ours) if f.mean() > 60]
    assert flash[:1] == [75]
    for k in (flash[0] - 1, flash[0], 40):  # scene frame k + 1 shows clip frame k
        shown = _blender_frame(scene, k + 1, tmp_path / f"b{k}.png")
        assert np.abs(shown.astype(int) - ours[k]).mean() < 3, k
