"""People-like figures of the harness (bpy): the ``person`` model of a :class:`~sintel_eval.look.FigureLook`.

Built from primitives under one root Empty, like the classic figure, with the same body
landmarks (hips at 0.9 m, head centre at 1.64 m, the focus point between the eyes at 1.665 m,
the mouth at 1.585 m; 1.75 m tall at scale 1), so a figure's depth, box and events mean the
same: legs with knees and shoes, pelvis, abdomen, chest and shoulders, arms with elbows and
hands, neck, head with chin, ears, nose, eyes (white and iris), eyebrows, lips and a jaw that
drops with the mouth, a hair cap with a style (short, long, bun, bob) and thin strands.

Every part's mesh is metric (scales are applied to the vertices), so photo textures on the
clothes keep their size from part to part. :func:`pose_person` poses the joints for a frame.
"""
from __future__ import annotations

import math

import numpy as np

from . import materials as mat
from .bpy_util import bmesh, empty, hair_strands, link_object, rod
from .look import FigureLook

HIP_Z = 0.9
JAW_DROP_M = 0.014  # how far the lower lip and chin drop when the mouth is fully open


def ellipsoid(name: str, radii, location, material, segments: int = 24, parent=None):
    """UV sphere scaled to ``radii`` (m) in its mesh (object scale stays 1), smooth shaded."""
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=max(8, segments // 2), radius=1.0)
    bmesh.ops.scale(bm, vec=tuple(float(r) for r in radii), verts=bm.verts)
    return link_object(name, bm, tuple(location), smooth=True, material=material, parent=parent)


def cone(name: str, r_top: float, r_bottom: float, z_top: float, z_bottom: float, material, segments: int = 24,
         parent=None, squash_y: float = 0.75):
    """A vertical truncated cone (a skirt), flattened front-to-back by ``squash_y``."""
    bm = bmesh.new()
    bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=segments, radius1=r_bottom, radius2=r_top,
                          depth=z_top - z_bottom)
    bmesh.ops.scale(bm, vec=(1.0, squash_y, 1.0), verts=bm.verts)
    return link_object(name, bm, (0.0, 0.0, 0.5 * (z_top + z_bottom)), smooth=True, material=material,
                       parent=parent)


