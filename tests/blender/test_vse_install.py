"""The extension zip (scripts/build_extension.py) installed through Blender's own extension
installer into a temporary user directory, enabled, and used end to end on a tiny clip:
Analyze -> Add Focus Target -> Auto Focus -> Render; F-curves and the result strip checked;
then the people depth cue from the extension's mediapipe wheel (no matplotlib in Blender).

Runs in a child Python (the bpy module reads its user directories once, at import) that sees
only what a Blender install ships (bpy, numpy, requests and its helpers, zstandard: links in a
temporary folder, ``python -S`` without the venv's site-packages), so the extension's own
wheels must provide OpenCV, OpenEXR, tqdm, imageio-ffmpeg and mediapipe.
Needs the wheels (scripts/fetch_wheels.sh); skipped with that advice when they are missing.

The second test runs, in the same isolation (torch not importable), Analyze with the estimator
network, Track, every Auto Focus preset of ``rvr_addon.laaf.presets.PRESETS`` and Render (about
15 s here).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[2]
INTERVIEW = ROOT.parent / "shared" / "data" / "clips" / "visualvoice_interview.mp4"
sys.path.insert(0, str(ROOT / "scripts"))
import build_extension  # noqa: E402

SCRIPT = r'''
import json, sys
from pathlib import Path
import bpy

zip_path, clip, depth, work = sys.argv[1:5]
result = {}
bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
pkg = "bl_ext.user_default.rvr_laaf"
result["enabled"] = pkg in bpy.context.preferences.addons
module = sys.modules[pkg]
result["module_file"] = module.__file__
result["prefs"] = type(bpy.context.preferences.addons[pkg].preferences).__name__
scene = bpy.context.scene
scene.render.fps = 24
editor = scene.sequence_editor_create()
bpy.ops.wm.save_as_mainfile(filepath=str(Path(work) / "project.blend"))
scene = bpy.context.scene
editor = scene.sequence_editor
strip = editor.strips.new_movie("Clip", clip, channel=2, frame_start=1)
editor.active_strip = strip
strip.rvr.depth_path = depth
strip.rvr.output_dir = "//renders/"
result["analyze"] = list(bpy.ops.rvr.analyze("EXEC_DEFAULT"))
result["add"] = list(bpy.ops.rvr.add_focus_target(x=50, y=28, w=8, h=8, frame=7))
result["autofocus"] = list(bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset="salient", lookahead_s=0.5))
result["render"] = list(bpy.ops.rvr.render_strip("EXEC_DEFAULT"))
from bpy_extras import anim_utils
adt = scene.animation_data
bag = anim_utils.action_get_channelbag_for_slot(adt.action, adt.action_slot)
result["fcurves"] = {fc.data_path: [tuple(k.co) for k in fc.keyframe_points] for fc in bag.fcurves}
out = editor.strips_all["Clip [RVR]"]
result["result_strip"] = {"type": out.type, "channel": out.channel, "start": out.frame_final_start,
                          "end": out.frame_final_end, "file": bpy.path.abspath(out.filepath)}
result["nfts"] = [(n.frame, n.source, n.keep) for n in strip.rvr.nfts]
result["cv2"] = sys.modules["cv2"].__file__
import importlib
import numpy as np
people = importlib.import_module(pkg + ".rvr_addon.depth.people")
frame = np.load(sys.argv[5]) if sys.argv[5] else np.zeros((72, 128, 3), np.uint8)
with people.PeopleDetector() as detector:
    found = detector(frame)
result["people"] = [(round(p.distance_m, 3), p.mouth_open is not None) for p in found.persons]
result["mediapipe"] = sys.modules["mediapipe"].__file__
result["matplotlib"] = "matplotlib" in sys.modules
print("RESULT " + json.dumps(result))
'''


SCRIPT_NO_TORCH = r'''
import json, sys
from pathlib import Path
import bpy

zip_path, clip, work, presets = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4].split(",")
result = {"torch_importable": True}
try:
    import torch  # noqa: F401
except ImportError:
    result["torch_importable"] = False
bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
pkg = "bl_ext.user_default.rvr_laaf"
import importlib
notes = importlib.import_module(pkg + ".operators.notes")
warnings = []
real_report = notes.report
def report(reporter):
    got = real_report(reporter)
    warnings.extend(got)
    return got
notes.report = report
scene = bpy.context.scene
scene.render.fps = 24
scene.sequence_editor_create()
bpy.ops.wm.save_as_mainfile(filepath=str(Path(work) / "project.blend"))
scene = bpy.context.scene
editor = scene.sequence_editor
strip = editor.strips.new_movie("Clip", clip, channel=2, frame_start=1)
editor.active_strip = strip
strip.rvr.output_dir = "//renders/"
ops = {}
ops["analyze"] = list(bpy.ops.rvr.analyze("EXEC_DEFAULT"))  # no Disparity maps: the estimator network runs
ops["add"] = list(bpy.ops.rvr.add_focus_target(x=20, y=16, w=10, h=10, frame=3))
ops["track"] = list(bpy.ops.rvr.track_targets("EXEC_DEFAULT"))
from bpy_extras import anim_utils
def focus_keys():
    adt = scene.animation_data
    bag = anim_utils.action_get_channelbag_for_slot(adt.action, adt.action_slot)
    fc = bag.fcurves.find('sequence_editor.strips_all["Clip"].rvr.focus_disparity')
    return [tuple(k.co) for k in fc.keyframe_points] if fc is not None else []
keys = {"track": focus_keys()}
props = importlib.import_module(pkg + ".operators.props")
presets = list(dict.fromkeys(presets + [item[0] for item in props.AUTOFOCUS_PRESETS]))  # every one the UI offers
result["presets"] = presets
for preset in presets:
    ops[preset] = list(bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset=preset, lookahead_s=0.5))
    keys[preset] = focus_keys()
# webrtcvad missing (another platform): Conversation falls back to the energy VAD with a warning
audio = importlib.import_module(pkg + ".rvr_addon.laaf.audio")
audio.webrtc_available = lambda: False
warnings.clear()
ops["conversation_no_vad"] = list(bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset="conversation", lookahead_s=0.5))
result["no_vad_warnings"] = list(warnings)
ops["render"] = list(bpy.ops.rvr.render_strip("EXEC_DEFAULT"))
out = editor.strips_all["Clip [RVR]"]
result["render_file"] = bpy.path.abspath(out.filepath)
meta = json.loads((Path(bpy.path.abspath(strip.rvr.cache_path)) / "meta.json").read_text())
result["model"] = {"hash": meta.get("model_hash"), "path": (meta.get("model") or {}).get("path")}
result["ops"], result["keys"] = ops, keys
result["modules"] = {m: getattr(sys.modules.get(m), "__file__", None) for m in ("onnxruntime", "webrtcvad", "cv2")}
result["torch_loaded"] = "torch" in sys.modules
print("RESULT " + json.dumps(result))
'''


BLENDER_BUNDLES = ("bpy", "numpy", "numpy.libs", "requests", "urllib3", "idna", "certifi", "charset_normalizer",
                   "zstandard")
"""Python packages a Blender 5.0 install ships in its own Python (what an extension may assume)."""


def blender_like_site(folder: Path) -> Path:
    """A folder of links to the BLENDER_BUNDLES packages (and their dist-info) of this Python."""
    import numpy

    site = Path(numpy.__file__).resolve().parents[1]
    assert (site / "bpy").is_dir(), f"bpy is not installed beside numpy in {site}"
    folder.mkdir()
    for entry in site.iterdir():
        name = entry.name.split("-")[0]
        if entry.name in BLENDER_BUNDLES or (entry.name.endswith(".dist-info") and name in BLENDER_BUNDLES):
            (folder / entry.name).symlink_to(entry)
    return folder


@pytest.fixture(scope="module")
def zip_path(tmp_path_factory) -> Path:
    """The extension zip, built once for this module's tests (skips when the wheels are not fetched)."""
    missing = build_extension.missing_wheels()
    if missing:
        pytest.skip(f"wheels {missing} are not fetched: run scripts/fetch_wheels.sh")
    return build_extension.build(tmp_path_factory.mktemp("dist"))


