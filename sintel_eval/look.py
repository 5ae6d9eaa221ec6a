"""The seeded "look" of a harness scene (no bpy): style, lighting, figures and photo textures.

The ``procedural`` style with ``classic`` lighting is the harness' original look: no
:class:`LookPlan` at all (``ScenePlan.look is None``), so those clips render exactly as before.
Otherwise :func:`make_look` draws, from its own random stream (the scene's layout, motions and
events do not change with the look):

- the lighting: ``day`` (bright interior: strong sky and sun, cool daylight windows), ``dim``
  (warm, low ambient, a few lamps), ``night`` (almost dark; many small very bright emitters:
  string lights, lamps, lit windows: bokeh balls far above the 8-bit range), with colour
  temperatures in kelvin and light strengths;
- people-like figures (``person`` model: jointed limbs, face with lips and a jaw, hair styles,
  varied skin tones, clothes);
- in the ``photo`` style, a crop of a real photograph for every textured surface (walls,
  floor, crates, posters, billboards, clothes), see :mod:`sintel_eval.textures`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .scene_plan import ScenePlan, half_width
from .textures import TextureLibrary, TextureSource, TextureUse

LOOK_VERSION = 1  # bump when a seed's look (photo style or lighting modes) renders differently
STYLES = ("procedural", "photo")
LIGHTINGS = ("classic", "day", "dim", "night")
HAIRSTYLES = ("short", "long", "bun", "bob")
TOPS = ("sweater", "shirt", "jacket", "dress")
# Linear albedo of skin, light to dark (the skin material's light tone; its dark tone is 0.56 x).
SKIN_TONES = ((0.92, 0.72, 0.60), (0.85, 0.60, 0.46), (0.72, 0.48, 0.34), (0.55, 0.36, 0.24),
              (0.40, 0.24, 0.15), (0.26, 0.15, 0.09))
HAIR_COLOURS = ((0.02, 0.015, 0.01), (0.07, 0.035, 0.018), (0.20, 0.10, 0.04), (0.30, 0.09, 0.03),
                (0.55, 0.42, 0.20), (0.42, 0.42, 0.43))
RGB = tuple[float, float, float]


def kelvin_rgb(kelvin: float) -> RGB:
    """Colour of a black body at ``kelvin`` K as linear Rec.709 RGB scaled to a maximum of 1
    (Tanner Helland's fit of the CIE data in sRGB, linearised; good to a few % in 1500-15000 K)."""
    t = float(np.clip(kelvin, 1000.0, 40000.0)) / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = 99.4708025861 * math.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
    b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * math.log(t - 10) - 305.0447927307)
    srgb = np.clip(np.array([r, g, b]) / 255.0, 0.0, 1.0)
    lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    lin = lin / max(lin.max(), 1e-9)
    return tuple(float(v) for v in lin)


@dataclass
class Lamp:
    """A practical light: ``floor`` lamp (pole + glowing shade) or ``street`` lamp (tall pole +
    bright bulb). radiance: of the shade/bulb surface (x display white); energy_w: the light
    object that lights the surroundings."""

    kind: str
    x: float
    y: float
    height: float
    radius: float
    radiance: float
    kelvin: float
    rgb: RGB
    energy_w: float


@dataclass
class LightString:
    """An extra sagging string of bulbs across the frame at depth ``y``, height ``z``."""

    y: float
    z: float
    bulbs: int
    gain: float


@dataclass
class Lighting:
    """One lighting mode's draws. Strengths: world background (x its colour), sun (W/m^2), key
    area light (W); gains multiply the set's window and bulb radiance; billboard_gain is the
    self-illumination of the photo billboards (1 = the photo's own brightness)."""

    mode: str
    world_kelvin: float | None
    world_rgb: RGB
    world_strength: float
    sun_kelvin: float | None
    sun_rgb: RGB
    sun_energy: float
    sun_elevation_deg: float
    sun_azimuth_deg: float
    key_kelvin: float | None
    key_rgb: RGB
    key_energy: float
    fill_energy: float
    window_kelvin: float | None
    window_rgb: RGB
    window_gain: float
    bulb_gain: float
    billboard_gain: float
    lamps: list[Lamp] = field(default_factory=list)
    strings: list[LightString] = field(default_factory=list)


