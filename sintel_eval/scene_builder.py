"""Build a :class:`~sintel_eval.scene_plan.ScenePlan` in Blender (bpy) and pose it per frame.

:func:`build_scene` starts from the current (fresh factory) state and creates the camera, the
set, the characters (primitives under one Empty each, with hips, a mouth and a focus point),
the movers, the emitters and the lights. :func:`apply_frame` poses everything for one frame
(camera, walking, mouths) and :func:`subject_frame` measures a subject on the posed frame.
Units: metres, radians; world axes as in scene_plan.

A plan without a look (``plan.look is None``: procedural style, classic lighting) builds the
original scene. With a :class:`~sintel_eval.look.LookPlan` the same set gets the look's
materials (photo textures where it chose them), lighting (day/dim/night: world, sun, key and
fill lights, lamps, extra light strings, window and bulb strengths), photo billboards and
people-like figures (:mod:`sintel_eval.figures`); the layout, motions and events are the same.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import materials as mat
from .bpy_util import bpy, box, cylinder, empty, hair_strands, quad, rod, sphere
from .camera_math import Lens, box_of, project_points
from .framing import (PLANT_LEAF_SIZE, PLANT_LEAF_SPREAD, PLANT_TIP_DX, PLANT_TIP_DY, PLANT_TIP_Z, STRAND_JITTER_M,
                      STRAND_TOP_Z)
from .scene_plan import BULB_RADIANCE, BULB_RADIUS_M, FOCAL_MM, SENSOR_WIDTH_MM, Character, ScenePlan, half_width
from .scripts_events import SubjectFrame

SET_ID, PROPS_ID, RAILING_ID, STRANDS_ID, PLANT_ID, LIGHTS_ID, WINDOWS_ID = 0, 21, 30, 31, 32, 40, 41
BILLBOARDS_ID, LAMPS_ID = 42, 43
HIP_Z = 0.9
MOUTH_CLOSED, MOUTH_OPEN = 0.15, 1.0  # z scale of the mouth at opening 0 and 1
STRIDE_M = 1.2


@dataclass
class CharacterRig:
    """Blender objects of one character: root Empty, hips (left, right), mouth, focus Empty and
    every mesh part with its local vertices (for the projected bounding box); a person figure
    also has joints (knees, shoulders, elbows, jaw) and its mouth's x/y scale."""

    root: object
    hips: tuple
    mouth: object
    focus: object
    parts: list = field(default_factory=list)
    verts: list = field(default_factory=list)
    joints: dict = field(default_factory=dict)
    mouth_scale: tuple = (1.3, 0.55)


@dataclass
class BuiltScene:
    """The scene in Blender: camera object, character rigs and movers by name, pass-index names,
    and the brightest emitted radiance per channel (an upper bound of any pixel's radiance)."""

    camera: object
    rigs: dict
    movers: dict
    object_ids: dict
    radiance_cap: np.ndarray
    emitters: list


def build_scene(plan: ScenePlan, width: int, height: int, texture_files: dict | None = None) -> BuiltScene:
    """Create the plan's objects in ``bpy.context.scene`` (expects an empty factory state).

    texture_files: slot -> image file of the look's photo textures (see
    :func:`sintel_eval.textures.cut`); a slot without a file keeps its procedural material."""
    scene = bpy.context.scene
    rng = np.random.default_rng([plan.seed, 101])
    cam_data = bpy.data.cameras.new("camera")
    cam_data.type = "PERSP"
    cam_data.lens_unit = "MILLIMETERS"
    cam_data.lens = getattr(plan.camera, "focal_mm", FOCAL_MM)
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = SENSOR_WIDTH_MM
    cam_data.sensor_height = SENSOR_WIDTH_MM * height / width
    cam_data.shift_x = cam_data.shift_y = 0.0
    cam_data.clip_start = 0.05
    cam_data.clip_end = 1000.0
    cam_data.dof.use_dof = False
    cam_data.dof.aperture_blades = 0  # a round aperture: our disk kernel
    cam_data.dof.aperture_rotation = 0.0
    cam_data.dof.aperture_ratio = 1.0
    camera = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(camera)
    scene.camera = camera

    ids = {SET_ID: "set"}
    emitters: list[dict] = []
    look = getattr(plan, "look", None)
    textures = _texture_files(plan, texture_files)
    _build_set(plan, rng, ids, emitters, textures)
    if look is None or look.figures_model == "classic":
        rigs = {c.name: _build_character(c, rng) for c in plan.characters}
    else:
        rigs = {c.name: _build_person(c, look.figures[c.name], rng, textures) for c in plan.characters}
    for c in plan.characters:
        ids[c.index] = c.name
    movers = {}
    for m in plan.movers:
        ball_mat = mat.checker_ball(f"{m.name}_mat")
        if m.name in textures:
            from . import photo_materials as photo

            ball_mat = photo.tiled(f"{m.name}_mat", textures[m.name], textures.tile(m.name), box=True, roughness=0.4)
        obj = sphere(m.name, m.radius, (0.0, m.motion.start[1], m.z), ball_mat, segments=32)
        obj.pass_index = m.index
        obj.rotation_mode = "AXIS_ANGLE"
        movers[m.name] = obj
        ids[m.index] = m.name
    if look is None:
        _lights(plan, rigs[plan.main])
    else:
        _look_extras(plan, look, textures, rng, ids, emitters)
        _look_lights(plan, look)
    cap = np.max([e["radiance"] for e in emitters], axis=0).astype(np.float32)
    return BuiltScene(camera, rigs, movers, {str(k): v for k, v in sorted(ids.items())}, cap, emitters)


