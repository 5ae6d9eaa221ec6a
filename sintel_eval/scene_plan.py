"""A seeded, bpy-free description of one animated harness scene: set layout, characters and
their motion, movers, camera path. :mod:`scene_builder` turns it into Blender objects.

World axes are Blender's (metres, Z up). The camera starts at ``(x0, 0, CAMERA_HEIGHT)`` looking
along +Y; "depth" in this module means the world y coordinate (the camera's view axis at
frame 1). Frames are 1-based. Everything is a pure function of the seed, the script and the
clip length, so a run can be resumed (or reproduced) by rebuilding the plan.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .camera_math import look_rotation, smoothstep

FOCAL_MM = 70.0
SENSOR_WIDTH_MM = 36.0
CAMERA_HEIGHT = 1.55
HALF_FOV_TAN = SENSOR_WIDTH_MM / 2.0 / FOCAL_MM  # half frame width / depth
WALK_M_PER_FRAME = 0.045  # ~1.1 m/s at 24 fps
# Small bright emitters (bulbs): radius (m) and radiance (x display white) ranges. A larger, less
# intense source gives the same bokeh energy with less Monte-Carlo noise on the bokeh rims.
BULB_RADIUS_M = (0.04, 0.055)
BULB_RADIANCE = (15.0, 50.0)
NAMES = ("ana", "ben", "cleo", "dev", "eli", "fay")
SWEATERS = ((0.55, 0.06, 0.08), (0.08, 0.22, 0.50), (0.10, 0.40, 0.18), (0.60, 0.45, 0.08),
            (0.35, 0.12, 0.45), (0.70, 0.30, 0.10))
SKINS = ((0.80, 0.56, 0.42), (0.55, 0.36, 0.24), (0.35, 0.20, 0.12), (0.90, 0.70, 0.58))
HAIRS = ((0.03, 0.02, 0.01), (0.25, 0.13, 0.05), (0.55, 0.42, 0.20), (0.12, 0.12, 0.13))


@dataclass
class CameraPath:
    """Pan (yaw about +Z, rad) and dolly (m along the frame-1 view axis) over the clip; focal_mm:
    the lens (mm on the SENSOR_WIDTH_MM sensor; the conversation script uses a longer one)."""

    start: tuple[float, float, float]
    yaw_start: float
    yaw_end: float
    dolly_m: float
    tilt: float
    frames: int
    focal_mm: float = FOCAL_MM

    @property
    def half_fov_tan(self) -> float:
        """Half the frame width over the depth (tan of the half horizontal field of view)."""
        return SENSOR_WIDTH_MM / 2.0 / self.focal_mm

    def world_to_camera(self, frame: int) -> np.ndarray:
        """(4, 4) world -> camera matrix on ``frame`` (Blender camera: looks along its -Z), the
        inverse of the matrix_world that scene_builder gives the camera object."""
        (x, y, z), (rx, _, rz) = self.pose(frame)
        cx, sx, cz, sz = math.cos(rx), math.sin(rx), math.cos(rz), math.sin(rz)
        rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
        rot_z = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
        rot = rot_z @ rot_x  # Euler XYZ (Y = 0)
        out = np.eye(4)
        out[:3, :3] = rot.T
        out[:3, 3] = -rot.T @ np.array([x, y, z])
        return out

    def pose(self, frame: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(location m, Euler XYZ rad) of the camera on ``frame``."""
        u = 0.0 if self.frames <= 1 else (frame - 1) / (self.frames - 1)
        yaw = self.yaw_start + (self.yaw_end - self.yaw_start) * u
        d = self.dolly_m * smoothstep(u)
        x0, y0, z0 = self.start
        fx, fy = -math.sin(self.yaw_start), math.cos(self.yaw_start)
        return (x0 + fx * d, y0 + fy * d, z0), look_rotation(yaw, self.tilt)


@dataclass
class Motion:
    """Floor trajectory of a character or mover.

    kind: "stand" (at ``start``), "walk_in" (walks from ``start`` to ``end`` from frame
    ``start_frame`` on, then stands), "start_walk" (stands at ``start`` until
    ``start_frame``, then walks towards ``end`` and keeps going), "cross" (walks from
    ``start`` through ``end`` from ``start_frame`` on). speed: m per frame.
    """

    kind: str
    start: tuple[float, float]
    end: tuple[float, float]
    start_frame: int = 1
    speed: float = WALK_M_PER_FRAME

    def travelled(self, frame: int) -> float:
        """Distance (m) walked by ``frame``."""
        if self.kind == "stand" or frame <= self.start_frame:
            return 0.0
        dist = (frame - self.start_frame) * self.speed
        if self.kind == "walk_in":
            return min(dist, self.length)
        return dist

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    def position(self, frame: int) -> tuple[float, float]:
        """Floor position (x, y) in m on ``frame``."""
        if self.length == 0:
            return self.start
        t = self.travelled(frame) / self.length
        return (self.start[0] + (self.end[0] - self.start[0]) * t, self.start[1] + (self.end[1] - self.start[1]) * t)

    def moving(self, frame: int) -> bool:
        """True when the position changes between ``frame - 1`` and ``frame``."""
        return self.travelled(frame) != self.travelled(frame - 1)

    def heading(self) -> float:
        """Yaw (rad) of the walking direction (0 = facing the camera, i.e. walking to -Y)."""
        dx, dy = self.end[0] - self.start[0], self.end[1] - self.start[1]
        return math.atan2(dx, -dy) if (dx or dy) else 0.0