@dataclass
class Billboard:
    """A photo of a real scene standing far behind (x centre, y depth, bottom z, size in m)."""

    slot: str
    x: float
    y: float
    z0: float
    width: float
    height: float


@dataclass
class FigureLook:
    """How a ``person`` figure looks: skin and hair (linear RGB), hair style, build (shoulder
    width factor), clothes (kind, colours, optional photo texture slots), lips, shoes."""

    name: str
    skin: RGB
    hair: RGB
    hairstyle: str
    build: float
    top: str
    sleeves: str
    top_rgb: RGB
    top_texture: str | None
    bottom_rgb: RGB
    bottom_texture: str | None
    shoes_rgb: RGB
    lips_rgb: RGB


@dataclass
class LookPlan:
    """Everything the look adds to a :class:`ScenePlan` (recorded in the manifest)."""

    style: str
    figures_model: str
    lighting: Lighting
    figures: dict[str, FigureLook]
    textures: dict[str, TextureUse]
    billboards: list[Billboard]
    texture_digest: str | None
    fallback: str | None = None
    version: int = LOOK_VERSION

    def texture(self, slot: str) -> TextureUse | None:
        return self.textures.get(slot)


# --------------------------------------------------------------------------------------------- draws


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def make_lighting(rng: np.random.Generator, mode: str, plan: ScenePlan) -> Lighting:
    """The draws of one lighting mode (see the module docstring)."""
    if mode == "day":
        world_k, world_s = _u(rng, 6500, 10000), _u(rng, 0.9, 1.8)
        sun_k, sun_e, sun_el = _u(rng, 5000, 5800), _u(rng, 3.0, 6.0), _u(rng, 30, 60)
        key_k, key_e, fill = _u(rng, 4500, 6500), _u(rng, 40, 80), _u(rng, 10, 25)
        win_k, win_g, bulb_g, bb_g = _u(rng, 6500, 9000), _u(rng, 1.0, 2.0), _u(rng, 0.7, 1.0), _u(rng, 0.5, 1.0)
        n_floor, n_street, lamp_rad, n_strings, lamp_w = int(rng.integers(0, 2)), 0, (2.0, 5.0), 0, (10, 30)
    elif mode == "dim":
        world_k, world_s = _u(rng, 3500, 6000), _u(rng, 0.06, 0.2)
        sun_k, sun_e, sun_el = _u(rng, 2800, 3500), _u(rng, 0.0, 0.6), _u(rng, 5, 20)
        key_k, key_e, fill = _u(rng, 2900, 4000), _u(rng, 15, 30), _u(rng, 2, 6)
        win_k, win_g, bulb_g, bb_g = _u(rng, 3000, 5000), _u(rng, 1.0, 1.8), _u(rng, 1.0, 1.5), _u(rng, 0.15, 0.4)
        n_floor, n_street, lamp_rad, n_strings, lamp_w = int(rng.integers(1, 3)), 0, (6.0, 20.0), 0, (15, 45)
    elif mode == "night":
        world_k, world_s = _u(rng, 9000, 14000), _u(rng, 0.002, 0.01)
        sun_k, sun_e, sun_el = _u(rng, 7000, 9000), _u(rng, 0.0, 0.03), _u(rng, 20, 50)  # moonlight
        key_k, key_e, fill = _u(rng, 2700, 3300), _u(rng, 4, 9), _u(rng, 0.3, 1.2)
        win_k, win_g, bulb_g, bb_g = _u(rng, 2700, 3500), _u(rng, 1.2, 2.5), _u(rng, 1.2, 2.2), _u(rng, 0.02, 0.08)
        n_floor, n_street, lamp_rad, n_strings = int(rng.integers(1, 3)), int(rng.integers(1, 3)), (15.0, 60.0), 1
        lamp_w = (5, 20)  # pools of light, not floodlights: the frame stays dark
    else:
        raise ValueError(f"unknown lighting mode {mode!r}: use one of {', '.join(LIGHTINGS[1:])}")
    sp = plan.set
    lamps: list[Lamp] = []
    taken = [(p.x, p.y) for p in sp.props]
    for kind, count in (("floor", n_floor), ("street", n_street)):
        for _ in range(count):
            for _try in range(20):
                if kind == "floor":
                    y = _u(rng, 10.5, min(15.0, sp.wall_y - 0.8))
                else:
                    y = _u(rng, 13.0, sp.wall_y - 0.5)
                x = float(rng.choice([-1.0, 1.0])) * _u(rng, 0.35, 0.95) * half_width(y)
                if all(math.hypot(x - a, y - b) > 1.0 for a, b in taken):
                    break
            taken.append((x, y))
            k = _u(rng, 2700, 3600) if kind == "floor" else _u(rng, 2200, 4200)
            if kind == "floor":
                lamps.append(Lamp("floor", x, y, _u(rng, 1.4, 1.9), _u(rng, 0.12, 0.2), _u(rng, *lamp_rad), k,
                                  kelvin_rgb(k), _u(rng, *lamp_w)))
            else:
                lamps.append(Lamp("street", x, y, _u(rng, 3.0, 4.5), _u(rng, 0.08, 0.14),
                                  _u(rng, 2 * lamp_rad[0], 3 * lamp_rad[1]), k, kelvin_rgb(k), _u(rng, 15, 50)))
    strings = [LightString(_u(rng, 7.5, 10.0), _u(rng, 2.2, 2.7), int(rng.integers(8, 14)), _u(rng, 1.0, 2.0))
               for _ in range(n_strings)]
    return Lighting(mode=mode, world_kelvin=world_k, world_rgb=kelvin_rgb(world_k), world_strength=world_s,
                    sun_kelvin=sun_k, sun_rgb=kelvin_rgb(sun_k), sun_energy=sun_e, sun_elevation_deg=sun_el,
                    sun_azimuth_deg=_u(rng, 120, 240), key_kelvin=key_k, key_rgb=kelvin_rgb(key_k), key_energy=key_e,
                    fill_energy=fill, window_kelvin=win_k, window_rgb=kelvin_rgb(win_k), window_gain=win_g,
                    bulb_gain=bulb_g, billboard_gain=bb_g, lamps=lamps, strings=strings)


