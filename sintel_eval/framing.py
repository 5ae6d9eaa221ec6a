"""Speaker framing without bpy: where a speaker's head and upper body land in the image, where
the set's thin foreground structures (hanging strands, the foreground plant) land, and
:func:`clear_speakers` that moves (or, failing that, drops) the structures that would cover a
speaker. Used by the ``conversation`` script: a conversation shot frames the speakers' faces.

Image coordinates here are in units of the frame *width* (the sensor fit is horizontal, so
this holds at any resolution): x in [0, 1] left to right, y down from the frame centre's row
(the frame's height depends on the aspect, so boxes are not clipped vertically). Multiply by
the width in px for px. World boxes are axis-aligned ``(x0, y0, z0, x1, y1, z1)`` in metres;
they bound the geometry that :mod:`scene_builder` makes from the plan (whatever its own random
draws), so a clear footprint here is clear in the render.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .scene_plan import SENSOR_WIDTH_MM, CameraPath, Character, SetPlan

# Geometry shared with scene_builder (its strands and plant are drawn from these ranges).
STRAND_TOP_Z = 4.0  # m: strands hang from here down to their z_bottom
STRAND_JITTER_M = 0.05  # the bottom end is offset sideways by up to this much
PLANT_TIP_DX, PLANT_TIP_DY, PLANT_TIP_Z = 0.15, 0.1, (1.3, 1.75)  # stem tips around the plant's (x, y)
PLANT_LEAF_SPREAD, PLANT_LEAF_SIZE = 0.18, (0.05, 0.1)  # leaves: centre offset and size around a tip
# A figure (scale 1, person or classic): head ellipsoid around z = 1.64 m (+-0.112 m), and the
# region a viewer reads as "the speaker": head, hair, shoulders, arms and chest.
HEAD_Z, HEAD_HALF_M = (1.528, 1.752), 0.1
UPPER_BODY_Z, UPPER_BODY_HALF_M = (1.0, 1.85), 0.3
CLEAR_MARGIN = 0.01  # of the frame width (3 px at 320): the keep-out region's border
SHIFT_STEP_M, SHIFT_MAX_M = 0.05, 3.0  # sideways search of a structure's new place


def project_box(camera: CameraPath, frame: int, box: tuple, w2c: np.ndarray | None = None
                ) -> tuple[np.ndarray, float, float]:
    """Image box ``[x0, y0, x1, y1]`` (frame-width units, unclipped) of a world box's 8 corners on
    ``frame``, and the nearest and farthest planar depth (m) of its corners. w2c: the camera's
    world-to-camera matrix on ``frame`` when already known."""
    x0, y0, z0, x1, y1, z1 = box
    corners = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], dtype=np.float64)
    w2c = camera.world_to_camera(frame) if w2c is None else w2c
    cam = corners @ w2c[:3, :3].T + w2c[:3, 3]
    depth = np.maximum(-cam[:, 2], 1e-6)
    f = camera.focal_mm / SENSOR_WIDTH_MM  # focal length in frame widths
    u = 0.5 + f * cam[:, 0] / depth
    v = -f * cam[:, 1] / depth
    return np.array([u.min(), v.min(), u.max(), v.max()]), float(depth.min()), float(depth.max())


def _character_box(c: Character, frame: int, z_range: tuple[float, float], half: float) -> tuple:
    x, y = c.motion.position(frame)
    h = c.height
    return (x - half * h, y - half * h, z_range[0] * h, x + half * h, y + half * h, z_range[1] * h)


def head_box(c: Character, frame: int) -> tuple:
    """World box of a character's head (the face region) on ``frame``."""
    return _character_box(c, frame, HEAD_Z, HEAD_HALF_M)


def upper_body_box(c: Character, frame: int) -> tuple:
    """World box of a character's head, hair and upper body on ``frame``: what must stay clear."""
    return _character_box(c, frame, UPPER_BODY_Z, UPPER_BODY_HALF_M)


def strand_box(strand: tuple[float, float, float, float]) -> tuple:
    """World box of a hanging strand ``(x, y, z_bottom, radius)``."""
    x, y, zb, r = strand
    dx = STRAND_JITTER_M + r
    return (x - dx, y - r, zb - r, x + dx, y + r, STRAND_TOP_Z)


