"""Generate one ground-truth clip folder (format in sintel_eval/DATASET.md): resumable, atomic.

:func:`generate` builds the seeded scene in a fresh Blender state, measures every subject on
every frame (boxes, focus points, disparity), derives the events and focus tracks, writes the
manifest, then renders the frames that are not complete yet (pinhole deep pass, the DOF focus
tracks, training apertures on every ``train_every``-th frame) and finally the videos.

A frame is complete only when ``done/frame_%05d.json`` exists, carries the run's
``config_hash`` and every file it lists exists with the recorded size. The marker of a frame
is deleted before any of its files is rewritten and written last, atomically.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from rvr_addon.color import linear_to_srgb, to_uint8
from rvr_addon.errors import InputError, OutputError
from rvr_addon.io.exr import write_exr
from rvr_addon.pipeline import exponent_from_radiance

from .camera_math import Lens, affine_between, affine_to_blur
from .scene_plan import DEFAULT_TILT_DEG, FOCAL_MM, SENSOR_WIDTH_MM
from .scripts_events import SCRIPT_VERSIONS, SCRIPTS, check_script

FORMAT = "rvr-laaf-harness/1"
HARNESS_VERSION = 2  # bump when the scene generator changes what a seed renders (2: start_moving rule -> rack track)
STYLES = ("auto", "procedural", "photo")
LIGHTING_CHOICES = ("auto", "classic", "day", "dim", "night")
logger = logging.getLogger(__name__)
OUR_ENTRIES = ("manifest.json", "events.json", "input", "input.mp4", "audio", "gt", "dof", "train", "done")
TRACKS = ("constant", "rack")
MAX_SEED = 2 ** 32 - 1


def parse_seed(text: str | int) -> int:
    """A seed from the command line: a whole number 0..2^32-1, decimal or 0x-hex."""
    if isinstance(text, (int, np.integer)) and not isinstance(text, bool):
        value = int(text)
    else:
        s = str(text).strip().lower().replace("_", "")
        try:
            value = int(s, 16) if s.startswith("0x") else int(s, 10)
        except ValueError:
            raise InputError(f"--seed '{text}' is not a seed: give a whole number 0..{MAX_SEED} "
                             "(decimal like 7, or hex like 0x1f)") from None
    if not 0 <= value <= MAX_SEED:
        raise InputError(f"--seed {value} is out of range: use 0..{MAX_SEED}")
    return value


@dataclass(frozen=True)
class GenerateConfig:
    """Settings of one clip. samples: Cycles samples of the pinhole pass; dof_samples: of the
    DOF passes of the focus tracks (and of the focal triplet's second focus); train_samples:
    of the mid/small apertures of the aperture triplets (less blur, converge faster); f_numbers: (large, mid, small) -- the tracks use ``large``, the aperture
    triplet all three; f_number_ref: the f-number of aperture scale 1 (defines K);
    train_every: training passes on frames 1, 1 + n, ... (0 = none); pull_frames: length of
    the rack focus pull; fps: frame rate of the clip and its audio.

    style: "procedural" (the original look), "photo" (photo textures, people-like figures,
    varied lighting) or "auto" (photo when a texture source is found, else procedural, with a
    warning); lighting: "auto" (procedural: classic; photo: a seeded day, dim or night),
    "classic", "day", "dim" or "night"; textures: the texture folder (None: $RVR_TEXTURES or
    ../shared/data); texture_cache: where crops go (None: $RVR_TEXTURE_CACHE or
    ~/.cache/rvr-laaf/textures). See sintel_eval/DATASET.md "Looks".

    dof: render the shallow-DOF focus tracks (``dof/``); False (``--no-dof``) renders only the
    deep pass (input, GT disparity, HDR), e.g. event clips for AF-Net, and implies
    ``train_every = 0`` (the training triplets need the DOF passes)."""

    seed: int
    frames: int = 48
    width: int = 320
    height: int = 180
    script: str = "random"
    samples: int = 16
    dof_samples: int = 24
    train_samples: int = 16
    f_numbers: tuple[float, float, float] = (1.0, 2.8, 8.0)
    f_number_ref: float = 1.0
    train_every: int = 4
    pull_frames: int = 10
    denoise: bool = True
    fps: int = 24
    style: str = "procedural"
    lighting: str = "auto"
    textures: str | None = None
    texture_cache: str | None = None
    tilt_deg: tuple[float, float] = DEFAULT_TILT_DEG
    dof: bool = True

    def validated(self) -> "GenerateConfig":
        """A normalised copy; raises InputError naming the setting and the fix."""
        seed = parse_seed(self.seed)
        script = check_script(self.script)
        if int(self.frames) < 1:
            raise InputError(f"--frames {self.frames}: render at least 1 frame")
        if int(self.width) < 16 or int(self.height) < 9:
            raise InputError(f"--size {self.width}x{self.height}: use at least 16x9 pixels")
        if min(int(self.samples), int(self.dof_samples), int(self.train_samples)) < 1:
            raise InputError(f"--samples {self.samples} / --dof-samples {self.dof_samples} / --train-samples "
                             f"{self.train_samples}: use at least 1 sample")
        f_numbers = tuple(float(v) for v in self.f_numbers)
        if len(f_numbers) != 3 or not all(math.isfinite(v) and v > 0 for v in f_numbers):
            raise InputError(f"--f-numbers {self.f_numbers}: give three positive f-numbers LARGE,MID,SMALL "
                             "(aperture), e.g. 1.0,2.8,8.0")
        if not f_numbers[0] < f_numbers[1] < f_numbers[2]:
            raise InputError(f"--f-numbers {','.join(map(str, f_numbers))}: list them from the largest aperture "
                             "to the smallest (increasing f-numbers), e.g. 1.0,2.8,8.0")
        if not (math.isfinite(self.f_number_ref) and self.f_number_ref > 0):
            raise InputError(f"f_number_ref={self.f_number_ref}: must be a positive f-number")
        dof = bool(self.dof)
        if int(self.train_every) < 0:
            raise InputError(f"--train-every {self.train_every}: use 0 (no training passes) or a positive step")
        if int(self.pull_frames) < 1:
            raise InputError(f"--pull-frames {self.pull_frames}: a focus pull lasts at least 1 frame")
        if int(self.fps) < 1:
            raise InputError(f"fps={self.fps}: use a positive frame rate")
        style = str(self.style).strip().lower()
        if style not in STYLES:
            raise InputError(f"--style '{self.style}': use one of {', '.join(STYLES)}")
        lighting = str(self.lighting).strip().lower()
        if lighting not in LIGHTING_CHOICES:
            raise InputError(f"--lighting '{self.lighting}': use one of {', '.join(LIGHTING_CHOICES)}")
        tilt = tuple(float(v) for v in self.tilt_deg)
        if len(tilt) != 2 or not all(math.isfinite(v) for v in tilt) or not -30.0 <= tilt[0] <= tilt[1] <= 30.0:
            raise InputError(f"--tilt {self.tilt_deg}: give MIN,MAX camera tilt in degrees (positive = up), "
                             "MIN <= MAX, within -30..30, e.g. -12,0")
        return replace(self, seed=seed, style=style, lighting=lighting, tilt_deg=tilt,
                       textures=str(self.textures) if self.textures else None,
                       texture_cache=str(self.texture_cache) if self.texture_cache else None,
                       script=script, frames=int(self.frames), width=int(self.width),
                       height=int(self.height), samples=int(self.samples), dof_samples=int(self.dof_samples),
                       train_samples=int(self.train_samples),
                       f_numbers=f_numbers, f_number_ref=float(self.f_number_ref),
                       train_every=int(self.train_every) if dof else 0, dof=dof,
                       pull_frames=int(self.pull_frames), denoise=bool(self.denoise), fps=int(self.fps))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["f_numbers"] = list(self.f_numbers)
        d["tilt_deg"] = list(self.tilt_deg)
        return d

    @property
    def original_look(self) -> bool:
        """True for the original procedural look (no LookPlan): its hash is the one of earlier versions."""
        return self.style == "procedural" and self.lighting in ("auto", "classic")

    def config_hash(self, blender_version: str, texture_digest: str | None = None) -> str:
        """Identity of what the run renders (settings, generator version, Blender version; for a
        look other than the original one also the look's version and the texture library's
        content digest -- texture and cache paths are not part of it)."""
        from .look import LOOK_VERSION

        config = self.to_dict()
        for key in ("style", "lighting", "textures", "texture_cache"):
            config.pop(key)
        if tuple(self.tilt_deg) == DEFAULT_TILT_DEG:
            config.pop("tilt_deg")  # the hash of a default clip is the one of earlier versions
        if config.get("dof", True):
            config.pop("dof", None)  # likewise for a clip with its DOF passes
        blob = {"config": config, "format": FORMAT, "harness": HARNESS_VERSION, "blender": blender_version}
        script_version = SCRIPT_VERSIONS.get(self.script, 1)
        if script_version > 1:  # only scripts changed since: the others keep their earlier hash
            blob["script_version"] = script_version
        if not self.original_look:
            blob["look"] = {"style": self.style, "lighting": self.lighting, "version": LOOK_VERSION,
                            "textures": texture_digest}
        return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:16]


@dataclass
class GenerateResult:
    """What a run did: the folder, frames rendered now, frames kept from an earlier run,
    timings in seconds (per pass kind and total) and the look (style, lighting, figures)."""

    out: Path
    rendered: list[int]
    kept: list[int]
    timings: dict = field(default_factory=dict)
    look: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------- files


def frame_name(frame: int) -> str:
    return f"frame_{frame:05d}"


def f_label(f_number: float) -> str:
    return f"f{f_number:.1f}"


def _atomic_bytes(path: Path, data: bytes) -> None:
    from .bpy_util import atomic

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic(path, ".tmp" + path.suffix, lambda tmp: tmp.write_bytes(data))


def write_json(path: Path, obj) -> None:
    """Pretty JSON, atomically."""
    _atomic_bytes(Path(path), (json.dumps(obj, indent=1, allow_nan=False) + "\n").encode())


def write_png(path: Path, linear_rgb: np.ndarray) -> np.ndarray:
    """8-bit sRGB PNG of clipped linear radiance (exactly round(255 srgb(clip(L)))); returns it (RGB)."""
    import cv2

    img = to_uint8(linear_to_srgb(linear_rgb))
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]))
    if not ok:
        raise OutputError(f"cannot encode '{path}' as PNG")
    _atomic_bytes(Path(path), buf.tobytes())
    return img


def write_rgb_exr(path: Path, linear_rgb: np.ndarray) -> None:
    write_exr(path, {c: linear_rgb[..., i] for i, c in enumerate("RGB")})


def _with(base: Path, suffix: str) -> Path:
    """``base`` + suffix (``Path.with_suffix`` would eat the ".8" of "frame_00001_f2.8")."""
    return base.parent / (base.name + suffix)


def _copy(src: Path, dst: Path) -> None:
    from .bpy_util import atomic

    dst.parent.mkdir(parents=True, exist_ok=True)
    atomic(dst, ".tmp" + dst.suffix, lambda tmp: shutil.copyfile(src, tmp))


def frame_complete(out: Path, frame: int, config_hash: str) -> bool:
    """True when the frame's done marker is valid and every listed file has its recorded size."""
    marker = out / "done" / f"{frame_name(frame)}.json"
    try:
        data = json.loads(marker.read_text())
    except (OSError, ValueError):
        return False
    if data.get("config_hash") != config_hash or data.get("frame") != frame:
        return False
    files = data.get("files")
    if not isinstance(files, dict) or not files:
        return False
    for rel, size in files.items():
        p = out / rel
        try:
            if p.stat().st_size != size:
                return False
        except OSError:
            return False
    return True


def _remove_ours(out: Path) -> None:
    for name in OUR_ENTRIES:
        p = out / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def _remove_temp_files(out: Path) -> None:
    """Hidden temp files an interrupted run may have left in our folders."""
    for name in ("input", "gt", "dof", "train", "done", "audio"):
        folder = out / name
        if folder.is_dir():
            for p in folder.rglob(".*.tmp*"):
                p.unlink(missing_ok=True)
    for p in out.glob(".*.tmp*"):
        p.unlink(missing_ok=True)


def prepare_folder(out: Path, config_hash: str, config: GenerateConfig, force: bool) -> None:
    """Create ``out`` or check it can be resumed; ``force`` removes the harness' own entries
    (never anything else). Raises InputError naming the folder and the fix."""
    if out.exists() and not out.is_dir():
        raise InputError(f"-o '{out}' is a file: give a folder for the clip")
    manifest = out / "manifest.json"
    if out.is_dir():
        ours = [n for n in OUR_ENTRIES if (out / n).exists()]
        if force:
            _remove_ours(out)
        elif manifest.exists():
            try:
                old = json.loads(manifest.read_text())
            except (OSError, ValueError) as exc:
                raise InputError(f"'{manifest}' is unreadable ({exc}): pass --force to regenerate the clip") from exc
            if old.get("config_hash") != config_hash:
                was = old.get("config", {})
                diff = {k: (was.get(k), v) for k, v in config.to_dict().items() if was.get(k) != v}
                what = ", ".join(f"{k}: {a!r} -> {b!r}" for k, a, b in ((k, *ab) for k, ab in diff.items()))
                raise InputError(f"'{out}' holds a clip generated with other settings ({what or 'another generator or Blender version'}): "
                                 "pass --force to regenerate it, or choose another -o folder")
        elif ours:
            raise InputError(f"'{out}' has {', '.join(ours)} but no manifest.json: pass --force to regenerate "
                             "(removes only the harness' entries), or choose an empty -o folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create '{out}' ({exc}): choose a writable -o folder") from exc
    _remove_temp_files(out)


# --------------------------------------------------------------------------------------------- generate


def generate(out_dir: str | Path, config: GenerateConfig, force: bool = False, progress: bool = True,
             log: Callable[[str], None] | None = None) -> GenerateResult:
    """Generate (or resume) the clip ``config`` in ``out_dir``; see the module docstring."""
    from .bpy_util import bpy, reset_blender
    from .passes import PassRenderer, configure_cycles
    from .scene_builder import apply_frame, build_scene, subject_frame, world_to_camera
    from .scripts_events import detect_events, focus_tracks, make_plan, plan_rack

    t_start = time.perf_counter()
    cfg = config.validated()
    out = Path(out_dir)
    say = log or (lambda msg: None)
    cfg, library = resolve_style(cfg)
    chash = cfg.config_hash(bpy.app.version_string, library.digest if (library and cfg.style == "photo") else None)
    # -- the plan and the speech first: their errors (no espeak-ng, clip too short for two
    # turns) come before the folder is touched
    plan = make_plan(cfg.seed, cfg.script, cfg.frames, cfg.fps, style=cfg.style, lighting=cfg.lighting,
                     library=library, tilt_deg=cfg.tilt_deg)
    texture_files = cut_textures(plan, library)
    conversation = None
    if cfg.script == "conversation":
        from .speech import plan_conversation

        speakers = [c.name for c in plan.characters if c.speaker]
        conversation = plan_conversation(speakers, cfg.frames, cfg.fps, np.random.default_rng([cfg.seed, 7]))
    mouth = conversation.mouth if conversation else None
    prepare_folder(out, chash, cfg, force)

    # -- the scene and everything that does not need a render
    reset_blender()
    scene = bpy.context.scene
    render_settings = configure_cycles(scene, cfg.width, cfg.height, cfg.seed, cfg.denoise, cfg.fps)
    built = build_scene(plan, cfg.width, cfg.height, texture_files=texture_files)

    apply_frame(built, plan, 1, mouth)
    focal_mm = getattr(plan.camera, "focal_mm", FOCAL_MM)  # the conversation script's lens is longer
    probe = Lens(focal_mm, SENSOR_WIDTH_MM, cfg.width, cfg.f_number_ref, 1.0)
    s_ref = subject_frame(built, plan.main, probe, cfg.width, cfg.height).depth_m
    lens = Lens(focal_mm, SENSOR_WIDTH_MM, cfg.width, cfg.f_number_ref, s_ref)
    records = {c.name: [] for c in plan.characters}
    cameras = []
    for k in range(1, cfg.frames + 1):
        apply_frame(built, plan, k, mouth)
        for c in plan.characters:
            records[c.name].append(subject_frame(built, c.name, lens, cfg.width, cfg.height))
        m = np.array(built.camera.matrix_world, dtype=np.float64)
        cameras.append({"frame": k, "index": k - 1, "location_m": list(map(float, built.camera.location)),
                        "rotation_euler_rad": list(map(float, built.camera.rotation_euler)),
                        "matrix_world": m.tolist(), "world_to_camera": world_to_camera(built).tolist()})
    events = detect_events(plan, records, conversation.turns if conversation else None)
    rack = plan_rack(plan, events, cfg.pull_frames)
    f_large = cfg.f_numbers[0]
    tracks = focus_tracks(plan, records, lens, rack, f_large)
    t_build = time.perf_counter() - t_start

    manifest = _manifest(cfg, chash, plan, lens, built, records, cameras, events, rack, tracks, conversation,
                         render_settings)
    manifest["scene"]["look"] = look_record(plan, library, texture_files)
    old_runs = _old_runs(out / "manifest.json")
    manifest["runs"] = old_runs
    write_json(out / "manifest.json", manifest)
    write_json(out / "events.json", events)
    if conversation is not None:
        conversation.write(out / "audio")

    # -- frames
    renderer = PassRenderer(scene, built.camera, cfg.samples, cfg.dof_samples, built.radiance_cap)
    rendered, kept = [], []
    try:
        from tqdm import tqdm

        bar = tqdm(range(1, cfg.frames + 1), desc=f"generate {cfg.script} seed {cfg.seed}", unit="frame",
                   disable=not progress)
        for k in bar:
            if frame_complete(out, k, chash):
                kept.append(k)
                continue
            apply_frame(built, plan, k, mouth)
            _render_frame(out, k, cfg, chash, lens, renderer, tracks, render_settings["denoiser"])
            rendered.append(k)
    finally:
        renderer.close()

    # -- videos, tracks, status
    t0 = time.perf_counter()
    _finalize(out, cfg, tracks, conversation is not None)
    t_encode = time.perf_counter() - t0
    total = time.perf_counter() - t_start
    timings = {"build_s": t_build, "deep_s": renderer.timings["deep"], "dof_s": renderer.timings["dof"],
               "deep_renders": renderer.counts["deep"], "dof_renders": renderer.counts["dof"],
               "encode_s": t_encode, "total_s": total, "frames_rendered": len(rendered),
               "frames_kept": len(kept)}
    manifest["runs"] = old_runs + [{"timings_s": timings, "rendered": rendered}]
    manifest["timings_s"] = timings
    done = sum(frame_complete(out, k, chash) for k in range(1, cfg.frames + 1))
    manifest["status"] = {"complete": done == cfg.frames, "frames_done": done}
    write_json(out / "manifest.json", manifest)
    say(f"{out}: {len(rendered)} frame(s) rendered, {len(kept)} kept, {total:.1f} s")
    look = manifest["scene"]["look"]
    return GenerateResult(out, rendered, kept, timings, {k: look[k] for k in ("style", "lighting", "figures")}
                          | {"textures": len(look["textures"]), "fallback": look["fallback"]})


def resolve_style(cfg: GenerateConfig):
    """(config with a concrete style, texture library or None). ``auto`` becomes ``photo`` when
    the texture library has a source, else ``procedural``; ``photo`` without a source keeps its
    figures and lighting on procedural materials. Both fallbacks log a warning."""
    if cfg.style == "procedural":
        return cfg, None
    from .textures import discover

    library = discover(cfg.textures, cfg.texture_cache)
    if library:
        return replace(cfg, style="photo"), library
    why = "; ".join(library.notes) or "no images or clips found"
    if cfg.style == "auto":
        logger.warning("no photo texture source (%s): generating the procedural style instead", why)
        return replace(cfg, style="procedural"), None
    logger.warning("--style photo without a texture source (%s): procedural materials on the photo-style set", why)
    return cfg, library


def cut_textures(plan, library) -> dict:
    """slot -> crop file (in the texture cache) of every photo texture the plan chose."""
    from .textures import cut

    look = getattr(plan, "look", None)
    if look is None or not library or not look.textures:
        return {}
    try:
        return {slot: str(cut(library, use)) for slot, use in sorted(look.textures.items())}
    except OSError as exc:
        raise OutputError(f"cannot prepare the photo textures in '{library.cache}' ({exc}): choose a writable "
                          "--texture-cache folder") from exc


def look_record(plan, library, texture_files: dict) -> dict:
    """The manifest's ``scene.look``: style, lighting, figures, texture library and every texture
    used (slot, source name, sha256 of the source file, crop, cache file)."""
    from .textures import used_sources

    look = getattr(plan, "look", None)
    if look is None:
        return {"style": "procedural", "lighting": "classic", "figures": "classic", "textures": [], "sources": [],
                "library": None, "fallback": None}
    uses = [look.textures[s] for s in sorted(look.textures)] if texture_files else []
    return {"style": look.style, "lighting": look.lighting.mode, "figures": look.figures_model,
            "lighting_detail": asdict(look.lighting), "version": look.version,
            "textures": [asdict(u) | {"file": Path(texture_files[u.slot]).name} for u in uses],
            "sources": used_sources(library, uses) if uses else [],
            "library": library.describe() if library is not None else None, "fallback": look.fallback}


def _old_runs(path: Path) -> list:
    try:
        runs = json.loads(path.read_text()).get("runs", [])
        return runs if isinstance(runs, list) else []
    except (OSError, ValueError):
        return []


def _render_frame(out: Path, k: int, cfg: GenerateConfig, chash: str, lens: Lens, renderer, tracks: dict,
                  denoiser: str) -> None:
    """Render and write every file of frame ``k`` (posed already), then its done marker."""
    from .passes import LensSetting

    name = frame_name(k)
    marker = out / "done" / f"{name}.json"
    marker.unlink(missing_ok=True)  # from here on the frame is incomplete until the new marker lands
    files: list[Path] = []
    t0 = time.perf_counter()

    deep = renderer.render_deep()
    rgb = deep["rgb"]
    png = write_png(out / "input" / f"{name}.png", rgb)
    write_rgb_exr(out / "gt" / "hdr" / f"{name}.exr", rgb)
    disparity = lens.disparity(deep["z"])
    write_exr(out / "gt" / "disparity" / f"{name}.exr", {"D": disparity, "Z": deep["z"], "ID": deep["id"]})
    e = exponent_from_radiance(png, rgb)
    write_exr(out / "gt" / "exponent" / f"{name}.exr", {f"E.{c}": e[..., i] for i, c in enumerate("RGB")})
    files += [out / "input" / f"{name}.png", out / "gt" / "hdr" / f"{name}.exr",
              out / "gt" / "disparity" / f"{name}.exr", out / "gt" / "exponent" / f"{name}.exr"]

    made: dict[tuple, tuple[Path, Path]] = {}  # lens key -> (png, exr) already written this frame

    def lens_render(setting: LensSetting, png_path: Path, exr_path: Path, samples: int | None = None) -> str | None:
        """Render (or copy an identical lens' files); returns the source it was copied from."""
        key = setting.key()
        if key in made:
            src_png, src_exr = made[key]
            _copy(src_png, png_path)
            _copy(src_exr, exr_path)
            return str(src_png.relative_to(out))
        img = renderer.render_dof(setting, samples)
        write_png(png_path, img)
        write_rgb_exr(exr_path, img)
        made[key] = (png_path, exr_path)
        return None

    lens_meta = {"blades": 0, "ratio": 1.0, "samples": cfg.dof_samples, "denoiser": denoiser}
    for track in TRACKS if cfg.dof else ():  # --no-dof: the deep pass only
        rec = dict(tracks[track][k - 1])
        base = out / "dof" / track / name
        src = lens_render(LensSetting(rec["focus_distance_m"], rec["f_number"]), _with(base, ".png"),
                          _with(base, ".exr"))
        rec.update(lens_meta, copied_from=src)
        write_json(_with(base, ".json"), rec)
        files += [_with(base, ".png"), _with(base, ".exr"), _with(base, ".json")]

    if cfg.train_every and (k - 1) % cfg.train_every == 0:
        files += _training(out, k, cfg, lens, tracks, lens_render)

    sizes = {str(p.relative_to(out)): p.stat().st_size for p in files}
    write_json(marker, {"frame": k, "index": k - 1, "config_hash": chash, "files": sizes,
                        "seconds": time.perf_counter() - t0})


def _training(out: Path, k: int, cfg: GenerateConfig, lens: Lens, tracks: dict, lens_render) -> list[Path]:
    """Aperture triplet (large/mid/small f-numbers, one focus), focal triplet (input + large
    at the main focus + large at the second subject) and their sidecar; returns the files."""
    from .passes import LensSetting

    name = frame_name(k)
    const = tracks["constant"][k - 1]
    second = tracks["focusB"][k - 1]
    f_large, f_mid, f_small = cfg.f_numbers
    members: dict[str, dict] = {}
    files: list[Path] = []

    def member(role: str, png: Path, exr: Path, focus: float, s_f: float, f_number: float, subject: str,
               copied: str | None, samples: int) -> None:
        a = lens.aperture_scale(f_number)
        alpha, beta = affine_to_blur(focus, a)
        members[role] = {"png": str(png.relative_to(out)), "exr": str(exr.relative_to(out)),
                         "focus_disparity": focus, "aperture_scale": a, "focus_distance_m": s_f,
                         "f_number": f_number, "K_N_px": lens.k_for(f_number), "subject": subject,
                         "alpha": alpha, "beta": beta, "copied_from": copied, "samples": samples}

    dof = out / "dof" / "constant" / name
    member("large", _with(dof, ".png"), _with(dof, ".exr"), const["focus_disparity"],
           const["focus_distance_m"], f_large, const["subject"], None, cfg.dof_samples)
    for role, f_number in (("mid", f_mid), ("small", f_small)):
        base = out / "train" / f"{name}_{f_label(f_number)}"
        src = lens_render(LensSetting(const["focus_distance_m"], f_number), _with(base, ".png"),
                          _with(base, ".exr"), cfg.train_samples)
        member(role, _with(base, ".png"), _with(base, ".exr"), const["focus_disparity"],
               const["focus_distance_m"], f_number, const["subject"], src, cfg.train_samples)
        files += [_with(base, ".png"), _with(base, ".exr")]
    base = out / "train" / f"{name}_focusB"
    src = lens_render(LensSetting(second["focus_distance_m"], f_large), _with(base, ".png"),
                      _with(base, ".exr"))
    member("focusB", _with(base, ".png"), _with(base, ".exr"), second["focus_disparity"],
           second["focus_distance_m"], f_large, second["subject"], src, cfg.dof_samples)
    files += [_with(base, ".png"), _with(base, ".exr")]

    relations = []
    for a_role, b_role in (("large", "mid"), ("large", "small"), ("mid", "small"), ("large", "focusB")):
        a, b = members[a_role], members[b_role]
        alpha, beta = affine_between(a["focus_disparity"], a["aperture_scale"], b["focus_disparity"],
                                     b["aperture_scale"])
        relations.append({"from": a_role, "to": b_role, "alpha": alpha, "beta": beta})
    sidecar = {"frame": k, "index": k - 1, "input": f"input/{name}.png", "members": members,
               "aperture_pair": {"small": "small", "large": "large"},
               "aperture_triplet": ["large", "mid", "small"], "focal_triplet": ["input", "large", "focusB"],
               "relations": relations,
               "convention": "member: D_member = alpha * D + beta (signed blur radius px, r = |D_member|); "
                             "relations: D_to = alpha * D_from + beta"}
    path = out / "train" / f"{name}.json"
    write_json(path, sidecar)
    return files + [path]


def _finalize(out: Path, cfg: GenerateConfig, tracks: dict, with_audio: bool) -> None:
    """rvr_track.json per track, input.mp4 (with the speech track) and the track previews."""
    import cv2

    from rvr_addon.io.writer import VideoWriter

    tracks_done = TRACKS if cfg.dof else ()  # --no-dof: no dof/ folder at all
    for track in tracks_done:
        keys = [{"frame": r["index"], "focus": r["focus_disparity"], "aperture": r["aperture_scale"]}
                for r in tracks[track]]
        write_json(out / "dof" / track / "rvr_track.json", keys)
    audio = out / "audio" / "speech.wav" if with_audio else None
    for video, folder in [(out / "input.mp4", out / "input")] + [(out / "dof" / f"{t}.mp4", out / "dof" / t)
                                                                 for t in tracks_done]:
        with VideoWriter(video, cfg.fps, (cfg.width, cfg.height)) as writer:
            for k in range(1, cfg.frames + 1):
                img = cv2.imread(str(folder / f"{frame_name(k)}.png"), cv2.IMREAD_COLOR)
                if img is None:
                    raise OutputError(f"'{folder / frame_name(k)}.png' is missing or unreadable: re-run the "
                                      "same command to render it (or --force)")
                writer.write(np.ascontiguousarray(img[..., ::-1]))
        if audio is not None:
            mux_audio(video, audio)


def mux_audio(video: Path, wav: Path) -> None:
    """Add ``wav`` to ``video`` as its AAC track (cut or padded with silence to the video's
    length; the H.264 stream is copied untouched), replacing ``video`` atomically."""
    import subprocess

    from rvr_addon.io.paths import temp_sibling
    from rvr_addon.io.video import ffmpeg_exe

    tmp = temp_sibling(video, ".tmp.mp4")
    cmd = [ffmpeg_exe(), "-hide_banner", "-nostdin", "-v", "error", "-y", "-i", str(video), "-i", str(wav),
           "-map", "0:v:0", "-map", "1:a:0", "-c:v", "copy", "-af", "apad", "-c:a", "aac", "-b:a", "160k",
           "-shortest", "-movflags", "+faststart", "-f", "mp4", str(tmp)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0 or not tmp.is_file():
        tmp.unlink(missing_ok=True)
        raise OutputError(f"ffmpeg could not add the speech '{wav}' to '{video}': {done.stderr.strip()[-400:]}")
    os.replace(tmp, video)


def _manifest(cfg: GenerateConfig, chash: str, plan, lens: Lens, built, records: dict, cameras: list,
              events: list, rack, tracks: dict, conversation, render_settings: dict) -> dict:
    subjects = {}
    for c in plan.characters:
        subjects[c.name] = {
            "index": c.index, "role": c.role, "speaker": c.speaker, "motion": asdict(c.motion),
            "voice": conversation.voices.get(c.name) if conversation else None,
            "per_frame": [asdict(r) | {"frame": i + 1} for i, r in enumerate(records[c.name])],
            "mouth_open": [float(v) for v in conversation.mouth[c.name]] if conversation and c.speaker else None,
        }
    f_large = cfg.f_numbers[0]
    speech = None
    if conversation is not None:
        from .speech import SAMPLE_RATE

        speech = {"tool": "espeak-ng", "sample_rate": SAMPLE_RATE, "voices": conversation.voices,
                  "lines": conversation.lines, "turns": [asdict(t) for t in conversation.turns],
                  "audio": "audio/speech.wav", "per_speaker": {s: f"audio/{s}.wav" for s in conversation.speakers},
                  "vad": "RMS envelope (10 ms hops) above -32 dB of the speaker's peak, gaps < 0.25 s bridged"}
    return {
        "format": FORMAT,
        "harness_version": HARNESS_VERSION,
        "script_version": SCRIPT_VERSIONS.get(cfg.script, 1),
        "config": cfg.to_dict(),
        "config_hash": chash,
        "frames": cfg.frames, "width": cfg.width, "height": cfg.height, "fps": cfg.fps,
        "frame_numbering": "files and 'frame' fields are 1-based; 'index' and rvr_track.json are 0-based",
        "camera": {
            "focal_mm": lens.focal_mm, "sensor_width_mm": lens.sensor_width_mm,
            "sensor_height_mm": lens.sensor_width_mm * cfg.height / cfg.width, "sensor_fit": "HORIZONTAL",
            "f_px": lens.f_px, "f_number_ref": lens.f_number_ref, "K_px": lens.k_px, "s_ref_m": lens.s_ref_m,
            "K_units": "px * m: D = K * (1/S_ref - 1/S), S planar depth in m",
            "K_N_px": {f_label(n): lens.k_for(n) for n in cfg.f_numbers},
            "aperture_scale": {f_label(n): lens.aperture_scale(n) for n in cfg.f_numbers},
            "coc_convention": "Cycles thin lens: aperture radius f/(2N), image plane at f (no focus breathing); "
                              "blur radius r = (f/(2N)) * f * (W/sensor_width) * |1/S_f - 1/S| px; "
                              "focus f = K (1/S_ref - 1/S_f), aperture a = N_ref / N",
            "blades": 0, "ratio": 1.0, "rotation": 0.0,
            "projection": "pinhole; x = W/2 + f_px * Xc / Sc, y = H/2 - f_px * Yc / Sc with (Xc, Yc, -Sc) = "
                          "world_to_camera @ point (Blender camera looks along its -Z)",
            "scene_start_m": list(plan.camera.start),
        },
        "camera_per_frame": cameras,
        "disparity_units": "px blur radius at aperture 1, native width; + = behind the focal plane",
        "scene": {"seed": cfg.seed, "script": cfg.script, "plan": plan.to_dict(), "main": plan.main,
                  "second": plan.second, "emitters": built.emitters,
                  "radiance_cap": [float(v) for v in built.radiance_cap]},
        "object_ids": built.object_ids,
        "subjects": subjects,
        "events": events,
        "focus_tracks": {
            "constant": {"subject": plan.main, "f_number": f_large, "aperture_scale": lens.aperture_scale(f_large),
                         "frames": tracks["constant"]},
            "rack": {"from": rack.source, "to": rack.target, "pull_start": rack.start,
                     "pull_frames": rack.pull_frames, "shape": "smoothstep in disparity", "f_number": f_large,
                     "aperture_scale": lens.aperture_scale(f_large), "frames": tracks["rack"]},
            "focusB": {"subject": plan.second, "f_number": f_large, "frames": tracks["focusB"],
                       "use": "second focus target of the focal triplets"},
        },
        "passes": {
            "deep": {"lens": "pinhole", "samples": cfg.samples, "passes": ["Combined", "Z", "IndexOB"],
                     "files": ["input/frame_%05d.png", "gt/hdr/frame_%05d.exr", "gt/disparity/frame_%05d.exr",
                               "gt/exponent/frame_%05d.exr"]},
            "dof": {"tracks": list(TRACKS) if cfg.dof else [], "skipped": not cfg.dof,
                    "samples": cfg.dof_samples, "f_number": f_large,
                    "files": ["dof/<track>/frame_%05d.png", "dof/<track>/frame_%05d.exr",
                              "dof/<track>/frame_%05d.json"]},
            "train": {"every": cfg.train_every, "f_numbers": list(cfg.f_numbers),
                      "samples": {"large": cfg.dof_samples, "mid": cfg.train_samples, "small": cfg.train_samples,
                                  "focusB": cfg.dof_samples},
                      "frames": [k for k in range(1, cfg.frames + 1)
                                 if cfg.train_every and (k - 1) % cfg.train_every == 0]},
        },
        "speech": speech,
        "render": render_settings,
        "color": {"png": "sRGB 8-bit = round(255 * srgb_oetf(clip(L, 0, 1))), Standard view, no dither",
                  "exr": "scene-linear Rec.709 radiance, float32, clamped only to the brightest emitter"},
        "status": {"complete": False, "frames_done": None},
    }


__all__ = ["GenerateConfig", "GenerateResult", "generate", "parse_seed", "frame_complete", "SCRIPTS", "FORMAT",
           "write_png", "resolve_style", "STYLES", "LIGHTING_CHOICES"]
