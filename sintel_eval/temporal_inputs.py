"""Input stages of the temporal-filter ablation rows: "temporal filter off / causal / centred".

The per-frame estimates of the rows ``temporal_off / causal / centred`` are **SIMULATED**:
the clip's ground-truth D and E degraded with per-frame independent errors typical of a
single-frame network (:func:`rvr_addon.temporal.simulate.simulate_estimates`),
seeded by the frame's content and index, so the three rows see identical estimates. The
radiance is rebuilt from the 8-bit input and the (filtered) E, as the product does:
``srgb_to_linear(input) * exp(50 E)``.

Real estimates replace the simulation by one argument: the ``temporal_*_est`` rows pass the
trained estimator (:func:`.estimator_inputs.estimate`); ``estimates=cache_estimates(CACHE)``
takes a cache written by ``rvr estimate`` for that clip.
"""
from __future__ import annotations

import zlib
from collections import deque
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from rvr_addon.color import srgb_to_linear, to_float01
from rvr_addon.render.model import hdr_radiance
from rvr_addon.temporal.filter import TemporalFilter, TemporalSettings
from rvr_addon.temporal.simulate import EstimateErrors, simulate_estimates

from .reader import GTFrame

Estimates = Callable[[GTFrame], tuple[np.ndarray, np.ndarray]]
"""frame -> (D (H, W) px, E (H, W, 3)): the per-frame estimates a temporal row filters."""


def simulated_estimates(seed: int = 0, errors: EstimateErrors | None = None) -> Estimates:
    """SIMULATED per-frame estimates of a frame's ground truth (see the module docstring).

    The seed mixes ``seed``, the frame index and a checksum of the frame's ground-truth
    disparity, so clips differ and every variant of one run sees the same estimates.
    """
    def estimate(frame: GTFrame) -> tuple[np.ndarray, np.ndarray]:
        content = zlib.crc32(np.ascontiguousarray(frame.disparity[::7, ::7]).tobytes())
        return simulate_estimates(frame.disparity, frame.exponent, frame.index, seed=(seed * 7919) ^ content,
                                  errors=errors)

    return estimate


def cache_estimates(folder: str | Path) -> Estimates:
    """Real per-frame estimates from a cache written by ``rvr estimate`` for the clip being
    evaluated (raw channels D, E.R/G/B of ``frame_NNNNN.exr``, NNNNN = frame index + 1)."""
    from rvr_addon.estimate.cache import frame_path
    from rvr_addon.io.exr import read_exr

    root = Path(folder)

    def estimate(frame: GTFrame) -> tuple[np.ndarray, np.ndarray]:
        ch = read_exr(frame_path(root, frame.index))
        return ch["D"], np.dstack([ch["E.R"], ch["E.G"], ch["E.B"]])

    return estimate


def estimate_radiance(image_srgb: np.ndarray, exponent: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 linear radiance the product renders: ``srgb_to_linear(input) * exp(50 E)``."""
    return np.asarray(hdr_radiance(srgb_to_linear(to_float01(image_srgb)), exponent), dtype=np.float32)


def temporal_stage(window: str | None, estimates: Estimates | None = None,
                   settings: TemporalSettings | None = None):
    """An :data:`~sintel_eval.variants.InputStage` rendering per-frame estimates, unfiltered
    (``window=None``: "temporal filter off") or through the temporal filter ("causal" or
    "centred"; a centred stage reads M/2 frames ahead, holding them in a bounded queue)."""
    from .variants import RenderInputs

    def stage(frames: Iterator[GTFrame]) -> Iterator[tuple[GTFrame, "RenderInputs"]]:
        get = estimates or simulated_estimates()
        if window is None:
            for fr in frames:
                d, e = get(fr)
                yield fr, RenderInputs(fr.input_srgb, estimate_radiance(fr.input_srgb, e), d)
            return
        base = settings or TemporalSettings()
        filt = TemporalFilter(TemporalSettings(**{**base.to_dict(), "window": window}))
        waiting: deque[GTFrame] = deque()

        def ready(outputs):
            for index, d_s, e_s, _ in outputs:
                while waiting and waiting[0].index < index:
                    waiting.popleft()
                fr = waiting.popleft()
                yield fr, RenderInputs(fr.input_srgb, estimate_radiance(fr.input_srgb, e_s), d_s)

        for fr in frames:
            d, e = get(fr)
            waiting.append(fr)
            yield from ready(filt.push(fr.index, fr.input_srgb, d, e))
        yield from ready(filt.finish())

    return stage