def blender_env(tmp_path: Path) -> tuple[Path, dict, Path]:
    """(the user folder Blender installs into, the child's environment: Blender's user folders
    there and only what Blender ships on the path, an empty work folder)."""
    user = tmp_path / "user"
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(user), "BLENDER_USER_CONFIG": str(user / "config"),
           "BLENDER_USER_SCRIPTS": str(user / "scripts"), "BLENDER_USER_EXTENSIONS": str(user / "extensions"),
           "PYTHONPATH": str(blender_like_site(tmp_path / "blender_site")), "PYTHONNOUSERSITE": "1"}
    work = tmp_path / "work"
    work.mkdir()
    return user, env, work


def test_zip_installs_and_runs_the_workflow(tmp_path, zip_path, vse_clip, vse_depth):
    user, env, work = blender_env(tmp_path)
    frame = ""  # the people cue sees the shared interview clip's split screen (two people) when present
    if INTERVIEW.is_file():
        from rvr_addon.io.video import iter_frames

        np.save(tmp_path / "frame.npy", next(iter_frames(INTERVIEW, 100, 101)))
        frame = str(tmp_path / "frame.npy")
    done = subprocess.run([sys.executable, "-S", "-c", SCRIPT, str(zip_path), str(vse_clip), str(vse_depth), str(work),
                           frame],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("RESULT ")]
    assert done.returncode == 0 and lines, done.stdout[-3000:] + done.stderr[-3000:]
    r = json.loads(lines[-1][len("RESULT "):])
    assert r["enabled"] and r["prefs"] == "RVR_AP_preferences"
    assert Path(r["module_file"]).is_relative_to(user / "extensions")  # the installed copy, not the repository
    assert Path(r["cv2"]).is_relative_to(user / "extensions")  # OpenCV from the extension's wheels
    assert r["analyze"] == r["add"] == r["autofocus"] == r["render"] == ["FINISHED"]
    keys = r["fcurves"]['sequence_editor.strips_all["Clip"].rvr.focus_disparity']
    assert len(keys) >= 2 and all(1 <= f <= 12 for f, _ in keys)
    assert (6, "manual", True) in [tuple(n) for n in r["nfts"]]
    s = r["result_strip"]
    assert (s["type"], s["channel"], s["start"], s["end"]) == ("MOVIE", 3, 1, 13)
    assert Path(s["file"]) == work / "renders" / "Clip.mp4" and Path(s["file"]).stat().st_size > 0
    assert Path(r["mediapipe"]).is_relative_to(user / "extensions") and not r["matplotlib"]
    if frame:
        assert len(r["people"]) == 2 and all(0.3 < d < 2.0 and mesh for d, mesh in r["people"])
    else:
        assert r["people"] == []


