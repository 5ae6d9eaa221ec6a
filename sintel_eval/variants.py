"""The ablation variants: ONE table (:data:`VARIANTS`), one entry per way of making the video.

A :class:`Variant` says where its disparity and HDR radiance come from (an *input stage*) and
which renderer turns them into a shallow-DOF frame. Every variant is compared with Cycles'
ground truth by the same scorer.

Adding a variant (e.g. when the estimator or the temporal filter lands) is one entry:

- per-frame inputs: ``inputs=per_frame(disparity=my_disparity, radiance=gt_hdr_radiance)``
  where ``my_disparity(frame: GTFrame) -> (H, W) float32`` in DESIGN units (e.g. the RGBD-HDR
  estimator run on ``frame.input_srgb``), and ``radiance`` returns (H, W, 3) linear radiance
  (e.g. ``srgb_to_linear(input) * exp(50 * E_estimated)``);
- stateful or look-ahead inputs (temporal filter off / causal / centred): write an
  :data:`InputStage`, a generator ``stage(frames: Iterator[GTFrame]) -> Iterator[(GTFrame,
  RenderInputs)]`` that keeps its own bounded window and yields each frame's inputs paired with
  that frame's GTFrame (so a centred filter may yield frame t after reading t + M);
- a new renderer: ``renderer=`` a factory ``(ApertureSpec) -> Renderer`` called once per run.

List a variant only when it really runs: ``requires`` names the Python modules it needs; a
variant whose module is missing is reported as unavailable, never faked.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from rvr_addon.color import srgb_to_linear, to_float01
from rvr_addon.errors import InputError
from rvr_addon.render.aperture import ApertureSpec
from rvr_addon.render.fast import FastRenderer
from rvr_addon.render.model import hdr_radiance

from . import estimator_inputs
from .ideal_filter import ideal_stage
from .reader import GTFrame
from .temporal_inputs import temporal_stage


@dataclass
class RenderInputs:
    """What a renderer gets for one frame.

    image_srgb: (H, W, 3) uint8 sRGB frame (what a phone recorded).
    radiance: (H, W, 3) float32 linear radiance to blur (HDR if the variant recovers it).
    disparity: (H, W) float32 disparity the variant renders with, DESIGN units.
    """

    image_srgb: np.ndarray
    radiance: np.ndarray
    disparity: np.ndarray


InputStage = Callable[[Iterator[GTFrame]], Iterator[tuple[GTFrame, RenderInputs]]]
"""Turns a clip's ground-truth frame stream into (frame, inputs) pairs, in frame order."""
Renderer = Callable[[RenderInputs, float, float], np.ndarray]
"""(inputs, focus disparity, aperture scale) -> linear shallow-DOF radiance (H, W, 3) float32."""
RendererFactory = Callable[[ApertureSpec], Renderer]
"""Makes a renderer for a run (one clip and track) with the dataset camera's aperture shape."""


# ----------------------------------------------------------------------------------------
# Input sources


def gt_disparity(frame: GTFrame) -> np.ndarray:
    """Ground-truth disparity (exact, from Cycles' Z pass)."""
    return frame.disparity


def gt_hdr_radiance(frame: GTFrame) -> np.ndarray:
    """The product's HDR input with the ground-truth exponent: ``srgb_to_linear(png) * exp(50 E)``
    (8-bit quantised below the clip, exact radiance where the 8-bit input clipped)."""
    return np.asarray(hdr_radiance(srgb_to_linear(to_float01(frame.input_srgb)), frame.exponent), dtype=np.float32)


def sdr_radiance(frame: GTFrame) -> np.ndarray:
    """HDR off: the clipped 8-bit input linearised (E = 0, nothing above white)."""
    return np.asarray(srgb_to_linear(to_float01(frame.input_srgb)), dtype=np.float32)


def per_frame(disparity: Callable[[GTFrame], np.ndarray], radiance: Callable[[GTFrame], np.ndarray]) -> InputStage:
    """An input stage applying two per-frame functions (no state, no look-ahead)."""
    def stage(frames: Iterator[GTFrame]) -> Iterator[tuple[GTFrame, RenderInputs]]:
        for fr in frames:
            yield fr, RenderInputs(fr.input_srgb, radiance(fr), disparity(fr))

    return stage


# ----------------------------------------------------------------------------------------
# Renderers


def ours(naive: bool = False) -> RendererFactory:
    """Our fast renderer (occlusion-aware layers, or Srinivasan-style naive summed layers)."""
    def factory(spec: ApertureSpec) -> Renderer:
        renderer = FastRenderer(spec=spec, naive=naive)

        def render(inputs: RenderInputs, focus: float, aperture: float) -> np.ndarray:
            return renderer.render_linear(inputs.radiance, inputs.disparity, focus, aperture)

        return render

    return factory


def blender_defocus(spec: ApertureSpec) -> Renderer:
    """Blender's Compositor Defocus node (round bokeh, "No Z-buffer" radius input) on the 8-bit
    input and the blur radius ``a |D - f|`` of the variant's disparity. It cannot take HDR."""
    from .blender_baseline import blender_defocus_linear

    def render(inputs: RenderInputs, focus: float, aperture: float) -> np.ndarray:
        radius = np.abs(inputs.disparity.astype(np.float32) - np.float32(focus)) * np.float32(aperture)
        return blender_defocus_linear(inputs.image_srgb, radius)

    return render


# ----------------------------------------------------------------------------------------
# The table


