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
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rvr_addon.errors import InputError, OutputError
from rvr_addon.io.exr import read_exr, write_exr
from rvr_addon.io.paths import temp_sibling

try:  # sintel_eval may import bpy; give a clear message where it is missing.
    import bpy
    import bmesh
except ImportError as exc:  # pragma: no cover - exercised only without bpy
    raise ImportError(
        "bpy is not installed: run ./scripts/setup.sh (it installs bpy==5.0.1 into .venv)"
    ) from exc

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


def _link_object(name: str, bm: "bmesh.types.BMesh", location=(0.0, 0.0, 0.0), smooth: bool = False,
                 material=None, scale=(1.0, 1.0, 1.0)):
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    if smooth:
        mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    obj.scale = scale
    if material is not None:
        mesh.materials.append(material)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _sphere(name, radius, location, material, segments=32, scale=(1.0, 1.0, 1.0)):
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=max(8, segments // 2), radius=radius)
    return _link_object(name, bm, location, smooth=True, material=material, scale=scale)


def _cylinder(name, radius, z0, z1, xy, material, segments=24):
    bm = bmesh.new()
    bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=segments,
                          radius1=radius, radius2=radius, depth=z1 - z0)
    return _link_object(name, bm, (xy[0], xy[1], 0.5 * (z0 + z1)), smooth=True, material=material)


def _box(name, size, location, material):
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0)
    bmesh.ops.scale(bm, vec=size, verts=bm.verts)
    return _link_object(name, bm, location, material=material)


def _quad(name, corners, material):
    bm = bmesh.new()
    verts = [bm.verts.new(c) for c in corners]
    bm.faces.new(verts)
    return _link_object(name, bm, material=material)


class _Mat:
    """A node material built from a Principled BSDF; small helpers to wire textures into it."""

    def __init__(self, name: str):
        self.mat = bpy.data.materials.new(name)
        self.nt = self.mat.node_tree
        self.nt.nodes.clear()
        self.out = self.nt.nodes.new("ShaderNodeOutputMaterial")
        self.bsdf = self.nt.nodes.new("ShaderNodeBsdfPrincipled")
        self.link(self.bsdf.outputs["BSDF"], self.out.inputs["Surface"])

    def node(self, kind: str, **inputs):
        n = self.nt.nodes.new(kind)
        for key, value in inputs.items():
            n.inputs[key].default_value = value
        return n

    def link(self, a, b):
        self.nt.links.new(a, b)

    def coords(self, space: str = "Object", swizzle: str | None = None, scale=None, offset=None):
        """Texture coordinates; ``swizzle='xz'`` maps world-like (x, z) to the texture's (x, y)."""
        tc = self.nt.nodes.new("ShaderNodeTexCoord")
        socket = tc.outputs[space]
        if swizzle:
            sep = self.nt.nodes.new("ShaderNodeSeparateXYZ")
            comb = self.nt.nodes.new("ShaderNodeCombineXYZ")
            self.link(socket, sep.inputs[0])
            for i, axis in enumerate(swizzle):
                self.link(sep.outputs[axis.upper()], comb.inputs[i])
            socket = comb.outputs[0]
        if scale is not None or offset is not None:
            mp = self.nt.nodes.new("ShaderNodeMapping")
            if scale is not None:
                mp.inputs["Scale"].default_value = scale
            if offset is not None:
                mp.inputs["Location"].default_value = offset
            self.link(socket, mp.inputs["Vector"])
            socket = mp.outputs["Vector"]
        return socket

    def ramp(self, factor_socket, stops):
        cr = self.nt.nodes.new("ShaderNodeValToRGB")
        elems = cr.color_ramp.elements
        while len(elems) < len(stops):
            elems.new(0.5)
        for elem, (pos, rgb) in zip(elems, stops):
            elem.position = pos
            elem.color = (*rgb, 1.0)
        self.link(factor_socket, cr.inputs["Fac"])
        return cr.outputs["Color"]

    def base(self, color_socket_or_rgb, roughness: float = 0.6, specular: float = 0.5):
        if isinstance(color_socket_or_rgb, tuple):
            self.bsdf.inputs["Base Color"].default_value = (*color_socket_or_rgb, 1.0)
        else:
            self.link(color_socket_or_rgb, self.bsdf.inputs["Base Color"])
        self.bsdf.inputs["Roughness"].default_value = roughness
        self.bsdf.inputs["Specular IOR Level"].default_value = specular
        return self.mat