def test_zip_runs_every_preset_and_the_render_without_torch(tmp_path, zip_path, vse_clip):
    """The zip alone, in a Python with only what Blender ships (no torch): Analyze with the
    estimator network (its ONNX export on onnxruntime from the zip), Track, every Auto Focus
    preset (Learned = AF-Net's export; Conversation with the zip's webrtcvad, then without it:
    the energy fallback and a warning), Render; each finishes and writes focus keys that are
    not all 0. Slow (a minute or two: every detector on a tiny clip)."""
    from rvr_addon.laaf.presets import PRESETS

    user, env, work = blender_env(tmp_path)
    env.pop("RVR_INFERENCE", None)
    presets = list(PRESETS)
    done = subprocess.run([sys.executable, "-S", "-c", SCRIPT_NO_TORCH, str(zip_path), str(vse_clip), str(work),
                           ",".join(presets)], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("RESULT ")]
    assert done.returncode == 0 and lines, done.stdout[-3000:] + done.stderr[-3000:]
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    r = json.loads(lines[-1][len("RESULT "):])
    assert not r["torch_importable"] and not r["torch_loaded"]
    for name in ("onnxruntime", "webrtcvad", "cv2"):
        assert r["modules"][name] and Path(r["modules"][name]).is_relative_to(user / "extensions"), name
    assert {op: v for op, v in r["ops"].items() if v != ["FINISHED"]} == {}
    assert r["model"]["path"].endswith("estimator.onnx")  # the network ran from the zip's export
    from rvr_addon import onnxrun
    from rvr_addon.estimate.infer import SHIPPED_WEIGHTS

    assert r["model"]["hash"] == onnxrun.file_hash(SHIPPED_WEIGHTS)  # the same cache key as torch's run
    assert set(r["presets"]) >= set(presets) and len(r["presets"]) >= 6, r["presets"]
    presets = r["presets"]
    for name in ["track", *presets]:
        keys = r["keys"][name]
        assert len(keys) >= 1 and all(1 <= f <= 12 for f, _ in keys), (name, keys)
    assert any(abs(v) > 1e-3 for name in ["track", *presets] for _, v in r["keys"][name])  # focus is not 0
    assert any("webrtcvad" in w for w in r["no_vad_warnings"]), r["no_vad_warnings"]
    assert Path(r["render_file"]).stat().st_size > 0
