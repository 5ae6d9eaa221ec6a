"""Frame ranges of the batch tasks and the overlap every stage reads beyond its range.

A clip of n frames is cut into chunks [a, b) of ``chunk_frames`` frames (the last one may be
shorter; a remainder under a quarter of a chunk joins the previous chunk). Per stage:

* estimate: the network alone (``--depth-method network``) or external maps is per frame, no
  context: reads exactly [a, b). The fused depth system (auto, parallax, people) keeps clip-wide
  state (parallax scale chain, network fit memory, reference depth), so its estimate is ONE task
  over the whole clip (:func:`estimate_ranges`); clips still run in parallel;
* stabilize: the filter's output at t is a function of frames t - P .. t + F only (P past,
  F future frames of the window: causal P = M, F = 0; centred P = M // 2, F = M - P), so
  the chunk reads [a - P, b + F) clipped to the clip and writes [a, b): equal to one pass;
* LAAF is split (``laaf.analysis``): its per-frame part (decode, shrink to 320 px, disparity,
  the detectors' ``measure``: face detection, saliency, optical flow, mouth and block motion)
  is a pure function of frames t - 1 and t and of the boxes of the last face detection, so a
  measure chunk reads [``analysis_start(a)``, b) and writes [a, b): the same numbers as one pass.
  What carries state across frames (face tracks, the action memory, speech windows, the
  combination that reads them, the step detector, KCF tracking of a subject from its NFT to
  the next, however far apart, the pulls) runs in one autofocus task per clip, in frame order,
  on those measurements: no bounded overlap would reproduce a tracker at chunk seams;
* render: per frame given D, E and the focus track: reads exactly [a, b).
"""
from __future__ import annotations

from ..temporal.filter import TemporalSettings


def chunk_ranges(n_frames: int, chunk_frames: int) -> list[tuple[int, int]]:
    """[(a, b), ...] covering 0..n_frames - 1 in order; chunk_frames <= 0 = one chunk."""
    if n_frames <= 0:
        return []
    if chunk_frames <= 0 or chunk_frames >= n_frames:
        return [(0, n_frames)]
    starts = list(range(0, n_frames, chunk_frames))
    if len(starts) > 1 and n_frames - starts[-1] < max(chunk_frames // 4, 1):
        starts.pop()  # a short tail joins the chunk before it
    return [(a, starts[i + 1] if i + 1 < len(starts) else n_frames) for i, a in enumerate(starts)]


def stabilize_reads(a: int, b: int, n_frames: int, temporal: TemporalSettings) -> tuple[int, int]:
    """Frames [lo, hi) the temporal filter reads to write frames [a, b) exactly."""
    return max(0, a - temporal.past), min(n_frames, b + temporal.future)


def estimate_ranges(n_frames: int, chunk_frames: int, clip_wide: bool) -> list[tuple[int, int]]:
    """The estimate tasks' ranges: one over the whole clip when ``clip_wide`` (the fused depth
    system, :attr:`.settings.BatchSettings.clip_wide_estimate`), else :func:`chunk_ranges`."""
    return chunk_ranges(n_frames, 0 if clip_wide else chunk_frames)
