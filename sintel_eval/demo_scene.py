"""A small procedural ground-truth scene rendered with Cycles (CPU) through the bpy module.

`render_demo_scene` builds the scene from a fresh factory state, renders a short clip with a
pinhole (deep depth of field) camera and writes, per frame (numbered from 1):

- ``frames/frame_%05d.png``    8-bit sRGB, highlights clipped (Standard view transform);
- ``hdr/frame_%05d.exr``       scene-linear radiance (Combined pass), channels R, G, B float32;
- ``disparity/frame_%05d.npy`` float32 (H, W) signed disparity in DESIGN units,
  ``D = K * (1/S_ref - 1/S)`` with S the planar depth of Cycles' Z pass;
- ``meta.json``                the camera constants (K, S_ref, ...) and the scene's ground truth.

Geometry (metres, Blender world axes, Z up). The camera looks along +Y with its image plane
parallel to the XZ plane (no rotation other than the fixed +90 deg about X, no lens shift), so
planes of constant y are fronto-parallel: planar depth is simply ``S = y - camera_y``. The camera
trucks slowly to +x and dollies slowly to +y; its orientation never changes, so the far wall
stays fronto-parallel and its planar depth is known exactly on every frame.

Cycles' Z pass for a perspective camera is the planar depth (distance along the view axis), not
the radial distance to the camera centre: verified on a fronto-parallel plane, whose Z is
constant to float precision out to the image corners, where a radial distance would be 2.1%
larger with this lens (tests/blender/test_demo_scene.py checks it on the far wall every run).

The notional "aperture scale 1" lens is the render camera's own 100 mm lens on a 36 mm wide
sensor at f/1.0 focused at the subject's eye plane S_ref = 2.0 m; its exact thin-lens constant is

    K = (A / 2) * v * (W_px / sensor_width),   A = f / N,   v = f * S_ref / (S_ref - f)

(A, v, f, sensor width in mm; divided by 1000 to express K in px * m so that
``D = K * (1/S_ref - 1/S)`` takes S in metres). The far wall at 20 m then blurs with a radius of
about 7% of the frame width at aperture scale 1.
"""
from __future__ import annotations

import json
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rvr_addon.errors import InputError, OutputError
from rvr_addon.io.exr import write_exr

from .bpy_util import aim as _aim
from .bpy_util import atomic as _atomic
from .bpy_util import bpy
from .bpy_util import box as _box
from .bpy_util import cylinder as _cylinder
from .bpy_util import emission_material as _emission_material
from .bpy_util import quad as _quad
from .bpy_util import read_multilayer as _read_multilayer
from .bpy_util import reset_blender
from .bpy_util import set_image_settings as _set_image_settings
from .bpy_util import setup_render as _setup_render
from .bpy_util import sphere as _sphere
from .bpy_util import working_space as _working_space
from .materials import demo_library as _materials

# ---------------------------------------------------------------------------------------------
# Camera and scene constants (metres unless suffixed _mm)

FOCAL_MM = 100.0
SENSOR_WIDTH_MM = 36.0
F_NUMBER = 1.0
S_REF_M = 2.0  # planar depth of the subject's eye plane (front of the head) on frame 1
FPS = 24

CAMERA_START = (0.0, 0.0, 1.5)
CAMERA_TRUCK_M_PER_FRAME = 0.002  # +x
CAMERA_DOLLY_M_PER_FRAME = 0.0015  # +y, towards the scene

WALL_Y = 20.0  # the far wall is the plane y = WALL_Y (fronto-parallel)
WALL_X = (-20.0, 20.0)
WALL_Z = (-1.0, 12.0)

HEAD_RADIUS = 0.09
HEAD_CENTRE = (-0.13, S_REF_M + HEAD_RADIUS, 1.52)  # the head's front point is at y = S_REF_M
SUBJECT_POINT = (HEAD_CENTRE[0], S_REF_M, HEAD_CENTRE[2])  # "subject centre": front of the head

