"""Benchmark baseline: Blender's own Compositor *Defocus* node, run headlessly through bpy 5.0.

``blender_defocus(image_srgb, radius_px, max_radius_px=...)`` blurs an 8-bit sRGB frame with a
per-pixel blur-radius map using Blender's Defocus node and returns (seconds per frame, linear
float RGB output).  It is meant to be run in the same process/run as our renderer so that the
two can be compared on the same image and the same blur radii.

How the Defocus node works in Blender 5.0 (source: source/blender/nodes/composite/nodes/
node_composite_defocus.cc and compositor/cached_resources/intern/bokeh_kernel.cc; confirmed by
the experiments in ``_footprint`` / the ``__main__`` demo below):

* Sockets: ``Image`` (colour) and ``Z`` (float; the 0..1 soft range only applies to the
  unconnected default value, a connected image can carry any value).  Everything else is still
  a node *property* in 5.0 (not a socket): ``bokeh`` (CIRCLE, TRIANGLE .. OCTAGON), ``angle``
  (rad, ignored for CIRCLE), ``f_stop``, ``blur_max``, ``use_zbuffer``, ``z_scale`` and
  ``scene`` (whose active camera is used).  The old ``samples``/``use_preview``/``threshold``/
  ``use_gamma_correction`` options are gone: 5.0 always does the exact full gather.
* Radius map.  ``use_zbuffer=False`` ("No Z-buffer"):  radius = clamp(Z * z_scale, 0, blur_max)
  in PIXELS -- no camera involved.  ``use_zbuffer=True``: Z is a metric depth and the radius is
  the Potmesil-Chakravarty circle of confusion of the scene camera (focal length, focus
  distance = camera DOF distance, sensor fit/size -> pixels per metre) with the node's
  ``f_stop`` (NOT the camera's), capped at blur_max; that radius map is then eroded by a
  "morphological blur" (min(r, gaussian_blur(r, max radius))) so sharp regions are not
  overrun -- which changes the radii near any in-focus edge.
* Gather.  For every output pixel p with radius r_p, every neighbour q within the square
  search window of half-size ceil(max radius) contributes with radius r = min(r_p, r_q), only
  if max(|dx|, |dy|) <= r, weighted by a bokeh kernel image (size 2*ceil(blur_max)+1,
  circumradius blur_max+0.5, 1-texel linear anti-aliasing at the rim) bilinearly sampled after
  scaling it to a (2r+1)-pixel footprint; the result is the normalised weighted mean (a
  *gather* filter; no occlusion/layering, no premultiplied depth ordering).  blur_max < 1 makes
  the node a pass-through.  Cost is O(W*H*(2*ceil(blur_max)+1)^2) regardless of the radii.

Mapping used here (default, ``use_zbuffer=False``): Z input = radius_px (float32 written into
all RGB channels of a Non-Color float image, so the implicit colour->float conversion is
exact), ``z_scale = 1``, ``blur_max = max_radius_px``; Blender therefore uses per pixel exactly
radius r = min(radius_px, max_radius_px) (subject to the min(r_p, r_q) gather rule above).
Footprint for a constant radius r (measured with an impulse, ``_footprint``; blur_max = 32):
the point spread function is the bokeh disk of radius ~r + 0.5 clipped to the square
max(|dx|, |dy|) <= r, so its support half-width is floor(r) (integer steps!) and r < 1 gives no
blur at all.  Area-equivalent radius, Blender vs our anti-aliased disk kernel of radius r:

    r (px)      0.75   1.0   1.5   2.0   3.0   4.0   6.0   8.0   11    16    24    32
    Blender     0.56   1.69  1.69  2.59  3.43  4.48  6.48  8.39  11.36 16.25 24.11 32.00
    ours        0.75   1.00  1.50  2.00  3.00  4.00  6.00  8.00  11.00 16.00 24.00 32.00

i.e. Blender's blur radius is within about -0.2..+0.7 px of ours (typically +0.3..+0.5 px;
the excess shrinks as r approaches blur_max because the kernel's 1-texel anti-aliasing band is
scaled by (2r+1)/(2*blur_max+1)); ~+3 % at 16 px, ~0 % at 32 px, but up to +70 % at 1 px.  No
bias is applied: because the support is quantised to floor(r), shifting the input cannot
track fractional radii any better, it only trades the error sign.

The ``use_zbuffer=True`` variant (camera + depth derived from the radius map by inverting the
far-side CoC formula) is also provided for completeness.  Checked: for a constant radius map it
reproduces the no-Z-buffer output to ~3e-6, and on a smooth ramp it differs only at a few
columns where the float32 round trip moves r across an integer (support step); but near depth
*discontinuities* the erosion step shrinks the larger radii (within ~blur_max px of the edge),
so it does not reproduce an arbitrary radius map.

Execution: the node group is assigned to a private scene's ``compositing_node_group`` (5.0
replaced ``scene.node_tree``); there is no Composite node any more, the final output is a
``NodeGroupOutput`` fed through a colour output socket of the group interface.  The scene has
no Render Layers node, so ``bpy.ops.render.render(scene=...)`` renders nothing 3-D and only
runs the compositor (CPU device: GPU compositing is unavailable in background mode).  In
background mode Blender 5.0 does NOT evaluate Viewer nodes during a render (only the group
output and File Output nodes), and the Render Result image has no readable ``pixels``, so the
output is fetched after the timed region via ``Image.save_render`` to an uncompressed float
EXR in a temp dir and reloaded with bpy.
"""
from __future__ import annotations