def classic_lighting(plan: ScenePlan) -> Lighting:
    """The harness' original lights (dusk-blue world, warm sun, key on the main subject) as a
    :class:`Lighting` (colours given directly, not as temperatures; kelvin fields None)."""
    return Lighting(mode="classic", world_kelvin=None, world_rgb=(0.30, 0.38, 0.55),
                    world_strength=plan.set.world_strength, sun_kelvin=None, sun_rgb=(1.0, 0.8, 0.6), sun_energy=2.0,
                    sun_elevation_deg=40.0, sun_azimuth_deg=200.0 if plan.set.key_side < 0 else 160.0,
                    key_kelvin=None, key_rgb=(1.0, 0.93, 0.85), key_energy=45.0, fill_energy=0.0,
                    window_kelvin=None, window_rgb=(1.0, 0.82, 0.55), window_gain=1.0, bulb_gain=1.0,
                    billboard_gain=0.6)


def _tone(rng: np.random.Generator, palette) -> RGB:
    """A colour between two neighbours of ``palette`` (continuous), jittered by a few %."""
    t = _u(rng, 0.0, len(palette) - 1.0)
    i = min(int(t), len(palette) - 2)
    a, b = np.array(palette[i]), np.array(palette[i + 1])
    rgb = (a + (b - a) * (t - i)) * rng.uniform(0.94, 1.06, 3)
    return tuple(float(v) for v in np.clip(rgb, 0.0, 1.0))


def _cloth_rgb(rng: np.random.Generator) -> RGB:
    hue = _u(rng, 0.0, 1.0)
    sat = _u(rng, 0.1, 0.8)
    val = _u(rng, 0.04, 0.6)
    import colorsys

    return tuple(float(v) for v in colorsys.hsv_to_rgb(hue, sat, val))