BALL_RADIUS = 0.18  # the moving mid-ground object

EMITTER_COUNT = 10
EMITTER_STRENGTH = (40.0, 150.0)  # Emission strength; radiance = strength * colour (max channel 1)
EMITTER_RADIUS = (0.035, 0.055)
EMITTER_DEPTH = (12.0, 18.5)
EMITTER_CHECK_FRAMES = (1, 24, 48)  # fixed, so the scene does not depend on the number of frames


def camera_k_px(width_px: int, focal_mm: float = FOCAL_MM, f_number: float = F_NUMBER,
                sensor_width_mm: float = SENSOR_WIDTH_MM, s_ref_m: float = S_REF_M) -> float:
    """Thin-lens disparity constant K in px * m, so that ``D = K * (1/S_ref - 1/S)`` (S in m)."""
    f = focal_mm
    s_ref_mm = s_ref_m * 1000.0
    aperture_mm = f / f_number
    image_distance_mm = f * s_ref_mm / (s_ref_mm - f)
    k_px_mm = (aperture_mm / 2.0) * image_distance_mm * (width_px / sensor_width_mm)
    return k_px_mm / 1000.0


def disparity_from_depth(depth_m: np.ndarray, k_px: float, s_ref_m: float = S_REF_M) -> np.ndarray:
    """Planar depth (m) -> signed disparity (px at aperture scale 1), float32."""
    s = np.maximum(np.asarray(depth_m, dtype=np.float64), 1e-6)
    return (k_px * (1.0 / s_ref_m - 1.0 / s)).astype(np.float32)


def camera_position(frame: int) -> tuple[float, float, float]:
    """World position of the camera on frame ``frame`` (1-based)."""
    t = frame - 1
    x0, y0, z0 = CAMERA_START
    return (x0 + CAMERA_TRUCK_M_PER_FRAME * t, y0 + CAMERA_DOLLY_M_PER_FRAME * t, z0)


def project(point, frame: int, width: int, height: int) -> tuple[float, float, float]:
    """World point -> (column, row, planar depth); continuous pixel coordinates (0 = left/top edge)."""
    cx, cy, cz = camera_position(frame)
    depth = point[1] - cy
    fpx = FOCAL_MM / SENSOR_WIDTH_MM * width
    col = width / 2.0 + fpx * (point[0] - cx) / depth
    row = height / 2.0 - fpx * (point[2] - cz) / depth
    return col, row, depth


def ball_transform(frame: int) -> tuple[tuple[float, float, float], float]:
    """Moving mid-ground ball: position and roll angle (about y) on frame ``frame``."""
    t = frame - 1
    x = -0.05 + 0.018 * t
    z = 1.30 + 0.12 * abs(math.sin(0.25 * t))
    return (x, 5.0, z), -(0.018 * t) / BALL_RADIUS


# ---------------------------------------------------------------------------------------------
# Small scene-building helpers (bmesh geometry, node materials)

@dataclass
class _Emitter:
    position: tuple[float, float, float]
    radius: float
    radiance: tuple[float, float, float]


