"""Procedural rooms, streets and close-ups for the estimator's disparity supervision (ours).

The harness renders ~40 s of Cycles per ground-truth clip, so a training set of hundreds of
scenes costs hours; and its photo prints (whole photographs on flat boards) taught the network
that a photographed scene is flat. This module ray-casts, in numpy, a new random scene in about
half a second (320x180, 2x2 samples a pixel, one core): a room (floor, walls, ceiling, a
window, shelves) or a street (ground to the horizon, sky, building blocks), with boxes, tables,
pillars, balls, people-like figures, clutter and often a large object near the camera, or
(generator 3) a close-up of things on a floor or table in front of a backdrop, pot plants
among them. Everything is textured with crops of real photographs (:class:`TexturePool`:
material-sized pieces, never a whole scene on a board) or procedural patterns, tiled on the 3D
surfaces so that perspective, texture gradients, contact points and occlusions carry the depth
as in real footage. Lambert shading from a sun or sky light and point lamps, soft contact
shadows; emitters and windows far brighter than white (HDR, clipped in the 8-bit input).

Units: world in metres, y up, the floor at y = 0. A frame's ground truth is planar depth S (m);
:func:`render_scene` returns D in px of blur radius at the frame's width,
``D = K (1/S_ref - 1/S)`` with ``K = k_rel * width / 100`` and S_ref the depth of a random
object, i.e. DESIGN's units for a lens of blur constant ``k_rel`` per cent of the width x m.
The absolute K and S_ref of such a scene mean nothing (there is no lens): the trainer supervises
these frames up to a positive scale and a shift (:func:`.losses.align_median_scale`).

Radiance is linear, exposed so the scene's median is mid-grey; the input is its sRGB 8-bit
rendering (clipped), 2x2 supersampled (the disparity is the sample nearest each pixel centre).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from ..color import linear_to_srgb, srgb_to_linear
from ..errors import InputError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
EXCLUDED_NAMES = ("motorcycle_left.png", "motorcycle_right.png")
"""Never used as textures: Middlebury Motorcycle is the estimator's real-footage test."""
SKIMAGE_PHOTOS = ("astronaut.png", "chelsea.png", "coffee.png", "rocket.jpg", "brick.png", "grass.png",
                  "gravel.png", "camera.png")
MAX_TEXTURE_PX = 512
CLOSEUP_SHARE = 1 / 3
"""Share of close-up scenes (generator version 3 on)."""
MIP_LEVELS = 5
FAR_M = 1.0e4
"""Depth of the sky (m): D is K / S_ref there, up to 1e-4 of K."""


# ------------------------------------------------------------------------------ textures


@dataclass(frozen=True)
class TexturePool:
    """Photographs to cut material textures from: float32 linear RGB, at most 512 px a side."""

    images: tuple[np.ndarray, ...]
    names: tuple[str, ...] = ()

    @classmethod
    def from_paths(cls, paths: Iterable[Path]) -> "TexturePool":
        """Load image files (unreadable ones raise InputError naming the file)."""
        import cv2

        images, names = [], []
        for p in paths:
            p = Path(p)
            if p.name in EXCLUDED_NAMES:
                continue
            img = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if img is None:
                raise InputError(f"texture {p} could not be read as an image; remove it from the texture folder")
            h, w = img.shape[:2]
            s = min(1.0, MAX_TEXTURE_PX / max(h, w))
            if s < 1.0:
                img = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
            images.append(srgb_to_linear(img[..., ::-1].astype(np.float32) / 255.0).astype(np.float32))
            names.append(p.name)
        return cls(tuple(images), tuple(names))


def texture_paths(folders: Iterable[Path] = (), skimage_photos: bool = True) -> list[Path]:
    """Every png/jpg under ``folders`` (recursively) plus, when scikit-image is installed, its sample
    photographs (:data:`SKIMAGE_PHOTOS`); the Motorcycle pair is always left out."""
    paths: list[Path] = []
    for folder in folders:
        folder = Path(folder)
        if not folder.is_dir():
            raise InputError(f"texture folder {folder} does not exist; pass a folder of png/jpg photographs")
        paths += sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_EXTENSIONS)
    if skimage_photos:
        try:
            import skimage
            root = Path(skimage.__file__).parent / "data"
            paths += [root / n for n in SKIMAGE_PHOTOS if (root / n).is_file()]
        except ImportError:
            pass
    return [p for p in paths if p.name not in EXCLUDED_NAMES]