class _Picker:
    """Chooses texture crops from a library with a random stream."""

    def __init__(self, rng: np.random.Generator, library: TextureLibrary | None):
        self.rng = rng
        self.lib = library if library else None
        self.uses: dict[str, TextureUse] = {}

    def _source(self, kinds: tuple[str, ...]) -> TextureSource:
        pool = [s for s in self.lib.sources if s.kind in kinds] or self.lib.sources
        return pool[int(self.rng.integers(len(pool)))]

    def square(self, slot: str, frac: tuple[float, float], size: int, tile_m: float,
               kinds: tuple[str, ...] = ("scene", "material"), y_range: tuple[float, float] = (0.0, 1.0)):
        """A square (in pixels) crop of side ``frac`` x the source's shorter side, tiled every ``tile_m`` m."""
        if self.lib is None:
            return None
        s = self._source(kinds)
        side = _u(self.rng, *frac) * min(s.width, s.height)
        fw, fh = side / s.width, side / s.height
        x0 = _u(self.rng, 0.0, 1.0 - fw)
        lo, hi = y_range[0], max(y_range[0], min(y_range[1], 1.0 - fh))
        y0 = _u(self.rng, lo, hi)
        return self._add(slot, s, (x0, y0, x0 + fw, min(y0 + fh, 1.0)), size, tile_m)

    def framed(self, slot: str, aspect: float | None, size: int, margin: float = 0.12):
        """A crop of a whole scene (for posters and billboards), of pixel aspect ``aspect`` (w/h;
        None = the source's own, trimmed by up to ``margin`` on each side)."""
        if self.lib is None:
            return None
        s = self._source(("scene",))
        if aspect is None:
            x0, x1 = _u(self.rng, 0.0, margin), 1.0 - _u(self.rng, 0.0, margin)
            y0, y1 = _u(self.rng, 0.0, margin), 1.0 - _u(self.rng, 0.0, margin)
        else:
            src_aspect = s.width / s.height
            if aspect < src_aspect:  # narrower than the source: full height (trimmed), a slice of the width
                fh = 1.0 - _u(self.rng, 0.0, margin)
                fw = fh * aspect / src_aspect
            else:
                fw = 1.0 - _u(self.rng, 0.0, margin)
                fh = min(1.0, fw * src_aspect / aspect)
            x0, y0 = _u(self.rng, 0.0, 1.0 - fw), _u(self.rng, 0.0, 1.0 - fh)
            x1, y1 = x0 + fw, y0 + fh
        return self._add(slot, s, (x0, y0, x1, y1), size, None)

    def _add(self, slot: str, s: TextureSource, rect, size: int, tile_m: float | None) -> TextureUse:
        tint = (1.0, 1.0, 1.0)
        if s.gray:  # a grey photo gets a muted colour
            tint = tuple(float(v) for v in np.clip(np.array(_cloth_rgb(self.rng)) / 0.6 * 0.5 + 0.5, 0.3, 1.0))
        use = TextureUse(slot=slot, source=s.name, sha256=s.sha256, rect=tuple(float(v) for v in rect),
                         size=int(size), flip=bool(self.rng.uniform() < 0.5), tint=tint,
                         tile_m=None if tile_m is None else float(tile_m), frame_time_s=s.frame_time_s)
        self.uses[slot] = use
        return use

    def pixel_aspect(self, use: TextureUse) -> float:
        s = self.lib.get(use.source)
        x0, y0, x1, y1 = use.rect
        return (x1 - x0) * s.width / max((y1 - y0) * s.height, 1e-9)


