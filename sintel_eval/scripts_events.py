"""Scene scripts (who stands, enters, starts moving, speaks, and when), the New Focus Target
events they produce, and the ground-truth focus tracks (no bpy).

Scripts: ``random`` (a mix of entering, crossing and starting subjects), ``enter`` (a second
subject walks into the frame), ``start-moving`` (a standing subject starts to walk), and
``conversation`` (two or three figures take turns speaking; needs espeak-ng).
Frames are 1-based; boxes ``[x, y, w, h]`` in px (see DATASET.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rvr_addon.errors import InputError

from .camera_math import Lens, smoothstep
from .framing import clear_speakers
from .scene_plan import (DEFAULT_TILT_DEG, NAMES, WALK_M_PER_FRAME, CameraPath, Character, Motion, Mover, ScenePlan, edge_x,
                         half_width, make_camera, make_set, new_character)

SCRIPTS = ("random", "enter", "start-moving", "conversation")
START_VISIBLE = 0.2  # a started movement counts when the face and this share of the subject's box are in frame
# (standing figures at 4-6 m are cut at the knees by the 16:9 frame: ~45% of their box is in view)
FACE_LEAD = 0.1  # m: the focus point (face) leads a walking body's root by this much
HFOV = math.atan(half_width(1.0))
# The conversation script frames its speakers' faces like a two-shot: a longer lens, speakers
# nearer (heads >= ~38 px tall at 320 px wide), a gentler pan and push-in, and no strand or
# plant in front of a speaker's head and upper body (sintel_eval.framing). Each script has a
# version in the config hash when it is above 1 (dataset.GenerateConfig.config_hash), so an old
# conversation clip is not resumed with the new scene while the other scripts keep their hash.
SCRIPT_VERSIONS = {"conversation": 2}  # 2: close framing, 85 mm, speakers clear of foreground structures
CONVERSATION_FOCAL_MM = 85.0
CONVERSATION_NEAR_M = (2.8, 3.1)  # the first speaker's depth
CONVERSATION_GAP_M = (1.1, 1.4)  # the second speaker stands this much further back
CONVERSATION_PAN, CONVERSATION_DOLLY = 0.3, 0.3  # of the drawn pan and dolly
# Image angles of the speakers' marks (fractions of the half field of view): first speaker on
# side A, second on side B, the third (if any) near the centre on side B, between them in depth.
CONVERSATION_X = {2: ((0.25, 0.4), (0.35, 0.5), None), 3: ((0.55, 0.65), (0.55, 0.65), (0.0, 0.1))}


def _x_at(angle: float, depth: float, camera: CameraPath) -> float:
    """World x of a point at ``depth`` (world y) seen at image angle ``angle`` (rad, + = right)
    from the mid-clip camera."""
    yaw_mid = 0.5 * (camera.yaw_start + camera.yaw_end)
    return camera.start[0] + depth * math.tan(angle - yaw_mid)


def check_script(script: str) -> str:
    """Normalise a script name; raises InputError naming the valid ones."""
    name = str(script).strip().lower().replace("_", "-")
    if name not in SCRIPTS:
        raise InputError(f"--script '{script}' is not a scene script: use one of {', '.join(SCRIPTS)}")
    return name


def make_plan(seed: int, script: str, frames: int, fps: int, speakers_hint: int | None = None, *,
              style: str = "procedural", lighting: str = "auto", library=None,
              tilt_deg: tuple[float, float] = DEFAULT_TILT_DEG) -> ScenePlan:
    """The seeded scene of ``script`` for a clip of ``frames`` frames (see the module docstring).

    style, lighting, library: the look (:func:`sintel_eval.look.make_look`), drawn from its own
    random stream: layout, motions and events do not depend on it. The defaults give the
    original procedural look (``plan.look is None``)."""
    script = check_script(script)
    rng = np.random.default_rng([int(seed), SCRIPTS.index(script)])
    camera = make_camera(rng, frames, tilt_deg)
    set_plan = make_set(rng)
    names = list(rng.permutation(NAMES))
    side_a = -1.0 if camera.yaw_end > camera.yaw_start else 1.0  # the pan brings A towards the centre
    side_b = -side_a
    y_a = float(rng.uniform(2.8, 3.4))
    u_a = float(rng.uniform(0.2, 0.4))
    x_a = _x_at(side_a * u_a * HFOV, y_a, camera)
    chars: list[Character] = []
    a = new_character(rng, names[0], 1, Motion("stand", (x_a, y_a), (x_a, y_a)), role="main")
    chars.append(a)
    t_event = max(2, int(round(0.35 * frames)))
    notes: dict = {"event_target_frame": t_event}

    def walk_in(name: str, index: int, y: float, side: float, t_target: int) -> Character:
        """Walks in from outside the frame to a mark; its face crosses the frame edge at t_target."""
        mark = (_x_at(side * float(rng.uniform(0.25, 0.5)) * HFOV, y, camera), y)
        return new_character(rng, name, index, _entering("walk_in", y, side, t_target, mark[0]), role="second")

    def _entering(kind: str, y: float, side: float, t_target: int, inner_x: float) -> Motion:
        # At t_target the root is FACE_LEAD - half a step outside the edge, so the face (which
        # leads the walking body by FACE_LEAD) is just inside; one frame earlier it is outside.
        edge = edge_x(camera, t_target, y, side)
        at_target = edge + side * (FACE_LEAD - 0.5 * WALK_M_PER_FRAME)
        start = (at_target + side * 0.9, y)
        end = (inner_x, y)
        steps = int(round(0.9 / WALK_M_PER_FRAME))
        # keep walking the straight line start -> end; the start is 0.9 m further out
        return Motion(kind, start, end, start_frame=t_target - steps)

    def start_walk(name: str, index: int, y: float, side: float, t_start: int) -> Character:
        mark = (_x_at(side * float(rng.uniform(0.2, 0.5)) * HFOV, y, camera), y)
        end = (mark[0] + side * 4.0, y - float(rng.uniform(0.0, 1.2)))
        return new_character(rng, name, index, Motion("start_walk", mark, end, start_frame=t_start - 1),
                             facing=side * math.radians(20.0), role="second")

    def cross(name: str, index: int, y: float, side: float, t_enter: int) -> Character:
        far_side = _x_at(-side * HFOV, y, camera) - side * 1.5
        return new_character(rng, name, index, _entering("cross", y, side, t_enter, far_side), role="extra")

    if script == "enter":
        chars.append(walk_in(names[1], 2, float(rng.uniform(4.3, 5.5)), side_b, t_event))
    elif script == "start-moving":
        chars.append(start_walk(names[1], 2, float(rng.uniform(4.2, 5.4)), side_b, t_event))
    elif script == "conversation":
        n = speakers_hint or (3 if frames / fps >= 4.0 and rng.uniform() < 0.5 else 2)
        _conversation(rng, camera, chars, names, n, side_a, (y_a - 2.8) / 0.6, (u_a - 0.2) / 0.2)
        set_plan, cleared = clear_speakers(set_plan, camera, [c for c in chars if c.speaker], frames)
        notes["cleared_for_speakers"] = cleared
    else:  # random
        kind = str(rng.choice(["enter", "start-moving", "cross"]))
        y_b = float(rng.uniform(4.2, 5.5))
        t_b = int(rng.integers(max(2, int(0.2 * frames)), max(3, int(0.55 * frames)) + 1))
        notes["event_target_frame"] = t_b
        notes["second_kind"] = kind
        if kind == "enter":
            chars.append(walk_in(names[1], 2, y_b, side_b, t_b))
        elif kind == "start-moving":
            chars.append(start_walk(names[1], 2, y_b, side_b, t_b))
        else:
            b = cross(names[1], 2, y_b, side_b, t_b)
            b.role = "second"
            chars.append(b)
        if rng.uniform() < 0.6:
            t_c = int(rng.integers(1, max(2, int(0.7 * frames)) + 1))
            chars.append(cross(names[2], 3, float(rng.uniform(5.5, 7.5)), float(rng.choice([-1.0, 1.0])), t_c))

    movers = [_ball(rng, camera, frames)]
    if script == "random" and rng.uniform() < 0.5:
        movers.append(_ball(rng, camera, frames, name="ball_2", index=12))
    plan = ScenePlan(seed=int(seed), script=script, frames=frames, fps=fps, camera=camera, set=set_plan,
                     characters=chars, movers=movers, main=chars[0].name, second=chars[1].name, notes=notes)
    if style != "procedural" or lighting not in ("auto", "classic"):
        from .look import make_look

        plan.look = make_look(plan, style, lighting, library, SCRIPTS.index(script))
    return plan



def _lerp(lo_hi: tuple[float, float], t: float) -> float:
    return lo_hi[0] + (lo_hi[1] - lo_hi[0]) * t


def _conversation(rng: np.random.Generator, camera: CameraPath, chars: list[Character], names: list, n: int,
                  side_a: float, t_depth: float, t_angle: float) -> None:
    """Frame a conversation of ``n`` speakers: sets the camera's lens, pan and dolly, moves the
    first speaker (``chars[0]``; t_depth, t_angle in [0, 1]: its seeded place within the ranges)
    and appends the others. The speakers stand at distinct depths (nearest first)."""
    side_b = -side_a
    camera.focal_mm = CONVERSATION_FOCAL_MM
    camera.yaw_end = camera.yaw_start + CONVERSATION_PAN * (camera.yaw_end - camera.yaw_start)
    camera.dolly_m *= CONVERSATION_DOLLY
    hfov = math.atan(camera.half_fov_tan)
    x_range_a, x_range_b, x_range_c = CONVERSATION_X[min(max(n, 2), 3)]
    a = chars[0]
    y_a = _lerp(CONVERSATION_NEAR_M, t_depth)
    x_a = _x_at(side_a * _lerp(x_range_a, t_angle) * hfov, y_a, camera)
    a.motion = Motion("stand", (x_a, y_a), (x_a, y_a))
    a.speaker = True
    a.facing = side_b * math.radians(float(rng.uniform(25.0, 40.0)))
    y_b = y_a + float(rng.uniform(*CONVERSATION_GAP_M))
    x_b = _x_at(side_b * float(rng.uniform(*x_range_b)) * hfov, y_b, camera)
    chars.append(new_character(rng, names[1], 2, Motion("stand", (x_b, y_b), (x_b, y_b)),
                               facing=side_a * math.radians(float(rng.uniform(25.0, 40.0))), role="second",
                               speaker=True))
    if n >= 3:  # between the two in disparity, near the centre
        w = float(rng.uniform(0.4, 0.6))
        y_c = 1.0 / ((1.0 - w) / y_a + w / y_b)
        x_c = _x_at(side_b * float(rng.uniform(*x_range_c)) * hfov, y_c, camera)
        chars.append(new_character(rng, names[2], 3, Motion("stand", (x_c, y_c), (x_c, y_c)), role="extra",
                                   speaker=True))


def _ball(rng: np.random.Generator, camera: CameraPath, frames: int, name: str = "ball", index: int = 11) -> Mover:
    """A ball rolling across the mid-ground: enters on one side, leaves on the other."""
    y = float(rng.uniform(5.0, 9.0))
    side = float(rng.choice([-1.0, 1.0]))
    radius = float(rng.uniform(0.12, 0.2))
    start = (_x_at(side * HFOV, y, camera) + side * 0.5, y)
    end = (_x_at(-side * HFOV, y, camera) - side * 0.5, y + float(rng.uniform(-1.0, 1.0)))
    speed = float(rng.uniform(0.07, 0.12))
    t_in = int(rng.integers(1, max(2, int(0.5 * frames)) + 1))
    s = t_in - int(round(0.5 / speed))
    return Mover(name, index, "ball", radius, radius, Motion("cross", start, end, start_frame=s, speed=speed))


# --------------------------------------------------------------------------------------------- events


@dataclass
class SubjectFrame:
    """A subject on one frame: projected box (clipped), visible fraction of the unclipped box,
    focus point (px), its planar depth (m) and disparity (px), and whether the focus point (the
    face) is inside the frame."""

    box: list[float]
    visible: float
    point: list[float]
    depth_m: float
    disparity: float
    face_in_frame: bool = True


def detect_events(plan: ScenePlan, records: dict[str, list[SubjectFrame]], turns: list | None = None
                  ) -> list[dict]:
    """New Focus Target events of the clip, in frame order (see DATASET.md "Events")."""
    events: list[dict] = []

    def event(kind: str, name: str, frame: int, detail: dict | None = None) -> dict:
        rec = records[name][frame - 1]
        return {"frame": frame, "index": frame - 1, "type": kind, "subject": name, "box": rec.box,
                "point": rec.point, "disparity": rec.disparity, "depth_m": rec.depth_m, "detail": detail or {}}

    for char in plan.characters:
        recs = records[char.name]
        for k in range(2, plan.frames + 1):  # "enter": the face comes into the frame
            if recs[k - 1].face_in_frame and not recs[k - 2].face_in_frame:
                events.append(event("enter", char.name, k, {"visible_fraction": recs[k - 1].visible}))
                break
        if char.motion.kind == "start_walk":
            k = next((k for k in range(2, plan.frames + 1) if char.motion.moving(k)), None)
            if k is not None and recs[k - 1].face_in_frame and recs[k - 1].visible >= START_VISIBLE:
                events.append(event("start_moving", char.name, k, {"speed_m_per_frame": char.motion.speed}))
    for turn in turns or []:
        if 1 <= turn.start_frame <= plan.frames:
            events.append(event("speech_start", turn.speaker, turn.start_frame,
                                {"start_s": turn.start_s, "end_s": turn.end_s, "text": turn.text,
                                 "end_frame": turn.end_frame}))
    events.sort(key=lambda e: (e["frame"], e["subject"]))
    return events


# --------------------------------------------------------------------------------------------- focus


@dataclass
class RackSpec:
    """A rack focus from subject ``source`` to ``target`` (pull over ``pull_frames`` frames in
    disparity, smoothstep, starting at ``start``)."""

    source: str
    target: str
    start: int
    pull_frames: int

    def weight(self, frame: int) -> float:
        """0 before the pull, 1 after it."""
        return smoothstep((frame - self.start) / max(self.pull_frames, 1))


def plan_rack(plan: ScenePlan, events: list[dict], pull_frames: int) -> RackSpec:
    """The rack: main -> second subject, centred on the second subject's first event (a
    conversation racks from the first speaker to the next); mid-clip without an event."""
    source, target = plan.main, plan.second
    speech = [e for e in events if e["type"] == "speech_start"]
    if speech:
        source = speech[0]["subject"]
        nxt = next((e for e in speech if e["subject"] != source), None)
        target = nxt["subject"] if nxt else (plan.second if source == plan.main else plan.main)
        centre = nxt["frame"] if nxt else (plan.frames + 1) // 2
    else:
        ev = next((e for e in events if e["subject"] == target), None)
        centre = ev["frame"] if ev else (plan.frames + 1) // 2
    start = max(1, min(centre - pull_frames // 2, plan.frames - pull_frames))
    return RackSpec(source, target, start, pull_frames)


def focus_tracks(plan: ScenePlan, records: dict[str, list[SubjectFrame]], lens: Lens, rack: RackSpec,
                 f_number: float) -> dict[str, list[dict]]:
    """Per-frame lens of the "constant" and "rack" tracks and of the second focus target
    ("focusB", for focal triplets): focus disparity f (px), planar focus distance (m),
    aperture scale a, f-number, subject."""
    a = lens.aperture_scale(f_number)
    out: dict[str, list[dict]] = {"constant": [], "rack": [], "focusB": []}
    for k in range(1, plan.frames + 1):
        f_main = records[plan.main][k - 1].disparity
        f_src = records[rack.source][k - 1].disparity
        f_tgt = records[rack.target][k - 1].disparity
        w = rack.weight(k)
        f_rack = (1.0 - w) * f_src + w * f_tgt
        subject_rack = rack.source if w < 0.5 else rack.target
        for track, f, subject in (("constant", f_main, plan.main), ("rack", f_rack, subject_rack),
                                  ("focusB", records[plan.second][k - 1].disparity, plan.second)):
            if track == "rack" and w in (0.0, 1.0):  # exactly the subject's own focus distance
                s_f = records[rack.source if w == 0.0 else rack.target][k - 1].depth_m
            else:
                s_f = records[subject][k - 1].depth_m if track != "rack" else lens.focus_distance(f)
            out[track].append({"frame": k, "index": k - 1, "track": track, "focus_disparity": float(f),
                               "aperture_scale": float(a), "focus_distance_m": float(s_f),
                               "f_number": float(f_number), "K_N_px": lens.k_for(f_number),
                               "subject": subject, "rack_weight": float(w) if track == "rack" else None})
    return out