import math
import os
import statistics
import tempfile
import time
from dataclasses import dataclass

import numpy as np

SCENE_NAME = "RVR_DefocusBench"
GROUP_NAME = "RVR_DefocusBenchGroup"

#: Details of the most recent ``blender_defocus`` call (timings, settings, note).
LAST_RUN: dict = {}


def _srgb_to_linear(x01: np.ndarray) -> np.ndarray:
    try:  # keep the exact same conversion as the renderer when the package is importable
        from rvr_addon.color import srgb_to_linear

        return np.asarray(srgb_to_linear(x01), dtype=np.float32)
    except Exception:  # pragma: no cover - standalone use
        x = np.asarray(x01, dtype=np.float32)
        return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4).astype(np.float32)


@dataclass
class _Bench:
    scene: object
    group: object
    src: object
    size: object
    defocus: object
    camera_obj: object
    width: int
    height: int


_BENCH: _Bench | None = None


def _ensure_bench(width: int, height: int):
    """Build (once) the private scene + compositor node group:

    Image(src) ----------------> Defocus.Image
    Image(size, Non-Color) ----> Defocus.Z          Defocus.Image -> Group Output "Image"
    """
    global _BENCH
    import bpy

    if _BENCH is not None:
        try:
            _BENCH.scene.name  # still valid (not freed by a factory reset)?
        except ReferenceError:
            _BENCH = None
    if _BENCH is not None and (_BENCH.width, _BENCH.height) == (width, height):
        return _BENCH

    scene = bpy.data.scenes.get(SCENE_NAME) or bpy.data.scenes.new(SCENE_NAME)
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.use_border = False
    r.use_compositing = True
    r.use_sequencer = False
    r.compositor_device = "CPU"  # the only device available in background mode
    r.compositor_precision = "FULL"
    r.use_persistent_data = False
    scene.view_settings.view_transform = "Standard"  # irrelevant for float EXR, but be explicit
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    im = r.image_settings
    im.file_format = "OPEN_EXR"
    im.color_depth = "32"
    im.color_mode = "RGBA"
    im.exr_codec = "NONE"

    # Camera (only used by the use_zbuffer=True variant; the Defocus node reads scene.camera).
    cam_obj = bpy.data.objects.get(SCENE_NAME + "_Camera")
    if cam_obj is None:
        cam_data = bpy.data.cameras.new(SCENE_NAME + "_Camera")
        cam_obj = bpy.data.objects.new(SCENE_NAME + "_Camera", cam_data)
        scene.collection.objects.link(cam_obj)
    scene.camera = cam_obj

    group = bpy.data.node_groups.get(GROUP_NAME)
    if group is not None:
        bpy.data.node_groups.remove(group)
    group = bpy.data.node_groups.new(GROUP_NAME, "CompositorNodeTree")
    group.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    scene.compositing_node_group = group

    for name in (SCENE_NAME + "_src", SCENE_NAME + "_size"):
        old = bpy.data.images.get(name)
        if old is not None:
            bpy.data.images.remove(old)
    src = bpy.data.images.new(SCENE_NAME + "_src", width, height, alpha=True, float_buffer=True)
    src.colorspace_settings.name = "Linear Rec.709"  # pixels are written as scene-linear floats
    size = bpy.data.images.new(SCENE_NAME + "_size", width, height, alpha=True, float_buffer=True)
    size.colorspace_settings.name = "Non-Color"  # raw data: radius in px / depth in m

    n_src = group.nodes.new("CompositorNodeImage")
    n_src.image = src
    n_size = group.nodes.new("CompositorNodeImage")
    n_size.image = size
    defocus = group.nodes.new("CompositorNodeDefocus")
    defocus.bokeh = "CIRCLE"
    defocus.angle = 0.0
    out = group.nodes.new("NodeGroupOutput")
    group.links.new(n_src.outputs["Image"], defocus.inputs["Image"])
    group.links.new(n_size.outputs["Image"], defocus.inputs["Z"])
    group.links.new(defocus.outputs["Image"], out.inputs[0])

    _BENCH = _Bench(scene, group, src, size, defocus, cam_obj, width, height)
    return _BENCH