def _emission_material(name: str, rgb, strength: float):
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*rgb, 1.0)
    em.inputs["Strength"].default_value = strength
    nt.links.new(em.outputs["Emission"], out.inputs["Surface"])
    # Seen by the camera only: they must not light the scene (fireflies at low sample counts).
    mat.cycles.emission_sampling = "NONE"
    return mat


def _materials(rng: np.random.Generator) -> dict:
    m = {}

    skin = _Mat("skin")
    n = skin.node("ShaderNodeTexNoise", Scale=25.0, Detail=4.0, Roughness=0.6)
    skin.link(skin.coords("Object", offset=tuple(rng.uniform(0, 100, 3))), n.inputs["Vector"])
    v = skin.node("ShaderNodeTexVoronoi", Scale=90.0)
    skin.link(skin.coords("Object"), v.inputs["Vector"])
    mix = skin.node("ShaderNodeMath")
    mix.operation = "MULTIPLY_ADD"
    skin.link(v.outputs["Distance"], mix.inputs[0])
    mix.inputs[1].default_value = 0.3
    skin.link(n.outputs["Fac"], mix.inputs[2])
    m["skin"] = skin.base(skin.ramp(mix.outputs[0], [(0.35, (0.45, 0.24, 0.16)), (0.95, (0.80, 0.55, 0.42))]),
                          roughness=0.45)

    hair = _Mat("hair")
    n = hair.node("ShaderNodeTexNoise", Scale=30.0, Detail=5.0, Roughness=0.7)
    hair.link(hair.coords("Object", scale=(6.0, 6.0, 0.6)), n.inputs["Vector"])
    m["hair"] = hair.base(hair.ramp(n.outputs["Fac"], [(0.3, (0.03, 0.015, 0.01)), (0.7, (0.28, 0.14, 0.06))]),
                          roughness=0.35)

    eye = _Mat("eye")
    m["eye"] = eye.base((0.02, 0.02, 0.025), roughness=0.05, specular=1.0)

    sweater = _Mat("sweater")
    w = sweater.node("ShaderNodeTexWave", Scale=9.0, Distortion=2.0, Detail=3.0)
    sweater.link(sweater.coords("Object"), w.inputs["Vector"])
    c_a = tuple(rng.uniform([0.45, 0.03, 0.05], [0.65, 0.10, 0.12]))
    m["sweater"] = sweater.base(sweater.ramp(w.outputs["Fac"], [(0.45, c_a), (0.55, (0.75, 0.70, 0.55))]),
                                roughness=0.8)

    wall = _Mat("wall")
    b = wall.node("ShaderNodeTexBrick", Scale=1.0, **{"Mortar Size": 0.025, "Brick Width": 0.5,
                                                      "Row Height": 0.22, "Bias": 0.0})
    b.offset = 0.5
    wall.link(wall.coords("Object", swizzle="xz"), b.inputs["Vector"])
    brick_a = tuple(rng.uniform([0.35, 0.10, 0.06], [0.50, 0.16, 0.10]))
    brick_b = tuple(rng.uniform([0.20, 0.12, 0.10], [0.32, 0.18, 0.14]))
    b.inputs["Color1"].default_value = (*brick_a, 1.0)
    b.inputs["Color2"].default_value = (*brick_b, 1.0)
    b.inputs["Mortar"].default_value = (0.55, 0.53, 0.50, 1.0)
    grime = wall.node("ShaderNodeTexNoise", Scale=0.35, Detail=4.0)
    wall.link(wall.coords("Object", swizzle="xz", offset=tuple(rng.uniform(0, 50, 3))), grime.inputs["Vector"])
    paint = wall.ramp(grime.outputs["Fac"], [(0.35, (0.35, 0.45, 0.55)), (0.65, (1.0, 1.0, 1.0))])
    mul = wall.node("ShaderNodeMix")
    mul.data_type = "RGBA"
    mul.blend_type = "MULTIPLY"
    # The Mix node has one socket per data type under the same name: pick the colour ones.
    rgba_in = {s.name: s for s in mul.inputs if s.type == "RGBA"}
    mul.inputs["Factor"].default_value = 1.0
    wall.link(b.outputs["Color"], rgba_in["A"])
    wall.link(paint, rgba_in["B"])
    result = next(s for s in mul.outputs if s.type == "RGBA")
    m["wall"] = wall.base(result, roughness=0.9, specular=0.0)  # matte: cheaper to shade

    floor = _Mat("floor")
    ck = floor.node("ShaderNodeTexChecker", Scale=1.0)
    floor.link(floor.coords("Object", scale=(1.2, 1.2, 1.2)), ck.inputs["Vector"])
    ck.inputs["Color1"].default_value = (0.30, 0.28, 0.25, 1.0)
    ck.inputs["Color2"].default_value = (0.12, 0.11, 0.10, 1.0)
    m["floor"] = floor.base(ck.outputs["Color"], roughness=0.7, specular=0.0)

    wood = _Mat("wood")
    w = wood.node("ShaderNodeTexWave", Scale=3.0, Distortion=6.0, Detail=4.0, **{"Detail Scale": 2.0})
    w.wave_type = "RINGS"
    wood.link(wood.coords("Object", scale=(1.0, 1.0, 0.15), offset=tuple(rng.uniform(0, 10, 3))), w.inputs["Vector"])
    m["wood"] = wood.base(wood.ramp(w.outputs["Fac"], [(0.2, (0.30, 0.15, 0.05)), (0.9, (0.65, 0.42, 0.20))]),
                          roughness=0.5)

    marble = _Mat("marble")
    n = marble.node("ShaderNodeTexNoise", Scale=4.0, Detail=6.0, Roughness=0.65, Distortion=3.0)
    marble.link(marble.coords("Object", offset=tuple(rng.uniform(0, 50, 3))), n.inputs["Vector"])
    m["marble"] = marble.base(marble.ramp(n.outputs["Fac"], [(0.40, (0.12, 0.22, 0.35)), (0.60, (0.70, 0.75, 0.80))]),
                              roughness=0.3)

    ball = _Mat("ball")
    ck = ball.node("ShaderNodeTexChecker", Scale=6.0)
    ball.link(ball.coords("Generated"), ck.inputs["Vector"])
    ck.inputs["Color1"].default_value = (0.85, 0.65, 0.05, 1.0)
    ck.inputs["Color2"].default_value = (0.05, 0.25, 0.55, 1.0)
    m["ball"] = ball.base(ck.outputs["Color"], roughness=0.35)

    metal = _Mat("pole")
    n = metal.node("ShaderNodeTexNoise", Scale=60.0, Detail=2.0)
    metal.link(metal.coords("Object"), n.inputs["Vector"])
    metal.bsdf.inputs["Metallic"].default_value = 0.7
    m["pole"] = metal.base(metal.ramp(n.outputs["Fac"], [(0.3, (0.25, 0.27, 0.30)), (0.7, (0.55, 0.56, 0.58))]),
                           roughness=0.4)

    wire = _Mat("wire")
    m["wire"] = wire.base((0.015, 0.015, 0.015), roughness=0.5)
    return m


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