def _build_scene(rng: np.random.Generator) -> tuple[dict, list[_Emitter]]:
    mats = _materials(rng)
    objs = {}

    # Far backdrop: a fronto-parallel brick wall and a floor; no camera ray reaches the world.
    x0, x1 = WALL_X
    z0, z1 = WALL_Z
    objs["wall"] = _quad("wall", [(x0, WALL_Y, z0), (x1, WALL_Y, z0), (x1, WALL_Y, z1), (x0, WALL_Y, z1)],
                         mats["wall"])
    objs["floor"] = _quad("floor", [(x0, -3.0, 0.0), (x1, -3.0, 0.0), (x1, WALL_Y, 0.0), (x0, WALL_Y, 0.0)],
                          mats["floor"])

    # Foreground subject: head-and-shoulders bust from primitives, eye plane at S_REF_M.
    hx, hy, hz = HEAD_CENTRE
    r = HEAD_RADIUS
    objs["head"] = _sphere("head", r, HEAD_CENTRE, mats["skin"], segments=48, scale=(0.9, 1.0, 1.15))
    _sphere("hair", r * 1.06, (hx, hy + 0.022, hz + 0.03), mats["hair"], segments=48, scale=(0.93, 0.95, 1.12))
    for side in (-1.0, 1.0):
        _sphere(f"eye_{'lr'[side > 0]}", 0.011, (hx + side * 0.03, S_REF_M + 0.012, hz + 0.018), mats["eye"], 16)
    _sphere("nose", 0.014, (hx, S_REF_M + 0.006, hz - 0.035), mats["skin"], 16)
    _cylinder("neck", 0.045, 1.25, hz - 0.06, (hx, hy + 0.01), mats["skin"])
    _sphere("shoulders", 1.0, (hx, hy + 0.03, 1.27), mats["sweater"], segments=48, scale=(0.21, 0.12, 0.09))
    _cylinder("torso", 0.17, 0.6, 1.27, (hx, hy + 0.03), mats["sweater"], segments=32)

    # Mid-ground (4-6 m): a wooden crate-column, a marble pillar and a moving ball.
    objs["crate"] = _box("crate", (0.55, 0.55, 1.55), (0.55, 4.6, 0.775), mats["wood"])
    objs["pillar"] = _cylinder("pillar", 0.22, 0.0, 3.2, (-0.62, 5.6), mats["marble"], segments=48)
    objs["ball"] = _sphere("ball", BALL_RADIUS, ball_transform(1)[0], mats["ball"], segments=40)

    # Thin structures: poles (various depths) and a few hanging strands.
    poles = [(0.30, 3.0, 0.008), (-0.40, 7.5, 0.010), (0.85, 9.0, 0.012), (-1.05, 11.0, 0.015)]
    for i, (px, py, pr) in enumerate(poles):
        px += float(rng.uniform(-0.05, 0.05))
        _cylinder(f"pole_{i}", pr, 0.0, 5.0, (px, py), mats["pole"], segments=12)
    for i in range(3):
        sy = float(rng.uniform(3.2, 4.2))
        sx = float(rng.uniform(-0.45, 0.55)) * sy / 3.5
        _cylinder(f"strand_{i}", 0.0025, float(rng.uniform(0.6, 1.1)), 4.0, (sx, sy), mats["wire"], segments=8)

    # Small, very bright emitters in front of the wall (bokeh balls), placed where the scene does
    # not hide them from the camera (ray casts from frames 1, 24 and 48).
    emitters = _place_emitters(rng, objs["ball"])

    # Lights: a soft key on the subject, a dim warm sun for the set, a dusky sky for fill.
    key_data = bpy.data.lights.new("key", type="AREA")
    key_data.energy = 28.0
    key_data.size = 0.8
    key_data.color = (1.0, 0.93, 0.85)
    key = bpy.data.objects.new("key", key_data)
    key.location = (-0.95, 0.9, 2.05)
    _aim(key, HEAD_CENTRE)
    bpy.context.scene.collection.objects.link(key)

    sun_data = bpy.data.lights.new("sun", type="SUN")
    sun_data.energy = 2.2
    sun_data.angle = math.radians(4.0)
    sun_data.color = (1.0, 0.8, 0.6)
    sun = bpy.data.objects.new("sun", sun_data)
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(200.0))
    bpy.context.scene.collection.objects.link(sun)

    world = bpy.data.worlds.new("dusk")
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.30, 0.38, 0.55, 1.0)
    bg.inputs["Strength"].default_value = 0.8
    bpy.context.scene.world = world
    return objs, emitters


