"""Each frame's fused depth refined with the frames after it: a fixed-lag two-way smoother along
the flow, for a moving camera (the last step of the depth system, after :mod:`.fuse`).

The fuser works forward: a frame knows the frames before it (the parallax cue's window, the
depth carried along the flow), not the ones after. A clip is analysed offline, so
:class:`ClipRefiner` holds each fused frame back ``refine_lag`` frames (L) and then, at the
fuser's analysis size:

1. **Backward.** The fused D of the latest held frame t+L is carried along the optical flow into
   t+L-1 and averaged there with that frame's own fused D, each weighted by its confidence; the
   result is carried into t+L-2, and so on down to t.
2. **Forward.** The result is averaged the same way with the previous *output* frame carried into
   t (so the output is consistent with what came before it, not only with what comes after).

A carried value weighs its confidence x ``refine_decay`` x a photometric check
``exp(-|luma difference| / refine_photo)`` (8-bit code values: an occlusion or a moving object
does not take the neighbour's depth); a frame's own value weighs its fused confidence, which is 0
where no geometric cue spoke: a frame whose parallax failed, or the clip's first frames, before
the parallax cue has any history, take their neighbours' geometry. Nothing crosses a cut (the
detector every stage shares, :class:`rvr_addon.temporal.cuts.CutDetector`). The full-size D gets
the refinement's difference, upsampled (its own edges are kept).

HoloLens office (120 frames, moving camera), mean per-frame affine-invariant error of D: 0.400 ->
0.374 (its first frames 0.95 / 0.79 / 0.82 -> 0.57 / 0.47 / 0.46), flicker 0.124 -> 0.068. On the
cue maps captured from that clip, without the cut check: L = 2, 3, 4, 8, 16 scored 0.376, 0.374,
0.372, 0.373, 0.373 (the decay forgets a value carried more than a few frames); without the forward
step 0.378. Only clips whose plan has the parallax cue (a moving camera) are refined.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
from typing import Iterator

import numpy as np

from .carry import carry_along, flow_maps_into
from .fuse import FusedDepth, FusionSettings, analysis_size, resize

Item = tuple[np.ndarray, np.ndarray, np.ndarray, FusedDepth]
"""What :class:`~.system.DepthStream` yields per frame: (frame RGB uint8, D, E, FusedDepth)."""


@dataclass
class _Held:
    """One held frame: the stream's item and its analysis-size copies."""

    item: Item
    d: np.ndarray          # fused D at the analysis size (DESIGN units)
    c: np.ndarray          # its confidence 0..1
    gray: np.ndarray       # luma at the flow size (uint8)
    luma: np.ndarray       # luma at the analysis size (float32, 8-bit code values)
    to_prev: np.ndarray | None = None   # maps sampling the previous frame at this frame's pixels
    to_next: np.ndarray | None = None   # maps sampling the next frame at this frame's pixels
    cut_before: bool = False            # this frame starts a new shot


def carry_step(own_d: np.ndarray, own_c: np.ndarray, own_luma: np.ndarray, other_d: np.ndarray,
               other_c: np.ndarray, other_luma: np.ndarray, maps: np.ndarray, photo: float,
               decay: float) -> tuple[np.ndarray, np.ndarray]:
    """One frame's D averaged with a neighbour's D carried into it along the flow.

    own_*: this frame's D (DESIGN units), confidence (0..1) and luma (code values) at one size;
    other_*: the neighbour's; maps (h, w, 2) float32: where each of this frame's pixels lies in
    the neighbour (absolute px). Returns (D, confidence): the confidence-weighted mean, with
    the carried weight = its confidence x ``decay`` x exp(-|luma difference| / ``photo``)
    (:func:`.carry.carry_along`; outside the neighbour: 0), and the larger of the two weights.
    """
    q, cw = carry_along(maps, other_d, other_c, other_luma, own_luma, photo, decay)
    total = own_c + cw
    safe = np.maximum(total, np.float32(1e-6))
    d = np.where(total > 1e-6, (own_c * own_d + cw * q) / safe, own_d)
    return d.astype(np.float32), np.clip(np.maximum(own_c, cw), 0.0, 1.0).astype(np.float32)