def _value_noise(rng: np.random.Generator, size: int, octaves: int) -> np.ndarray:
    """Fractal value noise in [0, 1], (size, size)."""
    import cv2

    out = np.zeros((size, size), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        n = 2 ** (o + 2)
        grid = rng.random((n, n)).astype(np.float32)
        out += amp * cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.55
    out /= total
    return np.clip((out - out.min()) / max(float(np.ptp(out)), 1e-6), 0, 1)


def _random_colour(rng: np.random.Generator) -> np.ndarray:
    """A plausible linear albedo (desaturated more often than not)."""
    grey = rng.uniform(0.03, 0.75)
    tint = rng.uniform(0.4, 1.6, 3) ** rng.uniform(0.0, 1.2)
    return np.clip(grey * tint / tint.mean(), 0.01, 0.95).astype(np.float32)


def procedural_texture(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    """Noise, stripes, checker, planks or a plain colour with grain: (size, size, 3) linear."""
    kind = rng.choice(["noise", "stripes", "checker", "planks", "plain"], p=[0.3, 0.15, 0.1, 0.2, 0.25])
    a, b = _random_colour(rng), _random_colour(rng)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    if kind == "noise":
        m = _value_noise(rng, size, int(rng.integers(4, 7)))
    elif kind == "stripes":
        m = (np.sin(2 * np.pi * (xx * rng.integers(2, 12))) > rng.uniform(-0.5, 0.5)).astype(np.float32)
    elif kind == "checker":
        n = int(rng.integers(2, 9))
        m = ((np.floor(xx * n) + np.floor(yy * n)) % 2).astype(np.float32)
    elif kind == "planks":
        n = int(rng.integers(3, 10))
        grain = _value_noise(rng, size, 4)
        m = 0.5 * ((np.floor(yy * n) % 2) + np.sin(40 * xx + 6 * grain) * 0.5 + 0.5) * 0.7 + 0.3 * grain
    else:
        m = 0.5 + 0.15 * (_value_noise(rng, size, 5) - 0.5)
    tex = a[None, None] * (1 - m[..., None]) + b[None, None] * m[..., None]
    return np.clip(tex, 0.005, 0.95).astype(np.float32)


def pick_texture(rng: np.random.Generator, pool: TexturePool, photo_share: float = 0.7) -> np.ndarray:
    """A material: a crop of 12-50 % (at least 48 px) of a photograph's shorter side (shifted in colour and contrast
    now and then), or a procedural texture. Never a whole photograph."""
    import cv2

    if pool.images and rng.random() < photo_share:
        img = pool.images[int(rng.integers(len(pool.images)))]
        h, w = img.shape[:2]
        side = min(min(h, w), max(48, int(min(h, w) * rng.uniform(0.12, 0.5))))
        y0, x0 = int(rng.integers(h - side + 1)), int(rng.integers(w - side + 1))
        tex = img[y0:y0 + side, x0:x0 + side]
        if side > 192:
            tex = cv2.resize(tex, (192, 192), interpolation=cv2.INTER_AREA)
        if rng.random() < 0.3:  # recolour: keep the pattern, change the material
            lum = tex.mean(axis=2, keepdims=True)
            tex = lum / max(float(lum.mean()), 1e-4) * _random_colour(rng)[None, None]
        tex = tex * rng.uniform(0.6, 1.4)
        return np.clip(tex, 0.003, 0.95).astype(np.float32)
    return procedural_texture(rng)


def mip_pyramid(tex: np.ndarray, levels: int = MIP_LEVELS) -> list[np.ndarray]:
    """The texture and its successive halvings (area), for sampling without aliasing."""
    import cv2

    out = [tex]
    while len(out) < levels and min(out[-1].shape[:2]) >= 8:
        t = out[-1]
        out.append(cv2.resize(t, (t.shape[1] // 2, t.shape[0] // 2), interpolation=cv2.INTER_AREA))
    return out


def _mirror(u: np.ndarray, n: int) -> np.ndarray:
    """Mirrored tiling of texel coordinates onto [0, n - 1]."""
    m = np.mod(u, 2 * n)
    return np.where(m < n, m, 2 * n - m - 1e-3).clip(0, n - 1)


def sample_texture(pyramid: list[np.ndarray], u: np.ndarray, v: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """Colours (N, 3) at texel coordinates (u, v) of level 0, mirrored-tiled; ``footprint`` is the
    screen pixel's size in level-0 texels (picks the mip level)."""
    import cv2

    level = np.clip(np.floor(np.log2(np.maximum(footprint, 1e-6))), 0, len(pyramid) - 1).astype(int)
    out = np.empty((u.size, 3), np.float32)
    for k in np.unique(level):
        sel = level == k
        tex = pyramid[k]
        h, w = tex.shape[:2]
        mu, mv = _mirror(u[sel] / 2**k, w), _mirror(v[sel] / 2**k, h)
        n = mu.size
        pad = -n % 1024  # remap wants maps under 32767 rows: fold them into rows of 1024
        mu = np.pad(mu, (0, pad)).astype(np.float32).reshape(-1, 1024)
        mv = np.pad(mv, (0, pad)).astype(np.float32).reshape(-1, 1024)
        out[sel] = cv2.remap(tex, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT).reshape(-1, 3)[:n]
    return out


# ------------------------------------------------------------------------------ primitives


@dataclass
class Material:
    """A surface's look: a mip pyramid, its texel size in metres, or an emitter's gain."""

    pyramid: list[np.ndarray]
    texel_m: float
    emission: float = 0.0
    """> 0: the surface emits ``emission`` x its texture (linear), unlit."""


@dataclass
class Rect:
    """A rectangle (or an infinite plane, half sizes inf) at ``centre`` spanned by unit axes a1, a2
    (normal a1 x a2); ``shape``: "rect", "disc" (an ellipse in the rectangle) or "figure"."""

    centre: np.ndarray
    a1: np.ndarray
    a2: np.ndarray
    half: tuple[float, float]
    material: Material
    shape: str = "rect"

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, dict]:
        n = np.cross(self.a1, self.a2)
        oc = o - self.centre
        den = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -(oc @ n) / den
        s1 = (oc @ self.a1) + t * (d @ self.a1)  # in-plane coordinates of the hit (m)
        s2 = (oc @ self.a2) + t * (d @ self.a2)
        h1, h2 = self.half
        if self.shape == "disc":
            inside = (s1 / h1) ** 2 + (s2 / h2) ** 2 <= 1
        else:
            inside = (np.abs(s1) <= h1) & (np.abs(s2) <= h2)
        hit = (t > 1e-4) & inside & (np.abs(den) > 1e-9)
        return np.where(hit, t, np.inf), {"s1": s1, "s2": s2, "n": n}

    def shade(self, p: np.ndarray, d: np.ndarray, info: dict):
        """(texture coordinates (u, v) in m, normals (N, 3), |cos| of the view angle) of hits p."""
        n = np.broadcast_to(info["n"], (len(p), 3))
        cos = np.abs(d @ info["n"]) / np.linalg.norm(d, axis=1)
        return (info["s1"], info["s2"]), n, cos


@dataclass
class Sphere:
    centre: np.ndarray
    radius: float
    material: Material

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, dict]:
        oc = o - self.centre
        a = np.einsum("ij,ij->i", d, d)
        b = 2 * (d @ oc)
        c = float(oc @ oc) - self.radius**2
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        t0, t1 = (-b - sq) / (2 * a), (-b + sq) / (2 * a)
        t = np.where(t0 > 1e-4, t0, t1)
        return np.where((disc >= 0) & (t > 1e-4), t, np.inf), {}

    def shade(self, p: np.ndarray, d: np.ndarray, info: dict):
        n = (p - self.centre) / self.radius
        cos = np.abs(np.einsum("ij,ij->i", n, d)) / np.linalg.norm(d, axis=1)
        u = np.arctan2(n[:, 0], n[:, 2]) * self.radius
        v = np.arcsin(np.clip(n[:, 1], -1, 1)) * self.radius
        return (u, v), n, cos


@dataclass
class Cylinder:
    """A vertical cylinder (axis along y) between heights y0 and y1 (side only; cap it with a disc)."""

    x: float
    z: float
    radius: float
    y0: float
    y1: float
    material: Material

    def intersect(self, o, d):
        ox, oz = o[0] - self.x, o[2] - self.z
        a = d[:, 0] ** 2 + d[:, 2] ** 2
        b = 2 * (d[:, 0] * ox + d[:, 2] * oz)
        c = ox * ox + oz * oz - self.radius**2
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (-b - sq) / (2 * a), (-b + sq) / (2 * a)
        best = np.full(d.shape[0], np.inf)
        for tc in (t1, t0):  # t0 last: the nearer root wins where both are valid
            y = o[1] + tc * d[:, 1]
            ok = (disc >= 0) & (a > 1e-12) & (tc > 1e-4) & (y >= self.y0) & (y <= self.y1)
            best = np.where(ok, tc, best)
        return best, {}

    def shade(self, p: np.ndarray, d: np.ndarray, info: dict):
        n = np.stack([p[:, 0] - self.x, np.zeros(len(p)), p[:, 2] - self.z], 1) / self.radius
        cos = np.abs(np.einsum("ij,ij->i", n, d)) / np.linalg.norm(d, axis=1)
        u = np.arctan2(n[:, 0], n[:, 2]) * self.radius
        return (u, p[:, 1]), n, cos


@dataclass
class Group:
    """Primitives inside a bounding sphere (centre, radius): rays that miss it skip them all."""

    parts: list
    centre: np.ndarray
    radius: float

    @classmethod
    def around(cls, parts: list, points: np.ndarray) -> "Group":
        """A group bounding ``points`` (N, 3) (every extreme point of the parts)."""
        lo, hi = points.min(axis=0), points.max(axis=0)
        centre = (lo + hi) / 2
        return cls(parts, centre, float(np.linalg.norm(hi - lo) / 2) + 1e-3)

    def candidates(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Indices of the rays that may hit a part (they cross the bounding sphere ahead)."""
        oc = o - self.centre
        a = np.einsum("ij,ij->i", d, d)
        b = 2 * (d @ oc)
        c = float(oc @ oc) - self.radius**2
        disc = b * b - 4 * a * c
        far = (-b + np.sqrt(np.maximum(disc, 0))) / (2 * a)
        return np.nonzero((disc >= 0) & (far > 0))[0]


# ------------------------------------------------------------------------------ scenes


@dataclass
class Camera:
    """A pinhole at ``position`` (m) with rotation ``rotation`` (camera -> world, columns x right,
    y up, z forward) and focal length ``f_px`` (px) for a frame of ``width`` x ``height`` px whose
    principal point is ``centre`` (px)."""

    position: np.ndarray
    rotation: np.ndarray
    f_px: float
    width: int
    height: int
    centre: tuple[float, float]


@dataclass
class Scene:
    camera: Camera
    objects: list = field(default_factory=list)
    sun: np.ndarray = field(default_factory=lambda: np.array([0.3, 0.8, -0.5]))
    sun_rgb: np.ndarray = field(default_factory=lambda: np.ones(3, np.float32))
    ambient_rgb: np.ndarray = field(default_factory=lambda: np.full(3, 0.3, np.float32))
    lamps: list = field(default_factory=list)  # (position (3,), rgb (3,)) point lights, 1/r^2
    sky: Material | None = None
    contacts: list = field(default_factory=list)  # (x, z, radius) footprints on the floor (soft shadows)


def _rot(yaw: float, pitch: float, roll: float) -> np.ndarray:
    cy, sy, cp, sp, cr, sr = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz


def _material(rng: np.random.Generator, pool: TexturePool, lo: float, hi: float, photo_share: float = 0.7) -> Material:
    tex = pick_texture(rng, pool, photo_share)
    size_m = rng.uniform(lo, hi)  # the texture's width in metres
    return Material(mip_pyramid(tex), size_m / tex.shape[1])


def _box(rng, pool, x, z, w, dep, h, yaw, y0=0.0, mat=None) -> list[Group]:
    """A box standing at (x, y0, z), rotated by yaw about y: a group of its five faces (no bottom)."""
    faces = _box_faces(rng, pool, x, z, w, dep, h, yaw, y0, mat)
    ext = math.hypot(w, dep) / 2
    return [Group.around(faces, np.array([[x - ext, y0, z - ext], [x + ext, y0 + h, z + ext]]))]


def _box_faces(rng, pool, x, z, w, dep, h, yaw, y0=0.0, mat=None) -> list[Rect]:
    """Five faces (no bottom) of a box standing at (x, y0, z), rotated by yaw about y."""
    mat = mat or _material(rng, pool, 0.3, 1.5)
    c, s = math.cos(yaw), math.sin(yaw)
    ex, ez, ey = np.array([c, 0, -s]), np.array([s, 0, c]), np.array([0.0, 1, 0])
    ctr = np.array([x, y0 + h / 2, z])
    faces = [Rect(ctr + ey * h / 2, ex, ez, (w / 2, dep / 2), mat)]
    for sign in (-1, 1):
        faces.append(Rect(ctr + sign * ex * w / 2, ez, ey, (dep / 2, h / 2), mat))
        faces.append(Rect(ctr + sign * ez * dep / 2, ex, ey, (w / 2, h / 2), mat))
    return faces


def _figure(rng, pool, x, z, scale) -> list:
    """A person-like figure: legs, torso, arms (cylinders), a head (sphere)."""
    procedural_texture(rng, 32)  # drawn and unused: keeps generator 2's random stream (the skin is plain)
    skin = Material(mip_pyramid(np.full((32, 32, 3), np.clip(_random_colour(rng) * 0.9 + 0.05, 0, 1), np.float32)),
                    0.01)
    top, legs = _material(rng, pool, 0.2, 0.6), _material(rng, pool, 0.2, 0.6)
    r = 0.16 * scale
    parts = [Cylinder(x - 0.08 * scale, z, 0.07 * scale, 0.0, 0.85 * scale, legs),
             Cylinder(x + 0.08 * scale, z, 0.07 * scale, 0.0, 0.85 * scale, legs),
             Cylinder(x, z, r, 0.85 * scale, 1.45 * scale, top),
             Rect(np.array([x, 1.45 * scale, z]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), (r, r), top, "disc"),
             Cylinder(x - r - 0.05 * scale, z, 0.045 * scale, 0.8 * scale, 1.42 * scale, top),
             Cylinder(x + r + 0.05 * scale, z, 0.045 * scale, 0.8 * scale, 1.42 * scale, top),
             Cylinder(x, z, 0.05 * scale, 1.45 * scale, 1.55 * scale, skin),
             Sphere(np.array([x, 1.64 * scale, z]), 0.11 * scale, skin)]
    return [Group.around(parts, np.array([[x - 0.3 * scale, 0, z - 0.3 * scale],
                                          [x + 0.3 * scale, 1.76 * scale, z + 0.3 * scale]]))]


def _table(rng, pool, x, z, w, dep, h, yaw) -> list:
    mat = _material(rng, pool, 0.4, 1.5)
    parts: list = _box_faces(rng, pool, x, z, w, dep, 0.04, yaw, y0=h - 0.04, mat=mat)
    c, s = math.cos(yaw), math.sin(yaw)
    for sx in (-1, 1):
        for sz in (-1, 1):
            lx, lz = sx * (w / 2 - 0.05), sz * (dep / 2 - 0.05)
            parts.append(Cylinder(x + c * lx + s * lz, z - s * lx + c * lz, 0.025, 0.0, h - 0.04, mat))
    ext = math.hypot(w, dep) / 2
    return [Group.around(parts, np.array([[x - ext, 0, z - ext], [x + ext, h, z + ext]]))]


def _shelf(rng, pool, x, z) -> list[Group]:
    """A shelf unit (side boards, shelf boards) standing against a wall at depth z, with boxes of
    random sizes and materials on its shelves."""
    w, h, dep = rng.uniform(0.6, 2.2), rng.uniform(0.8, 2.2), rng.uniform(0.25, 0.45)
    wood = _material(rng, pool, 0.3, 1.2)
    parts: list = []
    n = int(rng.integers(2, 6))
    for k in range(n + 1):
        y = k * h / n
        parts += _box_faces(rng, pool, x, z, w, dep, 0.025, 0.0, y0=y, mat=wood)
    for sx in (-1, 1):
        parts += _box_faces(rng, pool, x + sx * w / 2, z, 0.025, dep, h, 0.0, mat=wood)
    for k in range(n):
        y, gap = k * h / n + 0.025, h / n - 0.04
        px = x - w / 2 + 0.03
        while px < x + w / 2 - 0.08:
            bw = rng.uniform(0.05, min(0.4, w / 2))
            if px + bw > x + w / 2 - 0.03:
                break
            if rng.random() < 0.75:
                bh, bd = gap * rng.uniform(0.3, 0.95), dep * rng.uniform(0.4, 0.95)
                parts += _box_faces(rng, pool, px + bw / 2, z + rng.uniform(-0.05, 0.05), bw, bd, bh,
                                    rng.uniform(-0.3, 0.3), y0=y)
            px += bw + rng.uniform(0.0, 0.08)
    return [Group.around(parts, np.array([[x - w / 2 - 0.1, 0, z - dep], [x + w / 2 + 0.1, h + 0.1, z + dep]]))]


def _plant(rng, pool, x, z, scale=1.0, y0=0.0) -> list[Group]:
    """A pot plant: a pot (cylinder) and 6-20 long thin leaves fanning out from its top (~0.5 m
    tall at ``scale`` 1)."""
    pot_r, pot_h = rng.uniform(0.06, 0.2) * scale, rng.uniform(0.08, 0.3) * scale
    pot = _material(rng, pool, 0.2, 0.6)
    green = pick_texture(rng, pool)
    lum = green.mean(axis=2, keepdims=True)
    leaf_rgb = np.array([rng.uniform(0.05, 0.3), rng.uniform(0.25, 0.6), rng.uniform(0.03, 0.25)], np.float32)
    leaf = Material(mip_pyramid((lum / max(float(lum.mean()), 1e-4) * leaf_rgb).clip(0.003, 0.95).astype(np.float32)),
                    rng.uniform(0.1, 0.4) / green.shape[1])
    top = np.array([x, y0 + pot_h, z])
    parts: list = [Cylinder(x, z, pot_r, y0, y0 + pot_h, pot),
                   Rect(top, np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), (pot_r, pot_r), pot, "disc")]
    reach = 0.0
    for _ in range(int(rng.integers(6, 21))):
        length, width = rng.uniform(0.15, 0.6) * scale, rng.uniform(0.01, 0.04) * scale
        az, el = rng.uniform(-math.pi, math.pi), math.radians(rng.uniform(15, 85))
        along = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
        across = np.array([math.cos(az), 0.0, -math.sin(az)])
        parts.append(Rect(top + along * length / 2, across, along, (width, length / 2), leaf))
        reach = max(reach, length)
    return [Group.around(parts, np.array([[x - reach, y0, z - reach], [x + reach, y0 + pot_h + reach, z + reach]]))]


def closeup_scene(rng: np.random.Generator, pool: TexturePool, width: int, height: int) -> Scene:
    """Things photographed from close by: 3-9 boxes, balls, pots, plants and figurines (each a tenth
    to half the frame wide) on a floor or table top, from the nearest floor point in view to the
    backdrop (a wall or curtain 1.2-5 m away, sometimes a second, further
    one beside it), lit by a key light, ambient light and sometimes lamps."""
    hfov = math.radians(rng.uniform(40, 75))
    f_px = width / (2 * math.tan(hfov / 2))
    cam_h = rng.uniform(0.4, 1.4)
    pitch = math.radians(rng.uniform(-30, 0))
    rot = _rot(math.radians(rng.uniform(-20, 20)), pitch, math.radians(rng.uniform(-3, 3)))
    cam = Camera(np.array([0.0, cam_h, 0.0]), rot, f_px, width, height, (width / 2, height / 2))
    scene = Scene(cam)
    objs = scene.objects
    x_ax, up, z_ax = np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])
    objs.append(Rect(np.zeros(3), x_ax, z_ax, (np.inf, np.inf), _material(rng, pool, 0.3, 1.5)))
    back = rng.uniform(1.2, 5.0)
    objs.append(Rect(np.array([0, 0, back]), x_ax, up, (np.inf, np.inf), _material(rng, pool, 0.4, 2.0)))
    if rng.random() < 0.25:  # a nearer backdrop panel on one side (a cupboard, a screen, a door)
        side = rng.choice([-1.0, 1.0])
        objs.append(Rect(np.array([side * rng.uniform(0.5, 1.5), 0, back * rng.uniform(0.6, 0.9)]), x_ax, up,
                         (rng.uniform(0.2, 0.6), rng.uniform(1.0, 3.0)), _material(rng, pool, 0.3, 1.5)))
    # the nearest floor point in view (the frame's bottom edge, 80 % down), so things are seen whole
    below = -pitch + math.atan(height / (2 * f_px)) * 0.8
    nearest = cam_h / math.tan(below) if below > 0.05 else back
    nearest = min(max(0.5, nearest), back * 0.7)
    for _ in range(int(rng.integers(3, 10))):
        x, z = _place(rng, cam, nearest, max(back - 0.2, nearest * 1.1), 0.8)
        kind = rng.choice(["box", "ball", "pot", "plant", "figure"], p=[0.3, 0.2, 0.15, 0.2, 0.15])
        seen = math.hypot(x - cam.position[0], z - cam.position[2]) * width / f_px  # frame width there (m)
        size = seen * rng.uniform(0.1, 0.45)
        if kind == "box":
            objs += _box(rng, pool, x, z, size, size * rng.uniform(0.4, 1.5), size * rng.uniform(0.4, 2.0),
                         rng.uniform(-math.pi, math.pi))
        elif kind == "ball":
            objs.append(Sphere(np.array([x, size / 2, z]), size / 2, _material(rng, pool, 0.1, 0.6)))
        elif kind == "pot":
            mat = _material(rng, pool, 0.1, 0.6)
            h = size * rng.uniform(0.6, 2.5)
            objs += [Cylinder(x, z, size / 2, 0.0, h, mat),
                     Rect(np.array([x, h, z]), x_ax, z_ax, (size / 2, size / 2), mat, "disc")]
        elif kind == "plant":
            objs += _plant(rng, pool, x, z, size / 0.4)
        else:
            objs += _figure(rng, pool, x, z, min(size * rng.uniform(1.5, 3.0), 1.1))
    scene.sun = np.array([rng.uniform(-1, 1), rng.uniform(0.4, 1.0), rng.uniform(-1, 0.2)])
    scene.sun_rgb = np.array([1.0, 0.97, 0.9], np.float32) * rng.uniform(0.5, 2.0)
    scene.ambient_rgb = np.array([1.0, 0.97, 0.93], np.float32) * rng.uniform(0.15, 0.6)
    for _ in range(int(rng.integers(0, 3))):
        p = np.array([rng.uniform(-1.5, 1.5), rng.uniform(0.5, 2.0), rng.uniform(0.5, back - 0.1)])
        rgb = np.array([1.0, rng.uniform(0.6, 0.95), rng.uniform(0.3, 0.8)], np.float32) * rng.uniform(0.2, 1.5)
        scene.lamps.append((p, rgb))
        objs.append(Sphere(p, rng.uniform(0.01, 0.05),
                           Material(mip_pyramid(np.ones((8, 8, 3), np.float32) * rgb / rgb.max()), 0.05,
                                    emission=rng.uniform(5, 150))))
    _add_contacts(scene)
    return scene


def _add_contacts(scene: Scene) -> None:
    """Soft contact shadows under every group, ball and cylinder standing on the floor."""
    for o in scene.objects:
        if isinstance(o, Group) and o.centre[1] - o.radius < 0.5:
            scene.contacts.append((float(o.centre[0]), float(o.centre[2]), o.radius * 0.7))
        elif isinstance(o, (Sphere, Cylinder)):
            c = o.centre if isinstance(o, Sphere) else np.array([o.x, 0.0, o.z])
            if isinstance(o, Cylinder) or o.centre[1] - o.radius < 0.05:
                scene.contacts.append((float(c[0]), float(c[2]), o.radius * 1.2))


def _place(rng: np.random.Generator, cam: Camera, near: float, far: float, spread: float = 0.9) -> tuple[float, float]:
    """A floor point roughly in view: at a random distance, within the horizontal field of view."""
    dist = math.exp(rng.uniform(math.log(near), math.log(far)))
    half_fov = math.atan(cam.width / (2 * cam.f_px))
    ang = rng.uniform(-1, 1) * half_fov * spread
    fwd = cam.rotation[:, 2].copy()
    yaw = math.atan2(fwd[0], fwd[2]) + ang
    return float(cam.position[0] + dist * math.sin(yaw)), float(cam.position[2] + dist * math.cos(yaw))


def random_scene(rng: np.random.Generator, pool: TexturePool, width: int, height: int,
                 version: int = 3) -> Scene:
    """A random room or street seen by a phone-like camera (horizontal field of view 45-82 deg)
    in a frame of ``width`` x ``height`` px; from generator version 3 on, a close-up (things on a
    floor or table in front of a backdrop, 1.2-5 m away) one time in three. ``version`` 2 draws
    exactly what that version drew (datasets stay reproducible)."""
    if version >= 3 and rng.random() < CLOSEUP_SHARE:
        return closeup_scene(rng, pool, width, height)
    hfov = math.radians(rng.uniform(45, 82))
    f_px = width / (2 * math.tan(hfov / 2))
    cx, cy = width / 2, height / 2
    outdoor = rng.random() < 0.3
    cam_h = rng.uniform(0.5, 1.9) if not outdoor else rng.uniform(1.0, 2.2)
    pitch = math.radians(rng.uniform(-30, 5))
    rot = _rot(math.radians(rng.uniform(-35, 35)), pitch, math.radians(rng.uniform(-3, 3)))
    cam = Camera(np.array([0.0, cam_h, 0.0]), rot, f_px, width, height, (cx, cy))
    scene = Scene(cam)
    objs = scene.objects
    floor = _material(rng, pool, 0.5, 2.5)
    objs.append(Rect(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), (np.inf, np.inf), floor))
    if outdoor:
        sky_tex = np.clip(_value_noise(rng, 128, 3)[..., None] * 0.4 + 0.6, 0, 1) * np.array([0.55, 0.7, 1.0])
        scene.sky = Material(mip_pyramid((sky_tex * rng.uniform(1.5, 6.0)).astype(np.float32)), 1.0, emission=1.0)
        for _ in range(int(rng.integers(2, 9))):  # building blocks along the street
            x, z = _place(rng, cam, 12, 120, 1.3)
            w, dep, h = rng.uniform(6, 30), rng.uniform(6, 30), rng.uniform(5, 40)
            objs += _box(rng, pool, x, z, w, dep, h, rng.uniform(-0.3, 0.3), mat=_material(rng, pool, 2, 10))
        scene.sun = np.array([rng.uniform(-1, 1), rng.uniform(0.3, 1.0), rng.uniform(-1, 1)])
        scene.sun_rgb = np.array([1.0, 0.95, 0.85], np.float32) * rng.uniform(1.5, 3.0)
        scene.ambient_rgb = np.array([0.45, 0.5, 0.6], np.float32) * rng.uniform(0.4, 1.0)
        n_obj, near, far = int(rng.integers(2, 9)), 1.5, 25.0
    else:
        half_w, back = rng.uniform(1.5, 5.0), rng.uniform(3.5, 14.0)
        left, right = -half_w * rng.uniform(0.6, 1.4), half_w * rng.uniform(0.6, 1.4)
        ceil = rng.uniform(2.4, 4.5)
        wall = _material(rng, pool, 0.6, 3.0)
        up, x_ax, z_ax = np.array([0, 1.0, 0]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
        objs += [Rect(np.array([0, ceil / 2, back]), x_ax, up, (np.inf, ceil / 2), wall),
                 Rect(np.array([left, ceil / 2, 0]), z_ax, up, (np.inf, ceil / 2),
                      wall if rng.random() < 0.5 else _material(rng, pool, 0.6, 3.0)),
                 Rect(np.array([right, ceil / 2, 0]), z_ax, up, (np.inf, ceil / 2),
                      wall if rng.random() < 0.5 else _material(rng, pool, 0.6, 3.0)),
                 Rect(np.array([0, ceil / 2, -1.5]), x_ax, up, (np.inf, ceil / 2), wall),
                 Rect(np.array([0, ceil, 0]), x_ax, z_ax, (np.inf, np.inf), _material(rng, pool, 1.0, 4.0, 0.3))]
        if rng.random() < 0.5:  # a window: a bright outdoor view set into a wall
            view = Material(mip_pyramid(pick_texture(rng, pool, 0.9)), rng.uniform(0.01, 0.03),
                            emission=rng.uniform(3, 40))
            wx = rng.uniform(left + 0.8, right - 0.8) if right - left > 1.8 else 0.0
            objs.append(Rect(np.array([wx, rng.uniform(1.2, 1.8), back - 0.01]), x_ax, up,
                             (rng.uniform(0.3, 1.0), rng.uniform(0.3, 0.7)), view))
        for wall_obj in range(int(rng.integers(0, 4))):  # frames, shelves, doors on the walls
            px = rng.uniform(left + 0.4, right - 0.4)
            objs.append(Rect(np.array([px, rng.uniform(0.4, 2.0), back - 0.02]), x_ax, up,
                             (rng.uniform(0.15, 0.8), rng.uniform(0.15, 0.9)), _material(rng, pool, 0.2, 1.0)))
        scene.sun = np.array([rng.uniform(-1, 1), 1.0, rng.uniform(-1, 1)])
        scene.sun_rgb = np.array([1.0, 0.97, 0.9], np.float32) * rng.uniform(0.2, 1.2)
        scene.ambient_rgb = np.array([1.0, 0.95, 0.9], np.float32) * rng.uniform(0.1, 0.5)
        for _ in range(int(rng.integers(0, 4))):  # lamps, as small bright balls
            lx, lz = rng.uniform(left + 0.3, right - 0.3), rng.uniform(1.0, back - 0.3)
            ly = rng.uniform(0.8, ceil - 0.1)
            rgb = np.array([1.0, rng.uniform(0.6, 0.95), rng.uniform(0.3, 0.8)], np.float32) * rng.uniform(0.5, 4)
            scene.lamps.append((np.array([lx, ly, lz]), rgb))
            glow = Material(mip_pyramid(np.full((8, 8, 3), 1.0, np.float32) * rgb / rgb.max()), 0.05,
                            emission=rng.uniform(5, 150))
            objs.append(Sphere(np.array([lx, ly, lz]), rng.uniform(0.03, 0.12), glow))
        n_obj, near, far = int(rng.integers(3, 14)), 0.8, max(back - 0.5, 1.2)
    for _ in range(n_obj):
        x, z = _place(rng, cam, near, far)
        kind = rng.choice(["box", "figure", "pillar", "ball", "table", "slab"], p=[0.3, 0.2, 0.12, 0.12, 0.14, 0.12])
        yaw = rng.uniform(-math.pi, math.pi)
        if kind == "box":
            w, dep, h = rng.uniform(0.2, 1.6, 3)
            objs += _box(rng, pool, x, z, w, dep, h, yaw)
            if rng.random() < 0.3:
                objs += _box(rng, pool, x, z, w * 0.6, dep * 0.6, rng.uniform(0.1, 0.6), yaw, y0=h)
        elif kind == "figure":
            objs += _figure(rng, pool, x, z, rng.uniform(0.8, 1.1))
        elif kind == "pillar":
            r, h = rng.uniform(0.05, 0.4), rng.uniform(0.4, 3.0)
            mat = _material(rng, pool, 0.3, 1.5)
            objs += [Cylinder(x, z, r, 0.0, h, mat),
                     Rect(np.array([x, h, z]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), (r, r), mat, "disc")]
        elif kind == "ball":
            r = rng.uniform(0.08, 0.6)
            objs.append(Sphere(np.array([x, r, z]), r, _material(rng, pool, 0.3, 1.5)))
        elif kind == "table":
            top = rng.uniform(0.45, 1.0)
            objs += _table(rng, pool, x, z, rng.uniform(0.6, 1.8), rng.uniform(0.5, 1.0), top, yaw)
            if rng.random() < 0.6:  # something on it
                if rng.random() < 0.5:
                    r = rng.uniform(0.04, 0.15)
                    objs.append(Sphere(np.array([x, top + r, z]), r, _material(rng, pool, 0.2, 0.6)))
                else:
                    objs += _box(rng, pool, x, z, *rng.uniform(0.1, 0.45, 3), yaw, y0=top)
        else:  # a standing slab: a door, a screen, a board of some material
            w, h = rng.uniform(0.3, 1.5), rng.uniform(0.5, 2.2)
            c, s = math.cos(yaw), math.sin(yaw)
            objs.append(Rect(np.array([x, h / 2, z]), np.array([c, 0, -s]), np.array([0, 1.0, 0]), (w / 2, h / 2),
                             _material(rng, pool, 0.3, 1.5)))
    for _ in range(int(rng.integers(0, 25))):  # small things on the floor
        x, z = _place(rng, cam, near * 0.8, min(far, 8.0))
        size = rng.uniform(0.05, 0.35)
        if rng.random() < 0.6:
            objs += _box(rng, pool, x, z, size, size * rng.uniform(0.5, 1.5), size * rng.uniform(0.3, 1.5),
                         rng.uniform(-math.pi, math.pi))
        else:
            objs.append(Sphere(np.array([x, size / 2, z]), size / 2, _material(rng, pool, 0.1, 0.5)))
    if not outdoor:
        for _ in range(int(rng.integers(0, 3))):  # shelves against the back wall, full of things
            objs += _shelf(rng, pool, rng.uniform(left + 0.5, right - 0.5), back - 0.25)
    if rng.random() < 0.45:  # a large object close to the camera, standing on the floor
        x, z = _place(rng, cam, 0.5, 1.6, 0.7)
        if rng.random() < 0.5:
            objs += _box(rng, pool, x, z, *rng.uniform(0.4, 1.2, 2), rng.uniform(0.4, cam_h + 0.3), rng.uniform(-1, 1))
        else:
            objs += _figure(rng, pool, x, z, rng.uniform(0.85, 1.1))
    _add_contacts(scene)
    return scene


def _contact_shade(p: np.ndarray, contacts: list) -> np.ndarray:
    """Light factor (N,) of floor points p: darker close to the footprints of things on the floor."""
    out = np.ones(len(p))
    for x, z, r in contacts:
        dist = np.hypot(p[:, 0] - x, p[:, 2] - z) / max(r, 1e-3)
        out *= 1.0 - 0.55 * np.clip(1.6 - dist, 0, 1) ** 2
    return out


def _rays(cam: Camera, ss: int) -> np.ndarray:
    """World ray directions (N, 3) with camera-z = 1 (so t is planar depth), ``ss`` x ``ss`` per px."""
    xs = (np.arange(cam.width * ss) + 0.5) / ss
    ys = (np.arange(cam.height * ss) + 0.5) / ss
    gx, gy = np.meshgrid(xs, ys)
    dc = np.stack([(gx - cam.centre[0]) / cam.f_px, -(gy - cam.centre[1]) / cam.f_px, np.ones_like(gx)], -1)
    return dc.reshape(-1, 3) @ cam.rotation.T


def trace(scene: Scene, ss: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast a scene: (linear radiance (H*ss, W*ss, 3) float32, planar depth (H*ss, W*ss) m)."""
    cam = scene.camera
    d = _rays(cam, ss)
    o = cam.position
    n_rays = d.shape[0]
    best_t = np.full(n_rays, np.inf)
    best_i = np.full(n_rays, -1)
    prims: list = []
    for item in scene.objects:
        if isinstance(item, Group):
            rays = item.candidates(o, d)
            if rays.size == 0:
                continue
            dd = d[rays]
            for part in item.parts:
                t, _ = part.intersect(o, dd)
                closer = t < best_t[rays]
                best_t[rays[closer]] = t[closer]
                best_i[rays[closer]] = len(prims)
                prims.append(part)
        else:
            t, _ = item.intersect(o, d)
            closer = t < best_t
            best_t[closer] = t[closer]
            best_i[closer] = len(prims)
            prims.append(item)
    rad = np.zeros((n_rays, 3), np.float32)
    sun = scene.sun / np.linalg.norm(scene.sun)
    for i, obj in enumerate(prims):
        sel = best_i == i
        if not sel.any():
            continue
        ds = d[sel]
        info = obj.intersect(o, ds)[1]  # the hit's surface coordinates, for these rays only
        p = o + ds * best_t[sel, None]
        (u, v), n, cos = obj.shade(p, ds, info)
        mat = obj.material
        dist = best_t[sel] * np.linalg.norm(ds, axis=1)
        footprint = dist / (cam.f_px * ss * np.maximum(cos, 0.15) * mat.texel_m)
        albedo = sample_texture(mat.pyramid, u / mat.texel_m, -v / mat.texel_m, footprint)
        if mat.emission > 0:
            rad[sel] = albedo * mat.emission
            continue
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
        facing = np.sign(-np.einsum("ij,ij->i", n, ds))[:, None]
        n = n * np.where(facing == 0, 1, facing)  # normals toward the camera
        light = scene.ambient_rgb[None] * (0.75 + 0.25 * n[:, 1:2]) + scene.sun_rgb[None] * np.maximum(n @ sun, 0)[:, None]
        if scene.lamps:
            for lp, rgb in scene.lamps:
                v_l = lp - p
                r2 = np.maximum(np.einsum("ij,ij->i", v_l, v_l), 0.05)
                light = light + rgb[None] * (np.maximum(np.einsum("ij,ij->i", n, v_l), 0) / r2 ** 1.5)[:, None]
        if i == 0 and scene.contacts:  # the floor: soft contact shadows under the things on it
            light = light * _contact_shade(p, scene.contacts)[:, None]
        rad[sel] = albedo * light
    miss = best_i < 0
    if miss.any():
        best_t[miss] = FAR_M
        if scene.sky is not None:
            dm = d[miss] / np.linalg.norm(d[miss], axis=1, keepdims=True)
            u = np.arctan2(dm[:, 0], dm[:, 2]) * 60
            v = np.arcsin(np.clip(dm[:, 1], -1, 1)) * 60
            sky = sample_texture(scene.sky.pyramid, u, v, np.full(u.shape, 0.5))
            rad[miss] = sky * scene.sky.emission * (0.6 + 0.4 * np.clip(dm[:, 1:2] * 3, 0, 1))
    h, w = cam.height * ss, cam.width * ss
    return rad.reshape(h, w, 3), best_t.reshape(h, w)


@dataclass
class ProceduralFrame:
    """One rendered frame: input sRGB (H, W, 3) float32 in [0, 1] (8-bit values), linear radiance
    (H, W, 3) on the input's exposure (> 1 where clipped), D (H, W) px at this width, depth S (m)."""

    image: np.ndarray
    radiance: np.ndarray
    disparity: np.ndarray
    depth: np.ndarray


def render_scene(scene: Scene, rng: np.random.Generator, ss: int = 2, k_rel: float = 6.8) -> ProceduralFrame:
    """Trace, expose (median to mid-grey), supersample down, add sensor noise and quantise to 8 bit;
    D from the depth sample nearest each pixel centre (module docstring for the units)."""
    import cv2

    rad, depth = trace(scene, ss)
    cam = scene.camera
    lin = cv2.resize(rad, (cam.width, cam.height), interpolation=cv2.INTER_AREA) if ss > 1 else rad
    exposure = rng.uniform(0.12, 0.3) / max(float(np.median(lin.mean(axis=2))), 1e-4)
    lin = lin * exposure
    if rng.random() < 0.5:  # lens softness
        lin = cv2.GaussianBlur(lin, (0, 0), rng.uniform(0.3, 0.8))
    noisy = lin + rng.normal(0, rng.uniform(0.0, 0.01), lin.shape).astype(np.float32) * np.sqrt(np.maximum(lin, 0) + 0.01)
    srgb = np.round(np.clip(linear_to_srgb(np.clip(noisy, 0, 1)), 0, 1) * 255) / 255
    s = depth[ss // 2::ss, ss // 2::ss][:cam.height, :cam.width]
    objects = s[s < FAR_M]
    s_ref = float(np.quantile(objects, rng.uniform(0.1, 0.6))) if objects.size else 3.0
    k_px = k_rel * cam.width / 100.0 if cam.width else k_rel
    disparity = (k_px * (1.0 / s_ref - 1.0 / s)).astype(np.float32)
    return ProceduralFrame(srgb.astype(np.float32), lin.astype(np.float32), disparity, s.astype(np.float32))


def random_frame(rng: np.random.Generator, pool: TexturePool, width: int, height: int,
                 version: int = 3) -> ProceduralFrame:
    """A new random scene rendered at ``width`` x ``height`` (generator ``version``)."""
    return render_scene(random_scene(rng, pool, width, height, version), rng)


# ------------------------------------------------------------------------------ datasets on disk

PROCEDURAL_FORMAT = "rvr-laaf-procedural/1"
GENERATOR_VERSION = 3
"""Bump when the same seed would draw a different scene (the manifest records it); older
versions stay available (``rvr procedural --generator``) so their datasets can be rebuilt."""
GENERATOR_VERSIONS = (2, 3)
FRAME_SIZES = ((320, 180), (288, 216), (240, 240), (180, 320), (300, 200))
"""Frame sizes (w, h) a dataset draws from: ~57,600 px, landscape, square and portrait."""


def frame_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of frame ``index`` (1-based) of a dataset of seed ``seed``: frames are
    independent, so a dataset can be written in any order, resumed or extended."""
    return np.random.default_rng([int(seed), int(index)])


def write_frame(folder: Path, index: int, seed: int, pool: TexturePool,
                sizes: tuple[tuple[int, int], ...] = FRAME_SIZES, version: int = GENERATOR_VERSION) -> None:
    """Render frame ``index`` of the dataset in ``folder``: input PNG, gt/disparity EXR (D in px at
    the frame's width, Z planar depth in m), gt/hdr EXR (linear R, G, B on the input's exposure),
    then its done marker listing the files and their sizes (the marker is written last)."""
    import cv2

    from ..io.exr import write_exr

    rng = frame_rng(seed, index)
    w, h = sizes[int(rng.integers(len(sizes)))]
    fr = random_frame(rng, pool, w, h, version)
    name = f"frame_{index:05d}"
    rel = {"input": f"input/{name}.png", "disparity": f"gt/disparity/{name}.exr", "hdr": f"gt/hdr/{name}.exr"}
    (folder / "input").mkdir(parents=True, exist_ok=True)
    png = np.round(fr.image * 255).astype(np.uint8)[..., ::-1]
    if not cv2.imwrite(str(folder / rel["input"]), png):
        raise InputError(f"could not write {folder / rel['input']}; check free disk space and permissions")
    write_exr(folder / rel["disparity"], {"D": fr.disparity, "Z": fr.depth})
    write_exr(folder / rel["hdr"], {"R": fr.radiance[..., 0], "G": fr.radiance[..., 1], "B": fr.radiance[..., 2]},
              half=True)
    marker = {"frame": index, "seed": seed, "generator_version": version,
              "files": {v: (folder / v).stat().st_size for v in rel.values()}}
    (folder / "done").mkdir(exist_ok=True)
    tmp = folder / "done" / f".{name}.json.tmp"
    tmp.write_text(json.dumps(marker))
    tmp.replace(folder / "done" / f"{name}.json")


def write_dataset(folder: str | Path, frames: int, seed: int, pool: TexturePool, progress: bool = False,
                  sizes: tuple[tuple[int, int], ...] = FRAME_SIZES, version: int = GENERATOR_VERSION,
                  workers: int = 1) -> int:
    """Write (or complete) a procedural dataset of ``frames`` frames in ``folder``, each of one of
    ``sizes`` (w, h); frames whose done marker exists are kept. Returns the number of frames
    rendered now, in ``workers`` processes (the frames are the same whatever their number). A
    folder written with another seed or generator version is refused (InputError naming it), as
    is a version this module cannot draw."""
    if version not in GENERATOR_VERSIONS:
        raise InputError(f"generator version {version} is not available; choose one of {GENERATOR_VERSIONS}")
    from tqdm import tqdm

    folder = Path(folder)
    manifest = folder / "manifest.json"
    record = {"format": PROCEDURAL_FORMAT, "generator_version": int(version), "seed": int(seed),
              "frames": int(frames), "textures": list(pool.names)}
    if manifest.is_file():
        old = json.loads(manifest.read_text())
        if old.get("seed") != seed or old.get("generator_version") != version:
            raise InputError(f"{folder} holds a procedural dataset of seed {old.get('seed')} (generator "
                             f"{old.get('generator_version')}); pass --seed {old.get('seed')} --generator "
                             f"{old.get('generator_version')} to extend it, or another output folder")
        record["frames"] = max(int(old.get("frames", 0)), int(frames))
    folder.mkdir(parents=True, exist_ok=True)
    manifest.write_text(json.dumps(record, indent=1))
    todo = [i for i in range(1, frames + 1) if not (folder / "done" / f"frame_{i:05d}.json").is_file()]
    if workers > 1 and len(todo) > 1:
        _write_in_parallel(folder, todo, seed, pool, sizes, version, workers, progress)
        return len(todo)
    for i in tqdm(todo, desc="procedural frames", unit="frame", disable=not progress):
        write_frame(folder, i, seed, pool, sizes, version)
    return len(todo)


def _write_frames(folder: Path, indices: list[int], seed: int, pool: TexturePool,
                  sizes: tuple[tuple[int, int], ...], version: int) -> None:
    """One worker's share of :func:`write_dataset` (frames are independent: any order, any split)."""
    for i in indices:
        write_frame(folder, i, seed, pool, sizes, version)


def _write_in_parallel(folder: Path, todo: list[int], seed: int, pool: TexturePool,
                       sizes: tuple[tuple[int, int], ...], version: int, workers: int, progress: bool) -> None:
    """Render ``todo`` in ``workers`` processes (every workers-th frame each); the bar counts done
    markers. A worker that fails raises InputError after the others finish; written frames stay."""
    import multiprocessing as mp
    import time

    from tqdm import tqdm

    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
    procs = [ctx.Process(target=_write_frames, args=(folder, todo[k::workers], seed, pool, sizes, version),
                         daemon=True) for k in range(min(workers, len(todo)))]
    for proc in procs:
        proc.start()
    done_dir = folder / "done"
    with tqdm(total=len(todo), desc="procedural frames", unit="frame", disable=not progress) as bar:
        while any(proc.is_alive() for proc in procs):
            time.sleep(0.5)
            bar.update(sum((done_dir / f"frame_{i:05d}.json").is_file() for i in todo) - bar.n)
        bar.update(sum((done_dir / f"frame_{i:05d}.json").is_file() for i in todo) - bar.n)
    failed = [proc.exitcode for proc in procs if proc.exitcode != 0]
    if failed:
        raise InputError(f"{len(failed)} of {len(procs)} `rvr procedural` workers failed (exit codes {failed}; see "
                         f"the messages above); the frames written in {folder} are kept: run the command again "
                         "to finish")