def plant_box(plant: tuple[float, float]) -> tuple:
    """World box of the foreground plant at floor ``(x, y)``: stems and leaves."""
    x, y = plant
    leaf = PLANT_LEAF_SPREAD + 0.5 * PLANT_LEAF_SIZE[1]
    return (x - PLANT_TIP_DX - leaf, y - PLANT_TIP_DY - leaf, 0.0,
            x + PLANT_TIP_DX + leaf, y + PLANT_TIP_DY + leaf, PLANT_TIP_Z[1] + leaf)


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])


class KeepOut:
    """Per frame, the image regions (frame-width units, with ``margin``, clipped left/right) of
    every speaker's head and upper body and their farthest depth: what a structure in front of
    them must not overlap."""

    def __init__(self, camera: CameraPath, speakers: list[Character], frames: int, margin: float = CLEAR_MARGIN):
        self.camera = camera
        self.frames: dict[int, tuple[np.ndarray, list]] = {}
        for k in range(1, frames + 1):
            w2c = camera.world_to_camera(k)
            regions = []
            for c in speakers:
                img, _, far = project_box(camera, k, upper_body_box(c, k), w2c)
                keep = img + np.array([-margin, -margin, margin, margin])
                keep[0], keep[2] = max(keep[0], 0.0), min(keep[2], 1.0)
                regions.append((c.name, keep, far))
            self.frames[k] = (w2c, regions)

    def covered(self, box: tuple) -> tuple[str, int] | None:
        """(speaker, frame) of the first frame where the world ``box`` lies (partly) in front of a
        speaker's region inside the frame, or None when it never does."""
        for k, (w2c, regions) in self.frames.items():
            img, near, _ = project_box(self.camera, k, box, w2c)
            if img[2] <= 0.0 or img[0] >= 1.0:  # entirely outside the frame (left/right)
                continue
            for name, keep, far in regions:
                if near < far and _overlap(img, keep):
                    return name, k
        return None

    def nearest_clear_x(self, x: float, make_box) -> float | None:
        """The x nearest to ``x`` (sideways steps of SHIFT_STEP_M, up to SHIFT_MAX_M) where
        ``make_box(x)`` covers no speaker, or None."""
        for k in range(1, int(round(SHIFT_MAX_M / SHIFT_STEP_M)) + 1):
            for sign in (1.0, -1.0):
                cand = x + sign * k * SHIFT_STEP_M
                if self.covered(make_box(cand)) is None:
                    return cand
        return None


def clear_speakers(set_plan: SetPlan, camera: CameraPath, speakers: list[Character], frames: int
                   ) -> tuple[SetPlan, dict]:
    """A copy of ``set_plan`` whose strands and plant cover no speaker's head or upper body on
    any frame: each offending structure moves sideways to the nearest clear place (it may
    then sit at or beyond the frame edge) or, with none within SHIFT_MAX_M, is dropped.
    Returns the new set and a record {"moved": [...], "dropped": [...]} for the plan's notes."""
    keep_out = KeepOut(camera, speakers, frames)
    record: dict = {"moved": [], "dropped": []}
    strands = []
    for i, s in enumerate(set_plan.strands):
        if keep_out.covered(strand_box(s)) is None:
            strands.append(s)
            continue
        x = keep_out.nearest_clear_x(s[0], lambda v, s=s: strand_box((v, *s[1:])))
        if x is None:
            record["dropped"].append(f"strand_{i}")
        else:
            strands.append((x, *s[1:]))
            record["moved"].append({"what": f"strand_{i}", "from_x": s[0], "to_x": x})
    plant = set_plan.plant
    if plant is not None and keep_out.covered(plant_box(plant)) is not None:
        x = keep_out.nearest_clear_x(plant[0], lambda v: plant_box((v, plant[1])))
        if x is None:
            record["dropped"].append("plant")
            plant = None
        else:
            record["moved"].append({"what": "plant", "from_x": plant[0], "to_x": x})
            plant = (x, plant[1])
    return replace(set_plan, strands=strands, plant=plant), record