def _aim(obj, target) -> None:
    from mathutils import Vector

    direction = Vector(target) - Vector(obj.location)
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def _setup_render(scene, width: int, height: int, samples: int, seed: int, denoise: bool) -> str:
    scene.render.engine = "CYCLES"
    cyc = scene.cycles
    cyc.device = "CPU"
    cyc.samples = samples
    cyc.use_adaptive_sampling = False
    cyc.seed = seed
    cyc.use_animated_seed = False
    cyc.max_bounces = 4
    cyc.diffuse_bounces = 2
    cyc.glossy_bounces = 2
    cyc.transmission_bounces = 0
    cyc.volume_bounces = 0
    cyc.transparent_max_bounces = 2
    cyc.caustics_reflective = False
    cyc.caustics_refractive = False
    cyc.sample_clamp_indirect = 10.0
    denoiser = "none"
    if denoise:
        import _cycles  # Cycles' own module: tells whether OpenImageDenoise was compiled in

        if getattr(_cycles, "with_openimagedenoise", False):
            cyc.use_denoising = True
            cyc.denoiser = "OPENIMAGEDENOISE"
            cyc.denoising_input_passes = "RGB_ALBEDO_NORMAL"
            denoiser = "OPENIMAGEDENOISE"
        else:
            cyc.use_denoising = False
    else:
        cyc.use_denoising = False

    r = scene.render
    r.resolution_x, r.resolution_y = width, height
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.fps, r.fps_base = FPS, 1.0
    r.film_transparent = False
    r.use_motion_blur = False
    r.dither_intensity = 0.0  # the PNG must be exactly the sRGB encoding of the clipped radiance
    r.use_persistent_data = True
    r.use_compositing = False
    r.use_sequencer = False

    vs = scene.view_settings
    scene.display_settings.display_device = "sRGB"
    vs.view_transform = "Standard"
    vs.look = "None"
    vs.exposure = 0.0
    vs.gamma = 1.0
    vs.use_curve_mapping = False
    if hasattr(vs, "use_white_balance"):
        vs.use_white_balance = False

    vl = scene.view_layers[0]
    vl.use_pass_combined = True
    vl.use_pass_z = True
    return denoiser