# --------------------------------------------------------------------------------------------- set


def _emitter_sphere(name: str, position, radius: float, rgb, strength: float, emitters: list,
                    camera_visible: bool = True, glossy_visible: bool = False):
    obj = sphere(name, radius, position, mat.emitter(f"{name}_mat", rgb, strength), segments=10)
    obj.visible_diffuse = obj.visible_transmission = obj.visible_shadow = obj.visible_volume_scatter = False
    obj.visible_glossy = glossy_visible
    obj.visible_camera = camera_visible
    obj.pass_index = LIGHTS_ID
    emitters.append({"name": name, "position_m": list(position), "radius_m": radius,
                     "radiance": [float(c) * strength for c in rgb], "camera_visible": camera_visible})
    return obj


def _warm(rng: np.random.Generator) -> tuple[float, float, float]:
    palette = np.array([[1.0, 0.78, 0.45], [1.0, 0.55, 0.25], [1.0, 0.92, 0.75], [0.55, 0.80, 1.0],
                        [1.0, 0.45, 0.55], [0.75, 1.0, 0.60]])
    rgb = np.clip(palette[rng.integers(len(palette))] * rng.uniform(0.9, 1.1, 3), 0.0, None)
    return tuple(float(c) for c in rgb / rgb.max())


class _Textures(dict):
    """slot -> crop file of the plan's photo textures (empty without a photo look)."""

    def __init__(self, files: dict, uses: dict):
        super().__init__(files)
        self.uses = uses

    def tile(self, slot: str) -> float:
        return float(self.uses[slot].tile_m or 1.0)


def _texture_files(plan: ScenePlan, files: dict | None) -> _Textures:
    look = getattr(plan, "look", None)
    files = files or {}
    uses = look.textures if look is not None else {}
    return _Textures({k: v for k, v in files.items() if k in uses}, uses)


