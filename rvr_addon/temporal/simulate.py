"""SIMULATED inputs for testing and measuring the temporal filter (no trained estimator yet).

Two things live here, and only here:

* :func:`synthetic_clip`: a synthetic video with *known* motion, rendered in numpy: a
  textured background plane panning (slanted: its disparity varies across it and moves with
  it), small clipped highlights on it (HDR exponent E > 0), and a textured foreground disk
  crossing in front of it (an occluder), optionally a scene cut to another such scene.
  Every frame comes with its exact disparity and E.
* :func:`simulate_estimates`: **simulated per-frame estimates**: ground-truth D and E
  degraded with per-frame independent errors typical of a single-frame network: a
  low-frequency per-frame scale/shift wobble, a smooth random error field, spatially
  correlated noise, sparse outlier blobs; for E a per-frame gain wobble, missed highlights
  and a few false ones. Seeded per (seed, frame index), so every variant of a comparison sees
  the same estimates.

The magnitudes are stated as fractions of the frame width (D is in px of blur at the native
width, DESIGN units, so it scales with the width). Figures measured on these inputs are
labelled "simulated" wherever they are reported; they stand in for real estimates (a cache
written by ``rvr estimate``) until trained weights exist.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import cv2
import numpy as np

from ..color import image_to_linear


@dataclass
class SynthFrame:
    """One synthetic frame. image: (H, W, 3) uint8 sRGB (clipped); disparity: (H, W) float32
    px (DESIGN units); exponent: (H, W, 3) float32 (eq. 3); occluder: (H, W) bool, pixels of
    the foreground disk; scene: 0 before a cut, 1 after."""

    index: int
    image: np.ndarray
    disparity: np.ndarray
    exponent: np.ndarray
    occluder: np.ndarray
    scene: int

    def radiance(self) -> np.ndarray:
        """(H, W, 3) float32 linear HDR radiance: ``srgb_to_linear(image) * exp(50 E)``."""
        return (image_to_linear(self.image) * np.exp(50.0 * self.exponent)).astype(np.float32)


def _noise_texture(rng: np.random.Generator, h: int, w: int, channels: int, scales: tuple[int, ...]) -> np.ndarray:
    """(h, w, channels) float32 multi-scale value noise in about [0, 1]."""
    out = np.zeros((h, w, channels), np.float32)
    total = 0.0
    for i, cell in enumerate(scales):
        gh, gw = max(h // cell + 2, 2), max(w // cell + 2, 2)
        grid = rng.random((gh, gw, channels)).astype(np.float32)
        layer = cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        if layer.ndim == 2:
            layer = layer[..., None]
        amp = 0.6 ** i
        out += amp * layer
        total += amp
    return np.clip(out / total, 0.0, 1.0)


class _Scene:
    """One synthetic scene: a background canvas, a foreground disk, their motion."""

    def __init__(self, width: int, height: int, frames: int, seed: int) -> None:
        rng = np.random.default_rng(seed)
        self.w, self.h = width, height
        self.pan = max(1, int(round(0.003 * width)))  # px / frame to the left
        self.speed = max(2, int(round(0.008 * width)))  # disk px / frame to the right
        self.margin = self.pan * frames + 8
        cw, ch = width + self.margin, height
        cell = max(width // 80, 2)
        tex = _noise_texture(rng, ch, cw, 3, (cell * 8, cell * 3, cell, max(cell // 2, 1)))
        tint = rng.uniform(0.35, 0.8, size=3).astype(np.float32)
        self.bg = np.clip(0.15 + tex * tint * 1.2, 0, 1)
        ys, xs = np.mgrid[0:ch, 0:cw].astype(np.float32)
        # slanted background plane: far at the top, nearer at the bottom (DESIGN px at this width)
        self.bg_d = (0.012 - 0.008 * ys / ch + 0.002 * np.sin(xs / cw * 6.0)).astype(np.float32) * width
        self.bg_e = np.zeros((ch, cw, 3), np.float32)
        r = max(2, int(round(0.006 * width)))
        for _ in range(int(rng.integers(6, 10))):
            cx, cy = int(rng.integers(r, cw - r)), int(rng.integers(r, ch // 2))
            spot = ((xs - cx) ** 2 + (ys - cy) ** 2) <= r * r
            self.bg[spot] = 1.0
            self.bg_e[spot] = np.float32(rng.uniform(0.03, 0.07))
        self.radius = int(round(0.11 * height))
        self.disk_tex = np.clip(0.2 + 0.9 * _noise_texture(rng, 2 * self.radius + 1, 2 * self.radius + 1, 3,
                                                           (max(cell * 3, 2), cell, max(cell // 2, 1))), 0, 1)
        self.disk_tex *= rng.uniform(0.6, 1.0, size=3).astype(np.float32)
        self.disk_d = np.float32(-0.006 * width)
        self.disk_y = int(round(0.55 * height))
        self.disk_x0 = -self.radius - 2

    def frame(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        x0 = self.pan * t
        img = self.bg[:, x0:x0 + self.w].copy()
        d = self.bg_d[:, x0:x0 + self.w].copy()
        e = self.bg_e[:, x0:x0 + self.w].copy()
        cx = self.disk_x0 + self.speed * t
        r = self.radius
        ys, xs = np.mgrid[-r:r + 1, -r:r + 1]
        inside = xs * xs + ys * ys <= r * r
        occ = np.zeros((self.h, self.w), bool)
        x_lo, x_hi = max(cx - r, 0), min(cx + r + 1, self.w)
        y_lo, y_hi = max(self.disk_y - r, 0), min(self.disk_y + r + 1, self.h)
        if x_lo < x_hi and y_lo < y_hi:
            sub = inside[y_lo - (self.disk_y - r):y_hi - (self.disk_y - r), x_lo - (cx - r):x_hi - (cx - r)]
            tex = self.disk_tex[y_lo - (self.disk_y - r):y_hi - (self.disk_y - r), x_lo - (cx - r):x_hi - (cx - r)]
            region = (slice(y_lo, y_hi), slice(x_lo, x_hi))
            img[region][sub] = tex[sub]
            d[region][sub] = self.disk_d
            e[region][sub] = 0.0
            occ[region] = sub
        image = (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
        return image, d, e, occ


def synthetic_clip(width: int = 320, height: int = 180, frames: int = 24, seed: int = 0,
                   cut_at: int | None = None) -> Iterator[SynthFrame]:
    """Stream a synthetic clip with known motion (see the module docstring).

    The background pans left by ``round(0.003 width)`` px per frame, the foreground disk
    (radius 0.11 height, disparity -0.006 width px, in front of the focal plane) moves right
    by ``round(0.008 width)`` px per frame, entering from the left edge. cut_at: index of the
    first frame of a second, unrelated scene (a scene cut), or None.
    """
    scenes = [_Scene(width, height, frames, seed)]
    if cut_at is not None:
        scenes.append(_Scene(width, height, frames, seed + 1000))
    for t in range(frames):
        k = 1 if cut_at is not None and t >= cut_at else 0
        local = t - cut_at if k else t
        image, d, e, occ = scenes[k].frame(local)
        yield SynthFrame(t, image, d, e, occ, k)


# ----------------------------------------------------------------------------------------
# Simulated per-frame estimates


@dataclass(frozen=True)
class EstimateErrors:
    """Magnitudes of the SIMULATED per-frame estimate errors (D ones as fractions of the width).

    gain: std of the per-frame relative scale error of D. shift: std of the per-frame offset.
    field: std of a smooth (4x3-cell) per-frame error field. noise: std of spatially
    correlated noise (Gaussian-blurred white noise, sigma = noise_sigma * width px).
    blobs: mean number of outlier blobs per frame; blob_size: their radius; blob_offset: their
    peak error (random sign). e_gain: std of the per-frame gain of E; e_miss: probability a
    highlight is missed in a frame; e_false: mean false highlight blobs per frame.
    """

    gain: float = 0.04
    shift: float = 0.0008
    field: float = 0.0008
    noise: float = 0.0005
    noise_sigma: float = 0.005
    blobs: float = 2.0
    blob_size: float = 0.03
    blob_offset: float = 0.006
    e_gain: float = 0.15
    e_miss: float = 0.1
    e_false: float = 0.5


def simulate_estimates(disparity: np.ndarray, exponent: np.ndarray, index: int, seed: int = 0,
                       errors: EstimateErrors | None = None) -> tuple[np.ndarray, np.ndarray]:
    """SIMULATED single-frame estimates: (D (H, W) px, E (H, W, 3) >= 0) float32.

    disparity: ground-truth D (H, W), DESIGN units; exponent: ground-truth E (H, W, 3).
    Deterministic in (seed, index); independent from frame to frame.
    """
    err = errors or EstimateErrors()
    rng = np.random.default_rng([int(seed) & 0x7FFFFFFF, int(index)])
    h, w = disparity.shape
    gt = np.asarray(disparity, np.float32)
    d = gt * np.float32(1.0 + rng.normal(0.0, err.gain)) + np.float32(rng.normal(0.0, err.shift * w))
    grid = rng.normal(0.0, err.field * w, size=(3, 4)).astype(np.float32)
    d += cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
    sigma = max(err.noise_sigma * w, 0.5)
    noise = cv2.GaussianBlur(rng.normal(0.0, 1.0, size=(h, w)).astype(np.float32), (0, 0), sigma)
    noise *= np.float32(err.noise * w / max(float(noise.std()), 1e-6))
    d += noise
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for _ in range(int(rng.poisson(err.blobs))):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        r = err.blob_size * w * rng.uniform(0.5, 1.0)
        amp = err.blob_offset * w * rng.choice((-1.0, 1.0)) * rng.uniform(0.6, 1.0)
        d += np.float32(amp) * np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / np.float32(2 * (r / 2) ** 2))
    e = np.asarray(exponent, np.float32) * np.float32(max(0.0, 1.0 + rng.normal(0.0, err.e_gain)))
    if (exponent > 0).any():
        n_lab, labels = cv2.connectedComponents((exponent.max(axis=2) > 0).astype(np.uint8))
        for lab in range(1, n_lab):
            if rng.random() < err.e_miss:
                e[labels == lab] = 0.0
    for _ in range(int(rng.poisson(err.e_false))):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        r = max(0.006 * w, 1.0)
        spot = (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r
        e[spot] = np.maximum(e[spot], np.float32(rng.uniform(0.01, 0.04)))
    return d.astype(np.float32), np.maximum(e, 0.0).astype(np.float32)
