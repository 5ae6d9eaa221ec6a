"""Temporal stabilization of disparity D and HDR exponent E (paper section 4.2).

For each target frame t, the estimates of its neighbours j are warped onto t with
concatenated optical flow and averaged with per-pixel weights

    W_j = w_occl_j * w_med_j,    X_t' = sum_j W_j warp(X_j) / sum_j W_j      (X = D or E)

over the window j = t - P .. t + F (the current frame included, with w_occl = 1):

* **occlusion weight** ``w_occl_j``: 1 where the flow from t to j is forward-backward
  consistent on every link of the chain (``|f_ab(p) + f_ba(p + f_ab(p))| <= delta +
  0.05 |f_ab|``, flow px), lands inside the frame, and the warped colour matches (beyond the
  paper: :func:`.flow.photometric_ok`, on each link and on the whole chain, since DIS flow
  is consistent with itself where it is wrong, e.g. on the rim of a moving object); 0
  elsewhere. Link masks are chained by warping them along the flow (bilinear, so they are
  soft at their edges).
* **outlier weight** ``w_med_j = exp(-median_k |X_k - X_j| / s)``, the median over the
  window's warped values k (occluded ones replaced by the current value, so they neither vote
  nor count as disagreement). For the current frame this is the paper's formula
  ``exp(-median |warped - current|)``. The paper does not give a scale: D is in px here, so
  ``s = outlier_scale_d * width`` px for D; ``s = outlier_scale_e`` for E, whose weight uses the
  mean of its three channels.

Windows: ``causal`` (the paper): P = M = 6 past frames, F = 0; ``centred`` (beyond the paper,
for recorded video whose future is available): P = M // 2, F = M - P. Both hold M + 1
frames. Flows are computed once per consecutive pair (forward and backward, at a reduced
"flow resolution"); the flow from t to t - k is concatenated as
``f_{t->t-k} = f_{t->t-1} + warp(f_{t-1->t-k}, f_{t->t-1})`` (the future chain is extended
at its far end, ``f_{t->n} = f_{t->n-1} + warp(f_{n-1->n}, f_{t->n-1})``).

Where this differs from the paper, and why:

* The paper computes ``w_med_j`` once per frame j over j's own window; we compute every
  sample's outlier weight over the *target's* window (the same formula for the current
  frame). It needs only the M + 1 frames of the window, works unchanged for the centred
  window, and makes the output at t a function of frames t - P .. t + F only, so a resumed
  run (warm-up of P frames) reproduces an uninterrupted one exactly.
* Weights (and the outlier medians) are computed at the flow resolution and upsampled
  (bilinear); the weighted sum itself is at full resolution, and warps the estimates with
  the nearest pixel (a bilinear warp blends the two sides of a depth edge into a disparity
  no surface has).
* Scene cuts and size changes restart the window: a pair of frames where more than
  ``cut_fraction`` of the pixels fail the consistency or photometric check is a cut.

Confidence (``S.C`` in the cache): ``sum_j W_j / (M + 1)`` for D, in [0, 1]: 1 when all M + 1
frames are visible and agree, about ``1 / (M + 1)`` when only the current frame was usable
(clip start, after a cut, disocclusions, outliers).
"""
from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Iterable, Iterator

import cv2
import numpy as np

from ..errors import InputError
from . import flow as fl
from .cuts import link_checks
from .settings import WINDOWS, TemporalSettings  # noqa: F401 - re-exported: rvr_addon.temporal.filter.TemporalSettings

log = logging.getLogger(__name__)

Output = tuple[int, np.ndarray, np.ndarray, np.ndarray]
"""(clip index, D (H, W) px, E (H, W, 3), confidence (H, W) in [0, 1]), all float32."""


# ----------------------------------------------------------------------------------------
# Pure weighting math