def _place_emitters(rng: np.random.Generator, ball) -> list[_Emitter]:
    from mathutils import Vector

    scene = bpy.context.scene
    ball_location = tuple(ball.location)

    def visible(point, radius) -> bool:
        for frame in EMITTER_CHECK_FRAMES:
            origin = Vector(camera_position(frame))
            centre = Vector(ball_transform(frame)[0])
            for dx, dz in ((0, 0), (1.5, 0), (-1.5, 0), (0, 1.5), (0, -1.5)):
                target = Vector(point) + Vector((dx * radius, 0.0, dz * radius))
                ray = target - origin
                direction = ray.normalized()
                # The moving ball (analytically, at this frame's position) ...
                t = (centre - origin).dot(direction)
                if (origin + t * direction - centre).length < BALL_RADIUS * 1.1:
                    return False
                # ... and every static object (the ball itself is parked out of the way).
                hit, *_ = scene.ray_cast(depsgraph, origin, direction, distance=ray.length)
                if hit:
                    return False
        return True

    ball.location = (0.0, -50.0, -50.0)
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()

    palette = np.array([[1.0, 0.78, 0.45], [1.0, 0.55, 0.25], [1.0, 0.92, 0.75], [0.55, 0.80, 1.0],
                        [1.0, 0.45, 0.55], [0.75, 1.0, 0.60]])
    fx = FOCAL_MM / SENSOR_WIDTH_MM  # focal length in units of the frame width
    emitters: list[_Emitter] = []
    for _ in range(400):
        if len(emitters) == EMITTER_COUNT:
            break
        # Uniform over the frame (normalised image coordinates, 16:9) and over depth.
        u, v = rng.uniform(-0.45, 0.45), rng.uniform(-0.42, 0.30) * 9.0 / 16.0
        ey = float(rng.uniform(*EMITTER_DEPTH))
        cx, cy, cz = camera_position(1)
        point = (cx + u / fx * (ey - cy), ey, cz - v / fx * (ey - cy))
        radius = float(rng.uniform(*EMITTER_RADIUS))
        rgb = np.clip(palette[rng.integers(len(palette))] * rng.uniform(0.9, 1.1, 3), 0.0, None)
        rgb = rgb / rgb.max()
        strength = float(rng.uniform(*EMITTER_STRENGTH))
        if not visible(point, radius) or any(_overlap(point, radius, e) for e in emitters):
            continue
        i = len(emitters)
        mat = _emission_material(f"emitter_{i}", tuple(float(c) for c in rgb), strength)
        obj = _sphere(f"emitter_{i}", radius, point, mat, segments=12)
        obj.visible_diffuse = obj.visible_glossy = obj.visible_transmission = False
        obj.visible_shadow = obj.visible_volume_scatter = False
        emitters.append(_Emitter(point, radius, tuple(float(c) for c in rgb * strength)))
        bpy.context.view_layer.update()
        depsgraph = bpy.context.evaluated_depsgraph_get()  # later lights must not hide behind this one
    ball.location = ball_location
    return emitters


def _overlap(point, radius: float, other: _Emitter) -> bool:
    """Would two emitters touch (with a margin) in the image on one of the checked frames?"""
    for frame in EMITTER_CHECK_FRAMES:
        cx, cy, cz = camera_position(frame)
        a = np.array([(point[0] - cx) / (point[1] - cy), (point[2] - cz) / (point[1] - cy)])
        q = other.position
        b = np.array([(q[0] - cx) / (q[1] - cy), (q[2] - cz) / (q[1] - cy)])
        if np.linalg.norm(a - b) < 2.0 * (radius / (point[1] - cy) + other.radius / (q[1] - cy)):
            return True
    return False


