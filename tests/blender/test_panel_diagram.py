"""scripts/panel_diagram.py (docs/blender_panel.png): the layout it captures from the panels' own
draw() holds the tab's panels in Blender's order and their main operators, so the diagram
cannot silently go empty; the painted picture has a callout for each of them."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "panel_diagram.py"


@pytest.fixture(scope="module")
def diagram():
    """scripts/panel_diagram.py imported as a module."""
    spec = importlib.util.spec_from_file_location("panel_diagram", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def _main_operators(addon) -> set[str]:
    ops = addon.operators
    return {ops.ops_analyze.RVR_OT_analyze.bl_idname, ops.ops_focus.RVR_OT_auto_focus.bl_idname,
            ops.ops_focus.RVR_OT_track_targets.bl_idname, ops.ops_render.RVR_OT_render_strip.bl_idname}


def test_capture_holds_the_panels_and_main_operators(diagram, addon_package, tmp_path):
    panels, job = diagram.capture(analyze=False)  # registers, builds the scene, unregisters
    assert [(p.idname, p.depth) for p in panels] == [("RVR_PT_focus", 0), ("RVR_PT_targets", 1)]
    nodes = [n for p in panels for n in p.root.walk()]
    ops = {n.ident: n for n in nodes if n.kind == "operator"}
    assert _main_operators(addon_package) <= set(ops)
    assert ops["rvr.analyze"].text == "Analyze" and ops["rvr.analyze"].icon == "VIEW_CAMERA"
    assert ops["rvr.render_strip"].text == "Render Refocused Strip"
    props = {n.ident: n for n in nodes if n.kind == "prop"}
    assert props["RVR_PG_strip.aperture_shape"].text == "Shape" and props["RVR_PG_strip.aperture_shape"].value == "Disk"
    assert props["RVR_PG_strip.focus_disparity"].split  # drawn with its label beside it
    lists = [n for n in nodes if n.kind == "list"]
    assert len(lists) == 1 and len(lists[0].children) == 2  # the two focus targets, drawn by draw_item
    assert any(n.kind == "box" for n in panels[1].root.walk())  # the active target's box
    assert any(n.kind == "progress" for n in job.walk())
    out = diagram.paint(panels, job, tmp_path / "panel.png")
    placed: list = []
    for p in panels:
        diagram.place(p.root, 0, 0, 400, placed)
    lines = [line for *_, line in diagram.callouts(placed)]
    assert all(any(line.startswith(name + ":") for line in lines)
               for name in ("Analyze", "Auto Focus", "Track", "Render Refocused Strip"))
    from PIL import Image

    with Image.open(out) as image:
        assert 1000 <= image.height <= 1500 and image.width >= 900


def test_capture_panels_follows_the_strip(diagram, registered, movie_strip):
    """With no focus target the list is empty; without a movie strip only the hint is drawn."""
    panels = diagram.capture_panels(bpy.context)
    assert [p.idname for p in panels] == ["RVR_PT_focus", "RVR_PT_targets"]
    (lst,) = [n for n in panels[1].root.walk() if n.kind == "list"]
    assert lst.children == []
    assert not any(n.kind == "box" for n in panels[1].root.walk())
    bpy.context.scene.sequence_editor.active_strip = None
    (panel,) = diagram.capture_panels(bpy.context)
    assert [(n.kind, n.text) for n in panel.root.children] == [("label", "Select a movie or image strip")]