def _set_pixels(img, rgba_top_down: np.ndarray) -> None:
    # bpy image rows are stored bottom-up
    img.pixels.foreach_set(np.ascontiguousarray(rgba_top_down[::-1], dtype=np.float32).ravel())
    img.update()


def _render_once(scene_name: str) -> float:
    import bpy

    t0 = time.perf_counter()
    bpy.ops.render.render(scene=scene_name)
    return time.perf_counter() - t0


def _read_render_result(bench: _Bench) -> np.ndarray:
    import bpy

    rr = bpy.data.images["Render Result"]
    with tempfile.TemporaryDirectory(prefix="rvr_blender_defocus_", dir="/dev/shm" if os.path.isdir("/dev/shm") else None) as d:
        path = os.path.join(d, "out.exr")
        rr.save_render(path, scene=bench.scene)
        img = bpy.data.images.load(path, check_existing=False)
        try:
            w, h = img.size
            buf = np.empty(w * h * 4, dtype=np.float32)
            img.pixels.foreach_get(buf)
        finally:
            bpy.data.images.remove(img)
    out = buf.reshape(h, w, 4)[::-1, :, :3]
    return np.ascontiguousarray(out)


def zbuffer_depth_from_radius(radius_px: np.ndarray, *, width: int, max_radius_px: float,
                              focal_mm: float = 50.0, sensor_mm: float = 36.0,
                              focus_m: float = 1.0, headroom: float = 2.0) -> tuple[np.ndarray, float]:
    """Depth map (metres) and node f-stop that make Blender's Z-buffer CoC equal ``radius_px``.

    Blender (Potmesil & Chakravarty): Vp = f*D/(D-f), Vu = f*z/(z-f),
    diameter = |Vu - Vp| * f / (N * Vu), radius_px = diameter/2 * ppm, ppm = width / sensor.
    Using the far side (z >= D) only: diameter = (Vp - f)/N - f*Vp/(N*z), hence
    z = f*Vp / (Vp - f - N*diameter).  N is chosen so that the radius at infinity is
    ``headroom * max_radius_px`` (keeps depths finite and well conditioned).
    """
    f = focal_mm / 1000.0
    ppm = width / (sensor_mm / 1000.0)
    vp = f * focus_m / (focus_m - f)
    n = (vp - f) * ppm / (2.0 * headroom * max(max_radius_px, 1e-3))
    diam = 2.0 * np.asarray(radius_px, dtype=np.float64) / ppm
    z = f * vp / (vp - f - n * diam)
    return z.astype(np.float32), float(n)


