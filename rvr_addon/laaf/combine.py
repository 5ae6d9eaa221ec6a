"""The paper's combination of detectors (section 5.2) and the discontinuities that become NFTs.

Per frame: intersect the binary regions (heat >= 0.5) of the preset's detectors; K-means
(K = 4, ``cv2.kmeans``) on the pixel positions of the intersection; the *majority* cluster's
centroid (x, y) is the focus point, and its disparity is read (``focus_reading``) over the
connected region that holds that cluster. Frames whose intersection is empty (or smaller than
``min_area`` of the frame) keep the previous level.

The level signal is then filtered with a 1-D bilateral filter and its discontinuities are found
by a step detector (edge detection on the filtered signal): a New Focus Target at frame e when
the medians of the ``r`` frames after and before e differ by at least ``min_step`` disparity
units and that difference is a local maximum; e is refined to the first frame past the middle
of the two levels.

Detector availability: a detector with no map on a frame (no face, nobody speaking) makes the
intersection empty, so the previous level is kept, unless it is a secondary detector and the
primary has a region (then the primary's region is used alone, as below); a detector that cannot run on the clip at all (speech without audio) is dropped and
the preset falls back (``FALLBACKS``).

Deviation from the paper: the action preset's saliency is a classical (not learned) saliency
map, and it misses people who are not visually distinctive (a figure walking in behind a
plant). It refines the action region when the two mostly overlap but cannot veto it: when the
intersection keeps less than a quarter of the *primary* detector's region (``PRIMARY``:
action, speech), that region is used alone.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from .detectors.base import DetectorOutput
from .focus_reading import read_focus
from .nft import Box
from .presets import DEFAULT_PRESET, PRESETS  # noqa: F401 - defined in .presets (light), re-exported here

FALLBACKS = {"conversation": "faces", "action": "salient"}
PRIMARY = {"action": "action", "conversation": "speech"}
INITIAL_CHAIN = ("face", "saliency")  # the first focus when the preset finds nothing on frame 0
K_MEANS = 4
SPEAKER_REGION = frozenset({"speech", "face"})
"""Detectors whose joint region is a speaking face's box: a target at any size (``region_min_area``)."""


def region_min_area(used: tuple[str, ...], min_area: float) -> float:
    """The smallest region (fraction of the frame) a frame's combination of the detectors ``used``
    may give: ``min_area``, which keeps specks of the pixel maps (saliency, motion) from becoming
    targets, except for the speaking face (speech alone or with the face detector), whose box the
    face detector already took as a face: a person speaking in a wide shot (a face of 11 px in a
    320 px analysis frame, 0.2 % of it) is the subject however small."""
    return 0.0 if used and "speech" in used and set(used) <= SPEAKER_REGION else min_area


def check_preset(name: str) -> tuple[str, ...]:
    """Detector names of a preset; ValueError naming the valid presets."""
    if name not in PRESETS:
        raise ValueError(f"preset {name!r} is not known; use one of {', '.join(PRESETS)}")
    return PRESETS[name]


@dataclass
class Region:
    """The focus region of one frame: point (x, y) and box (analysis px), pixel mask, area
    fraction of the frame, and which detectors made it."""

    x: float
    y: float
    box: Box
    mask: np.ndarray
    area: float
    detectors: tuple[str, ...]


def intersect(outputs: dict[str, DetectorOutput], primary: str | None = None, min_area: float = 0.0,
              keep_fraction: float = 0.25) -> tuple[np.ndarray | None, tuple[str, ...]]:
    """Intersection of the binary regions of the available detectors on this frame.

    Returns (mask, names of the detectors used); mask is None when a detector found nothing on
    this frame (an empty intersection) or no detector is available. primary: the preset's
    primary detector (``PRIMARY``); when the intersection keeps less than ``keep_fraction`` of
    the primary's region (and that region covers at least ``min_area`` of the frame), the
    primary's region is used alone; so is it when another detector found nothing on this frame
    (e.g. speech localised by audio-visual synchrony where the face detector sees no face).
    """
    live = {n: o for n, o in outputs.items() if o.available}
    if not live:
        return None, ()
    names = tuple(live)
    own_min = region_min_area((primary,), min_area) if primary else min_area
    if primary in live and len(live) > 1 and live[primary].heat is not None:
        own = live[primary].heat >= 0.5
        if own.mean() >= own_min and any(o.heat is None for o in live.values()):
            return own, (primary,)
    if any(o.heat is None for o in live.values()):
        return None, names
    mask = np.logical_and.reduce([o.heat >= 0.5 for o in live.values()])
    if primary in live and len(live) > 1:
        own = live[primary].heat >= 0.5
        if own.mean() >= own_min and mask.sum() < keep_fraction * own.sum():
            return own, (primary,)
    return mask, names


