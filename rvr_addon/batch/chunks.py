"""Frame ranges of the batch tasks and the overlap every stage reads beyond its range.

A clip of n frames is cut into chunks [a, b) of ``chunk_frames`` frames (the last one may be
shorter; a remainder under a quarter of a chunk joins the previous chunk). Per stage:

* estimate (per frame, no context): reads exactly [a, b);
* stabilize: the filter's output at t is a function of frames t - P .. t + F only (P past,
  F future frames of the window: causal P = M, F = 0; centred P = M // 2, F = M - P), so
  the chunk reads [a - P, b + F) clipped to the clip and writes [a, b): equal to one pass;
* autofocus (LAAF) runs over the whole clip in one task: a tracked subject carries its state
  from its NFT to the next one, however far apart, so no bounded overlap would make chunked
  decisions equal to one pass. It works at 320 px and costs a small part of a frame's time;
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