def _build_set(plan: ScenePlan, rng: np.random.Generator, ids: dict, emitters: list, textures: dict | None = None
               ) -> None:
    sp = plan.set
    look = getattr(plan, "look", None)
    textures = textures if textures is not None else {}
    photo = None
    if textures:
        from . import photo_materials as photo
    x0, x1 = -30.0, 30.0
    wall_mat = mat.brick_wall("wall", sp.brick_a, sp.brick_b, rng.uniform(0, 50, 3))
    if "wall" in textures:
        wall_mat = photo.tiled("wall_photo", textures["wall"], textures.tile("wall"), swizzle="xz", roughness=0.85,
                               specular=0.1)
    wall = quad("wall", [(x0, sp.wall_y, 0.0), (x1, sp.wall_y, 0.0), (x1, sp.wall_y, 16.0), (x0, sp.wall_y, 16.0)],
                wall_mat)
    floor_mat = mat.checker_floor("floor", tuple(rng.uniform(0.22, 0.36, 3)), tuple(rng.uniform(0.06, 0.14, 3)),
                                  scale=float(rng.uniform(0.8, 1.6)))
    if "floor" in textures:
        floor_mat = photo.tiled("floor_photo", textures["floor"], textures.tile("floor"), swizzle="xy",
                                roughness=0.6, specular=0.3)
    floor = quad("floor", [(x0, -5.0, 0.0), (x1, -5.0, 0.0), (x1, sp.wall_y, 0.0), (x0, sp.wall_y, 0.0)], floor_mat)
    wall.pass_index = floor.pass_index = SET_ID
    window_rgb, window_gain = (1.0, 0.82, 0.55), 1.0
    if look is not None:
        window_rgb, window_gain = tuple(look.lighting.window_rgb), float(look.lighting.window_gain)
    for i, (wx, wz, ww, wh, strength) in enumerate(sp.windows):
        y = sp.wall_y - 0.02
        strength = strength * window_gain
        w = quad(f"window_{i}", [(wx - ww / 2, y, wz - wh / 2), (wx + ww / 2, y, wz - wh / 2),
                                 (wx + ww / 2, y, wz + wh / 2), (wx - ww / 2, y, wz + wh / 2)],
                 mat.window(f"window_{i}_mat", window_rgb, strength))
        w.visible_diffuse = w.visible_glossy = w.visible_shadow = w.visible_transmission = False
        w.pass_index = WINDOWS_ID
        emitters.append({"name": f"window_{i}", "position_m": [wx, y, wz], "radius_m": 0.5 * min(ww, wh),
                         "radiance": [strength * c for c in window_rgb], "camera_visible": True})
    ids[WINDOWS_ID] = "windows"

    for i, p in enumerate(sp.props):
        pid = PROPS_ID + i
        ids[pid] = f"{p.kind}_{i}"
        slot = f"{p.kind}_{i}"
        if p.kind == "crate":
            crate_mat = mat.wood(f"crate_{i}_mat", rng.uniform(0, 10, 3))
            if slot in textures:
                crate_mat = photo.tiled(f"crate_{i}_photo", textures[slot], textures.tile(slot), box=True,
                                        roughness=0.6)
            objs = [box(f"crate_{i}", (p.size, p.size, p.size * 1.6), (p.x, p.y, p.size * 0.8), crate_mat)]
        elif p.kind == "pillar":
            pillar_mat = mat.marble(f"pillar_{i}_mat", rng.uniform(0, 50, 3))
            if slot in textures:
                pillar_mat = photo.tiled(f"pillar_{i}_photo", textures[slot], textures.tile(slot), box=True,
                                         roughness=0.4)
            objs = [cylinder(f"pillar_{i}", p.size, 0.0, 3.4, (p.x, p.y), pillar_mat, 40)]
        elif p.kind == "panel":
            panel_mat = mat.flat(f"panel_{i}_mat", p.color)
            if slot in textures:  # a poster: the photo mapped once onto the panel
                panel_mat = photo.mapped(f"panel_{i}_photo", textures[slot], (-0.5 * p.size, -0.95), (p.size, 1.9),
                                         roughness=0.45)
            objs = [box(f"panel_{i}", (p.size, 0.06, 1.9), (p.x, p.y, 0.95), panel_mat)]
        elif p.kind == "chrome":
            ped = box(f"pedestal_{i}", (0.4, 0.4, 0.9), (p.x, p.y, 0.45), mat.flat(f"pedestal_{i}_mat", p.color))
            ball = sphere(f"chrome_{i}", p.size, (p.x, p.y, 0.9 + p.size), mat.chrome(f"chrome_{i}_mat"), 48)
            objs = [ped, ball]
            # Small, very bright sources seen only in reflections: specular highlights >> 1.
            for j, (gx, gy, gz) in enumerate(((1.2, -2.5, 1.8), (-0.8, -3.0, 1.2))):
                _emitter_sphere(f"glint_{i}_{j}", (p.x + gx, p.y + gy, 0.9 + p.size + gz), 0.08, (1.0, 0.95, 0.85),
                                float(rng.uniform(120.0, 250.0)), emitters, camera_visible=False, glossy_visible=True)
        else:  # tree: trunk, branches (thin), leaves
            objs = _tree(f"tree_{i}", p.x, p.y, p.size, rng)
        for o in objs:
            o.pass_index = pid

    if sp.railing_y is not None:
        y = sp.railing_y
        w = 1.6 * half_width(y)
        rail = mat.brushed_metal("railing_mat")
        parts = [rod("rail_top", (-w, y, 1.0), (w, y, 1.0), 0.02, rail, 10),
                 rod("rail_mid", (-w, y, 0.5), (w, y, 0.5), 0.012, rail, 8)]
        for k, x in enumerate(np.arange(-w, w, 0.15)):
            parts.append(rod(f"baluster_{k}", (float(x), y, 0.0), (float(x), y, 1.0), 0.008, rail, 6))
        for o in parts:
            o.pass_index = RAILING_ID
        ids[RAILING_ID] = "railing"

    for k, (x, y, zb, r) in enumerate(sp.strands):
        color = tuple(float(c) for c in rng.uniform(0.05, 0.9, 3))
        x_bottom = x + float(rng.uniform(-STRAND_JITTER_M, STRAND_JITTER_M))
        o = rod(f"strand_{k}", (x, y, STRAND_TOP_Z), (x_bottom, y, zb), r,
                mat.flat(f"strand_{k}_mat", color, roughness=0.4), 6)
        o.pass_index = STRANDS_ID
    ids[STRANDS_ID] = "strands"

    if sp.plant is not None:
        for o in _plant("plant", sp.plant[0], sp.plant[1], rng):
            o.pass_index = PLANT_ID
        ids[PLANT_ID] = "plant"

    # String lights: a sagging wire of bulbs across the frame, plus loose lights further back.
    y, z = sp.string_lights_y, sp.string_lights_z
    w = 1.15 * half_width(y)
    wire = mat.flat("wire_mat", (0.02, 0.02, 0.02), roughness=0.5)
    xs = np.linspace(-w, w, sp.bulbs)
    sag = lambda x: z - 0.35 * (1.0 - (x / w) ** 2)  # noqa: E731
    pts = [(float(x), y, sag(float(x)) + 0.04) for x in np.linspace(-w, w, 9)]
    for k in range(len(pts) - 1):
        o = rod(f"light_wire_{k}", pts[k], pts[k + 1], 0.004, wire, 6)
        o.pass_index = LIGHTS_ID
    gain = float(look.lighting.bulb_gain) if look is not None else 1.0
    for k, x in enumerate(xs):
        _emitter_sphere(f"bulb_{k}", (float(x), y + float(rng.uniform(-0.3, 0.3)), sag(float(x))),
                        float(rng.uniform(*BULB_RADIUS_M)), _warm(rng), gain * float(rng.uniform(*BULB_RADIANCE)),
                        emitters)
    for k, (x, yy, zz, r, strength) in enumerate(sp.loose_lights):
        _emitter_sphere(f"light_{k}", (x, yy, zz), r, _warm(rng), gain * strength, emitters)
    ids[LIGHTS_ID] = "lights"