def majority_region(mask: np.ndarray, min_area: float = 0.004, k: int = K_MEANS,
                    max_points: int = 3000) -> Region | None:
    """K-means (k clusters) of the mask's pixel positions; the majority cluster's centroid and the
    connected part of the mask that holds it. None if the mask's area fraction < min_area."""
    import cv2

    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    if ys.size < max(k, min_area * h * w, 1):
        return None
    pts = np.stack([xs, ys], 1).astype(np.float32)
    if len(pts) > max_points:
        pts = pts[np.linspace(0, len(pts) - 1, max_points).astype(np.int64)]
    cv2.setRNGSeed(12345)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)
    _, labels, centres = cv2.kmeans(pts, k, None, crit, 2, cv2.KMEANS_PP_CENTERS)
    counts = np.bincount(labels.reshape(-1), minlength=k)
    major = int(np.argmax(counts))
    cx, cy = (float(v) for v in centres[major])
    n_comp, comp = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    members = pts[labels.reshape(-1) == major].astype(np.int64)
    ids = np.bincount(comp[members[:, 1], members[:, 0]], minlength=n_comp)
    ids[0] = 0
    region = comp == int(np.argmax(ids))
    if region.sum() < min_area * h * w:
        return None
    ry, rx = np.nonzero(region)
    box = (float(rx.min()), float(ry.min()), float(rx.max() - rx.min() + 1), float(ry.max() - ry.min() + 1))
    if not region[int(min(max(cy, 0), h - 1)), int(min(max(cx, 0), w - 1))]:
        j = int(np.argmin((rx - cx) ** 2 + (ry - cy) ** 2))
        cx, cy = float(rx[j]), float(ry[j])
    return Region(cx, cy, box, region, float(region.mean()), ())


def region_level(disparity: np.ndarray, region: Region) -> float:
    """Focus disparity of a region (foreground-biased reading over its mask and box)."""
    return read_focus(disparity, region.box, region.mask).value


def bilateral_1d(values: np.ndarray, sigma_t: float = 1.5, sigma_r: float = 0.4, radius: int = 3,
                 causal: bool = False) -> np.ndarray:
    """1-D bilateral filter of a level signal: weights exp(-dt^2/2sigma_t^2 - dv^2/2sigma_r^2)
    over +-radius frames (causal: only the past). NaN samples are ignored."""
    v = np.asarray(values, dtype=np.float64)
    out = v.copy()
    n = len(v)
    for i in range(n):
        if not np.isfinite(v[i]):
            continue
        lo, hi = max(0, i - radius), (i + 1 if causal else min(n, i + radius + 1))
        seg = v[lo:hi]
        dt = np.arange(lo, hi) - i
        ok = np.isfinite(seg)
        wgt = np.exp(-0.5 * (dt[ok] / sigma_t) ** 2 - 0.5 * ((seg[ok] - v[i]) / sigma_r) ** 2)
        out[i] = float((wgt * seg[ok]).sum() / wgt.sum())
    return out


@dataclass
class Step:
    """A discontinuity: frame e (first frame of the new level), levels before/after. speaker:
    the face track a change of speaker goes to, where the speech detector's decision chain made
    it (``lookahead``: a turn step), else None. region_frame: the frame whose region is the new
    subject, where that is not e..e+3 (a turn step: the frame the chain named the speaker)."""

    frame: int
    before: float
    after: float
    speaker: str | None = None
    region_frame: int | None = None


