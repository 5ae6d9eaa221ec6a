"""Thin-lens constants of Cycles' camera and the DESIGN.md disparity units (no bpy).

Cycles' perspective camera with depth of field (intern/cycles/kernel/camera): a ray leaves a
point of the aperture disk (radius ``f / (2 N)``, f the focal length, N the f-number) towards
the point where the pinhole ray of the pixel crosses the plane of focus, at *planar* distance
``S_f`` along the view axis. The image plane stays at the focal length whatever the focus
(no focus breathing), so a point at planar depth S spreads over a uniform disk centred on its
pinhole projection with radius

    r = K_N * |1/S_f - 1/S|,   K_N = (f / (2 N)) * f * (W_px / sensor_width)      [px * m]

(f and sensor width in mm, divided by 1000 so that S is in metres). Measured on a bright point
by tests/blender/test_harness_coc.py: this radius, not the diameter and not the physical thin
lens' ``(A/2) v_f`` with image distance ``v_f = f S_f / (S_f - f)``.

DESIGN units: ``D = K (1/S_ref - 1/S)`` with ``K = K_{N_ref}`` of the notional "aperture scale 1"
f-number; a render at (S_f, N) is our model at focus ``f = K (1/S_ref - 1/S_f)`` and aperture
scale ``a = K_N / K = N_ref / N``: ``r = a |D - f|`` exactly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

Metres = float
Pixels = float


@dataclass(frozen=True)
class Lens:
    """The clip's camera lens. focal_mm, sensor_width_mm: mm (sensor fit horizontal);
    width_px: render width in px; f_number_ref: f-number of aperture scale 1; s_ref_m: the
    planar depth (m) where D = 0."""

    focal_mm: float
    sensor_width_mm: float
    width_px: int
    f_number_ref: float
    s_ref_m: Metres

    @property
    def f_px(self) -> Pixels:
        """Focal length in px (pinhole projection scale)."""
        return self.focal_mm / self.sensor_width_mm * self.width_px

    def k_for(self, f_number: float) -> float:
        """Cycles' blur constant K_N (px * m) at f-number ``f_number``: r = K_N |1/S_f - 1/S|."""
        return blur_constant_px(self.focal_mm, f_number, self.sensor_width_mm, self.width_px)

    @property
    def k_px(self) -> float:
        """K (px * m) of the DESIGN units: the blur constant at ``f_number_ref``."""
        return self.k_for(self.f_number_ref)

    def focus_disparity(self, focus_distance_m: Metres) -> Pixels:
        """Focus disparity f (px) of a planar focus distance S_f (m)."""
        return self.k_px * (1.0 / self.s_ref_m - 1.0 / focus_distance_m)

    def focus_distance(self, focus_disparity: Pixels) -> Metres:
        """Planar focus distance S_f (m) of a focus disparity; raises ValueError at/after infinity."""
        inv = 1.0 / self.s_ref_m - focus_disparity / self.k_px
        if inv <= 0.0:
            raise ValueError(f"focus disparity {focus_disparity} px lies at or beyond infinity "
                             f"(max {self.k_px / self.s_ref_m} px)")
        return 1.0 / inv

    def aperture_scale(self, f_number: float) -> float:
        """Aperture scale a = K_N / K = N_ref / N of a render at f-number ``f_number``."""
        return self.k_for(f_number) / self.k_px

    def disparity(self, depth_m):
        """Planar depth (m; scalar or array) -> disparity (px). Arrays come back float32."""
        if np.isscalar(depth_m):
            return self.k_px * (1.0 / self.s_ref_m - 1.0 / max(float(depth_m), 1e-6))
        return disparity_from_depth(depth_m, self.k_px, self.s_ref_m)

    def physical_k_for(self, f_number: float, focus_distance_m: Metres) -> float:
        """The physical thin lens' constant (A/2) v_f W/sw (px * m), for reference only (Cycles
        does not model the image distance; see the module docstring)."""
        f = self.focal_mm
        v = f * focus_distance_m * 1000.0 / (focus_distance_m * 1000.0 - f)
        return self.k_for(f_number) * v / f


