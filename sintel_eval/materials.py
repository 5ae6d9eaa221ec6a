"""Node materials of the harness' scenes (bpy): procedural textures with explicit colours.

Each factory builds one material from a Principled BSDF (or an Emission shader) and takes its
colours (scene-linear RGB in [0, 1]) and texture offsets as arguments, so a seeded scene
passes its own draws. Shared by the demo scene and the generator.
"""
from __future__ import annotations

from .bpy_util import Mat, bpy, emission_material

RGB = tuple[float, float, float]


def skin(name: str, offset: tuple, dark: RGB = (0.45, 0.24, 0.16), light: RGB = (0.80, 0.55, 0.42)):
    """Skin: fine noise plus Voronoi pores between two tones."""
    m = Mat(name)
    n = m.node("ShaderNodeTexNoise", Scale=25.0, Detail=4.0, Roughness=0.6)
    m.link(m.coords("Object", offset=tuple(offset)), n.inputs["Vector"])
    v = m.node("ShaderNodeTexVoronoi", Scale=90.0)
    m.link(m.coords("Object"), v.inputs["Vector"])
    mix = m.node("ShaderNodeMath")
    mix.operation = "MULTIPLY_ADD"
    m.link(v.outputs["Distance"], mix.inputs[0])
    mix.inputs[1].default_value = 0.3
    m.link(n.outputs["Fac"], mix.inputs[2])
    return m.base(m.ramp(mix.outputs[0], [(0.35, dark), (0.95, light)]), roughness=0.45)


def hair(name: str, dark: RGB = (0.03, 0.015, 0.01), light: RGB = (0.28, 0.14, 0.06)):
    """Hair: streaky noise stretched along z."""
    m = Mat(name)
    n = m.node("ShaderNodeTexNoise", Scale=30.0, Detail=5.0, Roughness=0.7)
    m.link(m.coords("Object", scale=(6.0, 6.0, 0.6)), n.inputs["Vector"])
    return m.base(m.ramp(n.outputs["Fac"], [(0.3, dark), (0.7, light)]), roughness=0.35)


def glossy(name: str, rgb: RGB, roughness: float = 0.05, specular: float = 1.0):
    """A flat glossy colour (eyes)."""
    return Mat(name).base(tuple(rgb), roughness=roughness, specular=specular)


def flat(name: str, rgb: RGB, roughness: float = 0.7):
    """An untextured matte colour: the flat surfaces of the set."""
    return Mat(name).base(tuple(rgb), roughness=roughness, specular=0.2)


def sweater(name: str, main: RGB, stripe: RGB = (0.75, 0.70, 0.55)):
    """Knit-like wave texture between a main colour and a stripe colour."""
    m = Mat(name)
    w = m.node("ShaderNodeTexWave", Scale=9.0, Distortion=2.0, Detail=3.0)
    m.link(m.coords("Object"), w.inputs["Vector"])
    return m.base(m.ramp(w.outputs["Fac"], [(0.45, tuple(main)), (0.55, tuple(stripe))]), roughness=0.8)


def brick_wall(name: str, brick_a: RGB, brick_b: RGB, grime_offset: tuple):
    """Bricks (x-z plane, 0.5 m x 0.22 m) multiplied by large-scale paint/grime noise; matte."""
    m = Mat(name)
    b = m.node("ShaderNodeTexBrick", Scale=1.0, **{"Mortar Size": 0.025, "Brick Width": 0.5,
                                                   "Row Height": 0.22, "Bias": 0.0})
    b.offset = 0.5
    m.link(m.coords("Object", swizzle="xz"), b.inputs["Vector"])
    b.inputs["Color1"].default_value = (*brick_a, 1.0)
    b.inputs["Color2"].default_value = (*brick_b, 1.0)
    b.inputs["Mortar"].default_value = (0.55, 0.53, 0.50, 1.0)
    grime = m.node("ShaderNodeTexNoise", Scale=0.35, Detail=4.0)
    m.link(m.coords("Object", swizzle="xz", offset=tuple(grime_offset)), grime.inputs["Vector"])
    paint = m.ramp(grime.outputs["Fac"], [(0.35, (0.35, 0.45, 0.55)), (0.65, (1.0, 1.0, 1.0))])
    mul = m.node("ShaderNodeMix")
    mul.data_type = "RGBA"
    mul.blend_type = "MULTIPLY"
    # The Mix node has one socket per data type under the same name: pick the colour ones.
    rgba_in = {s.name: s for s in mul.inputs if s.type == "RGBA"}
    mul.inputs["Factor"].default_value = 1.0
    m.link(b.outputs["Color"], rgba_in["A"])
    m.link(paint, rgba_in["B"])
    result = next(s for s in mul.outputs if s.type == "RGBA")
    return m.base(result, roughness=0.9, specular=0.0)  # matte: cheaper to shade


def checker_floor(name: str, a: RGB = (0.30, 0.28, 0.25), b: RGB = (0.12, 0.11, 0.10), scale: float = 1.2):
    """A matte checkerboard (tiles of 1/scale m)."""
    m = Mat(name)
    ck = m.node("ShaderNodeTexChecker", Scale=1.0)
    m.link(m.coords("Object", scale=(scale, scale, scale)), ck.inputs["Vector"])
    ck.inputs["Color1"].default_value = (*a, 1.0)
    ck.inputs["Color2"].default_value = (*b, 1.0)
    return m.base(ck.outputs["Color"], roughness=0.7, specular=0.0)