def build_person(c, fl: FigureLook, rng: np.random.Generator, cloth) -> dict:
    """Create the figure of character ``c`` with looks ``fl``.

    cloth(slot, rgb, kind, name) -> material: the clothes' material (a photo texture when the
    plan textured ``slot``, else procedural by ``kind``). Returns {root, hips, mouth, focus, parts, joints,
    mouth_scale} for :class:`~sintel_eval.scene_builder.CharacterRig`.
    """
    n = c.name
    b = fl.build
    root = empty(f"{n}_root", (*c.motion.start, 0.0))
    root.scale = (c.height, c.height, c.height)
    tone = np.array(fl.skin)
    skin_m = mat.skin(f"{n}_skin", rng.uniform(0, 100, 3), tuple(tone * 0.56), tuple(tone))
    hair_m = mat.hair(f"{n}_hair", tuple(np.array(fl.hair) * 0.4), tuple(fl.hair))
    top_m = cloth(fl.top_texture, fl.top_rgb, fl.top, f"{n}_top")
    bottom_m = cloth(fl.bottom_texture, fl.bottom_rgb, "trousers", f"{n}_bottom")
    shoes_m = mat.flat(f"{n}_shoes", fl.shoes_rgb, roughness=0.35)
    lips_m = mat.flat(f"{n}_lips", fl.lips_rgb, roughness=0.4)
    mouth_m = mat.flat(f"{n}_mouth", (0.12, 0.02, 0.02), roughness=0.5)
    sclera_m = mat.glossy(f"{n}_sclera", (0.72, 0.70, 0.66), roughness=0.15)
    iris_m = mat.glossy(f"{n}_iris", tuple(float(v) for v in rng.uniform(0.01, 0.08, 3)), roughness=0.05)
    sleeve_m = top_m if fl.sleeves == "long" else skin_m
    parts, joints = [], {}
    hips = []
    bulk = 1.06 if fl.top == "jacket" else 1.0
    # -- legs: thigh, knee, shin, shoe (hip -> knee 0.44 m, knee -> sole 0.46 m)
    for side in (-1.0, 1.0):
        s = "lr"[side > 0]
        hip = empty(f"{n}_hip_{s}", (side * 0.095 * b, 0.0, HIP_Z), parent=root)
        parts.append(rod(f"{n}_thigh_{s}", (0.0, 0.0, 0.0), (0.0, 0.0, -0.44), 0.072, bottom_m, 12, parent=hip))
        knee = empty(f"{n}_knee_{s}", (0.0, 0.0, -0.44), parent=hip)
        parts.append(ellipsoid(f"{n}_kneecap_{s}", (0.06, 0.06, 0.06), (0.0, 0.0, 0.0), bottom_m, 12, parent=knee))
        parts.append(rod(f"{n}_shin_{s}", (0.0, 0.0, 0.0), (0.0, 0.0, -0.40), 0.054, bottom_m, 12, parent=knee))
        parts.append(ellipsoid(f"{n}_shoe_{s}", (0.052, 0.125, 0.045), (0.0, -0.045, -0.415), shoes_m, 16,
                               parent=knee))
        hips.append(hip)
        joints[f"knee_{s}"] = knee
    # -- trunk
    parts.append(ellipsoid(f"{n}_pelvis", (0.155 * b, 0.105, 0.11), (0.0, 0.0, 0.93),
                           top_m if fl.top == "dress" else bottom_m, 24, parent=root))
    parts.append(ellipsoid(f"{n}_abdomen", (0.148 * b * bulk, 0.10 * bulk, 0.16), (0.0, 0.0, 1.08), top_m, 24,
                           parent=root))
    parts.append(ellipsoid(f"{n}_chest", (0.172 * b * bulk, 0.115 * bulk, 0.19), (0.0, 0.0, 1.25), top_m, 28,
                           parent=root))
    parts.append(ellipsoid(f"{n}_shoulders", (0.21 * b, 0.10, 0.07), (0.0, 0.0, 1.385), top_m, 24, parent=root))
    parts.append(ellipsoid(f"{n}_trapezius", (0.12 * b, 0.08, 0.06), (0.0, 0.01, 1.43), top_m, 20, parent=root))
    if fl.top == "dress":
        parts.append(cone(f"{n}_skirt", 0.16 * b, 0.25 * b, 1.0, 0.45, top_m, 28, parent=root))
    elif fl.top == "jacket":
        parts.append(cone(f"{n}_hem", 0.165 * b, 0.18 * b, 1.0, 0.82, top_m, 24, parent=root, squash_y=0.7))
    # -- arms: shoulder -> elbow 0.29 m, elbow -> wrist 0.25 m, hand
    for side in (-1.0, 1.0):
        s = "lr"[side > 0]
        shoulder = empty(f"{n}_shoulder_{s}", (side * 0.195 * b, 0.0, 1.375), parent=root)
        parts.append(ellipsoid(f"{n}_deltoid_{s}", (0.055, 0.055, 0.06), (0.0, 0.0, 0.0), top_m, 12,
                               parent=shoulder))
        parts.append(rod(f"{n}_upper_arm_{s}", (0.0, 0.0, 0.0), (side * 0.025, 0.0, -0.29), 0.044, top_m, 12,
                         parent=shoulder))
        elbow = empty(f"{n}_elbow_{s}", (side * 0.025, 0.0, -0.29), parent=shoulder)
        parts.append(rod(f"{n}_forearm_{s}", (0.0, 0.0, 0.0), (0.0, 0.0, -0.25), 0.036, sleeve_m, 12, parent=elbow))
        parts.append(ellipsoid(f"{n}_hand_{s}", (0.024, 0.04, 0.055), (0.0, 0.0, -0.3), skin_m, 12, parent=elbow))
        joints[f"shoulder_{s}"] = shoulder
        joints[f"elbow_{s}"] = elbow
    # -- neck and head
    parts.append(rod(f"{n}_neck", (0.0, 0.008, 1.40), (0.0, 0.0, 1.57), 0.053, skin_m, 16, parent=root))
    parts.append(ellipsoid(f"{n}_head", (0.088, 0.098, 0.112), (0.0, 0.0, 1.64), skin_m, 40, parent=root))
    for side in (-1.0, 1.0):
        s = "lr"[side > 0]
        parts.append(ellipsoid(f"{n}_ear_{s}", (0.012, 0.024, 0.033), (side * 0.087, 0.004, 1.64), skin_m, 12,
                               parent=root))
        parts.append(ellipsoid(f"{n}_sclera_{s}", (0.0125, 0.009, 0.0085), (side * 0.032, -0.083, 1.665), sclera_m,
                               12, parent=root))
        parts.append(ellipsoid(f"{n}_iris_{s}", (0.0062, 0.004, 0.0062), (side * 0.032, -0.0915, 1.665), iris_m, 10,
                               parent=root))
        parts.append(rod(f"{n}_brow_{s}", (side * 0.014, -0.094, 1.688), (side * 0.05, -0.087, 1.69), 0.0035,
                         hair_m, 5, parent=root))
    parts.append(ellipsoid(f"{n}_nose", (0.012, 0.02, 0.024), (0.0, -0.098, 1.626), skin_m, 12, parent=root))
    parts.append(ellipsoid(f"{n}_upper_lip", (0.022, 0.009, 0.0055), (0.0, -0.089, 1.597), lips_m, 12, parent=root))
    mouth = ellipsoid(f"{n}_mouth", (0.027, 0.022, 0.022), (0.0, -0.086, 1.585), mouth_m, 16, parent=root)
    mouth.scale = (1.0, 0.55, 0.15)
    parts.append(mouth)
    jaw = empty(f"{n}_jaw", (0.0, 0.0, 1.585), parent=root)
    parts.append(ellipsoid(f"{n}_lower_lip", (0.021, 0.009, 0.0065), (0.0, -0.088, -0.012), lips_m, 12, parent=jaw))
    parts.append(ellipsoid(f"{n}_chin", (0.04, 0.045, 0.03), (0.0, -0.052, -0.042), skin_m, 16, parent=jaw))
    joints["jaw"] = jaw
    # -- hair
    parts.append(ellipsoid(f"{n}_hair", (0.0985, 0.101, 0.119), (0.0, 0.022, 1.67), hair_m, 40, parent=root))
    if fl.hairstyle == "long":
        parts.append(ellipsoid(f"{n}_hair_back", (0.095, 0.06, 0.19), (0.0, 0.065, 1.5), hair_m, 24, parent=root))
    elif fl.hairstyle == "bun":
        parts.append(ellipsoid(f"{n}_bun", (0.045, 0.045, 0.042), (0.0, 0.095, 1.73), hair_m, 16, parent=root))
    elif fl.hairstyle == "bob":
        parts.append(ellipsoid(f"{n}_bob", (0.108, 0.1, 0.085), (0.0, 0.028, 1.61), hair_m, 24, parent=root))
    strand_len = {"short": (0.08, 0.16), "bun": (0.08, 0.16), "bob": (0.14, 0.22), "long": (0.3, 0.45)}[fl.hairstyle]
    parts += hair_strands(n, c.hair_strands, rng, strand_len, hair_m, parent=root)
    focus = empty(f"{n}_focus", (0.0, -0.1, 1.665), parent=root)  # between the eyes, on the face
    for p in parts:
        p.pass_index = c.index
    return {"root": root, "hips": tuple(hips), "mouth": mouth, "focus": focus, "parts": parts, "joints": joints,
            "mouth_scale": (1.0, 0.55)}


def pose_person(joints: dict, phase: float, walking: bool, opening: float) -> None:
    """Knees, arms and jaw for a frame: ``phase`` (rad) of the walk cycle, ``opening`` 0..1 of
    the mouth. Rotations about x: + swings a hanging limb backwards (+y), - forwards."""
    swing = 0.4 * math.sin(phase) if walking else 0.0
    for s, sign, offset in (("l", 1.0, 0.0), ("r", -1.0, math.pi)):
        knee = 0.12 + 0.5 * max(0.0, math.sin(phase + offset + 0.6)) if walking else 0.03
        joints[f"knee_{s}"].rotation_euler = (knee, 0.0, 0.0)
        side = -1.0 if s == "l" else 1.0
        joints[f"shoulder_{s}"].rotation_euler = (-0.8 * sign * swing, -side * 0.07, 0.0)
        joints[f"elbow_{s}"].rotation_euler = (-(0.25 + 0.2 * max(0.0, -sign * swing / 0.4)) if walking else -0.12,
                                               0.0, 0.0)
    joints["jaw"].location.z = 1.585 - JAW_DROP_M * float(opening)
