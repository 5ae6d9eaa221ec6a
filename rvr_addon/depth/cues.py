"""The record every depth cue returns, and the conversion of inverse depth to DESIGN units.

Every cue answers, per frame, with an **inverse depth** map ``q`` (1/m where the cue knows the
metric scale, else up to a positive scale): larger = nearer, 0 = infinitely far; NaN where the
cue says nothing; and a per-pixel ``confidence`` in [0, 1] (0 wherever ``q`` is NaN).

``metric`` says whether ``q`` is in 1/m (people from face size: yes; parallax: only once a
metric cue has fixed its scale); ``shift_free`` whether ``q`` is known up to a scale alone
(geometry: parallax, face size) or up to a scale and a shift (a network's relative depth).

DESIGN units (px of blur radius at aperture scale 1 at the frame's native width, + = behind the
focal plane) follow from a thin lens: ``D = K (q_ref - q)``. :func:`lens_constant` gives K for
a reference lens (a 50 mm f/2 on a full-frame sensor: the shallow depth of field of cinema at
aperture 1), so D of the same scene point is the same in every frame of a clip.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

REFERENCE_FOCAL_M = 0.050
"""Focal length of the reference lens that fixes DESIGN units at aperture scale 1 (m)."""
REFERENCE_F_NUMBER = 2.0
REFERENCE_SENSOR_WIDTH_M = 0.036
DEFAULT_HFOV_DEG = 66.0
"""Field of view (deg) assumed across the frame's long side for a clip without metadata (a phone's
main camera, ~26 mm equivalent: the horizontal field of a landscape clip, the vertical one of a
portrait clip); only the focal length in px used by geometry (face size, triangulation) uses it."""


@dataclass
class CueMap:
    """One cue's answer for one frame (see the module docstring for the units).

    name: ``parallax``, ``people``, ``network`` or ``external``.
    inverse_depth: (H, W) float32, larger = nearer; NaN where the cue says nothing.
    confidence: (H, W) float32 in [0, 1], 0 where inverse_depth is NaN.
    metric: inverse_depth is in 1/m.
    shift_free: inverse_depth is known up to a positive scale only (0 = infinity).
    info: JSON-able notes for meta.json and the log (e.g. ``{"people": 2}``, ``{"baseline": 0.04}``).
    """

    name: str
    inverse_depth: np.ndarray
    confidence: np.ndarray
    metric: bool = False
    shift_free: bool = True
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.inverse_depth.shape != self.confidence.shape or self.inverse_depth.ndim != 2:
            raise ValueError(f"cue {self.name}: inverse_depth {self.inverse_depth.shape} and confidence "
                             f"{self.confidence.shape} must be the same (H, W)")

    @property
    def coverage(self) -> float:
        """Share of pixels with a confidence above 0 (0..1)."""
        return float(np.mean(self.confidence > 0))


def focal_px(long_side: int, hfov_deg: float = DEFAULT_HFOV_DEG) -> float:
    """Focal length in px of a pinhole camera whose frame's long side is ``long_side`` px, with a
    field of view of ``hfov_deg`` across that side (:data:`DEFAULT_HFOV_DEG`: a portrait clip's
    field is given across its height, as a phone's camera is specified)."""
    return 0.5 * float(long_side) / float(np.tan(np.radians(hfov_deg) / 2.0))


def blur_span(width: int, height: int) -> int:
    """The side of a (width, height) frame, in px, that the reference lens's sensor width spans:
    the long side. A phone held upright (a portrait clip) then gives the blur of the same phone
    held sideways, as the long side of a camera's sensor is its width whichever way it is held
    (Cycles' AUTO sensor fit does the same). D stays in px of the frame's native width."""
    return max(int(width), int(height))


def lens_constant(width: int, height: int | None = None) -> float:
    """K of ``D = K (q_ref - q)`` (px * m) for the reference lens at a ``width`` x ``height`` px
    frame (``height`` None: a landscape frame): blur radius on the sensor ~ (A f / 2)
    |1/S_f - 1/S| (A = f / N, the aperture diameter), in px, the sensor's width spanning the
    frame's long side (:func:`blur_span`)."""
    span = blur_span(width, height) if height is not None else int(width)
    aperture_m = REFERENCE_FOCAL_M / REFERENCE_F_NUMBER
    return 0.5 * aperture_m * REFERENCE_FOCAL_M * float(span) / REFERENCE_SENSOR_WIDTH_M


def inverse_depth_to_disparity(q: np.ndarray, width: int, q_ref: float = 0.0,
                               height: int | None = None) -> np.ndarray:
    """Metric inverse depth (1/m) -> D in DESIGN units at a ``width`` x ``height`` frame (``height``
    None: landscape); ``q_ref`` is the inverse depth put at D = 0 (the render's focus is set
    separately, so any value works)."""
    return (lens_constant(width, height) * (float(q_ref) - np.asarray(q, np.float32))).astype(np.float32)


def scale_K(K: np.ndarray, full_size: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    """Intrinsics of the full frame (px, ``full_size`` = (W, H)) at another size (w, h)
    (pixel centres at integer coordinates)."""
    sx, sy = size[0] / full_size[0], size[1] / full_size[1]
    K2 = np.array(K, np.float64).copy()
    K2[0, 0] *= sx
    K2[0, 1] *= sx
    K2[1, 1] *= sy
    K2[0, 2] = (K2[0, 2] + 0.5) * sx - 0.5
    K2[1, 2] = (K2[1, 2] + 0.5) * sy - 0.5
    return K2