class StepDetector:
    """Streaming bilateral filter + step detection on the held level signal (module docstring).

    Push the level of each frame in order (NaN = empty intersection: the previous level is
    held); ``push`` returns the steps that became certain. Look-ahead mode decides a step at e
    once frame e + ``delay`` has been pushed (symmetric filter); causal mode uses a one-sided
    filter and decides as soon as r frames of the new level are in. A step also needs the new
    level to be *measured* (not only held) on ``min_support`` of the frames after it, so a
    one-frame blip followed by empty frames does not become a target.
    """

    def __init__(self, min_step: float = 0.5, r: int = 3, min_gap: int = 6, sigma_r: float = 0.4,
                 causal: bool = False, min_support: int = 2, filter_radius: int = 2) -> None:
        """r: frames each side a step's two levels are measured over; min_gap: frames between two
        steps; sigma_r: the bilateral filter's range sigma (disparity units); filter_radius: its
        window (frames; its time sigma is 0.75 of it); min_support: frames the new level must be
        measured on."""
        self.min_step = min_step
        self.r = r
        self.min_gap = min_gap
        self.sigma_r = sigma_r
        self.causal = causal
        self.min_support = min_support
        self.filter_radius = int(filter_radius)
        self.sigma_t = 0.75 * self.filter_radius
        self.delay = (r - 1) if causal else (2 * r - 1 + self.filter_radius)
        self.raw: list[float] = []
        self.held: list[float] = []
        self.filtered: list[float] = []
        self._last_step = -10 ** 9
        self._next = r  # next frame index to test as a step

    def _filtered_at(self, i: int) -> float:
        v = np.asarray(self.held, dtype=np.float64)
        rad = self.filter_radius
        lo, hi = max(0, i - rad), (i + 1 if self.causal else min(len(v), i + rad + 1))
        seg = v[lo:hi]
        dt = np.arange(lo, hi) - i
        ok = np.isfinite(seg)
        if not np.isfinite(v[i]) or not ok.any():
            return float("nan")
        wgt = np.exp(-0.5 * (dt[ok] / self.sigma_t) ** 2 - 0.5 * ((seg[ok] - v[i]) / self.sigma_r) ** 2)
        return float((wgt * seg[ok]).sum() / wgt.sum())

    def push(self, level: float) -> list[Step]:
        """Add the next frame's level; returns newly certain steps."""
        self.raw.append(float(level))
        prev = self.held[-1] if self.held else float("nan")
        self.held.append(float(level) if math.isfinite(level) else prev)
        n = len(self.held)
        # filtered values are final once the symmetric window is complete
        ready = n if self.causal else n - self.filter_radius
        while len(self.filtered) < ready:
            self.filtered.append(self._filtered_at(len(self.filtered)))
        return self._scan(final=False)

    def finish(self) -> list[Step]:
        """End of the clip: finish filtering and report the remaining steps."""
        while len(self.filtered) < len(self.held):
            self.filtered.append(self._filtered_at(len(self.filtered)))
        return self._scan(final=True)

    def _jump(self, f: np.ndarray, e: int) -> float:
        r = self.r
        a, b = f[max(0, e - r):e], f[e:e + r]
        a, b = a[np.isfinite(a)], b[np.isfinite(b)]
        if a.size == 0 or b.size == 0:
            return 0.0
        return float(np.median(b) - np.median(a))

    def _scan(self, final: bool) -> list[Step]:
        f = np.asarray(self.filtered, dtype=np.float64)
        n = len(f)
        r = self.r
        steps = []
        need = 0 if self.causal else r  # look-ahead: the local-maximum test sees r frames further
        while True:
            e = self._next
            if not final and e + r - 1 + need >= n:
                break
            if e >= n:
                break
            self._next += 1
            if e - self._last_step < self.min_gap:
                continue
            j = self._jump(f, e)
            if abs(j) < self.min_step:
                continue
            # the new level must be measured (not only held) on at least min_support frames
            span = r if self.causal else 2 * r
            raw = np.asarray(self.raw[e:e + span], dtype=np.float64)
            after_level = float(np.median(f[e:e + r]))
            seen = np.isfinite(raw) & (np.abs(raw - after_level) <= max(0.5 * abs(j), 0.3))
            if int(seen.sum()) < self.min_support:
                continue
            if not self.causal:
                around = [abs(self._jump(f, k)) for k in range(max(r, e - r), min(n, e + r + 1))]
                if abs(j) < max(around) - 1e-9:
                    continue
            # refine: first frame past the middle of the two levels
            before = float(np.nanmedian(f[max(0, e - r):e]))
            after = float(np.nanmedian(f[e:e + r]))
            mid = 0.5 * (before + after)
            lo = max(self._last_step + 1, e - r + 1, 1)
            hi = e + r - 1
            cand = [k for k in range(lo, min(hi, n - 1) + 1)
                    if np.isfinite(f[k]) and (f[k] - mid) * np.sign(after - before) > 0]
            frame = cand[0] if cand else e
            steps.append(Step(frame, before, after))
            self._last_step = frame
            self._next = max(self._next, frame + self.min_gap)
        return steps