def blur_constant_px(focal_mm: float, f_number: float, sensor_width_mm: float, width_px: int) -> float:
    """K_N = (f / (2 N)) * f * (W / sensor_width) / 1000 in px * m (Cycles' CoC radius constant)."""
    if f_number <= 0 or focal_mm <= 0 or sensor_width_mm <= 0 or width_px <= 0:
        raise ValueError("focal length, f-number, sensor width and width must be positive")
    aperture_radius_mm = focal_mm / (2.0 * f_number)
    return aperture_radius_mm * focal_mm * (width_px / sensor_width_mm) / 1000.0


def disparity_from_depth(depth_m: np.ndarray, k_px: float, s_ref_m: Metres) -> np.ndarray:
    """Planar depth (H, W) in m -> signed disparity (H, W) float32 in px: K (1/S_ref - 1/S)."""
    s = np.maximum(np.asarray(depth_m, dtype=np.float64), 1e-6)
    return (k_px * (1.0 / s_ref_m - 1.0 / s)).astype(np.float32)


def blur_radius(disparity, focus: Pixels, aperture: float):
    """Blur radius (px) of our model: r = a |D - f|."""
    return aperture * np.abs(np.asarray(disparity, dtype=np.float64) - focus)


def affine_to_blur(focus: Pixels, aperture: float) -> tuple[float, float]:
    """(alpha, beta) with signed blur radius = alpha * D + beta for a render at (focus, aperture)."""
    return float(aperture), float(-aperture * focus)


def affine_between(focus_from: Pixels, aperture_from: float, focus_to: Pixels, aperture_to: float
                   ) -> tuple[float, float]:
    """(alpha, beta) with R_to = alpha * R_from + beta between two renders' signed blur radii.

    R = a (D - f) for each, so alpha = a_to / a_from and beta = a_to (f_from - f_to).
    """
    if aperture_from == 0:
        raise ValueError("the 'from' render has aperture 0: its blur radius says nothing about D")
    return float(aperture_to / aperture_from), float(aperture_to * (focus_from - focus_to))


def smoothstep(x: float) -> float:
    """C1 ease 0 -> 1 on [0, 1] (clamped outside)."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def project_points(world_to_camera: np.ndarray, points: np.ndarray, f_px: Pixels, width: int, height: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection of world points (N, 3) with a Blender camera (looks along its -Z).

    world_to_camera: (4, 4) inverse of the camera's matrix_world. Returns (xy (N, 2) in px with
    the DATASET.md pixel convention, planar depth (N,) in m; <= 0 behind the camera).
    """
    p = np.asarray(points, dtype=np.float64)
    cam = p @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    depth = -cam[:, 2]
    safe = np.where(np.abs(depth) < 1e-9, 1e-9, depth)
    x = width / 2.0 + f_px * cam[:, 0] / safe
    y = height / 2.0 - f_px * cam[:, 1] / safe
    return np.stack([x, y], axis=1), depth


def box_of(xy: np.ndarray, width: int, height: int) -> tuple[list[float], float]:
    """Bounding box [x, y, w, h] of projected points clipped to the frame, and the fraction of
    the unclipped box's area inside the frame (0 when it is entirely outside)."""
    x0, y0 = (float(v) for v in xy.min(axis=0))
    x1, y1 = (float(v) for v in xy.max(axis=0))
    area = max(x1 - x0, 1e-9) * max(y1 - y0, 1e-9)
    cx0, cy0 = min(max(x0, 0.0), width), min(max(y0, 0.0), height)
    cx1, cy1 = min(max(x1, 0.0), width), min(max(y1, 0.0), height)
    inside = max(cx1 - cx0, 0.0) * max(cy1 - cy0, 0.0)
    return [cx0, cy0, cx1 - cx0, cy1 - cy0], inside / area


def look_rotation(yaw_rad: float, tilt_rad: float = 0.0) -> tuple[float, float, float]:
    """Blender Euler XYZ of a level camera that looks along +Y turned by ``yaw`` about +Z
    (positive = to the left) and tilted by ``tilt`` (positive = up)."""
    return (math.pi / 2.0 + tilt_rad, 0.0, yaw_rad)
