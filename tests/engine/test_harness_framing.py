"""Conversation framing without Blender: the speakers' faces are large enough for a face
detector, no hanging strand or foreground plant covers a speaker's head or upper body, the
speakers stand at distinct disparities, the other scripts' plans are what they were, and only
the conversation clips' config hash moves."""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from sintel_eval.camera_math import Lens
from sintel_eval.dataset import FORMAT, HARNESS_VERSION, GenerateConfig
from sintel_eval.framing import KeepOut, clear_speakers, head_box, plant_box, project_box, strand_box
from sintel_eval.scene_plan import FOCAL_MM, SENSOR_WIDTH_MM, edge_x, make_camera
from sintel_eval.scripts_events import CONVERSATION_FOCAL_MM, SCRIPT_VERSIONS, SCRIPTS, make_plan

W, H = 320, 180
# sha256 over the plans of seeds (0, 1, 7, 1004) x frames (24, 72), taken before the
# conversation framing existed (camera.focal_mm, added then, left out).
OTHER_SCRIPTS = {"random": "76939e30f8cb22c5", "enter": "64561ab19295ac0d", "start-moving": "2da33b0447d2ead4"}


def _fingerprint(script: str) -> str:
    parts = []
    for seed in (0, 1, 7, 1004):
        for frames in (24, 72):
            d = make_plan(seed, script, frames, 24).to_dict()
            assert d["camera"].pop("focal_mm") == FOCAL_MM
            parts.append(hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12])
    return hashlib.sha256("".join(parts).encode()).hexdigest()[:16]


@pytest.mark.parametrize("script", sorted(OTHER_SCRIPTS))
def test_other_scripts_plans_are_unchanged(script):
    assert _fingerprint(script) == OTHER_SCRIPTS[script]


def test_world_to_camera_agrees_with_the_frame_edges():
    """The bpy-free camera matrix puts the floor line at edge_x on the image edges (edge_x is
    exact for a level camera: pan and dolly, no tilt)."""
    cam = make_camera(np.random.default_rng(5), 48)
    for focal in (FOCAL_MM, CONVERSATION_FOCAL_MM):
        cam = replace(cam, focal_mm=focal, tilt=0.0)
        for frame in (1, 30, 48):
            for side, u in ((-1.0, 0.0), (1.0, 1.0)):
                x = edge_x(cam, frame, 6.0, side)
                box, near, _ = project_box(cam, frame, (x, 6.0, 0.0, x, 6.0, 0.0))
                assert box[0] == pytest.approx(u, abs=1e-9)
            (cx, cy, cz), (_, _, yaw) = cam.pose(frame)
            ahead = (cx - 4.0 * math.sin(yaw), cy + 4.0 * math.cos(yaw), cz)  # 4 m along the view axis
            box, near, _ = project_box(cam, frame, ahead + ahead)
            assert box[0] == pytest.approx(0.5, abs=1e-9) and box[1] == pytest.approx(0.0, abs=1e-9)
            assert near == pytest.approx(4.0, rel=1e-9)


CASES = [(seed, 48, None) for seed in (0, 1, 5, 6, 13, 1004)] + [(seed, 120, 3) for seed in (1, 5, 24)] + \
        [(1004, 72, None)]


@pytest.mark.parametrize("seed, frames, speakers", CASES)
def test_conversation_frames_the_speakers_faces(seed, frames, speakers):
    plan = make_plan(seed, "conversation", frames, 24, speakers)
    assert plan.camera.focal_mm == CONVERSATION_FOCAL_MM
    talkers = [c for c in plan.characters if c.speaker]
    assert len(talkers) == (speakers or len(talkers)) >= 2
    for k in range(1, frames + 1):
        for c in talkers:
            box, near, _ = project_box(plan.camera, k, head_box(c, k))
            x0, x1 = box[0] * W, box[2] * W
            y0, y1 = H / 2 + box[1] * W, H / 2 + box[3] * W
            assert y1 - y0 >= 35.0, (c.name, k, y1 - y0)  # a face a detector can find at 320x180
            assert 0.0 <= x0 and x1 <= W and 0.0 <= y0 and y1 <= H, (c.name, k, box)  # in frame
    # No strand or plant in front of a speaker's head or upper body, on any frame (no margin).
    keep = KeepOut(plan.camera, talkers, frames, margin=0.0)
    for s in plan.set.strands:
        assert keep.covered(strand_box(s)) is None, s
    if plan.set.plant is not None:
        assert keep.covered(plant_box(plan.set.plant)) is None
    # Distinct depths: the rack between the two first speakers is a real pull at the default K.
    lens = Lens(CONVERSATION_FOCAL_MM, SENSOR_WIDTH_MM, W, 1.0, plan.character(plan.main).motion.start[1])
    disp = {c.name: lens.disparity(c.motion.start[1]) for c in talkers}
    assert disp[plan.second] - disp[plan.main] >= 2.5
    values = sorted(disp.values())
    assert min(np.diff(values)) >= 1.0


def test_clear_speakers_moves_what_covers_a_face():
    plan = make_plan(1004, "conversation", 48, 24)
    talkers = [c for c in plan.characters if c.speaker]
    a = plan.character(plan.main)
    x, y = a.motion.start
    # A strand hanging right in front of the first speaker's face, and the plant before it.
    bad = replace(plan.set, strands=[(x, y - 0.8, 0.8, 0.002)], plant=(x, 1.5))
    keep = KeepOut(plan.camera, talkers, 48)
    assert keep.covered(strand_box(bad.strands[0])) is not None
    assert keep.covered(plant_box(bad.plant)) is not None
    cleared, record = clear_speakers(bad, plan.camera, talkers, 48)
    assert keep.covered(strand_box(cleared.strands[0])) is None
    assert cleared.plant is None or keep.covered(plant_box(cleared.plant)) is None
    assert {m["what"] for m in record["moved"]} | set(record["dropped"]) == {"strand_0", "plant"}
    assert cleared.strands[0][1:] == bad.strands[0][1:]  # moved sideways only
    # A strand far behind everyone stays where it is.
    far = replace(plan.set, strands=[(x, 9.0, 0.8, 0.002)], plant=None)
    assert clear_speakers(far, plan.camera, talkers, 48)[0].strands == far.strands


def test_only_the_conversation_hash_carries_its_script_version():
    def legacy(cfg: GenerateConfig, extra: dict) -> str:
        config = {k: v for k, v in cfg.to_dict().items()
                  if k not in ("style", "lighting", "textures", "texture_cache", "tilt_deg", "dof")}
        blob = {"config": config, "format": FORMAT, "harness": HARNESS_VERSION, "blender": "5.0.1"} | extra
        return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:16]

    for script in SCRIPTS:
        cfg = GenerateConfig(seed=1004, frames=72, script=script).validated()
        if script == "conversation":
            assert SCRIPT_VERSIONS[script] >= 2
            assert cfg.config_hash("5.0.1") != legacy(cfg, {})  # an old conversation clip is not resumed
            assert cfg.config_hash("5.0.1") == legacy(cfg, {"script_version": SCRIPT_VERSIONS[script]})
        else:
            assert cfg.config_hash("5.0.1") == legacy(cfg, {})  # unchanged: these clips still resume
    assert math.isclose(CONVERSATION_FOCAL_MM, 85.0)
