"""Read one focus disparity for a subject from the disparity map inside its box.

A box drawn around a subject also holds background (and sometimes a nearer occluder). The
mean mixes them; the median lands on the background when the subject fills less than half
the box. We take a *foreground-biased percentile*: walking the centre-weighted distribution
of the disparities in the box from the near side (small D = near, DESIGN units; from the
``percentile / 3`` quantile on), the first value whose +-``band`` neighbourhood holds at
least ``min_support`` of the weight, i.e. the nearest surface that is more than a sliver (a
leaf in front of a face is skipped), snapped to the weighted median of that neighbourhood so
the reading sits on the surface rather than between two. For a tracked subject the previous
level is given as ``prior`` and the cluster nearest to it is read instead.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .nft import Box


@dataclass(frozen=True)
class FocusReading:
    """value: focus disparity (DESIGN units: px of blur radius at aperture 1, native width).
    support: weight fraction of the box within ``band`` of value (0..1; low = unreliable).
    pixels: number of map pixels read."""

    value: float
    support: float
    pixels: int


def _weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    order = np.argsort(values, kind="stable")
    v, w = values[order], weights[order]
    cum = np.cumsum(w)
    total = cum[-1]
    if total <= 0:
        return float(np.quantile(values, q))
    i = int(np.searchsorted(cum, q * total, side="left"))
    return float(v[min(i, len(v) - 1)])


def box_to_slices(box: Box, shape: tuple[int, int]) -> tuple[slice, slice]:
    """Integer row/column slices of a box (x, y, w, h) px in an (H, W) map, at least 1 px."""
    h, w = shape
    x0 = int(np.clip(np.floor(box[0]), 0, w - 1))
    y0 = int(np.clip(np.floor(box[1]), 0, h - 1))
    x1 = int(np.clip(np.ceil(box[0] + box[2]), x0 + 1, w))
    y1 = int(np.clip(np.ceil(box[1] + box[3]), y0 + 1, h))
    return slice(y0, y1), slice(x0, x1)


def read_focus(disparity: np.ndarray, box: Box, mask: np.ndarray | None = None, *,
               percentile: float = 30.0, band: float = 0.3, centre_sigma: float = 0.5, min_support: float = 0.2,
               prior: float | None = None) -> FocusReading:
    """Focus disparity of the subject in ``box``.

    disparity: (H, W) float32, DESIGN units; + = behind the focal plane. box: (x, y, w, h) in
    px of this map. mask: optional (H, W) bool/float weight (e.g. the detected region); pixels
    outside it are ignored (if it leaves nothing, the whole box is used). percentile: 0..100,
    from the near side. band: disparity units around the percentile that form the subject's
    cluster. centre_sigma: Gaussian centre weighting, as a fraction of the box size.
    min_support: weight fraction a cluster needs. prior: the subject's level on the previous
    frame; with it, the cluster nearest to it is read (a tracked subject keeps its depth when
    an occluder enters its box).
    Raises ValueError for a map that is not 2-D.
    """
    d = np.asarray(disparity)
    if d.ndim != 2:
        raise ValueError(f"disparity must be (H, W), got shape {d.shape}")
    rows, cols = box_to_slices(box, d.shape)
    patch = d[rows, cols].astype(np.float32, copy=False)
    ph, pw = patch.shape
    yy = (np.arange(ph, dtype=np.float32) + 0.5 - ph / 2) / max(centre_sigma * ph, 1e-3)
    xx = (np.arange(pw, dtype=np.float32) + 0.5 - pw / 2) / max(centre_sigma * pw, 1e-3)
    weight = np.exp(-0.5 * (yy[:, None] ** 2 + xx[None, :] ** 2))
    if mask is not None:
        m = np.asarray(mask, dtype=np.float32)[rows, cols]
        if float(m.sum()) > 0:
            weight = weight * m
    finite = np.isfinite(patch) & (weight > 0)
    if not finite.any():
        finite = np.isfinite(patch)
        weight = np.ones_like(patch)
    if not finite.any():
        return FocusReading(float("nan"), 0.0, 0)
    v, w = patch[finite].astype(np.float64), weight[finite].astype(np.float64)
    total = max(float(w.sum()), 1e-12)
    if prior is not None and np.isfinite(prior):
        # continuity: the surface cluster nearest the previous level that has some mass
        cands = [_weighted_quantile(v, w, q) for q in np.linspace(0.02, 0.98, 25)]
        cands = [c for c in cands if w[np.abs(v - c) <= band].sum() / total >= min_support / 2]
        p = min(cands, key=lambda c: abs(c - prior)) if cands else _weighted_quantile(v, w, 0.5)
    else:
        # foreground bias: the nearest surface cluster that holds at least min_support of the box
        p = None
        for q in np.linspace(float(np.clip(percentile, 0, 100)) / 100.0 / 3, 0.98, 25):
            c = _weighted_quantile(v, w, q)
            if w[np.abs(v - c) <= band].sum() / total >= min_support:
                p = c
                break
        if p is None:
            p = _weighted_quantile(v, w, float(np.clip(percentile, 0, 100)) / 100.0)
    near = np.abs(v - p) <= band
    value = _weighted_quantile(v[near], w[near], 0.5) if near.any() else p
    support = float(w[np.abs(v - value) <= band].sum() / total)
    return FocusReading(value, support, int(v.size))
