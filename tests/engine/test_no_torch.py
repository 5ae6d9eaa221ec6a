"""Torch is for training only: every engine module the Blender extension runs imports without it
(the extension zip has no torch; inference uses the ONNX exports, rvr_addon.onnxrun). A child
Python blocks ``import torch`` and imports every module of rvr_addon; only the training, export
and torch-renderer modules may need it."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

TRAINING_ONLY = {
    "rvr_addon.afnet.model", "rvr_addon.afnet.train", "rvr_addon.estimate.bilateral", "rvr_addon.estimate.head_fit", "rvr_addon.estimate.tfjs_graph", "rvr_addon.estimate.losses",
    "rvr_addon.estimate.train", "rvr_addon.estimate.unet", "rvr_addon.onnx_export", "rvr_addon.render.torch_render",
    "rvr_addon.training_run",
}
"""Modules that import torch at import time: training, ONNX export, the differentiable renderer."""

AUDIT = r'''
import importlib, json, pkgutil, sys

class Block:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r}")

sys.meta_path.insert(0, Block())
import rvr_addon
need = {}
for info in pkgutil.walk_packages(rvr_addon.__path__, "rvr_addon."):
    if info.name.endswith("__main__"):
        continue
    try:
        importlib.import_module(info.name)
    except ModuleNotFoundError as ex:
        if "torch" not in str(ex):
            raise
        need[info.name] = str(ex)
print(json.dumps(sorted(need)))
'''


def test_only_training_modules_need_torch():
    done = subprocess.run([sys.executable, "-c", AUDIT], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    need = set(json.loads(done.stdout.strip().splitlines()[-1]))
    assert need <= TRAINING_ONLY, f"these modules import torch at import time: {sorted(need - TRAINING_ONLY)}"