def _tree(name: str, x: float, y: float, height: float, rng: np.random.Generator) -> list:
    bark = mat.wood(f"{name}_bark", rng.uniform(0, 10, 3))
    foliage = mat.leaf(f"{name}_leaf", rng.uniform(0, 10, 3))
    objs = [cylinder(f"{name}_trunk", 0.08, 0.0, height * 0.75, (x, y), bark, 16)]
    tips = []
    for k in range(int(rng.integers(5, 9))):
        z0 = float(rng.uniform(0.45, 0.7)) * height
        ang = float(rng.uniform(0, 2 * math.pi))
        length = float(rng.uniform(0.5, 1.0))
        tip = (x + length * math.cos(ang), y + 0.5 * length * math.sin(ang), z0 + float(rng.uniform(0.2, 0.6)))
        objs.append(rod(f"{name}_branch_{k}", (x, y, z0), tip, float(rng.uniform(0.008, 0.02)), bark, 6))
        tips.append(tip)
    objs.append(_leaves(f"{name}_leaves", tips, int(rng.integers(90, 140)), 0.45, (0.05, 0.09), foliage, rng))
    return objs


def _plant(name: str, x: float, y: float, rng: np.random.Generator) -> list:
    stem_mat = mat.flat(f"{name}_stem", (0.10, 0.22, 0.05), roughness=0.6)
    foliage = mat.leaf(f"{name}_leaf", rng.uniform(0, 10, 3))
    objs, tips = [], []
    for k in range(int(rng.integers(3, 6))):
        tip = (x + float(rng.uniform(-PLANT_TIP_DX, PLANT_TIP_DX)), y + float(rng.uniform(-PLANT_TIP_DY, PLANT_TIP_DY)),
               float(rng.uniform(*PLANT_TIP_Z)))
        objs.append(rod(f"{name}_stem_{k}", (x, y, 0.0), tip, 0.006, stem_mat, 6))
        tips.append(tip)
    objs.append(_leaves(f"{name}_leaves", tips, int(rng.integers(30, 50)), PLANT_LEAF_SPREAD, PLANT_LEAF_SIZE, foliage,
                        rng))
    return objs


