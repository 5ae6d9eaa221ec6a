"""Harness pieces that need no Blender: lens constants, disparity units, scale/shift relations,
projection, scripts and events, seeds and settings, voice activity (sintel_eval, bpy-free modules)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rvr_addon.errors import InputError
from sintel_eval.camera_math import (Lens, affine_between, affine_to_blur, blur_constant_px, box_of,
                                     project_points, smoothstep)
from sintel_eval.dataset import GenerateConfig, parse_seed
from sintel_eval.scene_plan import Motion, edge_x, make_camera
from sintel_eval.scripts_events import SCRIPTS, check_script, make_plan
from sintel_eval.speech import SAMPLE_RATE, mouth_opening, voice_activity

LENS = Lens(focal_mm=70.0, sensor_width_mm=36.0, width_px=320, f_number_ref=1.0, s_ref_m=3.0)


def test_blur_constant_is_cycles_radius_formula():
    # K_N = (f / 2N) * f * W / sensor / 1000: 70 mm at f/1 on 36 mm, 320 px wide.
    assert blur_constant_px(70.0, 1.0, 36.0, 320) == pytest.approx(35.0 * 70.0 * 320 / 36.0 / 1000.0, rel=1e-12)
    assert LENS.k_px == pytest.approx(21.777777, rel=1e-6)
    # Twice the f-number halves the blur; the width scales it linearly (DESIGN: resampling scales D).
    assert LENS.k_for(2.0) == pytest.approx(LENS.k_px / 2.0, rel=1e-12)
    assert Lens(70.0, 36.0, 640, 1.0, 3.0).k_px == pytest.approx(2.0 * LENS.k_px, rel=1e-12)


def test_focus_and_aperture_reproduce_the_thin_lens_radius():
    """r_cycles = K_N |1/S_f - 1/S| must equal a |D - f| for every depth."""
    depth = np.array([1.2, 2.0, 3.0, 4.5, 9.0, 20.0, 1e4])
    d = LENS.disparity(depth).astype(np.float64)
    for s_f, n in ((3.0, 1.0), (4.5, 1.4), (1.7, 2.8), (12.0, 8.0)):
        f, a = LENS.focus_disparity(s_f), LENS.aperture_scale(n)
        assert a == pytest.approx(LENS.f_number_ref / n, rel=1e-12)
        r_model = a * np.abs(d - f)
        r_lens = LENS.k_for(n) * np.abs(1.0 / s_f - 1.0 / depth)
        np.testing.assert_allclose(r_model, r_lens, rtol=1e-6, atol=1e-6)
        assert LENS.focus_distance(f) == pytest.approx(s_f, rel=1e-12)
    assert LENS.focus_disparity(LENS.s_ref_m) == 0.0
    assert LENS.disparity(20.0) > 0 > LENS.disparity(1.5)  # + behind the reference plane
    with pytest.raises(ValueError):
        LENS.focus_distance(LENS.k_px / LENS.s_ref_m + 1.0)  # beyond infinity


def test_affine_relations_are_exact():
    rng = np.random.default_rng(0)
    d = rng.uniform(-5, 12, 1000)
    f1, a1, f2, a2 = 0.3, 1.0, 2.1, 0.357
    alpha, beta = affine_between(f1, a1, f2, a2)
    np.testing.assert_allclose(a2 * (d - f2), alpha * (a1 * (d - f1)) + beta, atol=1e-12)
    alpha, beta = affine_to_blur(f2, a2)
    np.testing.assert_allclose(alpha * d + beta, a2 * (d - f2), atol=1e-12)
    with pytest.raises(ValueError):
        affine_between(0.0, 0.0, 1.0, 1.0)


def test_projection_and_box():
    # Camera at the origin looking along +Y (Blender: rotation X = 90 deg) -> world_to_camera.
    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    cam_to_world = np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])
    w2c = np.linalg.inv(cam_to_world)
    pts = np.array([[0.0, 5.0, 0.0], [1.0, 5.0, 0.5], [-1.0, 10.0, -0.5]])
    xy, depth = project_points(w2c, pts, LENS.f_px, 320, 180)
    np.testing.assert_allclose(depth, [5.0, 5.0, 10.0], atol=1e-9)
    np.testing.assert_allclose(xy[0], [160.0, 90.0], atol=1e-9)
    np.testing.assert_allclose(xy[1], [160.0 + LENS.f_px / 5.0, 90.0 - LENS.f_px * 0.5 / 5.0], atol=1e-9)
    box, visible = box_of(np.array([[-10.0, 10.0], [30.0, 50.0]]), 320, 180)
    assert box == [0.0, 10.0, 30.0, 40.0] and visible == pytest.approx(0.75)
    assert box_of(np.array([[400.0, 10.0], [420.0, 20.0]]), 320, 180)[1] == 0.0


def test_edge_x_lies_on_the_image_edge():
    cam = make_camera(np.random.default_rng(3), 48)
    for frame in (1, 24, 48):
        (cx, cy, cz), euler = cam.pose(frame)
        yaw = euler[2]  # look_rotation: Euler (90 deg + tilt, 0, yaw)
        for side in (-1.0, 1.0):
            x = edge_x(cam, frame, 6.0, side)
            # angle of (x, 6) from the view axis equals +-HFOV
            dx, dy = x - cx, 6.0 - cy
            fwd = np.array([-math.sin(yaw), math.cos(yaw)])
            right = np.array([math.cos(yaw), math.sin(yaw)])
            assert (np.dot([dx, dy], right) / np.dot([dx, dy], fwd)) == pytest.approx(side * 18.0 / 70.0, rel=1e-9)


def test_motion_kinds():
    walk = Motion("walk_in", (2.0, 4.0), (0.0, 4.0), start_frame=5, speed=0.5)
    assert walk.position(5) == (2.0, 4.0) and not walk.moving(5)
    assert walk.moving(6) and walk.position(6) == pytest.approx((1.5, 4.0))
    assert walk.position(100) == pytest.approx((0.0, 4.0)) and not walk.moving(100)
    start = Motion("start_walk", (0.0, 4.0), (3.0, 4.0), start_frame=9)
    assert not start.moving(9) and start.moving(10)
    assert Motion("stand", (1.0, 2.0), (1.0, 2.0)).position(30) == (1.0, 2.0)
    assert smoothstep(-1) == 0.0 and smoothstep(0.5) == 0.5 and smoothstep(2) == 1.0


@pytest.mark.parametrize("script", SCRIPTS)
def test_plans_are_seeded_and_differ_by_seed(script):
    a, b, c = make_plan(7, script, 48, 24), make_plan(7, script, 48, 24), make_plan(8, script, 48, 24)
    assert a.to_dict() == b.to_dict()
    assert a.to_dict() != c.to_dict()
    assert a.main != a.second and len(a.characters) >= 2
    # The main subject stands nearer than the second: a rack between them is a real pull.
    assert a.character(a.main).motion.start[1] + 0.5 < a.character(a.second).motion.start[1]


def test_bad_script_and_seed_messages():
    with pytest.raises(InputError, match="--script 'dance'.*random, enter, start-moving, conversation"):
        check_script("dance")
    assert check_script("Start_Moving") == "start-moving"
    assert parse_seed("7") == 7 and parse_seed("0x1f") == 31 and parse_seed(12) == 12
    for bad in ("seven", "1.5", "-3", "", "0xzz"):
        with pytest.raises(InputError, match="--seed"):
            parse_seed(bad)
    with pytest.raises(InputError, match="out of range"):
        parse_seed(2 ** 40)


@pytest.mark.parametrize("change, message", [
    ({"frames": 0}, "--frames 0"),
    ({"width": 8}, "--size 8x180"),
    ({"f_numbers": (2.8, 1.0, 8.0)}, "increasing f-numbers"),
    ({"f_numbers": (1.0, -2.0, 8.0)}, "positive f-numbers"),
    ({"train_every": -1}, "--train-every -1"),
    ({"samples": 0}, "at least 1 sample"),
    ({"seed": "x7"}, "--seed 'x7'"),
])
def test_config_errors_name_the_setting(change, message):
    base = dict(seed=7)
    base.update(change)
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        GenerateConfig(**base).validated()


def test_config_hash_tracks_every_setting():
    a = GenerateConfig(seed=7).validated()
    assert a.config_hash("5.0.1") == GenerateConfig(seed="7").validated().config_hash("5.0.1")
    assert a.config_hash("5.0.1") != GenerateConfig(seed=7, frames=47).validated().config_hash("5.0.1")
    assert a.config_hash("5.0.1") != a.config_hash("5.1.0")


def test_voice_activity_and_mouth_on_a_synthetic_track():
    """Two bursts of a 150 Hz tone with a short inner gap (bridged) and a long pause (split)."""
    t = np.arange(int(2.0 * SAMPLE_RATE)) / SAMPLE_RATE
    tone = 0.5 * np.sin(2 * np.pi * 150 * t)
    env = ((t > 0.2) & (t < 0.5)) | ((t > 0.6) & (t < 0.9)) | ((t > 1.4) & (t < 1.8))
    track = (tone * env).astype(np.float32)
    seg = voice_activity(track)
    assert len(seg) == 2
    assert seg[0][0] == pytest.approx(0.2, abs=0.02) and seg[0][1] == pytest.approx(0.9, abs=0.02)
    assert seg[1][0] == pytest.approx(1.4, abs=0.02) and seg[1][1] == pytest.approx(1.8, abs=0.02)
    mouth = mouth_opening(track, 48, 24)
    assert mouth.shape == (48,) and mouth.max() == pytest.approx(1.0)
    assert mouth[int(1.0 * 24)] == 0.0 and mouth[int(1.6 * 24)] > 0.5  # closed in the pause, open in speech


def test_start_moving_event_needs_the_face_in_frame_not_half_the_body():
    """A standing figure at 4-6 m shows ~45% of its box (legs cut by the frame): its start of
    movement is still an event; with its face out of frame it is not."""
    from sintel_eval.scripts_events import SubjectFrame, detect_events, make_plan

    plan = make_plan(1003, "start-moving", 48, 24)
    walker = next(c for c in plan.characters if c.motion.kind == "start_walk")
    start = next(k for k in range(2, 49) if walker.motion.moving(k))

    def records(visible: float, face: bool) -> dict:
        rec = SubjectFrame(box=[10.0, 10.0, 20.0, 40.0], visible=visible, point=[20.0, 15.0], depth_m=5.0,
                           disparity=1.0, face_in_frame=face)
        return {c.name: [rec] * plan.frames for c in plan.characters}

    events = detect_events(plan, records(0.45, True))
    assert [(e["type"], e["subject"], e["frame"]) for e in events] == [("start_moving", walker.name, start)]
    assert detect_events(plan, records(0.45, False)) == []
    assert detect_events(plan, records(0.1, True)) == []