def blender_defocus(image_srgb: np.ndarray, radius_px: np.ndarray, *, max_radius_px: float,
                    repeats: int = 3, samples_note: str = "",
                    use_zbuffer: bool = False, measure: bool = True) -> tuple[float, np.ndarray]:
    """Run Blender's Compositor Defocus node on image_srgb (H, W, 3) uint8 sRGB with a per-pixel
    blur RADIUS map radius_px (H, W) float32 in pixels (>= 0; our renderer's |signed radius|),
    configured so that Blender blurs each pixel by (as close as Blender allows) the same radius,
    max blur = max_radius_px. Returns (seconds per frame of the compositor execution, measured as
    the median of `repeats` runs after one warm-up, excluding scene setup and image loading where
    possible; and the output image as float32 linear RGB (H, W, 3)).

    Mapping (default): Defocus "No Z-buffer" mode, Z input = radius_px, z_scale = 1,
    blur_max = max_radius_px -> Blender radius = min(radius_px, max_radius_px) px exactly
    (footprint ~0.5 px larger than our disk kernel, see module docstring).
    ``use_zbuffer=True``: the radius map is turned into a depth map for a 50 mm / 36 mm-sensor
    camera focused at 1 m with a matching node f-stop (see ``zbuffer_depth_from_radius``);
    Blender then also erodes the radius map, so radii near sharper regions shrink.

    The timing is the wall time of ``bpy.ops.render.render()`` on a scene without render layers
    (= one compositor evaluation: reading the two in-memory images, the Defocus node, writing the
    render result). ``measure=False`` renders once (no warm-up, no muted pass-through runs) for
    callers that only want the image, e.g. the ablation harness. ``LAST_RUN`` additionally holds the same timing with the Defocus node muted
    (pass-through overhead) and their difference. ``samples_note`` is only recorded in
    ``LAST_RUN`` (Blender 5.0's Defocus has no sample-count setting; it always gathers exactly).
    """
    img = np.asarray(image_srgb)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ValueError(f"image_srgb must be (H, W, 3), got {img.shape}")
    h, w = img.shape[:2]
    rad = np.asarray(radius_px, dtype=np.float32)
    if rad.shape != (h, w):
        raise ValueError(f"radius_px must be (H, W) = {(h, w)}, got {rad.shape}")
    if not (max_radius_px >= 0 and math.isfinite(max_radius_px)):
        raise ValueError(f"max_radius_px must be a finite number >= 0, got {max_radius_px}")
    repeats = max(1, int(repeats))
    rad = np.clip(np.nan_to_num(rad, nan=0.0, posinf=max_radius_px, neginf=0.0), 0.0, max_radius_px)

    if img.dtype == np.uint8:
        lin = _srgb_to_linear(img[..., :3].astype(np.float32) / 255.0)
    else:  # tolerate float sRGB in [0, 1]
        lin = _srgb_to_linear(np.clip(img[..., :3].astype(np.float32), 0.0, 1.0))

    t_setup = time.perf_counter()
    bench = _ensure_bench(w, h)
    d = bench.defocus
    d.mute = False
    d.blur_max = float(max_radius_px)
    if use_zbuffer:
        z, f_stop = zbuffer_depth_from_radius(rad, width=w, max_radius_px=max_radius_px)
        cam = bench.camera_obj.data
        cam.type = "PERSP"
        cam.lens = 50.0
        cam.sensor_fit = "HORIZONTAL"
        cam.sensor_width = 36.0
        cam.dof.focus_object = None
        cam.dof.focus_distance = 1.0
        d.use_zbuffer = True
        d.f_stop = f_stop
        d.z_scale = 1.0
        size_map = z
    else:
        d.use_zbuffer = False
        d.z_scale = 1.0
        d.f_stop = 128.0
        size_map = rad

    rgba = np.empty((h, w, 4), np.float32)
    rgba[..., :3] = lin
    rgba[..., 3] = 1.0
    _set_pixels(bench.src, rgba)
    zz = np.empty((h, w, 4), np.float32)
    zz[..., :3] = size_map[..., None]  # R = G = B so any colour->float conversion is exact
    zz[..., 3] = 1.0
    _set_pixels(bench.size, zz)
    setup_s = time.perf_counter() - t_setup

    name = bench.scene.name
    if not measure:
        times = [_render_once(name)]
        out = _read_render_result(bench)
        LAST_RUN.clear()
        LAST_RUN.update(seconds_per_frame=times[0], times=times, setup_seconds=setup_s, size=(w, h),
                        max_radius_px=float(max_radius_px), use_zbuffer=bool(use_zbuffer),
                        blender_f_stop=float(d.f_stop), samples_note=samples_note)
        return times[0], out
    _render_once(name)  # warm-up (bokeh kernel cache, image buffers, thread pool)
    times = [_render_once(name) for _ in range(repeats)]
    out = _read_render_result(bench)

    # pass-through overhead of the same render with the Defocus node muted
    d.mute = True
    _render_once(name)
    base = [_render_once(name) for _ in range(min(repeats, 3))]
    d.mute = False

    sec = float(statistics.median(times))
    LAST_RUN.clear()
    LAST_RUN.update(
        seconds_per_frame=sec, times=times, passthrough_seconds=float(statistics.median(base)),
        defocus_only_seconds=sec - float(statistics.median(base)), setup_seconds=setup_s,
        size=(w, h), max_radius_px=float(max_radius_px), use_zbuffer=bool(use_zbuffer),
        blender_f_stop=float(d.f_stop), samples_note=samples_note,
    )
    return sec, out


# ----------------------------------------------------------------------------------------------
# Checks / demo


