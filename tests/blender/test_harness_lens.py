"""Cycles' lens against the harness' units: circle-of-confusion convention, planar Z and
disparity on a plane at a known depth, and the pinhole projection used for event boxes."""
from __future__ import annotations

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from sintel_eval.bpy_util import emission_material, reset_blender, setup_render, sphere, quad  # noqa: E402
from sintel_eval.camera_math import Lens, project_points  # noqa: E402
from sintel_eval.passes import LensSetting, PassRenderer  # noqa: E402

FOCAL, SENSOR = 100.0, 36.0


def _scene(width: int, height: int, samples: int, rotation=(math.pi / 2, 0.0, 0.0), location=(0.0, 0.0, 0.0)):
    """Empty black world, a perspective camera (horizontal sensor fit), no denoising, a pixel
    filter of 0.01 px so a pixel is a point sample of the image plane."""
    reset_blender()
    scene = bpy.context.scene
    setup_render(scene, width, height, samples, seed=1, denoise=False, object_index=True)
    scene.cycles.filter_width = 0.01
    world = bpy.data.worlds.new("black")
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world
    cam = bpy.data.cameras.new("cam")
    cam.lens, cam.sensor_fit, cam.sensor_width = FOCAL, "HORIZONTAL", SENSOR
    cam.sensor_height = SENSOR * height / width
    cam.clip_start, cam.clip_end = 0.01, 1000.0
    obj = bpy.data.objects.new("cam", cam)
    obj.rotation_euler, obj.location = rotation, location
    scene.collection.objects.link(obj)
    scene.camera = obj
    return scene, obj


def _disk_radius(img: np.ndarray, source_radius_px: float) -> tuple[float, float, float]:
    """Radius of a uniform disk from the intensity-weighted second moment (E[x^2 + y^2] = r^2 / 2),
    minus the pixel box (1/12 per axis) and the source's own disk (a convolution adds moments)."""
    h, w = img.shape
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    m = img.sum()
    cx, cy = (img * xs).sum() / m, (img * ys).sum() / m
    var = (img * ((xs - cx) ** 2 + (ys - cy) ** 2)).sum() / m
    return math.sqrt(2.0 * (var - 2.0 / 12.0) - source_radius_px ** 2), cx, cy


def test_cycles_coc_is_the_radius_with_the_image_plane_at_f():
    """A small bright sphere far behind a close focus: its bokeh disk must have the radius
    r = (f / 2N) * f * (W / sensor) * |1/S_f - 1/S| predicted by camera_math (Cycles' aperture
    radius is f/(2N) and its image plane stays at f), not the diameter (2r) and not the
    physical thin lens' (A/2) v_f ... (1.33 r here, where v_f = f S_f / (S_f - f)).

    Tolerance 2%: the moment estimate is unbiased for a uniform disk; what is left is Monte-Carlo
    noise (256 samples on ~450 lit pixels: measured within 0.5% over sources of 1-5 px and
    focus distances 0.4-0.5 m) and the sphere's silhouette being slightly larger than R f / S.
    The two wrong conventions are 33% and 100% off. A second point off-axis (6 deg) checks that
    the focus is planar (its radius is the same; a radial focus distance would differ by 2% at
    the plane of focus and shift the radius by ~3%) and that the disk is centred on the pinhole
    projection (0.3 px).
    """
    w = h = 128
    scene, cam = _scene(w, h, 256)
    s_f = 0.4
    lens = Lens(FOCAL, SENSOR, w, f_number_ref=4.0, s_ref_m=s_f)
    depth, radius = 3.0, 0.025  # the source: a 3 px disk, so each lit pixel gets many hits
    mat = emission_material("hot", (1.0, 1.0, 1.0), 100.0)
    sphere("point", radius, (0.0, depth, 0.0), mat, segments=16)
    renderer = PassRenderer(scene, cam, 4, 256, np.array([1e9, 1e9, 1e9], dtype=np.float32))
    try:
        img = renderer.render_dof(LensSetting(focus_distance_m=s_f, f_number=4.0))[..., 0].astype(np.float64)
        src_px = radius / depth * lens.f_px
        measured, cx, cy = _disk_radius(img, src_px)
        predicted = lens.k_for(4.0) * abs(1.0 / s_f - 1.0 / depth)
        physical = lens.physical_k_for(4.0, s_f) * abs(1.0 / s_f - 1.0 / depth)
        assert measured == pytest.approx(predicted, rel=0.02), (measured, predicted)
        assert abs(measured - physical) > 0.15 * predicted and abs(measured - 2 * predicted) > 0.5 * predicted
        # In DESIGN units: focus f and aperture a give the same radius a |D - f| at the point.
        f, a = lens.focus_disparity(s_f), lens.aperture_scale(4.0)
        assert a * abs(lens.disparity(depth) - f) == pytest.approx(predicted, rel=1e-9)
        assert (cx, cy) == (pytest.approx(w / 2, abs=0.2), pytest.approx(h / 2, abs=0.2))

        # Off-axis at the same planar depth: same radius (planar focus), centred on the projection.
        bpy.data.objects["point"].location = (math.tan(math.radians(6)) * depth, depth, 0.0)
        img = renderer.render_dof(LensSetting(focus_distance_m=s_f, f_number=4.0))[..., 0].astype(np.float64)
        measured_off, cx, _ = _disk_radius(img, src_px)
        assert measured_off == pytest.approx(predicted, rel=0.02), (measured_off, predicted)
        assert cx == pytest.approx(w / 2 + lens.f_px * math.tan(math.radians(6)), abs=0.3)
    finally:
        renderer.close()


