"""Blender (bpy) building blocks shared by the harness' scenes: meshes, node materials, Cycles
render settings, multilayer-EXR read-back and atomic file writes.

Everything here acts on ``bpy.context.scene`` of a fresh factory state (see
:func:`reset_blender`). Lengths are metres, angles radians, colours scene-linear Rec.709.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rvr_addon.errors import OutputError
from rvr_addon.io.exr import read_exr
from rvr_addon.io.paths import temp_sibling

try:  # sintel_eval may import bpy; give a clear message where it is missing.
    import bpy
    import bmesh
except ImportError as exc:  # pragma: no cover - exercised only without bpy
    raise ImportError(
        "bpy is not installed: run ./scripts/setup.sh (it installs bpy==5.0.1 into .venv)"
    ) from exc

FPS = 24


def reset_blender() -> None:
    """Fresh, empty factory state (no user preferences, no startup file, no leftovers)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)


def link_object(name: str, bm: "bmesh.types.BMesh", location=(0.0, 0.0, 0.0), smooth: bool = False,
                material=None, scale=(1.0, 1.0, 1.0), parent=None):
    """Turn ``bm`` into a mesh object linked to the scene (``bm`` is freed); ``parent`` makes the
    location/scale local to that object."""
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
    if parent is not None:
        obj.parent = parent
    bpy.context.scene.collection.objects.link(obj)
    return obj


def sphere(name, radius, location, material, segments=32, scale=(1.0, 1.0, 1.0), parent=None):
    """UV sphere of ``radius`` (m) centred at ``location``, smooth shaded."""
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=max(8, segments // 2), radius=radius)
    return link_object(name, bm, location, smooth=True, material=material, scale=scale, parent=parent)


def cylinder(name, radius, z0, z1, xy, material, segments=24, parent=None):
    """Vertical capped cylinder from height z0 to z1 (m) at (x, y)."""
    bm = bmesh.new()
    bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=segments,
                          radius1=radius, radius2=radius, depth=z1 - z0)
    return link_object(name, bm, (xy[0], xy[1], 0.5 * (z0 + z1)), smooth=True, material=material, parent=parent)


def hair_strands(name: str, count: int, rng, length_range: tuple[float, float], material, parent=None) -> list:
    """``count`` thin hair strands from the crown (z 1.73 m) of a figure: most hang down the back
    (``length_range`` m long), every fourth flies off a side. Draws from ``rng`` in a fixed order."""
    strands = []
    for k in range(count):
        sx, sy = float(rng.uniform(-0.07, 0.07)), float(rng.uniform(0.0, 0.07))
        start = (sx, sy, 1.73)
        if k % 4 == 0:
            side = 1.0 if sx >= 0 else -1.0
            end = (sx + side * float(rng.uniform(0.1, 0.16)), sy + 0.02, 1.73 + float(rng.uniform(-0.08, 0.06)))
        else:
            end = (sx * 1.6 + float(rng.uniform(-0.04, 0.04)), sy + float(rng.uniform(0.04, 0.09)),
                   1.73 - float(rng.uniform(*length_range)))
        strands.append(rod(f"{name}_strand_{k}", start, end, float(rng.uniform(0.0012, 0.002)), material, 5,
                           parent=parent))
    return strands


def rod(name, p0, p1, radius, material, segments=8, parent=None):
    """Capped cylinder of ``radius`` (m) from point p0 to p1 (any direction): strands, rails, twigs."""
    from mathutils import Vector

    a, b = Vector(p0), Vector(p1)
    axis = b - a
    bm = bmesh.new()
    bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=segments,
                          radius1=radius, radius2=radius, depth=axis.length)
    rot = axis.to_track_quat("Z", "Y").to_matrix().to_4x4()
    bmesh.ops.transform(bm, matrix=rot, verts=bm.verts)
    return link_object(name, bm, tuple((a + b) / 2.0), smooth=True, material=material, parent=parent)


def box(name, size, location, material, parent=None):
    """Axis-aligned box of ``size`` (sx, sy, sz) m centred at ``location``."""
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0)
    bmesh.ops.scale(bm, vec=size, verts=bm.verts)
    return link_object(name, bm, location, material=material, parent=parent)


def quad(name, corners, material, parent=None):
    """One planar polygon through ``corners`` (world or parent-local coordinates)."""
    bm = bmesh.new()
    verts = [bm.verts.new(c) for c in corners]
    bm.faces.new(verts)
    return link_object(name, bm, material=material, parent=parent)


def empty(name: str, location=(0.0, 0.0, 0.0), parent=None):
    """An Empty (a transform node grouping a character's parts)."""
    obj = bpy.data.objects.new(name, None)
    obj.location = location
    if parent is not None:
        obj.parent = parent
    bpy.context.scene.collection.objects.link(obj)
    return obj


class Mat:
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


def emission_material(name: str, rgb, strength: float):
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


def aim(obj, target) -> None:
    from mathutils import Vector

    direction = Vector(target) - Vector(obj.location)
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def denoiser_available() -> bool:
    """True when this Cycles build has OpenImageDenoise."""
    import _cycles  # Cycles' own module: tells whether OpenImageDenoise was compiled in

    return bool(getattr(_cycles, "with_openimagedenoise", False))


def setup_render(scene, width: int, height: int, samples: int, seed: int, denoise: bool, fps: int = FPS,
                 object_index: bool = False) -> str:
    """Cycles on the CPU, fixed seed, no adaptive sampling, Standard view transform, no dither,
    Combined + Z (+ IndexOB) passes. Returns the denoiser used ("OPENIMAGEDENOISE" or "none")."""
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
        if denoiser_available():
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
    r.fps, r.fps_base = int(fps), 1.0
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
    vl.use_pass_object_index = bool(object_index)
    return denoiser


def set_image_settings(scene, kind: str) -> None:
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


def read_passes(path: Path, object_index: bool = False, depth: bool = True) -> dict[str, np.ndarray]:
    """Blender multilayer EXR -> {"rgb": (H, W, 3) linear float32, "z": (H, W) planar depth m,
    "id": (H, W) object pass index (float-coded integer)}; only the passes asked for."""
    chans = read_exr(path)

    def find(suffix):
        hits = [k for k in chans if k.endswith(suffix)]
        if not hits:
            raise OutputError(f"{path}: no channel '*{suffix}' in the render (channels: {sorted(chans)}); "
                              "the view layer lacks that pass")
        return chans[hits[0]]

    out = {"rgb": np.dstack([find(f"Combined.{c}") for c in "RGB"])}
    if depth:
        out["z"] = find("Depth.Z")
    if object_index:
        out["id"] = find("Object Index.X")
    return out


def read_multilayer(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Blender multilayer EXR -> (linear RGB float32 (H, W, 3), Z float32 (H, W))."""
    passes = read_passes(path)
    return passes["rgb"], passes["z"]


def atomic(path: Path, suffix: str, write) -> None:
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


def working_space() -> str:
    """The blend file's scene-linear working space (Blender 5.0+; Linear Rec.709 before)."""
    colorspace = getattr(bpy.data, "colorspace", None)
    return str(getattr(colorspace, "working_space", "") or "Linear Rec.709")