def _footprint(max_radius_px: float, radii: list[float], size: int = 96) -> list[tuple[float, float, float]]:
    """PSF of Blender's Defocus for constant radii: returns (r, area-equivalent radius,
    max |dx| of the support) per r.  Uses an impulse image (linear value 1 at the centre)."""
    out = []
    for r in radii:
        img = np.zeros((size, size, 3), np.uint8)
        img[size // 2, size // 2] = 255
        _, res = blender_defocus(img, np.full((size, size), r, np.float32), max_radius_px=max_radius_px, repeats=1)
        psf = res[..., 0]
        area = psf.sum() / max(psf.max(), 1e-12)
        ys, xs = np.nonzero(psf > 1e-6 * psf.max())
        out.append((r, math.sqrt(area / math.pi), float(np.abs(xs - size // 2).max())))
    return out


def _make_test_image(w: int, h: int, seed: int = 0) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    base = (rng.random((h // 8 + 1, w // 8 + 1, 3)) * 120 + 40).astype(np.uint8)
    img = cv2.resize(base, (w, h), interpolation=cv2.INTER_NEAREST)  # 8-px blocks: detail everywhere
    s = w / 640.0
    for i in range(6):
        cx, cy = int((60 + i * 100) * s), int(h * (0.3 if i % 2 else 0.7))
        col = tuple(int(c) for c in rng.integers(0, 256, 3))
        cv2.circle(img, (cx, cy), int((8 + 6 * i) * s), col, -1, lineType=cv2.LINE_AA)
    for i in range(24):  # bright specular spots
        x, y = int(rng.integers(4, w - 4)), int(rng.integers(4, h - 4))
        cv2.circle(img, (x, y), max(1, int(1.5 * s)), (255, 255, 255), -1)
    return img


def _laplacian_energy_by_band(img_lin: np.ndarray, radius: np.ndarray, edges) -> list[float]:
    import cv2

    g = img_lin.mean(axis=2).astype(np.float32)
    lap = cv2.Laplacian(g, cv2.CV_32F)
    return [float(np.mean(lap[(radius >= a) & (radius < b)] ** 2)) for a, b in zip(edges[:-1], edges[1:])]


def _demo(w: int, h: int, max_r: float, repeats: int) -> float:
    """Run the node on a radius ramp, print what it does; returns seconds per frame."""
    img = _make_test_image(w, h)
    ramp = np.tile(np.linspace(0.0, max_r, w, dtype=np.float32), (h, 1))
    sec, out = blender_defocus(img, ramp, max_radius_px=max_r, repeats=repeats)
    lin = _srgb_to_linear(img.astype(np.float32) / 255.0)
    print(f"{w}x{h}, radius ramp 0..{max_r:g} px: {sec:.3f} s/frame (median of {repeats}; "
          f"defocus muted: {LAST_RUN['passthrough_seconds']:.4f} s, setup {LAST_RUN['setup_seconds']:.3f} s)")
    edges = np.linspace(0.0, max_r + 1e-3, 7)
    e_in = _laplacian_energy_by_band(lin, ramp, edges)
    e_out = _laplacian_energy_by_band(out, ramp, edges)
    for a, b, ei, eo in zip(edges[:-1], edges[1:], e_in, e_out):
        print(f"  radius {a:5.1f}..{b:5.1f} px: Laplacian energy in {ei:.2e} -> out {eo:.2e} (ratio {eo / ei:.1e})")
    ratios = [eo / ei for ei, eo in zip(e_in, e_out)]
    mono = all(r1 >= r2 for r1, r2 in zip(ratios[:-1], ratios[1:]))
    print(f"  blur increases with radius (energy ratio monotonically decreasing): {mono}")
    zero = ramp < 0.5
    print(f"  max |out - in| where radius < 0.5 px: {float(np.abs(out - lin)[zero].max()):.2e}")
    return sec


if __name__ == "__main__":
    import json
    import sys

    print("Footprint of Blender's Defocus (no Z-buffer, z_scale=1) for constant radius r, blur_max=32:")
    for r, req, ext in _footprint(32.0, [0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 11.0, 16.0, 24.0, 32.0]):
        print(f"  r={r:5.2f} px -> area-equivalent radius {req:6.3f} px, support half-width {ext:4.0f} px")
    figures = {"blender_defocus.ramp.360p.s_per_frame": round(_demo(640, 360, 11.0, repeats=3), 5)}
    if "--no-1080p" not in sys.argv:
        figures["blender_defocus.ramp.1080p.s_per_frame"] = round(_demo(1920, 1080, 32.0, repeats=1), 5)
    print(json.dumps(figures))  # last line: flat JSON (DESIGN.md "Benchmarks and evaluation output")