def _leaves(name: str, centres: list, count: int, spread: float, size: tuple, material, rng: np.random.Generator):
    """One mesh of ``count`` small randomly oriented leaf quads around ``centres``."""
    import bmesh
    from mathutils import Euler, Vector

    from .bpy_util import link_object

    bm = bmesh.new()
    for _ in range(count):
        c = Vector(centres[int(rng.integers(len(centres)))]) + Vector(rng.uniform(-spread, spread, 3))
        s = float(rng.uniform(*size))
        rot = Euler(tuple(rng.uniform(0, math.pi, 3))).to_matrix()
        corners = [(0.0, -0.5), (0.35, 0.0), (0.0, 0.5), (-0.35, 0.0)]  # a diamond leaf
        verts = [bm.verts.new(c + rot @ Vector((u * s, 0.0, v * s))) for u, v in corners]
        bm.faces.new(verts)
    return link_object(name, bm, material=material)


# --------------------------------------------------------------------------------------------- characters


def _build_character(c: Character, rng: np.random.Generator) -> CharacterRig:
    n = c.name
    root = empty(f"{n}_root", (*c.motion.start, 0.0))
    root.scale = (c.height, c.height, c.height)
    tone = np.array(c.skin)
    skin_m = mat.skin(f"{n}_skin", rng.uniform(0, 100, 3), tuple(tone * 0.56), tuple(tone))
    hair_m = mat.hair(f"{n}_hair", tuple(np.array(c.hair) * 0.4), tuple(c.hair))
    sweater_m = mat.sweater(f"{n}_sweater", c.sweater)
    trousers = mat.flat(f"{n}_trousers", tuple(rng.uniform(0.03, 0.2, 3)))
    eye_m = mat.glossy(f"{n}_eye", (0.02, 0.02, 0.025))
    mouth_m = mat.flat(f"{n}_mouth", (0.18, 0.03, 0.03), roughness=0.5)
    parts = []
    hips = []
    for side in (-1.0, 1.0):
        hip = empty(f"{n}_hip_{'lr'[side > 0]}", (side * 0.1, 0.0, HIP_Z), parent=root)
        parts.append(rod(f"{n}_leg_{'lr'[side > 0]}", (0.0, 0.0, 0.0), (0.0, 0.0, -HIP_Z + 0.02), 0.07, trousers, 12,
                         parent=hip))
        hips.append(hip)
    parts.append(sphere(f"{n}_torso", 1.0, (0.0, 0.0, 1.14), sweater_m, 32, scale=(0.16, 0.11, 0.32), parent=root))
    parts.append(sphere(f"{n}_shoulders", 1.0, (0.0, 0.0, 1.39), sweater_m, 32, scale=(0.2, 0.11, 0.075),
                        parent=root))
    for side in (-1.0, 1.0):
        parts.append(rod(f"{n}_arm_{'lr'[side > 0]}", (side * 0.19, 0.0, 1.39), (side * 0.22, 0.02, 0.9), 0.04,
                         sweater_m, 12, parent=root))
    parts.append(cylinder(f"{n}_neck", 0.045, 1.42, 1.56, (0.0, 0.0), skin_m, 16, parent=root))
    parts.append(sphere(f"{n}_head", 0.1, (0.0, 0.0, 1.64), skin_m, 40, scale=(0.9, 1.0, 1.15), parent=root))
    parts.append(sphere(f"{n}_hair", 0.106, (0.0, 0.022, 1.67), hair_m, 40, scale=(0.93, 0.95, 1.12), parent=root))
    parts += hair_strands(n, c.hair_strands, rng, (0.18, 0.32), hair_m, parent=root)
    for side in (-1.0, 1.0):
        parts.append(sphere(f"{n}_eye_{'lr'[side > 0]}", 0.011, (side * 0.03, -0.09, 1.665), eye_m, 12, parent=root))
    parts.append(sphere(f"{n}_nose", 0.014, (0.0, -0.1, 1.63), skin_m, 12, parent=root))
    mouth = sphere(f"{n}_mouth", 0.022, (0.0, -0.086, 1.585), mouth_m, 16, scale=(1.3, 0.55, MOUTH_CLOSED),
                   parent=root)
    parts.append(mouth)
    focus = empty(f"{n}_focus", (0.0, -0.1, 1.665), parent=root)  # between the eyes, on the face
    for p in parts:
        p.pass_index = c.index
    verts = []
    for p in parts:
        arr = np.empty(len(p.data.vertices) * 3, dtype=np.float64)
        p.data.vertices.foreach_get("co", arr)
        verts.append(arr.reshape(-1, 3))
    return CharacterRig(root, tuple(hips), mouth, focus, parts, verts)


