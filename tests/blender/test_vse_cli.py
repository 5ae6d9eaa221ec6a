"""``blender -b -c rvr analyze|autofocus|render --blend FILE``: the registered command handler,
called through the bpy module as Blender calls it, on a saved .blend with a movie strip."""
from __future__ import annotations

import pytest

from conftest import VSE_N

bpy = pytest.importorskip("bpy")


def test_cli_analyze_autofocus_render(registered, movie_strip, saved_blend, vse_depth, no_shipped_weights, capsys):
    bpy.ops.wm.save_mainfile()
    blend = str(saved_blend)
    cli = registered._cli
    assert cli(["analyze", "--blend", blend, "--depth", str(vse_depth)]) == 0
    assert cli(["autofocus", "--blend", blend, "--preset", "none", "--target", "11,50,28,8,8",
                "--target", "19,35,17,14,14", "--lead-frames", "2"]) == 0
    assert cli(["render", "--blend", blend, "--strip", "Clip", "--size", "0.5"]) == 0
    bpy.ops.wm.open_mainfile(filepath=blend)  # everything was saved in the file
    editor = bpy.context.scene.sequence_editor
    strip = editor.strips_all["Clip"]
    assert strip.rvr.cache_path.startswith("//rvr_cache/")
    assert [n.frame for n in strip.rvr.nfts] == [0, 8] and strip.rvr.lead_frames == 2
    fc = registered.operators.fcurves.find_fcurve(strip, "focus_disparity")
    assert fc is not None and fc.evaluate(19 - 2) == pytest.approx(-2.0, abs=0.3)
    result = editor.strips_all["Clip [RVR]"]
    assert result.frame_final_duration == VSE_N and result.elements[0].orig_width in (0, 32)
    # bad input: a clear message and status 1; an unknown option: 2; engine commands still work
    assert cli(["analyze", "--blend", blend, "--strip", "Nope"]) == 1
    assert "no strip 'Nope'" in capsys.readouterr().err
    assert cli(["render", "--blend", str(saved_blend.parent / "missing.blend")]) == 1
    assert cli(["autofocus", "--blend", blend, "--bogus"]) == 2
    assert cli(["render"]) == 2  # the engine's `rvr render` without input
