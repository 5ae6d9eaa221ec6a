"""The dependency rules of DESIGN.md: the engine never imports bpy, the harness or the UI."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ENGINE = Path(__file__).resolve().parents[2] / "rvr_addon"
FORBIDDEN = ("bpy", "bpy_extras", "gpu", "sintel_eval", "operators", "panels")


@pytest.mark.parametrize("path", sorted(ENGINE.rglob("*.py")), ids=lambda p: str(p.relative_to(ENGINE)))
def test_engine_module_imports_no_blender_or_harness(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        for name in names:
            assert name.split(".")[0] not in FORBIDDEN, f"{path.name} imports {name}"


def test_render_pipeline_does_not_load_torch():
    """The fast path and the CLI stay light: Blender users need no torch to render."""
    code = "import sys, rvr_addon.pipeline, rvr_addon.cli; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=ENGINE.parent).stdout.strip()
    assert out == "False"