def wood(name: str, offset: tuple):
    """Wood rings."""
    m = Mat(name)
    w = m.node("ShaderNodeTexWave", Scale=3.0, Distortion=6.0, Detail=4.0, **{"Detail Scale": 2.0})
    w.wave_type = "RINGS"
    m.link(m.coords("Object", scale=(1.0, 1.0, 0.15), offset=tuple(offset)), w.inputs["Vector"])
    return m.base(m.ramp(w.outputs["Fac"], [(0.2, (0.30, 0.15, 0.05)), (0.9, (0.65, 0.42, 0.20))]), roughness=0.5)


def marble(name: str, offset: tuple):
    """Blue-grey marble veins."""
    m = Mat(name)
    n = m.node("ShaderNodeTexNoise", Scale=4.0, Detail=6.0, Roughness=0.65, Distortion=3.0)
    m.link(m.coords("Object", offset=tuple(offset)), n.inputs["Vector"])
    return m.base(m.ramp(n.outputs["Fac"], [(0.40, (0.12, 0.22, 0.35)), (0.60, (0.70, 0.75, 0.80))]), roughness=0.3)


def checker_ball(name: str, a: RGB = (0.85, 0.65, 0.05), b: RGB = (0.05, 0.25, 0.55)):
    """A beach-ball checker on generated coordinates (rolls visibly)."""
    m = Mat(name)
    ck = m.node("ShaderNodeTexChecker", Scale=6.0)
    m.link(m.coords("Generated"), ck.inputs["Vector"])
    ck.inputs["Color1"].default_value = (*a, 1.0)
    ck.inputs["Color2"].default_value = (*b, 1.0)
    return m.base(ck.outputs["Color"], roughness=0.35)


def brushed_metal(name: str, metallic: float = 0.7):
    """Noisy grey metal (poles, rails)."""
    m = Mat(name)
    n = m.node("ShaderNodeTexNoise", Scale=60.0, Detail=2.0)
    m.link(m.coords("Object"), n.inputs["Vector"])
    m.bsdf.inputs["Metallic"].default_value = metallic
    return m.base(m.ramp(n.outputs["Fac"], [(0.3, (0.25, 0.27, 0.30)), (0.7, (0.55, 0.56, 0.58))]), roughness=0.4)


def chrome(name: str):
    """A mirror-like metal: reflects small emitters as specular highlights far above 1."""
    m = Mat(name)
    m.bsdf.inputs["Metallic"].default_value = 1.0
    return m.base((0.9, 0.9, 0.92), roughness=0.04, specular=1.0)


def leaf(name: str, offset: tuple, dark: RGB = (0.04, 0.12, 0.03), light: RGB = (0.20, 0.42, 0.08)):
    """Leaves: a green noise, slightly glossy, two-sided by default."""
    m = Mat(name)
    n = m.node("ShaderNodeTexNoise", Scale=12.0, Detail=3.0)
    m.link(m.coords("Object", offset=tuple(offset)), n.inputs["Vector"])
    return m.base(m.ramp(n.outputs["Fac"], [(0.3, dark), (0.7, light)]), roughness=0.5, specular=0.4)


def window(name: str, rgb: RGB, strength: float):
    """A lit window: an emitter seen by the camera only (HDR, large bokeh)."""
    return emission_material(name, rgb, strength)


def emitter(name: str, rgb: RGB, strength: float):
    """A small light bulb: emission seen by the camera only (see bpy_util.emission_material)."""
    return emission_material(name, rgb, strength)


def demo_library(rng) -> dict:
    """The demo scene's materials (draws from ``rng`` in the demo's historical order)."""
    out = {}
    out["skin"] = skin("skin", rng.uniform(0, 100, 3))
    out["hair"] = hair("hair")
    out["eye"] = glossy("eye", (0.02, 0.02, 0.025))
    out["sweater"] = sweater("sweater", tuple(rng.uniform([0.45, 0.03, 0.05], [0.65, 0.10, 0.12])))
    brick_a = tuple(rng.uniform([0.35, 0.10, 0.06], [0.50, 0.16, 0.10]))
    brick_b = tuple(rng.uniform([0.20, 0.12, 0.10], [0.32, 0.18, 0.14]))
    out["wall"] = brick_wall("wall", brick_a, brick_b, rng.uniform(0, 50, 3))
    out["floor"] = checker_floor("floor")
    out["wood"] = wood("wood", rng.uniform(0, 10, 3))
    out["marble"] = marble("marble", rng.uniform(0, 50, 3))
    out["ball"] = checker_ball("ball")
    out["pole"] = brushed_metal("pole")
    out["wire"] = Mat("wire").base((0.015, 0.015, 0.015), roughness=0.5)
    return out


__all__ = ["bpy", "skin", "hair", "glossy", "flat", "sweater", "brick_wall", "checker_floor", "wood", "marble",
           "checker_ball", "brushed_metal", "chrome", "leaf", "window", "emitter", "demo_library"]