@dataclass(frozen=True)
class Variant:
    """One row of every ablation table.

    name: key in summary.json (``ablation.<name>.<metric>``), lower_snake_case.
    label: short title of its comparison panel. description: one line for the README.
    inputs: where disparity and radiance come from. renderer: factory of the renderer.
    requires: importable modules it needs (missing -> unavailable, reported, not faked).
    check: optional callable giving a further reason it cannot run (e.g. no trained weights), or None.
    """

    name: str
    label: str
    description: str
    inputs: InputStage
    renderer: RendererFactory
    requires: tuple[str, ...] = field(default=())
    check: Callable[[], str | None] | None = None

    def unavailable(self) -> str | None:
        """Why this variant cannot run here (a missing module, a failed ``check``), or None."""
        missing = [m for m in self.requires if importlib.util.find_spec(m) is None]
        if missing:
            return f"needs the Python module(s) {', '.join(missing)} (run ./scripts/setup.sh)"
        return self.check() if self.check is not None else None


VARIANTS: tuple[Variant, ...] = (
    Variant("ours_gt", "ours (GT D + HDR)",
            "our occlusion-aware layered renderer with ground-truth disparity and ground-truth HDR exponent",
            per_frame(gt_disparity, gt_hdr_radiance), ours()),
    Variant("naive_gt", "naive layers",
            "summed layers without occlusion (Srinivasan et al. 2018; --naive), ground-truth disparity and HDR",
            per_frame(gt_disparity, gt_hdr_radiance), ours(naive=True)),
    Variant("hdr_off", "HDR off",
            "ours with ground-truth disparity on the clipped 8-bit input (E = 0): no bokeh highlights",
            per_frame(gt_disparity, sdr_radiance), ours()),
    Variant("blender_defocus", "Blender Defocus",
            "Blender's Compositor Defocus node on the clipped 8-bit input with the ground-truth blur radius",
            per_frame(gt_disparity, sdr_radiance), blender_defocus, requires=("bpy",)),
    # Estimator rows: the trained RGBD-HDR network (ablate --estimator-weights W, or the shipped
    # weights); its D is used as predicted, in DESIGN units, without a fit to the ground truth.
    Variant("estimated_disparity", "estimated D (GT HDR)",
            "ours with the estimator's disparity (as predicted, DESIGN units, no fit) and the ground-truth HDR",
            per_frame(estimator_inputs.estimated_disparity, gt_hdr_radiance), ours(), requires=("torch",),
            check=estimator_inputs.unavailable),
    Variant("estimated_hdr", "estimated HDR (GT D)",
            "ours with the ground-truth disparity and the estimator's HDR exponent E",
            per_frame(gt_disparity, estimator_inputs.estimated_hdr_radiance), ours(), requires=("torch",),
            check=estimator_inputs.unavailable),
    # Temporal filter rows (paper 4.2): per-frame estimates SIMULATED from the GT, with the
    # errors of a single-frame network (sintel_eval/temporal_inputs.py); the _est rows below
    # filter the trained estimator's.
    Variant("temporal_off", "temporal filter off (sim.)",
            "SIMULATED per-frame estimates (GT D and E with per-frame errors of a single-frame network), unfiltered",
            temporal_stage(None), ours()),
    Variant("temporal_causal", "temporal causal (sim.)",
            "the same SIMULATED estimates through the causal temporal filter (paper: M = 6 past frames)",
            temporal_stage("causal"), ours()),
    Variant("temporal_centred", "temporal centred (sim.)",
            "the same SIMULATED estimates through the centred temporal filter (3 past + 3 future frames)",
            temporal_stage("centred"), ours()),
    # The same three rows on the trained estimator's real per-frame estimates (D as predicted,
    # E from the network; no fit to the ground truth).
    Variant("temporal_off_est", "estimated, filter off",
            "the estimator's per-frame D and E (as predicted), unfiltered",
            temporal_stage(None, estimator_inputs.estimate), ours(), requires=("torch",),
            check=estimator_inputs.unavailable),
    Variant("temporal_causal_est", "estimated, causal filter",
            "the estimator's per-frame D and E through the causal temporal filter (M = 6 past frames)",
            temporal_stage("causal", estimator_inputs.estimate), ours(), requires=("torch",),
            check=estimator_inputs.unavailable),
    Variant("temporal_centred_est", "estimated, centred filter",
            "the estimator's per-frame D and E through the centred temporal filter (3 past + 3 future frames)",
            temporal_stage("centred", estimator_inputs.estimate), ours(), requires=("torch",),
            check=estimator_inputs.unavailable),
    # The bound of any temporal filter on those estimates (sintel_eval/ideal_filter.py): the
    # floor of the three rows above.
    Variant("temporal_ideal_est", "estimated, ideal filter (bound)",
            "the bound of any temporal filter: each pixel's D and E error averaged over every frame of the clip "
            "that sees the same scene point (exact correspondences from the ground-truth depth and cameras)",
            ideal_stage(estimator_inputs.estimate), ours(), requires=("torch",),
            check=estimator_inputs.unavailable),
)
"""Every variant, in report order. The first is the reference row of the comparisons."""


def select(names: list[str] | None) -> list[Variant]:
    """Variants by name (all when ``names`` is None or empty), in table order.

    Raises InputError naming the unknown names and the known ones.
    """
    if not names:
        return list(VARIANTS)
    known = {v.name: v for v in VARIANTS}
    wanted = [n.strip() for part in names for n in part.split(",") if n.strip()]
    unknown = [n for n in wanted if n not in known]
    if unknown:
        raise InputError(f"unknown variant(s) {', '.join(unknown)}; choose from {', '.join(known)}")
    return [v for v in VARIANTS if v.name in wanted]