def _batcher_pairs(n: int) -> list[tuple[int, int]]:
    """Comparators of Batcher's odd-even merge sort for n inputs (any n >= 1)."""
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            for j in range(k % p, n - k, 2 * k):
                for i in range(min(k, n - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return pairs


def median_distance(values: np.ndarray) -> np.ndarray:
    """d_j = median over k of |v_k - v_j| (k over all n samples, j included), per pixel.

    values: (n, ...) float32. Returns (n, ...) float32. "Median" is the (n // 2 + 1)-th
    smallest of the n distances (the median for odd n, the upper median for even n).
    Computed without per-pixel Python: the samples are sorted per pixel with a sorting
    network; for any x, the m-th smallest distance from x to the sorted values s is
    ``min_a max(x - s_a, s_{a+m-1} - x)`` over the runs of m consecutive ranks (each run
    bounds it from above, and the run of x's m nearest values attains it).
    """
    v = np.asarray(values, dtype=np.float32)
    n = v.shape[0]
    if n == 1:
        return np.zeros_like(v)
    s = [v[i].copy() for i in range(n)]
    for i, j in _batcher_pairs(n):
        lo = np.minimum(s[i], s[j])
        np.maximum(s[i], s[j], out=s[j])
        s[i] = lo
    m = n // 2 + 1
    # max(x - lo, hi - x) = |x - c| + r with c the centre and r the half length of a run
    runs = [((s[a] + s[a + m - 1]) * np.float32(0.5), (s[a + m - 1] - s[a]) * np.float32(0.5))
            for a in range(n - m + 1)]
    out = np.empty_like(v)
    tmp = np.empty_like(v[0])
    for j in range(n):
        best = out[j]
        for k, (c, r) in enumerate(runs):
            np.subtract(v[j], c, out=tmp)
            np.abs(tmp, out=tmp)
            tmp += r
            if k == 0:
                best[...] = tmp
            else:
                np.minimum(best, tmp, out=best)
    return out


def outlier_weights(values: np.ndarray, valid: np.ndarray, scale: float) -> np.ndarray:
    """Outlier weights exp(-median_k |v_k - v_j| / scale), (n, ...) float32.

    values: (n, ...) warped samples, index 0 = the current frame. valid: (n, ...) bool,
    samples that are not occluded (index 0 is always used). Occluded samples are replaced by
    the current value before the median, so they neither vote nor count as disagreement.
    scale: in the units of ``values`` (px for D).
    """
    v = np.where(valid, values, values[0][None])
    d = median_distance(v)
    return np.exp(d * np.float32(-1.0 / scale))


def _chain(f_ab: np.ndarray, m_ab: np.ndarray, f_bc: np.ndarray, m_bc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate a flow and its valid mask: ``f_ac = f_ab + warp(f_bc, f_ab)``,
    ``m_ac = m_ab * warp(m_bc, f_ab)`` (outside the frame: 0). One 3-channel warp."""
    maps = fl.flow_maps(f_ab)
    w = fl.warp(np.dstack([f_bc, m_bc]), f_ab, border="zero", maps=maps)
    inside = fl.inside(f_ab, maps)
    f_ac = f_ab + w[..., :2]
    m_ac = m_ab * w[..., 2] * inside
    return f_ac, m_ac


def _mean_e(est: np.ndarray) -> np.ndarray:
    """Mean of the three E channels of a (h, w, 4) D/E stack (faster than .mean(axis=2))."""
    return (est[..., 1] + est[..., 2] + est[..., 3]) * np.float32(1 / 3)


# ----------------------------------------------------------------------------------------
# The streaming filter


@dataclass
class _Frame:
    """One frame in the window: its flow-resolution luma, its estimates, its flows."""

    index: int
    shape: tuple[tuple[int, int], tuple[int, int]]  # ((H, W) of the estimates, (h, w, 3) of the frame)
    gray: np.ndarray  # (h, w) uint8 luma at the flow resolution (for DIS)
    color: np.ndarray  # (h, w, 3) float32 RGB in [0, 1] at the flow resolution (photometric checks)
    grad: np.ndarray  # (h, w, 3) its local gradient magnitude per px
    d: np.ndarray  # (H, W) disparity, px
    e: np.ndarray  # (H, W, 3) HDR exponent
    e_any: bool  # any E > 0 (frames without highlights skip warping E)
    small: np.ndarray  # (h, w, 4) D, E.R, E.G, E.B at the flow resolution
    fwd: tuple[np.ndarray, np.ndarray] | None = None  # flow and valid mask to index + 1
    back: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # back[k-1]: to index - k
    ahead: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # ahead[k-1]: to index + k


class TemporalFilter:
    """The streaming filter: :meth:`push` frames in order, collect outputs, :meth:`finish`.

    Holds at most M + 1 frames (their estimates, flow-resolution luma and flows). Causal
    windows return frame t when it is pushed; centred windows return frame t when t + F is
    pushed (or at a restart / the end). Restarts the window at a scene cut, a change of frame
    or estimate size, or a gap in the indices (each logged).
    """

    def __init__(self, settings: TemporalSettings | None = None) -> None:
        self.settings = settings or TemporalSettings()
        self.flow = fl.DISFlow(self.settings.flow_preset)
        self.buffer: deque[_Frame] = deque()
        self.next_target: int | None = None
        self.cuts: list[int] = []
        """Indices at which the window restarted (first frame of each new segment)."""
        self.last_fail_fraction: float = 0.0
        self._kernel = (cv2.getStructuringElement(cv2.MORPH_RECT, (2 * self.settings.erode_px + 1,) * 2)
                        if self.settings.erode_px > 0 else None)

    # -- input -------------------------------------------------------------------------------
    def push(self, index: int, frame: np.ndarray, disparity: np.ndarray, exponent: np.ndarray) -> list[Output]:
        """Add frame ``index``: frame (h, w, 3) uint8 RGB (for the flow; any size), disparity
        (H, W) px, exponent (H, W, 3). Returns the outputs that became ready (0, 1 or more)."""
        d = np.asarray(disparity, dtype=np.float32)
        e = np.asarray(exponent, dtype=np.float32)
        if e.ndim == 2:
            e = np.repeat(e[..., None], 3, axis=2)
        if d.ndim != 2 or e.shape != d.shape + (3,):
            raise InputError(f"frame {index}: disparity must be (H, W) and exponent (H, W, 3) of the same size; "
                             f"got {d.shape} and {e.shape}")
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise InputError(f"frame {index}: the video frame must be (H, W, 3) RGB, got {frame.shape}")
        shape = (d.shape, frame.shape)
        out: list[Output] = []
        if self.buffer:
            last = self.buffer[-1]
            reason = None
            if last.shape != shape:
                reason = (f"frame {index} is {frame.shape[1]}x{frame.shape[0]} (estimates {d.shape[1]}x{d.shape[0]}) "
                          f"but frame {last.index} was {last.shape[1][1]}x{last.shape[1][0]} (estimates "
                          f"{last.shape[0][1]}x{last.shape[0][0]})")
            elif index != last.index + 1:
                reason = f"frame index jumps from {last.index} to {index}"
            if reason:
                log.warning("temporal filter: %s; restarting the temporal window", reason)
                out += self._restart(index)
        w_est, h_est = d.shape[1], d.shape[0]
        size = fl.flow_size(w_est, h_est, self.settings.flow_max_side)
        est = np.empty((h_est, w_est, 4), np.float32)
        est[..., 0] = d
        est[..., 1:] = e
        small = cv2.resize(est, size, interpolation=cv2.INTER_AREA) if (w_est, h_est) != size else est
        color = fl.to_flow_color(frame, size)
        cur = _Frame(index, shape, fl.to_flow_gray(frame, size), color, fl.gradient(color), d, e, bool(e.any()), small)
        if self.buffer and not self._link(self.buffer[-1], cur):
            log.info("temporal filter: scene cut between frames %d and %d (%.0f%% of the pixels fail the "
                     "flow checks); restarting the temporal window", index - 1, index,
                     100 * self.last_fail_fraction)
            out += self._restart(index)
        if self.next_target is None:
            self.next_target = index
        self.buffer.append(cur)
        out += self._emit(final=False)
        return out

    def finish(self) -> list[Output]:
        """Flush the frames still waiting for their future (centred window) and reset."""
        out = self._emit(final=True)
        self.buffer.clear()
        self.next_target = None
        return out

    # -- internals ---------------------------------------------------------------------------
    def _restart(self, index: int) -> list[Output]:
        out = self.finish()
        self.cuts.append(index)
        return out

    def _valid(self, mask: np.ndarray) -> np.ndarray:
        m = mask.astype(np.uint8)
        if self._kernel is not None:
            m = cv2.erode(m, self._kernel, borderType=cv2.BORDER_REPLICATE)
        return m.astype(np.float32)

    def _link(self, prev: _Frame, cur: _Frame) -> bool:
        """Flows between the newest buffered frame and ``cur``, chains; False at a scene cut."""
        s = self.settings
        link = link_checks(self.flow, prev.gray, cur.gray, prev.color, cur.color, prev.grad, cur.grad, s)
        f_pc, f_cp, ok_pc, ok_cp = link.f_ab, link.f_ba, link.ok_ab, link.ok_ba
        self.last_fail_fraction = link.fail_fraction
        if self.last_fail_fraction > s.cut_fraction:
            return False
        m_cp, m_pc = self._valid(ok_cp), self._valid(ok_pc)
        # backward chain of cur: f_{c->c-k} = f_{c->c-1} + warp(f_{c-1->c-k}, f_{c->c-1})
        cur.back = [(f_cp, m_cp)]
        for f_prev, m_prev in prev.back[: s.past - 1]:
            cur.back.append(_chain(f_cp, m_cp, f_prev, m_prev))
        # forward chains of the buffered frames: f_{t->c} = f_{t->c-1} + warp(f_{c-1->c}, f_{t->c-1})
        prev.fwd = (f_pc, m_pc)
        if s.future > 0:
            for t in self.buffer:
                k = cur.index - t.index
                if self.next_target is not None and t.index < self.next_target:
                    continue  # already filtered: needs no future
                if t is prev:
                    t.ahead = [(f_pc, m_pc)]
                elif 1 < k <= s.future and len(t.ahead) == k - 1:
                    t.ahead.append(_chain(*t.ahead[-1], f_pc, m_pc))
        if s.past == 0:
            cur.back = []
        return True

    def _emit(self, final: bool) -> list[Output]:
        out: list[Output] = []
        if self.next_target is None:
            return out
        newest = self.buffer[-1].index if self.buffer else -1
        while self.next_target is not None and self.next_target <= newest and (
                final or self.next_target + self.settings.future <= newest):
            target = next(f for f in self.buffer if f.index == self.next_target)
            out.append(self._filter(target))
            self.next_target += 1
        # drop frames no future target needs
        keep_from = (self.next_target if self.next_target is not None else newest + 1) - self.settings.past
        while self.buffer and self.buffer[0].index < keep_from:
            self.buffer.popleft()
        if final:
            self.next_target = None
        return out

    def _samples(self, t: _Frame) -> list[tuple[_Frame, np.ndarray, np.ndarray]]:
        """(frame j, flow t->j, mask t->j) for every neighbour j in the window."""
        by_index = {f.index: f for f in self.buffer}
        out = []
        for k, (f, m) in enumerate(t.back[: self.settings.past], start=1):
            if t.index - k in by_index:
                out.append((by_index[t.index - k], f, m))
        for k, (f, m) in enumerate(t.ahead[: self.settings.future], start=1):
            if t.index + k in by_index:
                out.append((by_index[t.index + k], f, m))
        return out

    def _filter(self, t: _Frame) -> Output:
        s = self.settings
        samples = self._samples(t)
        h_est, w_est = t.d.shape
        if not samples:
            conf = np.full((h_est, w_est), 1.0 / (s.m + 1), np.float32)
            return t.index, t.d.copy(), t.e.copy(), conf
        # weights at the flow resolution
        n = len(samples) + 1
        h, w = t.small.shape[:2]
        vd = np.empty((n, h, w), np.float32)
        ve = np.empty((n, h, w), np.float32)
        occ = np.empty((n, h, w), np.float32)
        vd[0], ve[0], occ[0] = t.small[..., 0], _mean_e(t.small), 1.0
        for i, (j, f, m) in enumerate(samples, start=1):
            maps = fl.flow_maps(f)
            ws = fl.warp(j.small, f, nearest=True, maps=maps)
            vd[i], ve[i] = ws[..., 0], _mean_e(ws)
            if abs(t.index - j.index) > 1:  # links were checked in _link; chains are checked here
                m = m * self._valid(fl.photometric_ok(t.color, j.color, f, s.photometric_tol, m > 0.5,
                                                      pixel_tol=s.pixel_tol, grad_a=t.grad, slack_px=s.slack_px,
                                                      maps=maps))
            occ[i] = m
        valid = occ > 0.5
        valid[0] = True
        w_d = outlier_weights(vd, valid, s.outlier_scale_d * w_est) * occ
        if float(ve.max() - ve.min()) > 0.0:
            w_e = outlier_weights(ve, valid, s.outlier_scale_e) * occ
        else:
            w_e = occ
        # the weighted sum at full resolution, weights upsampled. E is fused only at the pixels
        # where some sample of the window has E > 0 (elsewhere every sample is 0): few, usually
        size = (w_est, h_est)
        np.maximum(w_d[0], np.float32(1e-6), out=w_d[0])  # the current frame always counts a little
        np.maximum(w_e[0], np.float32(1e-6), out=w_e[0])
        total_d = fl.resize_map(w_d[0], size)
        acc_d = t.d * total_d
        e_px = _e_pixels(ve, size) if (t.e_any or any(j.e_any for j, _, _ in samples)) else None
        if e_px is not None:
            at_small = _small_coords(e_px, size, (w, h))  # (N, 1, 2) flow-resolution coordinates
            total_e = fl.remap(w_e[0], at_small)[:, 0]
            acc_e = t.e.reshape(-1, 3)[e_px] * total_e[:, None]
        for i, (j, f, _) in enumerate(samples, start=1):
            maps = fl.upsample_maps(f, size)
            wf = fl.resize_map(w_d[i], size)
            cv2.accumulateProduct(fl.remap(j.d, maps, nearest=True), wf, acc_d)
            cv2.accumulate(wf, total_d)
            if e_px is not None:
                wf = fl.remap(w_e[i], at_small)[:, 0]
                if j.e_any:
                    acc_e += fl.remap(j.e, maps.reshape(-1, 1, 2)[e_px], nearest=True)[:, 0] * wf[:, None]
                total_e += wf
        d_s = acc_d / total_d
        e_s = np.zeros_like(t.e)
        if e_px is not None:
            e_s.reshape(-1, 3)[e_px] = acc_e / total_e[:, None]
        total_d *= np.float32(1.0 / (s.m + 1))
        conf = np.minimum(total_d, np.float32(1.0), out=total_d)  # weights are >= 0
        return t.index, d_s, e_s, conf


def _e_pixels(e_small: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """Flat indices of the full-resolution pixels (``size`` = (W, H)) near which some warped
    sample has E > 0 (e_small: (n, h, w) at the flow resolution; one flow pixel of margin);
    None if there is none."""
    any_e = (e_small > 0).any(axis=0).astype(np.uint8)
    if not any_e.any():
        return None
    any_e = cv2.dilate(any_e, np.ones((3, 3), np.uint8))
    full = cv2.resize(any_e, tuple(size), interpolation=cv2.INTER_NEAREST)
    return np.flatnonzero(full)


def _small_coords(flat: np.ndarray, size: tuple[int, int], small: tuple[int, int]) -> np.ndarray:
    """(N, 1, 2) float32 flow-resolution (x, y) of full-resolution pixels given by flat index,
    with cv2.resize's pixel-centre convention (so sampling there equals resizing)."""
    ys, xs = np.divmod(flat, size[0])
    out = np.empty((flat.size, 1, 2), np.float32)
    out[:, 0, 0] = (xs + 0.5) * (small[0] / size[0]) - 0.5
    out[:, 0, 1] = (ys + 0.5) * (small[1] / size[1]) - 0.5
    return out


def stabilize_stream(frames: Iterable[np.ndarray], estimates: Iterable[tuple[np.ndarray, np.ndarray]],
                     settings: TemporalSettings | None = None, start: int = 0) -> Iterator[Output]:
    """Stream the temporal filter over a clip.

    frames: (h, w, 3) uint8 RGB frames (for the flow). estimates: (D (H, W) px, E (H, W, 3))
    per frame, in the same order. start: clip index of the first frame. Yields
    ``(index, D_s, E_s, confidence)`` in frame order (a centred window lags by F frames).
    Raises InputError when the two streams differ in length.
    """
    filt = TemporalFilter(settings)
    frames_it, est_it = iter(frames), iter(estimates)
    index = start
    while True:
        frame = next(frames_it, None)
        est = next(est_it, None)
        if frame is None or est is None:
            if frame is not None or est is not None:
                which = "frames" if frame is None else "estimates"
                raise InputError(f"the {which} ended after {index - start} items but the other stream goes on; "
                                 "give one estimate (D, E) per frame")
            break
        yield from filt.push(index, frame, est[0], est[1])
        index += 1
    yield from filt.finish()