def _lights(plan: ScenePlan, main_rig: CharacterRig) -> None:
    from .bpy_util import aim

    scene = bpy.context.scene
    key_data = bpy.data.lights.new("key", type="AREA")
    key_data.energy = 45.0
    key_data.size = 1.0
    key_data.color = (1.0, 0.93, 0.85)
    key = bpy.data.objects.new("key", key_data)
    x, y = plan.character(plan.main).motion.start
    key.location = (x + plan.set.key_side * 1.3, y - 1.8, 2.3)
    aim(key, (x, y, 1.6))
    key.visible_camera = False
    scene.collection.objects.link(key)

    sun_data = bpy.data.lights.new("sun", type="SUN")
    sun_data.energy = 2.0
    sun_data.angle = math.radians(4.0)
    sun_data.color = (1.0, 0.8, 0.6)
    sun = bpy.data.objects.new("sun", sun_data)
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(200.0 if plan.set.key_side < 0 else 160.0))
    scene.collection.objects.link(sun)

    world = bpy.data.worlds.new("dusk")
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.30, 0.38, 0.55, 1.0)
    bg.inputs["Strength"].default_value = plan.set.world_strength
    scene.world = world


# --------------------------------------------------------------------------------------------- looks


def _build_person(c: Character, fl, rng: np.random.Generator, textures: dict) -> CharacterRig:
    from .figures import build_person

    def cloth(slot, rgb, kind, name):
        if slot and slot in textures:
            from . import photo_materials as photo

            return photo.tiled(name, textures[slot], textures.tile(slot), box=True, roughness=0.85, specular=0.2)
        if kind == "sweater":
            stripe = tuple(float(v) for v in np.clip(np.array(rgb) * 1.8 + 0.08, 0.0, 0.9))
            return mat.sweater(name, tuple(rgb), stripe)
        return mat.flat(name, tuple(rgb), roughness=0.75 if kind != "jacket" else 0.55)

    f = build_person(c, fl, rng, cloth)
    verts = []
    for p in f["parts"]:
        arr = np.empty(len(p.data.vertices) * 3, dtype=np.float64)
        p.data.vertices.foreach_get("co", arr)
        verts.append(arr.reshape(-1, 3))
    return CharacterRig(f["root"], f["hips"], f["mouth"], f["focus"], f["parts"], verts, f["joints"],
                        f["mouth_scale"])


def _string_of_lights(name: str, y: float, z: float, bulbs: int, gain: float, rng: np.random.Generator,
                      emitters: list) -> None:
    w = 1.15 * half_width(y)
    wire = mat.flat(f"{name}_wire_mat", (0.02, 0.02, 0.02), roughness=0.5)
    sag = lambda x: z - 0.3 * (1.0 - (x / w) ** 2)  # noqa: E731
    pts = [(float(x), y, sag(float(x)) + 0.04) for x in np.linspace(-w, w, 9)]
    for k in range(len(pts) - 1):
        rod(f"{name}_wire_{k}", pts[k], pts[k + 1], 0.004, wire, 6).pass_index = LIGHTS_ID
    for k, x in enumerate(np.linspace(-w, w, bulbs)):
        _emitter_sphere(f"{name}_bulb_{k}", (float(x), y + float(rng.uniform(-0.2, 0.2)), sag(float(x))),
                        float(rng.uniform(*BULB_RADIUS_M)), _warm(rng), gain * float(rng.uniform(*BULB_RADIANCE)),
                        emitters)


