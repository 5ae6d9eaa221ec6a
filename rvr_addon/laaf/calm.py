"""Focus that holds: the ONE "calm <-> responsive" knob and what it sets (issue 23).

``calm`` in 0..1 (0 = responsive: the paper's behaviour, every detected step becomes a pull;
1 = calm: a focus puller who holds) sets four things at once (:func:`calm_settings`):

- **hysteresis**: a new target's level must differ from the current one by
  ``min_step * (1 + 1.5 calm)`` disparity units (the step detector's threshold);
- **minimum hold**: a new target is not taken within ``2.0 calm`` s of the previous one on
  the same shot; it is deferred to the end of the hold and taken only if the scene still
  asks for it then (not a change of speaker made by the speech detector's decision chain,
  whose own cost of a change of face is its hysteresis: a turn shorter than the hold is
  answered at its start, ``lookahead``);
- **cost of a change**: a step is taken only if its new level persists: measured within
  tolerance on >= ``PERSIST_SHARE`` of the ``1.2 calm`` s after it, as far as the look-ahead
  window sees before the pull must start (causal mode: not checked, as waiting for it would
  make every late pull later still);
- **deadband**: between pulls the focus follows its tracked subject only by what exceeds
  ``0.6 calm / aperture`` disparity units (a blur radius of 0.6 calm px: below what a viewer
  sees), so a subject's small depth wobble does not breathe the focus.

:func:`focus_activity` measures the result: target changes per second and the share of
frames on which the focus moves (``bench/calm_bench.py``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .presets import DEFAULT_CALM  # noqa: F401 - defined in .presets (light), re-exported here

PERSIST_SHARE = 0.6
"""Share of the persistence window on which a new level must be measured for a step to count."""
MOVING_EPS = 0.02
"""A frame's focus "moves" when it differs from the previous frame's by more than this (disparity units)."""


@dataclass(frozen=True)
class CalmSettings:
    """What a calm value sets. step_factor: multiplier of min_step (>= 1). hold_frames:
    shortest time between two targets of one shot (frames). persist_frames: frames after a
    step over which its new level must persist (frames). deadband: follow deadband
    (disparity units)."""

    calm: float
    step_factor: float
    hold_frames: int
    persist_frames: int
    deadband: float


def check_calm(calm: float) -> float:
    """The calm value as a float in 0..1; ValueError otherwise."""
    c = float(calm)
    if not (math.isfinite(c) and 0.0 <= c <= 1.0):
        raise ValueError(f"calm={calm!r} must be between 0 (responsive) and 1 (calm)")
    return c


def calm_settings(calm: float, fps: float, aperture: float = 1.0, max_persist: int | None = None) -> CalmSettings:
    """Settings of a calm value at frame rate ``fps`` (frames/s) and aperture scale;
    max_persist caps persist_frames (look-ahead: what the window can still see before a pull
    must start)."""
    c = check_calm(calm)
    persist = int(round(1.2 * c * fps))
    if max_persist is not None:
        persist = max(0, min(persist, int(max_persist)))
    return CalmSettings(c, 1.0 + 1.5 * c, int(round(2.0 * c * fps)), persist, 0.6 * c / max(float(aperture), 0.1))


def deadband(level: np.ndarray, band: float) -> np.ndarray:
    """A follower of ``level`` (disparity per frame; NaN = unknown, passed through) that
    moves only by what exceeds ``band`` units: out_t = out_{t-1} unless |level_t - out_{t-1}|
    > band, then out_t = level_t - sign * band. band <= 0 returns level unchanged."""
    v = np.asarray(level, dtype=np.float64)
    if band <= 0:
        return v.copy()
    out = v.copy()
    cur = math.nan
    for i, x in enumerate(v):
        if not math.isfinite(x):
            continue
        if not math.isfinite(cur):
            cur = x
        elif x > cur + band:
            cur = x - band
        elif x < cur - band:
            cur = x + band
        out[i] = cur
    return out


def persists(raw: np.ndarray, after: float, tol: float, share: float = PERSIST_SHARE) -> bool:
    """Whether a new level ``after`` persists in ``raw`` (measured levels of the frames after
    a step; NaN = nothing measured): within ``tol`` on at least ``share`` of the measured
    frames, and measured on at least half of them. An empty window persists."""
    r = np.asarray(raw, dtype=np.float64)
    if r.size == 0:
        return True
    ok = np.isfinite(r)
    if ok.sum() < 0.5 * r.size:
        return False
    return float(np.mean(np.abs(r[ok] - after) <= tol)) >= share


def focus_activity(focus: np.ndarray, fps: float, n_targets: int) -> dict[str, float]:
    """targets_per_s (target changes, i.e. targets after the first, per second),
    moving_share (share of frame steps whose focus changes by more than MOVING_EPS)."""
    f = np.asarray(focus, dtype=np.float64)
    seconds = max(len(f) / float(fps), 1e-9)
    moving = float(np.mean(np.abs(np.diff(f)) > MOVING_EPS)) if len(f) > 1 else 0.0
    return {"targets_per_s": max(n_targets - 1, 0) / seconds, "moving_share": moving}