class ClipRefiner:
    """Streams a clip's fused frames through the fixed-lag two-way smoother (module docstring).

    :meth:`push` each (frame, D, E, FusedDepth) in order; it yields the items whose refinement is
    complete (``refine_lag`` frames later), :meth:`finish` the rest. Yielded items carry the
    refined D and confidence (``FusedDepth.info["refined"]`` True where D changed).
    """

    def __init__(self, settings: FusionSettings = FusionSettings()) -> None:
        from ..temporal.cuts import CutDetector

        self.settings = settings
        self.lag = max(int(settings.refine_lag), 0)
        self._held: deque[_Held] = deque()
        self._last_out: _Held | None = None  # the previous output frame, with its refined d and c
        self._cuts = CutDetector() if self.lag else None
        self._dis = None
        self.refined = 0
        """Frames whose D the refinement changed."""

    # -------------------------------------------------------------- pieces

    def _flow_maps(self, a: np.ndarray, b: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """Maps sampling gray frame b at frame a's pixels, at the analysis ``size``."""
        import cv2

        from ..temporal.flow import PRESETS

        if self._dis is None:
            self._dis = cv2.DISOpticalFlow_create(PRESETS["medium"])
        return flow_maps_into(self._dis, a, b, size)

    def _hold(self, item: Item) -> _Held:
        from ..temporal.flow import flow_size, to_flow_gray

        s = self.settings
        frame, d_full, _e, fused = item
        h, w = frame.shape[:2]
        size = analysis_size(w, h, s.analysis_long_side)
        fw, fh = flow_size(w, h, s.carry_flow_side)
        gray = fused.flow_gray  # the fuser's carry computed it (same frame, same size)
        if gray is None or gray.shape != (fh, fw):
            gray = to_flow_gray(frame, (fw, fh))
        # only geometry from the camera's motion is shared between frames: the people cue is the
        # frame's own (metric, from face size), and a frame without parallax takes its neighbours'
        geometric = "parallax" in fused.cues or "carried" in fused.cues
        c = resize(fused.confidence.astype(np.float32), size) if geometric else np.zeros(size[::-1], np.float32)
        return _Held(item, resize(d_full.astype(np.float32), size), np.clip(c, 0.0, 1.0),
                     gray, resize(gray, size).astype(np.float32), cut_before=self._cuts.push(frame))

    def _output(self) -> Item:
        """Refine and release the oldest held frame."""
        s = self.settings
        t = self._held.popleft()
        # backward: from the latest held frame of t's shot down to t
        chain = [t]
        for u in self._held:
            if u.cut_before:
                break
            chain.append(u)
        d, c = chain[-1].d, chain[-1].c
        for k in range(len(chain) - 2, -1, -1):
            u, nxt = chain[k], chain[k + 1]
            d, c = carry_step(u.d, u.c, u.luma, d, c, nxt.luma, u.to_next, s.refine_photo, s.refine_decay)
        # forward: with the previous output frame
        prev = self._last_out
        if prev is not None and not t.cut_before and t.to_prev is not None:
            d, c = carry_step(d, c, t.luma, prev.d, prev.c, prev.luma, t.to_prev, s.refine_photo, s.refine_decay)
        self._last_out = _Held(t.item, d, c, t.gray, t.luma)
        frame, d_full, e, fused = t.item
        if np.array_equal(d, t.d):
            return t.item
        self.refined += 1
        h, w = d_full.shape
        if (w, h) == (d.shape[1], d.shape[0]):
            d_out, c_out = d, c
        else:  # the full-size D keeps its own edges and takes the refinement's difference
            d_out = (d_full + resize(d - t.d, (w, h))).astype(np.float32)
            c_out = resize(c, (w, h))
        return frame, d_out, e, replace(fused, disparity=d_out, confidence=c_out.astype(np.float32),
                                        info={**fused.info, "refined": True})

    # -------------------------------------------------------------- the stream

    def push(self, item: Item) -> Iterator[Item]:
        """Hold one more frame; yields the frames that are now ready (at most one)."""
        if self.lag == 0:
            yield item
            return
        cur = self._hold(item)
        prev = self._held[-1] if self._held else self._last_out
        if prev is not None and not cur.cut_before and prev.gray.shape == cur.gray.shape \
                and prev.d.shape == cur.d.shape:
            size = (cur.d.shape[1], cur.d.shape[0])
            given = cur.item[3].to_prev  # the fuser's carry ran the same flow (same frames, size and preset)
            same = given is not None and given.shape[:2] == cur.d.shape and self.settings.carry_flow_side > 0
            cur.to_prev = given if same else self._flow_maps(cur.gray, prev.gray, size)
            if self._held:
                prev.to_next = self._flow_maps(prev.gray, cur.gray, size)
        elif self._held and not cur.cut_before:
            cur.cut_before = True  # a change of size: nothing is carried across it
        self._held.append(cur)
        if len(self._held) > self.lag:
            yield self._output()

    def finish(self) -> Iterator[Item]:
        """The frames still held, refined with what follows them."""
        while self._held:
            yield self._output()