def make_look(plan: ScenePlan, style: str, lighting: str, library: TextureLibrary | None = None,
              script_index: int = 0) -> LookPlan | None:
    """The seeded look of ``plan`` (None for the original procedural + classic look).

    lighting: a mode of :data:`LIGHTINGS` or "auto" (procedural: classic; photo: a seeded
    choice of day, dim or night). library: texture sources of the photo style (None or empty:
    procedural materials, noted in ``fallback``).
    """
    if style not in STYLES:
        raise ValueError(f"unknown style {style!r}: use one of {', '.join(STYLES)}")
    rng = np.random.default_rng([int(plan.seed), int(script_index), 0x100C])
    if lighting == "auto":
        pick = np.random.default_rng([int(plan.seed), int(script_index), 0x30D])
        lighting = "classic" if style == "procedural" else str(pick.choice(["day", "dim", "night"], p=[0.4, 0.3, 0.3]))
    if lighting not in LIGHTINGS:
        raise ValueError(f"unknown lighting {lighting!r}: use auto or one of {', '.join(LIGHTINGS)}")
    if style == "procedural" and lighting == "classic":
        return None
    if lighting == "classic":
        light = classic_lighting(plan)
    else:
        light = make_lighting(np.random.default_rng([int(plan.seed), int(script_index), 0x11D]), lighting, plan)
    photo = style == "photo"
    picker = _Picker(np.random.default_rng([int(plan.seed), int(script_index), 0x7E7]), library if photo else None)
    fallback = None
    if photo and not library:
        fallback = "no texture source found: procedural materials on the photo-style set"
    sp = plan.set
    billboards: list[Billboard] = []
    if picker.lib is not None:
        picker.square("wall", (0.35, 0.8), 512, _u(rng, 3.0, 6.0))
        picker.square("floor", (0.3, 0.7), 512, _u(rng, 1.5, 3.5), y_range=(0.45, 1.0))
        for i, p in enumerate(sp.props):
            if p.kind == "crate":
                picker.square(f"crate_{i}", (0.2, 0.5), 256, _u(rng, 0.6, 1.2))
            elif p.kind == "panel":
                picker.framed(f"panel_{i}", p.size / 1.9, 384)
            elif p.kind == "pillar" and rng.uniform() < 0.5:
                picker.square(f"pillar_{i}", (0.2, 0.5), 256, _u(rng, 0.5, 1.0))
        for m in plan.movers:
            if rng.uniform() < 0.5:
                picker.square(f"{m.name}", (0.2, 0.5), 256, _u(rng, 0.3, 0.6))
        for k in range(int(rng.integers(1, 4))):
            use = picker.framed(f"billboard_{k}", None, 512)
            aspect = picker.pixel_aspect(use)
            # behind the string lights (bulbs next to a print would flood it with light), before the wall
            near = min(max(12.0, sp.wall_y - 5.0, sp.string_lights_y + 1.5), sp.wall_y - 0.3)
            y = _u(rng, near, sp.wall_y - 0.3)
            width = _u(rng, 3.0, 8.0)
            height = width / aspect
            if height > 5.0:
                width, height = width * 5.0 / height, 5.0
            billboards.append(Billboard(f"billboard_{k}", _u(rng, -0.8, 0.8) * half_width(y), y,
                                        _u(rng, 0.0, 1.2), width, height))
    for lamp in light.lamps:  # a lamp right before a print would floodlight it: keep 3 m in front
        for bb in billboards:
            if abs(lamp.y - bb.y) < 3.0 and abs(lamp.x - bb.x) < 0.5 * bb.width + 2.0:
                lamp.y = min(lamp.y, bb.y - 3.0)
    figures = {}
    frng = np.random.default_rng([int(plan.seed), int(script_index), 0xF16])
    for c in plan.characters if photo else []:  # the procedural style keeps its classic figures
        top = str(frng.choice(TOPS, p=[0.3, 0.3, 0.25, 0.15]))
        figures[c.name] = FigureLook(
            name=c.name, skin=_tone(frng, SKIN_TONES), hair=_tone(frng, HAIR_COLOURS),
            hairstyle=str(frng.choice(HAIRSTYLES)), build=_u(frng, 0.88, 1.15), top=top,
            sleeves=str(frng.choice(["long", "short"], p=[0.7, 0.3])), top_rgb=_cloth_rgb(frng),
            top_texture=(f"top_{c.name}" if picker.lib is not None and frng.uniform() < 0.6 else None),
            bottom_rgb=_cloth_rgb(frng),
            bottom_texture=(f"bottom_{c.name}" if picker.lib is not None and frng.uniform() < 0.4 else None),
            shoes_rgb=tuple(float(v) for v in frng.uniform(0.02, 0.25) * frng.uniform(0.8, 1.0, 3)),
            lips_rgb=tuple(float(v) for v in np.array([0.45, 0.16, 0.14]) * frng.uniform(0.6, 1.0)))
        if figures[c.name].top_texture:
            picker.square(figures[c.name].top_texture, (0.08, 0.25), 256, _u(frng, 0.25, 0.6))
        if figures[c.name].bottom_texture:
            picker.square(figures[c.name].bottom_texture, (0.08, 0.25), 256, _u(frng, 0.25, 0.6))
    return LookPlan(style=style, figures_model="person" if photo else "classic", lighting=light, figures=figures,
                    textures=picker.uses, billboards=billboards,
                    texture_digest=library.digest if (photo and library) else None, fallback=fallback)


__all__ = ["LOOK_VERSION", "STYLES", "LIGHTINGS", "Lamp", "LightString", "Lighting", "Billboard", "FigureLook",
           "LookPlan", "kelvin_rgb", "classic_lighting", "make_lighting", "make_look"]