def _set_image_settings(scene, kind: str) -> None:
    ims = scene.render.image_settings
    # Blender 5.0: the file_format enum depends on media_type. With MULTI_LAYER_IMAGE the only
    # item is 'OPEN_EXR_MULTILAYER', so set 'OPEN_EXR' while the media type is still IMAGE.
    if kind == "exr":
        ims.media_type = "IMAGE"
        ims.file_format = "OPEN_EXR"
        ims.media_type = "MULTI_LAYER_IMAGE"
        ims.color_depth = "32"
        ims.exr_codec = "ZIP"
    else:
        ims.media_type = "IMAGE"
        ims.file_format = "PNG"
        ims.color_mode = "RGB"
        ims.color_depth = "8"
        ims.compression = 15


def _read_multilayer(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Blender multilayer EXR -> (linear RGB float32 (H, W, 3), Z float32 (H, W))."""
    chans = read_exr(path)

    def find(suffix):
        hits = [k for k in chans if k.endswith(suffix)]
        if not hits:
            raise OutputError(f"{path}: no channel '*{suffix}' in the render (channels: {sorted(chans)})")
        return chans[hits[0]]

    rgb = np.dstack([find(f"Combined.{c}") for c in "RGB"])
    return rgb, find("Depth.Z")


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

    bpy.ops.wm.read_factory_settings(use_empty=True)
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


def _atomic(path: Path, suffix: str, write) -> None:
    """Call ``write(tmp)`` on a hidden sibling of ``path``, then rename it onto ``path``."""
    tmp = temp_sibling(path, suffix)
    try:
        write(tmp)
        if not tmp.is_file():
            raise OSError("nothing was written")
        os.replace(tmp, path)
    except Exception as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write '{path}': {exc}; check free disk space and write permission") from exc


def _working_space() -> str:
    """The blend file's scene-linear working space (Blender 5.0+; Linear Rec.709 before)."""
    colorspace = getattr(bpy.data, "colorspace", None)
    return str(getattr(colorspace, "working_space", "") or "Linear Rec.709")


def _remove_stale_frames(dirs: dict, frames: int) -> None:
    """Drop frame files of an earlier, longer render in our own sub-folders (our naming only)."""
    for d in dirs.values():
        for path in d.glob("frame_[0-9][0-9][0-9][0-9][0-9].*"):
            if path.suffix in (".png", ".exr", ".npy") and int(path.stem[6:]) > frames:
                path.unlink()