def _look_extras(plan: ScenePlan, look, textures: dict, rng: np.random.Generator, ids: dict, emitters: list) -> None:
    """Billboards (photos of real scenes far behind), lamps and extra strings of lights."""
    from . import photo_materials as photo

    light = look.lighting
    for b in look.billboards:
        if b.slot not in textures:
            continue
        x0 = b.x - 0.5 * b.width
        board = quad(b.slot, [(x0, b.y, b.z0), (x0 + b.width, b.y, b.z0), (x0 + b.width, b.y, b.z0 + b.height),
                              (x0, b.y, b.z0 + b.height)],
                     photo.mapped(f"{b.slot}_mat", textures[b.slot], (x0, b.z0), (b.width, b.height),
                                  roughness=0.6, emission=light.billboard_gain))
        board.pass_index = BILLBOARDS_ID
        ids[BILLBOARDS_ID] = "billboards"
        emitters.append({"name": b.slot, "position_m": [b.x, b.y, b.z0 + 0.5 * b.height],
                         "radius_m": 0.5 * min(b.width, b.height), "radiance": [light.billboard_gain] * 3,
                         "camera_visible": True})
    pole_mat = mat.brushed_metal("lamp_pole_mat", metallic=0.3)
    for k, lamp in enumerate(light.lamps):
        objs = [rod(f"lamp_{k}_pole", (lamp.x, lamp.y, 0.0), (lamp.x, lamp.y, lamp.height), 0.02, pole_mat, 8)]
        shade_rgb = tuple(lamp.rgb)
        if lamp.kind == "floor":  # a glowing shade on a pole
            shade = photo.glowing(f"lamp_{k}_shade_mat", shade_rgb, lamp.radiance, base=(0.8, 0.75, 0.65))
            top = lamp.height + 0.12
            objs.append(cylinder(f"lamp_{k}_shade", lamp.radius, lamp.height - 0.1, top, (lamp.x, lamp.y), shade, 20))
            z = lamp.height + 0.01
        else:  # a street lamp: a bare bright bulb under a small dark hood
            objs.append(rod(f"lamp_{k}_arm", (lamp.x, lamp.y, lamp.height), (lamp.x, lamp.y - 0.4, lamp.height),
                            0.02, pole_mat, 8))
            z = lamp.height - 0.08
            bulb = sphere(f"lamp_{k}_bulb", lamp.radius, (lamp.x, lamp.y - 0.4, z),
                          photo.glowing(f"lamp_{k}_bulb_mat", shade_rgb, lamp.radiance, base=(0.9, 0.9, 0.9)), 16)
            objs.append(bulb)
        for o in objs:
            o.pass_index = LAMPS_ID
        emitters.append({"name": f"lamp_{k}", "position_m": [lamp.x, lamp.y, z], "radius_m": lamp.radius,
                         "radiance": [lamp.radiance * c for c in shade_rgb], "camera_visible": True})
        data = bpy.data.lights.new(f"lamp_{k}_light", type="POINT")
        data.energy = float(lamp.energy_w)
        data.color = shade_rgb
        data.shadow_soft_size = float(lamp.radius)
        obj = bpy.data.objects.new(f"lamp_{k}_light", data)
        street = lamp.kind == "street"
        obj.location = (lamp.x, lamp.y - (0.4 if street else 0.0), z - (0.2 if street else 0.25))
        obj.visible_camera = False
        bpy.context.scene.collection.objects.link(obj)
        ids[LAMPS_ID] = "lamps"
    for k, s in enumerate(light.strings):
        _string_of_lights(f"string_{k}", s.y, s.z, s.bulbs, s.gain * light.bulb_gain, rng, emitters)


def _look_lights(plan: ScenePlan, look) -> None:
    """Key (area light on the main subject), fill (opposite, softer), sun and world of the look."""
    from .bpy_util import aim

    scene = bpy.context.scene
    light = look.lighting
    x, y = plan.character(plan.main).motion.start
    for name, energy, side, size, rgb in (("key", light.key_energy, plan.set.key_side, 1.0, light.key_rgb),
                                          ("fill", light.fill_energy, -plan.set.key_side, 2.5, light.world_rgb)):
        if energy <= 0:
            continue
        data = bpy.data.lights.new(name, type="AREA")
        data.energy = float(energy)
        data.size = size
        data.color = tuple(rgb)
        obj = bpy.data.objects.new(name, data)
        obj.location = (x + side * (1.3 if name == "key" else 2.0), y - (1.8 if name == "key" else 2.5),
                        2.3 if name == "key" else 1.8)
        aim(obj, (x, y, 1.4 if name == "fill" else 1.6))
        obj.visible_camera = False
        scene.collection.objects.link(obj)
    if light.sun_energy > 0:
        sun_data = bpy.data.lights.new("sun", type="SUN")
        sun_data.energy = float(light.sun_energy)
        sun_data.angle = math.radians(4.0)
        sun_data.color = tuple(light.sun_rgb)
        sun = bpy.data.objects.new("sun", sun_data)
        sun.rotation_euler = (math.radians(90.0 - light.sun_elevation_deg), 0.0, math.radians(light.sun_azimuth_deg))
        scene.collection.objects.link(sun)
    world = bpy.data.worlds.new(f"world_{light.mode}")
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*light.world_rgb, 1.0)
    bg.inputs["Strength"].default_value = float(light.world_strength)
    scene.world = world


