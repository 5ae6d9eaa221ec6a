"""The harness' looks without Blender: the seeded look plan (style, lighting modes, figures,
photo textures), the texture library (discovery, crops, digests) and the config hash that keeps
the original procedural clips resumable."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sintel_eval import textures
from sintel_eval.dataset import FORMAT, HARNESS_VERSION, GenerateConfig
from sintel_eval.look import LIGHTINGS, kelvin_rgb, make_look
from sintel_eval.scripts_events import SCRIPTS, make_plan

SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def _photo(path: Path, seed: int, size=(96, 64), gray: bool = False) -> Path:
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.integers(0, 256, (8, 12, 3), dtype=np.uint8), size, interpolation=cv2.INTER_CUBIC)
    if gray:
        img = img[..., 0]
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)
    return path


@pytest.fixture
def library(tmp_path, ffmpeg_run, monkeypatch):
    """A texture root with two photos, a grey one and a 1 s clip; no scikit-image samples."""
    monkeypatch.setattr(textures, "skimage_sources", lambda: [])
    root = tmp_path / "data"
    _photo(root / "stills" / "a.png", 1)
    _photo(root / "stills" / "b.jpg", 2, size=(80, 80))
    _photo(root / "stills" / "grey.png", 3, gray=True)
    _photo(root / "motorcycle_left.png", 4)  # the estimator's test image: never a texture
    (root / "clips").mkdir()
    ffmpeg_run("-f", "lavfi", "-i", "testsrc2=size=64x48:rate=10", "-frames:v", "10", "-pix_fmt", "yuv420p",
               str(root / "clips" / "t.mp4"))
    return textures.discover(root, tmp_path / "cache")


def test_library_finds_photos_and_clip_frames(library, tmp_path):
    names = [s.name for s in library.sources]
    assert names == sorted(names)
    assert {"stills/a.png", "stills/b.jpg", "stills/grey.png"} <= set(names)
    assert not any("motorcycle" in n for n in names)
    frames = [s for s in library.sources if s.frame_time_s is not None]
    assert len(frames) == len(textures.CLIP_FRAME_FRACTIONS)
    clip = tmp_path / "data" / "clips" / "t.mp4"
    assert all(s.sha256 == textures.sha256_file(clip) and Path(s.image).is_file() for s in frames)
    assert all(Path(s.image).is_relative_to(tmp_path / "cache") for s in frames)  # never beside the sources
    assert library.get("stills/grey.png").gray and not library.get("stills/a.png").gray
    again = textures.discover(tmp_path / "data", tmp_path / "cache")
    assert again.digest == library.digest and again.sources == library.sources


def test_missing_root_is_an_empty_library_with_a_note(tmp_path, monkeypatch):
    monkeypatch.setattr(textures, "skimage_sources", lambda: [])
    lib = textures.discover(tmp_path / "nope", tmp_path / "cache")
    assert not lib and "not found" in lib.notes[0] and "--textures" in lib.notes[0]


def test_crops_are_deterministic_and_named_by_content(library):
    plan = make_plan(7, "enter", 24, 24, style="photo", lighting="day", library=library)
    uses = plan.look.textures
    assert {"wall", "floor"} <= set(uses) and any(k.startswith("billboard_") for k in uses)
    paths = {slot: textures.cut(library, use) for slot, use in uses.items()}
    for slot, path in paths.items():
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        assert img is not None and max(img.shape[:2]) <= textures.MAX_CROP_PX
        assert path.name == uses[slot].cache_name()
    first = {slot: p.read_bytes() for slot, p in paths.items()}
    for p in paths.values():
        p.unlink()
    assert {slot: textures.cut(library, u).read_bytes() for slot, u in uses.items()} == first
    use = uses["wall"]
    moved = type(use)(**{**use.__dict__, "rect": (0.0, 0.0, 0.5, 0.5)})
    assert moved.cache_name() != use.cache_name()


@pytest.mark.parametrize("script", SCRIPTS)
def test_the_look_changes_no_layout_motion_or_event_timing(script, library):
    base = make_plan(11, script, 48, 24)
    assert base.look is None
    photo = make_plan(11, script, 48, 24, style="photo", lighting="auto", library=library)
    a, b = base.to_dict(), photo.to_dict()
    assert b.pop("look") is not None and a.pop("look") is None
    assert a == b
    assert photo.to_dict() == make_plan(11, script, 48, 24, style="photo", library=library).to_dict()
    assert set(photo.look.figures) == {c.name for c in photo.characters}


def test_lighting_modes_order_their_light(library):
    plan = make_plan(3, "random", 48, 24)
    looks = {m: make_look(plan, "photo", m, library).lighting for m in ("day", "dim", "night")}
    day, dim, night = looks["day"], looks["dim"], looks["night"]
    assert day.world_strength > dim.world_strength > night.world_strength
    assert day.key_energy > dim.key_energy > night.key_energy
    assert night.bulb_gain > day.bulb_gain and night.strings and not day.strings
    assert any(lamp.kind == "street" for lamp in night.lamps) and all(lamp.kind == "floor" for lamp in day.lamps)
    assert night.world_kelvin > 9000 and dim.key_kelvin < 4000  # moonlit blue, warm tungsten
    modes = {make_look(make_plan(s, "enter", 24, 24), "photo", "auto", library).lighting.mode for s in range(40)}
    assert modes == {"day", "dim", "night"}
    assert make_look(plan, "procedural", "auto") is None and make_look(plan, "procedural", "classic") is None
    assert make_look(plan, "procedural", "night").figures_model == "classic"
    assert set(LIGHTINGS) == {"classic", "day", "dim", "night"}


def test_photo_without_sources_falls_back_to_procedural_materials():
    plan = make_plan(5, "enter", 24, 24, style="photo", lighting="dim", library=None)
    assert plan.look.textures == {} and not plan.look.billboards
    assert "procedural materials" in plan.look.fallback and plan.look.figures_model == "person"


def test_kelvin_colours():
    warm, white, cold = kelvin_rgb(2700), kelvin_rgb(6500), kelvin_rgb(12000)
    assert warm[0] == 1.0 and warm[2] < 0.3 * warm[0]
    assert min(white) > 0.9
    assert cold[2] == 1.0 and cold[0] < 0.8


def test_config_hash_of_the_original_look_is_unchanged():
    """Clips generated before the looks existed keep their hash (they resume, not regenerate)."""
    cfg = GenerateConfig(seed=7).validated()
    legacy = {k: v for k, v in cfg.to_dict().items()
              if k not in ("style", "lighting", "textures", "texture_cache", "tilt_deg", "dof")}
    blob = json.dumps({"config": legacy, "format": FORMAT, "harness": HARNESS_VERSION, "blender": "5.0.1"},
                      sort_keys=True)
    assert cfg.config_hash("5.0.1") == hashlib.sha256(blob.encode()).hexdigest()[:16]
    photo = GenerateConfig(seed=7, style="photo").validated()
    assert photo.config_hash("5.0.1", "aa") != cfg.config_hash("5.0.1")
    assert photo.config_hash("5.0.1", "aa") != photo.config_hash("5.0.1", "bb")  # other texture sources
    night = GenerateConfig(seed=7, style="photo", lighting="night").validated()
    assert night.config_hash("5.0.1", "aa") != photo.config_hash("5.0.1", "aa")
    moved = GenerateConfig(seed=7, style="photo", textures="/elsewhere", texture_cache="/tmp/x").validated()
    assert moved.config_hash("5.0.1", "aa") == photo.config_hash("5.0.1", "aa")  # paths are not identity
    assert GenerateConfig(seed=7, tilt_deg=(0.5, 2.5)).validated().config_hash("5.0.1") == cfg.config_hash("5.0.1")
    assert GenerateConfig(seed=7, tilt_deg=(-14, 0)).validated().config_hash("5.0.1") != cfg.config_hash("5.0.1")
    assert GenerateConfig(seed=7, dof=False).validated().config_hash("5.0.1") != cfg.config_hash("5.0.1")


def test_camera_tilt_range():
    """--tilt draws the camera tilt from its range; the default range keeps the earlier plans."""
    import math

    default = make_plan(11, "random", 24, 24)
    assert 0.5 <= math.degrees(default.camera.tilt) <= 2.5
    down = make_plan(11, "random", 24, 24, tilt_deg=(-14.0, -10.0))
    assert -14.0 <= math.degrees(down.camera.tilt) <= -10.0
    assert down.camera.yaw_end == default.camera.yaw_end  # the same draws, only the tilt moves
    with pytest.raises(Exception, match="--tilt"):
        GenerateConfig(seed=7, tilt_deg=(5, -5)).validated()


@pytest.mark.parametrize("change, message", [({"style": "cartoon"}, "--style 'cartoon'"),
                                             ({"lighting": "noon"}, "--lighting 'noon'")])
def test_look_settings_errors(change, message):
    from rvr_addon.errors import InputError

    with pytest.raises(InputError, match=message):
        GenerateConfig(seed=1, **change).validated()


@pytest.mark.skipif(not (SHARED_DATA / "sintel_frames").is_dir(), reason="../shared/data is not on this machine")
def test_real_sources_from_shared_data(tmp_path, monkeypatch):
    """One Sintel frame and one real clip (linked, not copied): names, hashes and frames."""
    monkeypatch.setattr(textures, "skimage_sources", lambda: [])
    root = tmp_path / "data"
    (root / "clips").mkdir(parents=True)
    frame = sorted((SHARED_DATA / "sintel_frames").glob("*.png"))[0]
    clip = SHARED_DATA / "clips" / "lipnet_grid_lwbsza.mpg"
    (root / frame.name).symlink_to(frame)
    (root / "clips" / clip.name).symlink_to(clip)
    lib = textures.discover(root, tmp_path / "cache")
    assert [s.name for s in lib.sources][-1] == frame.name
    assert lib.get(frame.name).sha256 == textures.sha256_file(frame) and lib.get(frame.name).width == 1024
    clip_frames = [s for s in lib.sources if s.name.startswith("clips/")]
    assert len(clip_frames) == 4 and all(s.width == 360 for s in clip_frames)
