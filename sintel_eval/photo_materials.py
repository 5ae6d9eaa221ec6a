"""Node materials of the ``photo`` style (bpy): crops of real photographs as image textures.

Every image is loaded once (``check_existing``) in the sRGB colour space, so its 8-bit values
become scene-linear albedo (or, for billboards, radiance) through the sRGB EOTF. Coordinates are
metric object coordinates: a tiled texture repeats (mirrored, so crops tile without seams) every
``tile_m`` metres; posters and billboards are mapped once onto their face.
"""
from __future__ import annotations

from pathlib import Path

from .bpy_util import Mat, bpy

RGB = tuple[float, float, float]


def load_image(path: str | Path):
    """The image at ``path`` as a bpy image in the sRGB colour space (loaded once per path)."""
    img = bpy.data.images.load(str(path), check_existing=True)
    img.colorspace_settings.name = "sRGB"
    return img


def _image_node(m: Mat, path: str | Path, extension: str, box: bool = False):
    tex = m.nt.nodes.new("ShaderNodeTexImage")
    tex.image = load_image(path)
    tex.extension = extension
    tex.interpolation = "Linear"
    if box:
        tex.projection = "BOX"
        tex.projection_blend = 0.25
    return tex


def tiled(name: str, path: str | Path, tile_m: float, swizzle: str | None = None, box: bool = False,
          roughness: float = 0.7, specular: float = 0.3):
    """A photo repeated every ``tile_m`` m over a surface: ``swizzle`` picks the plane of a flat
    surface ("xz" walls, "xy" floors); ``box`` projects it from the three axes (crates, clothes)."""
    m = Mat(name)
    tex = _image_node(m, path, "MIRROR", box=box)
    s = 1.0 / float(tile_m)
    m.link(m.coords("Object", swizzle=swizzle, scale=(s, s, s)), tex.inputs["Vector"])
    return m.base(tex.outputs["Color"], roughness=roughness, specular=specular)


def mapped(name: str, path: str | Path, origin_xz: tuple[float, float], size_xz: tuple[float, float],
           roughness: float = 0.5, specular: float = 0.3, emission: float = 0.0):
    """A photo mapped once onto the x-z rectangle ``origin_xz`` (lower-left, object coordinates)
    of size ``size_xz`` m (posters, billboards). ``emission`` > 0 also makes it glow with the
    photo's own colours (a back-lit print or a screen: the photo's look survives any lighting);
    it is not sampled as a light, so it adds no noise."""
    m = Mat(name)
    tex = _image_node(m, path, "EXTEND")
    (x0, z0), (w, h) = origin_xz, size_xz
    m.link(m.coords("Object", swizzle="xz", scale=(1.0 / w, 1.0 / h, 1.0), offset=(-x0 / w, -z0 / h, 0.0)),
           tex.inputs["Vector"])
    if emission > 0:
        m.link(tex.outputs["Color"], m.bsdf.inputs["Emission Color"])
        m.bsdf.inputs["Emission Strength"].default_value = float(emission)
        m.mat.cycles.emission_sampling = "NONE"
    return m.base(tex.outputs["Color"], roughness=roughness, specular=specular)


def glowing(name: str, rgb: RGB, strength: float, base: RGB = (0.8, 0.8, 0.8)):
    """A lamp shade: diffuse ``base`` plus emission ``rgb * strength`` seen by the camera (the
    light it casts comes from a light object; the surface itself is not sampled)."""
    m = Mat(name)
    m.bsdf.inputs["Emission Color"].default_value = (*rgb, 1.0)
    m.bsdf.inputs["Emission Strength"].default_value = float(strength)
    m.mat.cycles.emission_sampling = "NONE"
    return m.base(tuple(base), roughness=0.8, specular=0.1)


__all__ = ["load_image", "tiled", "mapped", "glowing"]