# --------------------------------------------------------------------------------------------- per frame


def apply_frame(built: BuiltScene, plan: ScenePlan, frame: int, mouth: dict | None = None) -> None:
    """Pose camera, characters (walk cycle, facing, mouth opening 0..1) and movers for ``frame``."""
    scene = bpy.context.scene
    scene.frame_current = frame
    loc, rot = plan.camera.pose(frame)
    built.camera.location = loc
    built.camera.rotation_euler = rot
    for c in plan.characters:
        rig = built.rigs[c.name]
        x, y = c.motion.position(frame)
        phase = 2.0 * math.pi * c.motion.travelled(frame) / STRIDE_M
        walking = c.motion.moving(frame)
        rig.root.location = (x, y, 0.012 * abs(math.sin(phase)) if walking else 0.0)
        rig.root.rotation_euler = (0.0, 0.0, c.yaw(frame))
        swing = 0.4 * math.sin(phase) if walking else 0.0
        rig.hips[0].rotation_euler = (swing, 0.0, 0.0)
        rig.hips[1].rotation_euler = (-swing, 0.0, 0.0)
        opening = float(mouth[c.name][frame - 1]) if mouth and c.name in mouth else 0.0
        rig.mouth.scale = (*rig.mouth_scale, MOUTH_CLOSED + (MOUTH_OPEN - MOUTH_CLOSED) * opening)
        if rig.joints:
            from .figures import pose_person

            pose_person(rig.joints, phase, walking, opening)
    for m in plan.movers:
        obj = built.movers[m.name]
        x, y = m.motion.position(frame)
        obj.location = (x, y, m.z)
        dx, dy = m.motion.end[0] - m.motion.start[0], m.motion.end[1] - m.motion.start[1]
        norm = math.hypot(dx, dy) or 1.0
        obj.rotation_axis_angle = (m.motion.travelled(frame) / m.radius, -dy / norm, dx / norm, 0.0)
    bpy.context.view_layer.update()


def world_to_camera(built: BuiltScene) -> np.ndarray:
    """(4, 4) inverse of the camera's world matrix on the posed frame."""
    return np.array(built.camera.matrix_world.inverted(), dtype=np.float64)


def subject_frame(built: BuiltScene, name: str, lens: Lens, width: int, height: int) -> SubjectFrame:
    """Projected box, visible fraction, focus point, depth and disparity of a character on the
    posed frame (call :func:`apply_frame` first)."""
    rig = built.rigs[name]
    w2c = world_to_camera(built)
    pts = []
    for part, local in zip(rig.parts, rig.verts):
        m = np.array(part.matrix_world, dtype=np.float64)
        pts.append(local @ m[:3, :3].T + m[:3, 3])
    xy, depth = project_points(w2c, np.concatenate(pts), lens.f_px, width, height)
    in_front = depth > 0.05
    if not in_front.any():
        bbox, visible = [0.0, 0.0, 0.0, 0.0], 0.0
    else:
        bbox, visible = box_of(xy[in_front], width, height)
    f = np.array(rig.focus.matrix_world.translation, dtype=np.float64)[None]
    p_xy, p_depth = project_points(w2c, f, lens.f_px, width, height)
    d = float(p_depth[0])
    px, py = float(p_xy[0, 0]), float(p_xy[0, 1])
    face_in = bool(d > 0.05 and 0.0 <= px < width and 0.0 <= py < height)
    return SubjectFrame(bbox, float(visible), [px, py], d, float(lens.disparity(d)), face_in)