@dataclass
class Character:
    """A figure built from primitives: name, pass index, looks and motion.

    facing: yaw (rad) while standing (0 = faces the camera). speaker: has a speech track.
    height: overall scale (1 = 1.75 m). hair_strands: number of thin hair strands.
    """

    name: str
    index: int
    motion: Motion
    facing: float
    sweater: tuple[float, float, float]
    skin: tuple[float, float, float]
    hair: tuple[float, float, float]
    height: float = 1.0
    hair_strands: int = 16
    speaker: bool = False
    role: str = "extra"

    def yaw(self, frame: int) -> float:
        """Body yaw (rad) on ``frame``: the walking direction while walking, else ``facing``."""
        return self.motion.heading() if self.motion.moving(frame) else self.facing


@dataclass
class Mover:
    """A prop moving through the set (a rolling ball): kind, radius (m), height of its centre."""

    name: str
    index: int
    kind: str
    radius: float
    z: float
    motion: Motion


@dataclass
class Prop:
    """A static set piece: kind in {"crate", "pillar", "panel", "chrome", "tree"}, floor (x, y),
    size (m), a colour for flat pieces."""

    kind: str
    x: float
    y: float
    size: float
    color: tuple[float, float, float] = (0.5, 0.5, 0.5)


@dataclass
class SetPlan:
    """The static set: back wall depth, props, railing, strands, plant, string lights."""

    wall_y: float
    brick_a: tuple[float, float, float]
    brick_b: tuple[float, float, float]
    windows: list[tuple[float, float, float, float, float]]  # x, z, w, h, strength
    props: list[Prop]
    railing_y: float | None
    strands: list[tuple[float, float, float, float]]  # x, y, z_bottom, radius
    plant: tuple[float, float] | None  # x, y of a foreground plant
    string_lights_y: float
    string_lights_z: float
    bulbs: int
    loose_lights: list[tuple[float, float, float, float, float]]  # x, y, z, radius, strength
    key_side: float  # -1 key light from the left, +1 from the right
    world_strength: float


@dataclass
class ScenePlan:
    """Everything that defines a clip's scene. main/second: names of the two focus subjects;
    look: the :class:`~sintel_eval.look.LookPlan` (style, lighting, figures, photo textures) or
    None for the original procedural look."""

    seed: int
    script: str
    frames: int
    fps: int
    camera: CameraPath
    set: SetPlan
    characters: list[Character]
    movers: list[Mover]
    main: str
    second: str
    notes: dict = field(default_factory=dict)
    look: object = None

    def character(self, name: str) -> Character:
        return next(c for c in self.characters if c.name == name)

    def to_dict(self) -> dict:
        """JSON-ready description (for the manifest)."""
        return asdict(self)


def edge_x(camera: CameraPath, frame: int, y: float, side: float) -> float:
    """World x where the floor line at world ``y`` meets the left (side -1) or right (+1) image
    edge on ``frame`` (exact for the posed camera: pan and dolly included)."""
    (cx, cy, _), (_, _, yaw) = camera.pose(frame)
    t = camera.half_fov_tan
    dy = y - cy
    return cx + dy * (side * t * math.cos(yaw) - math.sin(yaw)) / (math.cos(yaw) + side * t * math.sin(yaw))


def half_width(depth: float) -> float:
    """Half the frame width (m) at planar depth ``depth`` (m)."""
    return HALF_FOV_TAN * depth


