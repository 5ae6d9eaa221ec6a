"""Settings of the temporal filter, importable without OpenCV or NumPy (``rvr stabilize --help``,
``rvr batch --help`` and the batch settings read the defaults from here; :mod:`.filter` runs them)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from ..errors import InputError

WINDOWS = ("causal", "centred")
FLOW_PRESETS = ("ultrafast", "fast", "medium")
"""Names of the DIS optical-flow presets (:data:`.flow.PRESETS` maps them to OpenCV's)."""


@dataclass(frozen=True)
class TemporalSettings:
    """Settings of the temporal filter (units in the names; see :mod:`.filter`'s docstring).

    window: "centred" (the default: a recorded clip has its future; M/2 past and M/2 future
    frames) or "causal" (the paper's: the current and M past frames, what a camera could do
    live). Centred beats causal on every figure measured: the harness (flicker of simulated
    estimates -64 % vs -51 %, PSNR 27.09 vs 26.80 dB), the rendered flicker of real clips (-46 %
    vs -40 %) and the real depth of the depth system (HoloLens office 0.375 vs 0.393, TUM
    fr1/rpy 0.663 vs 0.731; docs/temporal.md). m: frames besides the current one (paper: M = 6).
    delta_px: forward-backward threshold in px at the flow resolution, plus ``delta_rel``
    times the flow magnitude. photometric_tol: colour mismatch (fraction of full scale, mean
    over 5x5 px) beyond which a warped pixel is occluded; pixel_tol: the same for one pixel;
    slack_px: misregistration (flow px) forgiven on strong edges (the mismatch is lowered by
    slack_px times the local gradient). outlier_scale_d: scale of the D outlier weight as a
    fraction of the frame width (px of D = this * width); outlier_scale_e: the same for E (E
    units). flow_preset: DIS preset; flow_max_side: longer side of the flow resolution (px).
    cut_fraction: share of failing pixels that makes a scene cut. erode_px: erosion of each
    link's valid mask, flow px (0: eroding erases small highlights from the masks).
    """

    window: str = "centred"
    m: int = 6
    delta_px: float = 1.0
    delta_rel: float = 0.05
    photometric_tol: float = 0.05
    pixel_tol: float = 0.15
    slack_px: float = 0.2
    outlier_scale_d: float = 0.004
    outlier_scale_e: float = 0.01
    flow_preset: str = "medium"
    flow_max_side: int = 320
    cut_fraction: float = 0.6
    erode_px: int = 0

    def __post_init__(self) -> None:
        if self.window not in WINDOWS:
            raise InputError(f"temporal window {self.window!r} is not known; use one of {', '.join(WINDOWS)}")
        if not 1 <= int(self.m) <= 15:
            raise InputError(f"temporal window size M={self.m} must be between 1 and 15 (paper: 6)")
        if self.flow_preset not in FLOW_PRESETS:
            raise InputError(f"flow preset {self.flow_preset!r} is not known; use one of {', '.join(FLOW_PRESETS)}")
        if self.flow_max_side < 16:
            raise InputError(f"flow_max_side={self.flow_max_side} px is too small; use at least 16 (e.g. 480)")
        positive = {"delta_px": self.delta_px, "photometric_tol": self.photometric_tol,
                    "outlier_scale_d": self.outlier_scale_d, "outlier_scale_e": self.outlier_scale_e}
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"temporal setting {name}={value!r} must be a positive number")
        if not 0 < self.cut_fraction <= 1:
            raise InputError(f"cut_fraction={self.cut_fraction!r} must be in (0, 1]")

    @property
    def past(self) -> int:
        """P: past frames in the window."""
        return int(self.m) if self.window == "causal" else int(self.m) // 2

    @property
    def future(self) -> int:
        """F: future frames in the window (the output lags the input by F frames)."""
        return int(self.m) - self.past

    def to_dict(self) -> dict:
        """JSON-serialisable settings (the cache's stabilized record is keyed by this)."""
        return asdict(self)

