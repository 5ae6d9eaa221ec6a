"""Fixtures for tests that import bpy: the repository root imported as the package ``rvr_laaf``
(as Blender would import the extension), registered for one test and unregistered after."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "rvr_laaf"


@pytest.fixture(scope="session")
def addon_package(tmp_path_factory):
    """The repository root imported as ``rvr_laaf`` via a symlink on a temporary sys.path entry."""
    pytest.importorskip("bpy")
    root = tmp_path_factory.mktemp("addon_path")
    (root / PACKAGE).symlink_to(REPO_ROOT, target_is_directory=True)
    sys.path.insert(0, str(root))
    try:
        yield importlib.import_module(PACKAGE)
    finally:
        sys.path.remove(str(root))


@pytest.fixture
def factory_scene():
    """A fresh factory-settings file with an empty scene; returns that scene."""
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


@pytest.fixture
def registered(addon_package, factory_scene):
    """The add-on registered in a fresh file (unregistered afterwards)."""
    addon_package.register()
    try:
        yield addon_package
    finally:
        addon_package.unregister()


# ----------------------------------------------------------------------------- VSE tool fixtures

VSE_W, VSE_H, VSE_N, VSE_FPS = 64, 36, 12, 24


@pytest.fixture(scope="session")
def vse_clip(tmp_path_factory, ffmpeg):
    """64x36, 12 frames at 24 fps, H.264 + AAC: a bright square moving right over a textured
    background (something to track), with half a second of sine audio."""
    from tests.conftest import run_ffmpeg

    path = tmp_path_factory.mktemp("vse_clip") / "clip.mp4"
    src = (f"testsrc2=size={VSE_W}x{VSE_H}:rate={VSE_FPS}[bg];color=c=white:s=14x14:r={VSE_FPS}[fg];"
           f"[bg][fg]overlay=x='4+{3 * VSE_FPS}*t':y=10:shortest=1")
    run_ffmpeg(ffmpeg, "-f", "lavfi", "-i", src, "-f", "lavfi", "-i",
               "sine=frequency=440:sample_rate=48000:duration=0.5", "-frames:v", str(VSE_N),
               "-c:v", "libx264", "-preset", "ultrafast", "-pix_fmt", "yuv420p", "-g", "1",
               "-c:a", "aac", "-shortest", str(path))
    return path


@pytest.fixture(scope="session")
def vse_depth(tmp_path_factory):
    """One .npy disparity map per frame of vse_clip: a left-right ramp 0..12 with a near square
    (disparity -2) where the moving square is."""
    import numpy as np

    folder = tmp_path_factory.mktemp("vse_depth")
    for i in range(VSE_N):
        d = np.tile(np.linspace(0.0, 12.0, VSE_W, dtype=np.float32), (VSE_H, 1))
        d[10:24, 4 + 3 * i:18 + 3 * i] = -2.0
        np.save(folder / f"d_{i:04d}.npy", d)
    return folder


@pytest.fixture(scope="session")
def vse_weights(tmp_path_factory, addon_package):
    """Untrained estimator weights (test only: the cache and the jobs do not care what it learnt)."""
    est = importlib.import_module(f"{PACKAGE}.rvr_addon.estimate.train")
    unet = importlib.import_module(f"{PACKAGE}.rvr_addon.estimate.unet")
    import torch

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("vse_weights") / "estimator.pt"
    return est.export_weights(unet.EstimatorNet(), path, iterations=0, wall_time_s=0.0, training={"note": "test"})


@pytest.fixture
def no_shipped_weights(addon_package, monkeypatch, tmp_path):
    """Pretend no weights ship (true today; kept true when they land)."""
    infer = importlib.import_module(f"{PACKAGE}.rvr_addon.estimate.infer")
    missing = tmp_path / "weights" / "estimator.pt"
    monkeypatch.setattr(infer, "SHIPPED_WEIGHTS", missing)
    monkeypatch.setattr(infer, "SHIPPED_ONNX", missing.with_suffix(".onnx"))  # nor their ONNX export
    return missing


@pytest.fixture
def use_prefs(addon_package, monkeypatch):
    """Callable setting the preferences the operators read (the add-on is not enabled here)."""
    prefs = importlib.import_module(f"{PACKAGE}.operators.prefs")

    def set_prefs(**kw):
        values = prefs.Defaults(**kw)
        monkeypatch.setattr(prefs, "get", lambda context=None: values)
        return values

    return set_prefs


@pytest.fixture
def saved_blend(registered, factory_scene, tmp_path):
    """The factory scene saved as tmp_path/project.blend (// paths resolve next to it)."""
    bpy = pytest.importorskip("bpy")
    path = tmp_path / "project.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


@pytest.fixture
def movie_strip(registered, saved_blend, vse_clip):
    """vse_clip as movie strip 'Clip' on channel 2 at scene frame 11, active."""
    bpy = pytest.importorskip("bpy")
    scene = bpy.context.scene
    scene.render.fps = VSE_FPS
    editor = scene.sequence_editor_create()
    strip = editor.strips.new_movie("Clip", str(vse_clip), channel=2, frame_start=11)
    editor.active_strip = strip
    strip.rvr.output_dir = "//renders/"
    strip.rvr.focus_disparity = 0.0  # set by hand: Render refuses a strip whose focus nobody set
    return strip


class Event:
    """A stand-in for a bpy event in modal() tests."""

    def __init__(self, kind, value="NOTHING"):
        self.type = kind
        self.value = value


class OperatorStub:
    """Stands in for an operator instance (to call execute()/modal() directly and see reports)."""

    def __init__(self, cls, **props):
        self._cls = cls
        self.reports = []
        self._timer = None
        self.__dict__.update(props)

    def report(self, level, message):
        self.reports.append((set(level), message))

    def __getattr__(self, name):
        value = getattr(self._cls, name)
        return value.__get__(self) if hasattr(value, "__get__") and callable(value) else value


def retime(strip, percent: float, frame: int | None = None) -> None:
    """Set the speed of the retiming segment of ``strip`` under ``frame`` (default: its first
    frame) to ``percent`` %, as Strip > Retiming > Set Speed does (4.5 and 5.x)."""
    import bpy

    scene = strip.id_data
    scene.sequence_editor.active_strip = strip
    strip.select = True
    workspace = bpy.context.workspace
    if hasattr(workspace, "sequencer_scene"):  # 5.0: the Sequencer edits the workspace's scene
        workspace.sequencer_scene = scene
    scene.frame_set(int(strip.frame_final_start) if frame is None else frame)
    with bpy.context.temp_override(scene=scene):
        assert bpy.ops.sequencer.retiming_segment_speed_set(speed=percent) == {"FINISHED"}


def image_folder(folder, count: int, size=(VSE_W, VSE_H)):
    """``count`` PNG frames f_0000.png... of noise (seeded) in ``folder``; returns the folder."""
    import cv2
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for i in range(count):
        cv2.imwrite(str(folder / f"f_{i:04d}.png"), rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8))
    return folder


def color_strip(strips, name: str, channel: int, frame_start: int, length: int):
    """A colour strip of ``length`` frames in ``strips`` (5.0 ``new_effect(length=)``, 4.5 ``frame_end=``)."""
    try:
        return strips.new_effect(name, "COLOR", channel=channel, frame_start=frame_start, length=length)
    except TypeError:  # 4.5
        return strips.new_effect(name, "COLOR", channel=channel, frame_start=frame_start,
                                 frame_end=frame_start + length)
