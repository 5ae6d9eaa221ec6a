"""Streaming scores of one rendered run (a clip, a focus track, a variant) against ground truth.

:class:`RunScorer` takes frames one at a time (it keeps only the previous frame's two sRGB
images, for flicker) and pools the per-frame pieces of :mod:`.metrics` into clip figures:

- ``psnr_srgb_db`` / ``psnr_linear_db``: PSNR of the pooled MSE over all frames (the clip as
  one signal), sRGB resp. linear clipped to [0, 1], peak 1 (see :mod:`.metrics`);
- ``ssim_srgb`` / ``ssim_linear``: mean over frames;
- ``edge_band_psnr_srgb_db`` / ``edge_band_psnr_linear_db``: PSNR of the MSE pooled over the
  edge-band pixels of every frame; ``edge_band_fraction``: share of pixels in the band;
- ``splotchiness_px``: within-frame standard deviation of the blur-size error in flat
  regions, pooled over frames (px of blur radius);
- ``flicker``: mean over consecutive frame pairs (sRGB, fraction of full scale);
- ``flicker_exact``: the same against a reference render of our renderer from the exact
  (ground-truth) disparity and HDR instead of Cycles' image, when the caller gives one: the
  flicker the inputs cause (what a temporal filter of D and E can remove), without the
  renderer-vs-Cycles differences that every variant shares;
- ``flicker_exact_warped``: motion-compensated flicker of the error against that reference:
  ``|e_t - warp(e_{t-1})|`` with ``e = out - ref`` (sRGB), warped along the input's optical
  flow (:func:`.metrics.evaluation_flow`) on its consistent pixels. ``flicker_exact`` also
  counts an error that merely moves with the scene (a consistently wrong blur on a panning
  wall changes every pixel's value); this one counts errors that change along the motion
  (a wrong but steady depth still scores a little: defocus of a moving scene is not a rigid
  warp of the error image). Needs the input's motion (``motion``, computed once per clip by
  :func:`.ablate.run_variant`);
- ``bokeh_recall``: found / total highlight energy pooled over frames (0..1).

A figure with nothing to measure (no edge in the clip, no highlight, a single frame for
flicker) is NaN; :func:`aggregate` skips NaNs.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from . import metrics as m

METRICS: tuple[str, ...] = (
    "psnr_srgb_db", "psnr_linear_db", "ssim_srgb", "ssim_linear", "edge_band_psnr_srgb_db",
    "edge_band_psnr_linear_db", "splotchiness_px", "flicker", "flicker_exact", "flicker_exact_warped",
    "bokeh_recall",
)
"""Names of the figures of a run, in report order."""

HIGHER_IS_BETTER: dict[str, bool] = {
    "psnr_srgb_db": True, "psnr_linear_db": True, "ssim_srgb": True, "ssim_linear": True,
    "edge_band_psnr_srgb_db": True, "edge_band_psnr_linear_db": True, "splotchiness_px": False,
    "flicker": False, "flicker_exact": False, "flicker_exact_warped": False, "bokeh_recall": True,
}


@dataclass(frozen=True)
class ScoreSettings:
    """Thresholds of the masks; lengths in px at the dataset's native width.

    edge_band_px: half width of the band around depth edges. edge_threshold_px: a jump of the
    blur radius between neighbours above this is an edge. flat_gradient_px: blur-radius
    gradient (px per px) below which a region is flat; flat_erode_px: erosion of the flat set.
    highlight_threshold: linear radiance above which a ground-truth pixel is a highlight
    (1.0 = 8-bit white). min_defocus_px: highlights count only where the ground truth blurs
    by at least this radius (defocused highlights).
    """

    edge_band_px: int = 5
    edge_threshold_px: float = 1.0
    flat_gradient_px: float = 0.05
    flat_erode_px: int = 3
    highlight_threshold: float = 1.0
    min_defocus_px: float = 1.0


@dataclass
class FrameScore:
    """Per-frame figures (same names and units as the run's; flicker NaN on the first frame)."""

    frame: int
    psnr_srgb_db: float
    psnr_linear_db: float
    ssim_srgb: float
    ssim_linear: float
    edge_band_psnr_srgb_db: float
    flicker: float
    flicker_exact: float
    flicker_exact_warped: float
    bokeh_recall: float


def _ratio(num: float, den: float) -> float:
    return num / den if den else float("nan")


@dataclass
class RunScorer:
    """Accumulates the scores of one run frame by frame; see the module docstring."""

    settings: ScoreSettings = field(default_factory=ScoreSettings)
    frames: list[FrameScore] = field(default_factory=list)
    _sse: dict[str, float] = field(default_factory=lambda: dict.fromkeys(("srgb", "lin", "band_srgb", "band_lin"), 0.0))
    _n: dict[str, int] = field(default_factory=lambda: dict.fromkeys(("srgb", "lin", "band_srgb", "band_lin"), 0))
    _ssim: list[tuple[float, float]] = field(default_factory=list)
    _splotch: list[float] = field(default_factory=lambda: [0.0, 0.0])
    _bokeh: list[float] = field(default_factory=lambda: [0.0, 0.0])
    _flicker: list[float] = field(default_factory=list)
    _flicker_exact: list[float] = field(default_factory=list)
    _flicker_warped: list[float] = field(default_factory=list)
    _prev: tuple[np.ndarray, np.ndarray] | None = None
    _prev_ref: np.ndarray | None = None
    _band_px: int = 0
    _px: int = 0

    def add(self, frame: int, out_linear: np.ndarray, gt_linear: np.ndarray, disparity_used: np.ndarray,
            disparity_gt: np.ndarray, focus: float, aperture: float,
            ref_linear: np.ndarray | None = None,
            motion: tuple[np.ndarray, np.ndarray] | None = None) -> FrameScore:
        """Score one frame.

        out_linear / gt_linear: (H, W, 3) linear radiance of the variant and of the ground truth.
        ref_linear: optional (H, W, 3) render of the same frame from the exact inputs (for
        ``flicker_exact``; give it for every frame of the run or for none).
        motion: optional ``(flow, valid)`` from this frame's input to the previous frame's
        (:func:`.metrics.evaluation_flow`), for ``flicker_exact_warped`` (with ``ref_linear``).
        disparity_used / disparity_gt: (H, W) DESIGN units, what the variant rendered with and
        the truth. focus, aperture: the frame's focus disparity and aperture scale.
        """
        s = self.settings
        if out_linear.shape != gt_linear.shape:
            raise ValueError(f"frame {frame}: output {out_linear.shape} and ground truth {gt_linear.shape} differ.")
        out_s, gt_s = m.display_srgb(out_linear), m.display_srgb(gt_linear)
        out_l, gt_l = m.display_linear(out_linear), m.display_linear(gt_linear)
        band = m.edge_band(disparity_gt, s.edge_band_px, aperture=aperture, threshold_px=s.edge_threshold_px)
        flat = m.flat_regions(disparity_gt, aperture=aperture, gradient_px=s.flat_gradient_px, erode_px=s.flat_erode_px)
        soft = m.defocused(disparity_gt, focus, aperture, min_radius_px=s.min_defocus_px)

        pieces = {"srgb": m.squared_error_sum(out_s, gt_s), "lin": m.squared_error_sum(out_l, gt_l),
                  "band_srgb": m.squared_error_sum(out_s, gt_s, band), "band_lin": m.squared_error_sum(out_l, gt_l, band)}
        for key, (sse, n) in pieces.items():
            self._sse[key] += sse
            self._n[key] += n
        self._band_px += int(band.sum())
        self._px += band.size
        ssim_s, ssim_l = m.ssim(out_s, gt_s), m.ssim(out_l, gt_l)
        self._ssim.append((ssim_s, ssim_l))
        ss, n = m.splotch_moments(disparity_used, disparity_gt, focus, aperture, flat)
        self._splotch[0] += ss
        self._splotch[1] += n
        found, total = m.bokeh_energy(out_linear, gt_linear, threshold=s.highlight_threshold, mask=soft)
        self._bokeh[0] += found
        self._bokeh[1] += total
        fl = float("nan")
        if self._prev is not None:
            fl = m.flicker(self._prev[0], out_s, self._prev[1], gt_s)
            self._flicker.append(fl)
        fl_exact = float("nan")
        ref_s = None if ref_linear is None else out_s if ref_linear is out_linear else m.display_srgb(ref_linear)
        if ref_s is not None and self._prev is not None and self._prev_ref is not None:
            fl_exact = m.flicker(self._prev[0], out_s, self._prev_ref, ref_s)
            self._flicker_exact.append(fl_exact)
        fl_warped = float("nan")
        if not math.isnan(fl_exact) and motion is not None:
            fl_warped = m.warped_flicker(self._prev[0] - self._prev_ref, out_s - ref_s, *motion)
            if not math.isnan(fl_warped):
                self._flicker_warped.append(fl_warped)
        self._prev = (out_s, gt_s)
        self._prev_ref = ref_s

        band_sse, band_n = pieces["band_srgb"]
        score = FrameScore(
            frame=frame,
            psnr_srgb_db=m.psnr_from_mse(_ratio(*pieces["srgb"])),
            psnr_linear_db=m.psnr_from_mse(_ratio(*pieces["lin"])),
            ssim_srgb=ssim_s, ssim_linear=ssim_l,
            edge_band_psnr_srgb_db=m.psnr_from_mse(_ratio(band_sse, band_n)),
            flicker=fl, flicker_exact=fl_exact, flicker_exact_warped=fl_warped, bokeh_recall=_ratio(found, total),
        )
        self.frames.append(score)
        return score

    def result(self) -> dict[str, float]:
        """The run's figures (keys of :data:`METRICS` plus ``frames`` and ``edge_band_fraction``)."""
        def pooled_psnr(key: str) -> float:
            return m.psnr_from_mse(_ratio(self._sse[key], self._n[key]))

        ss = np.array(self._ssim, dtype=np.float64).reshape(-1, 2)
        return {
            "psnr_srgb_db": pooled_psnr("srgb"),
            "psnr_linear_db": pooled_psnr("lin"),
            "ssim_srgb": float(ss[:, 0].mean()) if len(ss) else float("nan"),
            "ssim_linear": float(ss[:, 1].mean()) if len(ss) else float("nan"),
            "edge_band_psnr_srgb_db": pooled_psnr("band_srgb"),
            "edge_band_psnr_linear_db": pooled_psnr("band_lin"),
            "splotchiness_px": math.sqrt(self._splotch[0] / self._splotch[1]) if self._splotch[1] else float("nan"),
            "flicker": float(np.mean(self._flicker)) if self._flicker else float("nan"),
            "flicker_exact": float(np.mean(self._flicker_exact)) if self._flicker_exact else float("nan"),
            "flicker_exact_warped": float(np.mean(self._flicker_warped)) if self._flicker_warped else float("nan"),
            "bokeh_recall": _ratio(self._bokeh[0], self._bokeh[1]),
            "frames": float(len(self.frames)),
            "edge_band_fraction": _ratio(self._band_px, self._px),
        }

    def frame_table(self) -> list[dict[str, float]]:
        """Per-frame figures as plain dicts (for the CSV and the plots)."""
        return [asdict(f) for f in self.frames]


def aggregate(results: list[dict[str, float]]) -> dict[str, float]:
    """Mean of each figure over runs, skipping NaNs (NaN if no run has it). ``frames`` is summed."""
    keys = [k for k in (results[0] if results else {})]
    out: dict[str, float] = {}
    for key in keys:
        vals = [r[key] for r in results if key in r and math.isfinite(r[key])]
        if key == "frames":
            out[key] = float(sum(vals))
        else:
            out[key] = float(np.mean(vals)) if vals else float("nan")
    return out