def make_set(rng: np.random.Generator) -> SetPlan:
    """The seeded static set."""
    wall_y = float(rng.uniform(16.0, 22.0))
    windows = []
    for _ in range(int(rng.integers(2, 5))):
        windows.append((float(rng.uniform(-5.0, 5.0)), float(rng.uniform(2.2, 3.8)), float(rng.uniform(0.5, 1.1)),
                        float(rng.uniform(0.6, 1.2)), float(rng.uniform(3.0, 9.0))))
    kinds = ["crate", "pillar", "panel", "chrome", "tree"]
    rng.shuffle(kinds)
    props: list[Prop] = []
    for i, kind in enumerate(kinds[: int(rng.integers(3, 5))]):
        y = float(rng.uniform(5.5, 11.0))
        side = -1.0 if i % 2 == 0 else 1.0
        x = side * float(rng.uniform(0.15, 0.9)) * half_width(y)
        size = {"crate": rng.uniform(0.5, 0.9), "pillar": rng.uniform(0.18, 0.3), "panel": rng.uniform(0.8, 1.4),
                "chrome": rng.uniform(0.22, 0.35), "tree": rng.uniform(2.6, 3.4)}[kind]
        color = tuple(float(c) for c in rng.uniform(0.1, 0.8, 3))
        props.append(Prop(kind, x, y, float(size), color))
    strands = []
    for _ in range(int(rng.integers(3, 7))):
        y = float(rng.uniform(2.0, 3.6))
        strands.append((float(rng.uniform(-0.9, 0.9)) * half_width(y), y, float(rng.uniform(0.6, 1.6)),
                        float(rng.uniform(0.0012, 0.0025))))
    plant = None
    if rng.uniform() < 0.6:
        y = float(rng.uniform(1.35, 1.7))
        plant = (float(rng.choice([-1.0, 1.0])) * 0.85 * half_width(y), y)
    loose = []
    for _ in range(int(rng.integers(4, 8))):
        y = float(rng.uniform(9.0, min(18.0, wall_y - 0.5)))
        loose.append((float(rng.uniform(-0.95, 0.95)) * half_width(y), y, float(rng.uniform(0.6, 3.4)),
                      float(rng.uniform(BULB_RADIUS_M[0], BULB_RADIUS_M[1] * 1.3)), float(rng.uniform(*BULB_RADIANCE))))
    return SetPlan(
        wall_y=wall_y,
        brick_a=tuple(float(c) for c in rng.uniform([0.35, 0.10, 0.06], [0.50, 0.16, 0.10])),
        brick_b=tuple(float(c) for c in rng.uniform([0.20, 0.12, 0.10], [0.32, 0.18, 0.14])),
        windows=windows,
        props=props,
        railing_y=float(rng.uniform(6.5, 8.5)) if rng.uniform() < 0.75 else None,
        strands=strands,
        plant=plant,
        string_lights_y=float(rng.uniform(11.0, 14.5)),
        string_lights_z=float(rng.uniform(2.5, 3.0)),
        bulbs=int(rng.integers(10, 16)),
        loose_lights=loose,
        key_side=float(rng.choice([-1.0, 1.0])),
        world_strength=float(rng.uniform(0.5, 0.9)),
    )


DEFAULT_TILT_DEG = (0.5, 2.5)
"""Range of the camera tilt in degrees (positive = up): the near subject's head stays in frame."""


def make_camera(rng: np.random.Generator, frames: int,
                tilt_deg: tuple[float, float] = DEFAULT_TILT_DEG) -> CameraPath:
    """A slow pan (2-5 degrees over the clip, either way), a dolly (0.2-0.6 m in) and a tilt
    drawn from ``tilt_deg`` (degrees, positive = up; default a slight upward tilt, 0.5-2.5: the
    near subject's head stays in frame; a downward range shows the floor receding, e.g. for
    the estimator's training data)."""
    pan = math.radians(float(rng.uniform(2.0, 5.0))) * float(rng.choice([-1.0, 1.0]))
    yaw0 = math.radians(float(rng.uniform(-2.0, 2.0)))
    scale = min(frames / 48.0, 2.0)  # longer clips move further (bounded)
    return CameraPath(start=(float(rng.uniform(-0.1, 0.1)), 0.0, CAMERA_HEIGHT), yaw_start=yaw0,
                      yaw_end=yaw0 + pan * scale, dolly_m=float(rng.uniform(0.2, 0.6)) * scale,
                      tilt=math.radians(float(rng.uniform(*tilt_deg))), frames=frames)


def new_character(rng: np.random.Generator, name: str, index: int, motion: Motion, facing: float = 0.0,
                  role: str = "extra", speaker: bool = False) -> Character:
    """A character with seeded looks."""
    return Character(name=name, index=index, motion=motion, facing=facing,
                     sweater=SWEATERS[int(rng.integers(len(SWEATERS)))],
                     skin=SKINS[int(rng.integers(len(SKINS)))], hair=HAIRS[int(rng.integers(len(HAIRS)))],
                     height=float(rng.uniform(0.95, 1.05)), hair_strands=int(rng.integers(10, 24)),
                     speaker=speaker, role=role)
