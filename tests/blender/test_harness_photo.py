"""The ``photo`` style of `python -m sintel_eval generate` on tiny clips (64x36, 1-4 samples):
photo textures recorded in the manifest, the fallback without a texture source, the dynamic
range of the lighting modes, and the people-like figures (mouth, jaw, joints, boxes)."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from rvr_addon.io.exr import read_exr  # noqa: E402
from sintel_eval import textures  # noqa: E402
from sintel_eval.dataset import GenerateConfig, generate  # noqa: E402

W, H = 64, 36
SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
LUMA = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def photo_root(tmp_path_factory) -> Path:
    """A texture folder: a few synthetic photos, plus one real Sintel frame (a link) when
    ../shared/data is on this machine."""
    root = tmp_path_factory.mktemp("texture_root")
    rng = np.random.default_rng(0)
    for k in range(3):
        img = cv2.resize(rng.integers(0, 256, (6, 9, 3), dtype=np.uint8), (180, 120), interpolation=cv2.INTER_CUBIC)
        assert cv2.imwrite(str(root / f"photo_{k}.png"), img)
    frames = sorted((SHARED_DATA / "sintel_frames").glob("*.png"))
    if frames:
        (root / frames[0].name).symlink_to(frames[0])
    return root


def _cfg(**kw) -> GenerateConfig:
    base = dict(seed=5, frames=1, width=W, height=H, script="enter", samples=2, dof_samples=1, train_samples=1,
                train_every=0, style="photo", lighting="day")
    base.update(kw)
    return GenerateConfig(**base)


@pytest.fixture(scope="module")
def photo_clip(tmp_path_factory, photo_root):
    out = tmp_path_factory.mktemp("photo") / "enter5"
    cache = tmp_path_factory.mktemp("texture_cache")
    cfg = _cfg(frames=3, lighting="day", textures=str(photo_root), texture_cache=str(cache))
    result = generate(out, cfg, progress=False)
    return out, result, json.loads((out / "manifest.json").read_text()), cache


def test_photo_style_renders_and_records_its_textures(photo_clip, photo_root):
    out, result, manifest, cache = photo_clip
    assert manifest["status"]["complete"] and result.look["style"] == "photo"
    assert manifest["config"]["style"] == "photo"
    look = manifest["scene"]["look"]
    assert look["style"] == "photo" and look["lighting"] == "day" and look["figures"] == "person"
    assert look["fallback"] is None and look["library"]["root"] == str(photo_root)
    slots = {t["slot"] for t in look["textures"]}
    assert {"wall", "floor"} <= slots and any(s.startswith("billboard_") for s in slots)
    lib = textures.discover(photo_root, cache)
    for t in look["textures"]:
        src = lib.get(t["source"])
        assert t["sha256"] == src.sha256 == textures.sha256_file(Path(src.file))
        assert (cache / "crops" / t["file"]).is_file()  # cut into the cache, not into the clip or the repo
    assert {s["name"] for s in look["sources"]} == {t["source"] for t in look["textures"]}
    assert all(len(s["sha256"]) == 64 for s in look["sources"])
    assert "billboards" in manifest["object_ids"].values()
    png = cv2.imread(str(out / "input" / "frame_00001.png"), cv2.IMREAD_COLOR)
    assert png.std() > 10  # a textured picture, not a flat one


def test_person_figures_keep_the_event_boxes(photo_clip):
    """Every pixel of a figure in the object-index pass lies in its recorded box, and the enter
    event still marks the frame its face comes in."""
    out, _, manifest, _ = photo_clip
    for name, subject in manifest["subjects"].items():
        for k, rec in enumerate(subject["per_frame"], start=1):
            ids = read_exr(out / "gt" / "disparity" / f"frame_{k:05d}.exr")["ID"]
            rows, cols = np.nonzero(np.round(ids) == subject["index"])
            x, y, w, h = rec["box"]
            if len(rows):
                assert cols.min() >= np.floor(x) - 1 and cols.max() + 1 <= np.ceil(x + w) + 1, (name, k)
                assert rows.min() >= np.floor(y) - 1 and rows.max() + 1 <= np.ceil(y + h) + 1, (name, k)
    main = manifest["scene"]["main"]
    assert manifest["subjects"][main]["per_frame"][0]["disparity"] == pytest.approx(0.0, abs=1e-9)


def test_resume_keeps_photo_frames(photo_clip):
    out, _, manifest, cache = photo_clip
    (out / "done" / "frame_00002.json").unlink()
    cfg = _cfg(frames=3, lighting="day", textures=manifest["config"]["textures"], texture_cache=str(cache))
    result = generate(out, cfg, progress=False)
    assert result.rendered == [2] and result.kept == [1, 3]


def test_missing_texture_source_falls_back_with_a_warning(tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(textures, "skimage_sources", lambda: [])
    missing = str(tmp_path / "no_such_folder")
    with caplog.at_level(logging.WARNING, logger="sintel_eval.dataset"):
        auto = generate(tmp_path / "auto", _cfg(style="auto", textures=missing, texture_cache=str(tmp_path / "c"),
                                                width=32, height=18, samples=1), progress=False)
    assert auto.look["style"] == "procedural" and auto.look["figures"] == "classic"
    assert "generating the procedural style instead" in caplog.text and "no_such_folder" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="sintel_eval.dataset"):
        photo = generate(tmp_path / "photo", _cfg(style="photo", textures=missing, width=32, height=18, samples=1,
                                                  texture_cache=str(tmp_path / "c")), progress=False)
    look = json.loads((tmp_path / "photo" / "manifest.json").read_text())["scene"]["look"]
    assert photo.look["style"] == "photo" and look["textures"] == [] and "procedural materials" in look["fallback"]
    assert "--style photo without a texture source" in caplog.text


def _hdr_luma(out: Path) -> np.ndarray:
    ch = read_exr(out / "gt" / "hdr" / "frame_00001.exr")
    return np.dstack([ch[c] for c in "RGB"]) @ LUMA


def test_lighting_modes_dynamic_range(tmp_path, photo_root):
    """Night: a dark frame (median far below display white) with emitters far above it; day:
    a bright frame; dim in between."""
    luma = {}
    for mode in ("day", "dim", "night"):
        out = tmp_path / mode
        generate(out, _cfg(lighting=mode, samples=4, textures=str(photo_root), texture_cache=str(tmp_path / "c")),
                 progress=False)
        luma[mode] = _hdr_luma(out)
        assert json.loads((out / "manifest.json").read_text())["scene"]["look"]["lighting"] == mode
    med = {m: float(np.median(v)) for m, v in luma.items()}
    print("median luma", med, "max", {m: float(v.max()) for m, v in luma.items()})
    assert luma["night"].max() > 10.0 and med["night"] < 0.03
    assert med["day"] > 0.08 and med["day"] > 4 * med["night"]
    assert med["day"] > med["dim"] > med["night"]


def test_person_mouth_jaw_and_walk_are_posed():
    """No render: the person rig's mouth opens, its jaw drops and its knees bend while walking."""
    from sintel_eval.bpy_util import reset_blender
    from sintel_eval.camera_math import Lens
    from sintel_eval.scene_builder import apply_frame, build_scene, subject_frame
    from sintel_eval.scene_plan import FOCAL_MM, SENSOR_WIDTH_MM
    from sintel_eval.scripts_events import make_plan

    reset_blender()
    plan = make_plan(2, "start-moving", 24, 24, style="photo", lighting="night", library=None)
    built = build_scene(plan, W, H)
    name = plan.main
    rig = built.rigs[name]
    assert {"jaw", "knee_l", "elbow_r", "shoulder_l"} <= set(rig.joints)
    lip = next(p for p in rig.parts if p.name.endswith("_lower_lip"))
    apply_frame(built, plan, 1, {name: [0.0, 1.0] * 12})
    closed = (rig.mouth.scale.z, float(lip.matrix_world.translation.z))
    lens = Lens(FOCAL_MM, SENSOR_WIDTH_MM, W, 1.0, 3.0)
    rec = subject_frame(built, name, lens, W, H)
    x, y, w, h = rec.box
    assert rec.face_in_frame and x <= rec.point[0] <= x + w and y <= rec.point[1] <= y + h
    apply_frame(built, plan, 2, {name: [0.0, 1.0] * 12})
    assert rig.mouth.scale.z > 3 * closed[0]
    assert float(lip.matrix_world.translation.z) < closed[1] - 0.005
    walker = plan.second
    frame = next(k for k in range(2, 25) if plan.character(walker).motion.moving(k))
    apply_frame(built, plan, frame + 3)
    knees = [built.rigs[walker].joints[f"knee_{s}"].rotation_euler.x for s in "lr"]
    assert max(knees) > 0.2