def render_demo_scene(out_dir, frames: int = 24, size: tuple[int, int] = (384, 216), samples: int = 16,
                      seed: int = 0, progress: bool = True, denoise: bool = True) -> Path:
    """Build the procedural demo scene in a fresh bpy state and render it; returns ``out_dir``.

    Resets Blender to factory settings (empty), renders ``frames`` frames at ``size`` (W, H)
    with ``samples`` Cycles samples on the CPU and writes frames/, hdr/, disparity/ and
    meta.json into ``out_dir`` (see the module docstring).
    """
    width, height = (int(v) for v in size)
    if int(frames) < 1:
        raise InputError(f"frames={frames}: render at least 1 frame (--frames N with N >= 1)")
    if width < 16 or height < 9:
        raise InputError(f"size={width}x{height}: use at least 16x9 pixels (--size WxH)")
    if int(samples) < 1:
        raise InputError(f"samples={samples}: use at least 1 sample (--samples S)")
    frames, samples, seed = int(frames), int(samples), int(seed)

    out = Path(out_dir)
    dirs = {k: out / k for k in ("frames", "hdr", "disparity")}
    try:
        for d in dirs.values():
            d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output folders ({exc}); choose a writable -o DIR") from exc

    _remove_stale_frames(dirs, frames)
    from tqdm import tqdm

    reset_blender()
    scene = bpy.context.scene
    rng = np.random.default_rng(seed)
    denoiser = _setup_render(scene, width, height, samples, seed, denoise)

    cam_data = bpy.data.cameras.new("camera")
    cam_data.type = "PERSP"
    cam_data.lens_unit = "MILLIMETERS"
    cam_data.lens = FOCAL_MM
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = SENSOR_WIDTH_MM
    cam_data.sensor_height = SENSOR_WIDTH_MM * height / width
    cam_data.shift_x = cam_data.shift_y = 0.0
    cam_data.clip_start = 0.05
    cam_data.clip_end = 1000.0
    cam_data.dof.use_dof = False  # pinhole: deep depth of field
    camera = bpy.data.objects.new("camera", cam_data)
    camera.rotation_euler = (math.pi / 2.0, 0.0, 0.0)  # look along +Y, image plane parallel to XZ
    scene.collection.objects.link(camera)
    scene.camera = camera

    objs, emitters = _build_scene(rng)
    ball = objs["ball"]
    scene.frame_start, scene.frame_end = 1, frames

    k_px = camera_k_px(width)
    radiance_cap = np.max([e.radiance for e in emitters], axis=0).astype(np.float32)
    subject_d: list[float] = []
    wall_d_measured: list[float] = []
    hdr_max = 0.0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rvr_demo_") as tmp_dir:
        tmp_exr = Path(tmp_dir) / "render.exr"
        for frame in tqdm(range(1, frames + 1), desc="render demo", unit="frame", disable=not progress):
            scene.frame_set(frame)
            camera.location = camera_position(frame)
            loc, roll = ball_transform(frame)
            ball.location = loc
            ball.rotation_euler = (0.0, roll, 0.0)
            bpy.ops.render.render(write_still=False)
            result = bpy.data.images["Render Result"]
            _set_image_settings(scene, "exr")
            result.save_render(str(tmp_exr), scene=scene)
            _set_image_settings(scene, "png")
            png_path = dirs["frames"] / f"frame_{frame:05d}.png"
            _atomic(png_path, ".tmp.png", lambda tmp: result.save_render(str(tmp), scene=scene))

            rgb, z = _read_multilayer(tmp_exr)
            if rgb.shape[:2] != (height, width):
                raise OutputError(f"{tmp_exr}: render is {rgb.shape[1]}x{rgb.shape[0]}, expected {width}x{height}")
            # No surface is brighter than the brightest emitter: OpenImageDenoise can overshoot
            # on tiny very bright discs (up to ~30% at low sample counts); cut that ringing.
            rgb = np.minimum(rgb, radiance_cap)
            write_exr(dirs["hdr"] / f"frame_{frame:05d}.exr", {c: rgb[..., i] for i, c in enumerate("RGB")})
            disp = disparity_from_depth(z, k_px)
            _atomic(dirs["disparity"] / f"frame_{frame:05d}.npy", ".tmp.npy", lambda tmp: np.save(tmp, disp))
            hdr_max = max(hdr_max, float(rgb.max()))

            col, row, _ = project(SUBJECT_POINT, frame, width, height)
            c, r_ = int(col), int(row)
            subject_d.append(float(np.median(disp[max(r_ - 1, 0):r_ + 2, max(c - 1, 0):c + 2])))
            wall = z > 0.99 * (WALL_Y - camera_position(frame)[1])
            wall[height // 2:] = False  # the floor meets the wall below the horizon
            if wall.any():
                wall_d_measured.append(float(np.median(disp[wall])))
    elapsed = time.perf_counter() - t0

    wall_depth_1 = WALL_Y - camera_position(1)[1]
    meta = {
        "frames": frames,
        "width": width,
        "height": height,
        "fps": FPS,
        "seed": seed,
        "camera": {
            "focal_mm": FOCAL_MM,
            "sensor_width_mm": SENSOR_WIDTH_MM,
            "f_number": F_NUMBER,
            "s_ref_m": S_REF_M,
            "K_px": k_px,
            "K_units": "px * m: D = K * (1/S_ref - 1/S), S planar depth in m",
            "aperture_mm": FOCAL_MM / F_NUMBER,
            "image_distance_mm": FOCAL_MM * S_REF_M * 1000.0 / (S_REF_M * 1000.0 - FOCAL_MM),
            "sensor_fit": "HORIZONTAL",
            "projection": "pinhole, looks along +Y, no shift; col = W/2 + fpx*(x-cx)/S, row = H/2 - fpx*(z-cz)/S",
            "f_px": FOCAL_MM / SENSOR_WIDTH_MM * width,
        },
        "disparity_units": "px blur radius at aperture 1, native width",
        "depth_source": "Cycles Z pass: planar depth along the view axis, one point sample per pixel "
                        "(never averaged across an edge)",
        "subject_disparity": subject_d[0],
        "subject_disparity_per_frame": subject_d,
        "background_disparity": float(k_px * (1.0 / S_REF_M - 1.0 / wall_depth_1)),
        "background_disparity_measured": wall_d_measured[0] if wall_d_measured else None,
        "background_blur_fraction_of_width": float(k_px * (1.0 / S_REF_M - 1.0 / wall_depth_1)) / width,
        "emitter_radiance_max": max(max(e.radiance) for e in emitters),
        "hdr_max": hdr_max,
        "hdr_clamp": [float(c) for c in radiance_cap],
        "emitters": [{"position_m": list(e.position), "radius_m": e.radius, "radiance": list(e.radiance)}
                     for e in emitters],
        "wall_plane_y_m": WALL_Y,
        "subject_point_m": list(SUBJECT_POINT),
        "camera_positions_m": [list(camera_position(f)) for f in range(1, frames + 1)],
        "color": {"frames": "sRGB 8-bit, view transform Standard, look None, clipped, no dither",
                  "hdr": "scene-linear radiance (Cycles Combined pass, before the view transform)",
                  "scene_linear": _working_space()},
        "render": {"engine": "CYCLES", "device": "CPU", "samples": samples, "denoiser": denoiser,
                   "blender": bpy.app.version_string, "seconds": elapsed},
    }
    _atomic(out / "meta.json", ".tmp", lambda tmp: tmp.write_text(json.dumps(meta, indent=2) + "\n"))
    return out


def _remove_stale_frames(dirs: dict, frames: int) -> None:
    """Drop frame files of an earlier, longer render in our own sub-folders (our naming only)."""
    for d in dirs.values():
        for path in d.glob("frame_[0-9][0-9][0-9][0-9][0-9].*"):
            if path.suffix in (".png", ".exr", ".npy") and int(path.stem[6:]) > frames:
                path.unlink()