def test_disparity_of_a_plane_at_known_planar_depth():
    """A plane perpendicular to the view axis of a panned and tilted camera, 5 m away along the
    axis: Cycles' Z pass is 5 m on every pixel (planar, not radial: the corners are 14% farther
    along their rays), and D = K (1/S_ref - 1/S) matches the formula to float32 precision."""
    w, h = 64, 36
    yaw, tilt = math.radians(20.0), math.radians(-8.0)
    scene, cam = _scene(w, h, 2, rotation=(math.pi / 2 + tilt, 0.0, yaw), location=(0.3, -0.2, 1.4))
    bpy.context.view_layer.update()
    m = np.array(cam.matrix_world)
    fwd, right, up = -m[:3, 2], m[:3, 0], m[:3, 1]
    centre = m[:3, 3] + 5.0 * fwd
    corners = [tuple(centre + 20.0 * (sx * right + sy * up)) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    quad("plane", corners, emission_material("grey", (0.5, 0.5, 0.5), 1.0))
    lens = Lens(FOCAL, SENSOR, w, f_number_ref=1.4, s_ref_m=2.5)
    renderer = PassRenderer(scene, cam, 2, 2, np.array([10.0, 10.0, 10.0], dtype=np.float32))
    try:
        deep = renderer.render_deep()
    finally:
        renderer.close()
    z = deep["z"].astype(np.float64)
    np.testing.assert_allclose(z, 5.0, atol=1e-4)
    d = lens.disparity(deep["z"])
    expected = lens.k_px * (1.0 / 2.5 - 1.0 / 5.0)
    np.testing.assert_allclose(d, expected, atol=1e-5)
    assert expected == pytest.approx((FOCAL / 2.8) * FOCAL * (w / SENSOR) / 1000.0 * 0.2, rel=1e-12)


def test_projection_matches_cycles():
    """Small emitters at known world points land where camera_math.project_points puts them
    (the boxes and points of the events use it), for a rotated, shifted camera."""
    w, h = 96, 54
    scene, cam = _scene(w, h, 16, rotation=(math.pi / 2 + math.radians(4.0), 0.0, math.radians(-9.0)),
                        location=(0.2, 0.1, 1.5))
    lens = Lens(FOCAL, SENSOR, w, 1.0, 3.0)
    bpy.context.view_layer.update()
    m = np.array(cam.matrix_world)
    fwd, right, up = -m[:3, 2], m[:3, 0], m[:3, 1]
    # World points behind chosen pixels, built from the camera's axes (not from project_points).
    targets = [(20.3, 12.7, 6.0), (71.6, 30.2, 8.0), (48.0, 44.9, 10.0)]
    points = [tuple(m[:3, 3] + s * (fwd + (x - w / 2) / lens.f_px * right + (h / 2 - y) / lens.f_px * up))
              for x, y, s in targets]
    radii = [2.5 * t[2] / lens.f_px for t in targets]  # 2.5 px discs: centroids resolve to ~0.05 px
    for i, p in enumerate(points):
        obj = sphere(f"p{i}", radii[i], p, emission_material(f"m{i}", (1.0, 1.0, 1.0), 50.0), segments=24)
        obj.pass_index = i + 1
    bpy.context.view_layer.update()
    w2c = np.array(cam.matrix_world.inverted())
    xy, depth = project_points(w2c, np.array(points), lens.f_px, w, h)
    np.testing.assert_allclose(xy, [t[:2] for t in targets], atol=1e-4)  # float32 matrices
    np.testing.assert_allclose(depth, [t[2] for t in targets], atol=1e-5)
    renderer = PassRenderer(scene, cam, 16, 16, np.array([1e3] * 3, dtype=np.float32))
    try:
        deep = renderer.render_deep()
    finally:
        renderer.close()
    img = deep["rgb"][..., 0].astype(np.float64)
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    for i, (x, y) in enumerate(xy):
        mask = np.round(deep["id"]) == i + 1
        assert mask.any(), f"point {i} not visible"
        wgt = img * mask
        assert (wgt * xs).sum() / wgt.sum() == pytest.approx(x, abs=0.25)
        assert (wgt * ys).sum() / wgt.sum() == pytest.approx(y, abs=0.25)
        assert depth[i] - radii[i] - 1e-4 < float(deep["z"][mask].min()) < depth[i] - 0.9 * radii[i]  # the front
