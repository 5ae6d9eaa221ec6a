"""Depth from the camera's own motion (parallax): the ``parallax`` cue of the depth system.

Per frame t, at an analysis size (long side ``analysis_long_side`` px):

1. **Tracks.** Corners (Shi-Tomasi) tracked frame to frame with pyramidal Lucas-Kanade and a
   forward-backward check give sparse correspondences between t and every frame of the window
   t-W..t+W (W = ``window``) at almost no cost.
2. **Neighbour choice.** For each candidate t+k a homography is fitted to the tracks (RANSAC):
   a homography explains a rotating camera (or a plane) exactly, so a residual under
   ``min_parallax_px`` means no baseline. Otherwise the tracks' essential matrix gives the
   rotation, and the median parallax left after removing it (px) measures the baseline. Per
   side (behind, ahead) the nearest candidate reaching ``target_parallax_px`` is chosen (else the
   one with the most), up to ``per_side`` per side; behind, an earlier frame that chose t as its
   neighbour ahead is taken first when its tracks reach the target from t too (the pair's flows
   and pose are then computed once for both frames).
3. **Pair geometry.** Dense DIS flow both ways (:mod:`rvr_addon.temporal.flow`, cached per pair
   while both frames are in the window); the relative pose from flow correspondences sampled on
   a grid where the flow is forward-backward consistent (``cv2.findEssentialMat`` with RANSAC,
   re-estimated on its inliers by LMedS unless that explains them worse (:func:`msac_score`:
   LMedS can lock onto a dominant plane), ``cv2.decomposeEssentialMat`` + cheirality). The flow
   is DIS refined down to the analysis size itself, patches every 4 px (:class:`PairFlow`, FLOW_FINEST_SCALE,
   FLOW_PATCH_STRIDE). A pair whose dense
   median parallax after de-rotation stays under MIN_DENSE_PARALLAX_PX is dropped, and so is one
   whose parallax does not dominate the flow its rotation makes (ROT_RATIO): a rolling shutter,
   a focal length or lens distortion off and the frames' timing all leave false parallax in
   proportion to the rotation (a pair between the two thresholds keeps part of its confidence).
4. **Triangulation.** Per pixel, the depth along t's ray that best meets the flow's ray in the
   neighbour (linear least squares, vectorised over pixels), with a confidence: forward-backward
   flow agreement, triangulation angle (px of de-rotated parallax), distance to the epipolar
   line (independent motion: people walking, cars) and positive depth in both views. A depth
   under half the baseline (Q_MAX) or far nearer than the bulk of the frame (SPIKE_RATIO) is a
   flow error that happens to lie on the epipolar line and is dropped.
5. **One scale per clip.** Two views give depth up to the pair's baseline. Every output frame
   keeps its inverse depth at its tracks; for frame t, each earlier output frame n of the window
   makes the tracks it shares with t 3-D points, PnP (RANSAC) on their positions in t gives t's
   pose in the clip's unit and so their inverse depth in t, and per track the median over the
   frames n is the prediction; each pair's scale is the median ratio of its map to it at the
   tracks (several earlier frames, not one anchor pair: the scale does not random-walk). Without
   enough predicted tracks, a behind neighbour n already output anchors it (the same pair
   triangulated in n's view must match n's map), and without that the frame sets a new unit
   (the first frame, or one after the tracks broke: info ``scale_reset``): median inverse depth
   1 on its trusted pixels.
6. **Fusion.** The neighbours' scaled maps are fused by a confidence-weighted mean of the values
   that agree with their median; neighbours that disagree (an object moving along the epipolar
   line) lower the confidence.
6b. **Photometric check** (:mod:`.sweep`, ``photometric_check``). A plane sweep of the fused
   neighbours (in the clip's unit, at half the analysis size) finds each pixel's best depth from
   the pictures themselves; where it contradicts the flow's depth by more than 10 %, the
   confidence drops to 0.3 of itself (flow interpolated over a textureless patch or across a
   depth edge). HoloLens office: the whole depth's per-frame error 0.366 -> 0.347.
7. **Signal to noise.** The frame's depth structure (robust std of its log inverse depth, at
   least SNR_SIGNAL_FLOOR) over how much independent measurements of it disagree (the median
   |log ratio| of two pairs' maps, the spread of a pair's map against the earlier frames'
   prediction at the tracks): under SNR_RANGE the map holds nothing the noise does not, and the
   whole frame's confidence goes down with it (small baselines against rotation, motion blur,
   distant scenes), so the fusion falls back on the prior. The clip's gate (:func:`clip_gate`, the median SNR
   of its frames) covers its first frames too: they are held back (at most GATE_HOLD_FRAMES)
   until CLIP_SNR_MIN_FRAMES frames have an SNR (TUM fr1/rpy: its first 3 frames handed the
   fusion noise, 0.93-0.98 against the network's 0.65-0.73). The scale chain keeps the geometric
   confidence.
8. **Memory.** The maps of the PROPAGATE_FRAMES latest output frames of the chain are carried
   into t: t's flow into n samples n's inverse depth, t's pose from n (the PnP of step 5) moves
   the point into t, and it must reproject onto the pixel that fetched it (REPROJECT_TOL_PX:
   a point n got wrong or one that moved since is dropped); its confidence fades by
   PROPAGATE_DECAY a frame. Fused with t's own map where they agree (within ~15 %), it fills
   what t's own pairs miss (the frame border, weak-baseline regions) and a frame whose own
   pairs all fail (rotation, pose failure) still gets the clip's depth in the clip's unit
   (info ``reason`` "carried from earlier frames (...)"); a frame whose own map is noise (low
   signal to noise) lends the carried map only part of its confidence. HoloLens office
   (default field of view): 24 of 120 frames had no parallax at all; per-frame error of the
   fused depth 0.51 -> 0.46, flicker 0.30 -> 0.19; TUM fr1/rpy 0.77-0.80 -> 0.80, flicker
   0.50 -> 0.22.

Output per frame: ``CueMap(name="parallax", metric=False, shift_free=True)`` at the frame's
full size: inverse depth in 1/(clip unit) (bilinear upsampling of inverse depth), NaN where
unknown, confidence 0..1 (nearest upsampling), info ``{"parallax", "neighbours",
"median_angle_deg", "scale_reset", "reason"}`` and, with parallax, ``pair_parallax_px``,
``focal_px``, ``focal_refined``, ``pair_disagreement``, ``track_spread``, ``snr``,
``rotation_ratio`` (per pair: parallax over the flow of its rotation), ``propagated`` and
``memory_disagreement`` (median |log ratio| of t's own map and the carried one). A frame
without parallax (still camera, rotation only, a plane, no texture, too little translation for
its rotation) gets an empty cue (all NaN, confidence 0) whose reason says why.

Intrinsics: the product does not know K; unless the caller passes one (px of the full frame),
a pinhole with the principal point at the centre whose focal length starts at
:func:`rvr_addon.depth.cues.focal_px`'s guess (66 deg across the frame's long side) and is refined once, on
the tracks of the first CAL_FRAMES frames (:func:`refine_focal`: the focal whose two-view
reconstructions a third view sees best, shrunk toward the guess by its bootstrap uncertainty);
info ``focal_px`` (full frame) and ``focal_refined``.

Streaming: :meth:`ParallaxEstimator.maps` holds at most max(2 W + 1, CAL_FRAMES) small gray
frames, their tracks, the flows of the pairs in use and the W last output maps at analysis size.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator

import cv2
import numpy as np

from .cues import DEFAULT_HFOV_DEG, CueMap, focal_px, scale_K
from .sweep import checked_confidence
from ..temporal.flow import PRESETS, dis_calc, fb_error, flow_size, to_flow_gray

NAME = "parallax"
MAX_CORNERS = 400
"""Tracked corners per frame (refilled when fewer than 70 % survive)."""
MIN_TRACKS = 24
"""Fewest common tracks for a pair to be judged at all."""
POSE_SAMPLES = 1500
"""About how many flow samples (on a grid) the pose is estimated from."""
REFINE_SAMPLES = 400
"""At most this many RANSAC inliers re-estimate the essential matrix (LMedS)."""
FB_SAMPLE_PX = 0.5
"""Forward-backward error (px) a flow sample may have to enter the pose estimation."""
E_THRESHOLD_PX = 0.75
"""RANSAC threshold (px) of the essential matrix."""
MIN_DENSE_PARALLAX_PX = 1.5
STILL_SHIFT_PX = 1.0
"""camera_translates: the lower quartile of the tracks must move this far (px at analysis size) across the
window before a homography residual counts as baseline (moving people on a still shot do not)."""
"""Median de-rotated parallax (px) of a pair's pose inliers under which the pair is dropped."""
FB_TOL_PX, FB_TOL_RELATIVE = 1.0, 0.05
"""Forward-backward tolerance of a pixel's flow: px + share of the flow's length."""
EPI_TOL_PX = 1.5
"""Tolerated distance (px) of the flow's end point from the epipolar line (more: independent
motion or a flow error)."""
Q_MAX = 2.0
"""Largest inverse depth a pair may triangulate, in 1/(its baseline): nothing the camera sees is
nearer than half the distance it moved (nearer: a flow error that happens to lie on the
epipolar line)."""
MIN_SCALE_TRACKS = 20
"""Fewest tracks with a known inverse depth that fix a pair's scale (else the dense anchor)."""
PNP_THRESHOLD_PX = 1.5
"""RANSAC threshold (px) of the PnP pose of a frame on an earlier frame's tracked points."""
CAL_FRAMES = 25
"""Frames read before the first output when the focal length is refined (at least 2 W + 1)."""
CAL_PARALLAX_PX = 6.0
"""refine_focal's frame triples (a, b, c): c is the first frame after a whose tracks leave this
homography residual (px) with a's, b the frame half-way."""
FOCAL_STEP, FOCAL_STEPS = 1.08, (-4, 5)
"""Focal lengths tried by refine_focal: the guess times FOCAL_STEP ** k, k in the range
(0.74-1.47 x the 66 deg guess: about 84 to 48 deg across the long side)."""
FOCAL_MIN_TRIPLES = 4
"""refine_focal keeps the guess unless this many frame triples answer."""
FOCAL_PRIOR_SIGMA = 0.15
"""Uncertainty (std of log) of the 66 deg guess: the refined focal is the guess and the tracks'
estimate weighted by their inverse variances (the estimate's from a bootstrap over triples)."""
FOCAL_BOOTSTRAP = 64
ROT_RATIO = (0.08, 0.16)
"""A pair's median de-rotated parallax over the flow its rotation makes (px / px) under which
it is dropped / from which it is fully trusted (rotation-proportional errors: rolling shutter,
focal length, lens distortion, timing)."""
SNR_SIGNAL_FLOOR = 0.1
"""The signal of a frame's SNR is at least this (std of log inverse depth): a flat wall measured
to a few % is a good answer."""
SNR_RANGE = (2.0, 4.0)
"""A frame's signal to noise (spread of its log inverse depth, robust std from the 10-90 %
range, over the disagreement of independent measurements of it) under which the cue trusts nothing / from which it keeps its
confidence."""
CLIP_SNR_MIN_FRAMES = 3
"""Frames with a signal to noise the clip's gate (the median SNR so far
through SNR_RANGE, :func:`clip_gate`) waits for before it gates anything."""
GATE_HOLD_FRAMES = 6
"""At most this many of a clip's first maps are held back until the clip's gate can judge them
(:meth:`ParallaxEstimator.maps`); each costs two maps of the full frame in memory."""
SPIKE_RATIO = 4.0
"""A pair's inverse depth above this many times the 95th percentile of its trusted values is
dropped (a near object covering under 5 % of the frame, or a flow error)."""
PROPAGATE_FRAMES = 2
"""Earlier output frames whose maps are carried into each frame (0 = each frame on its own)."""
PROPAGATE_DECAY = 0.8
"""Confidence kept by a map carried one frame on (so old measurements fade)."""
REPROJECT_TOL_PX = 2.0
"""px (analysis size) a carried point may land from the pixel whose flow fetched it."""
FLOW_FINEST_SCALE = 0
"""Finest pyramid level of the pairs' DIS flow (0 = the analysis size). The "medium" preset
stops at level 1 and upsamples: flow errors along the epipolar line are depth errors, and on
HoloLens office (ground-truth poses, 4 neighbours) the triangulated maps' error went
0.339 -> 0.315 at level 0; the whole fused depth 0.46 -> 0.44, at about twice the flow's time."""
FLOW_PATCH_STRIDE = 4
"""px between the DIS patches of the pairs' flow at level 0 (the "medium" preset: 3). With the
photometric check (:mod:`.sweep`) HoloLens office scored 0.3473 at 3, 0.3481 at 4, 0.3448 at 6;
each pair's flow took 67 / 52 / 43 ms at 640x360, which pays for the check. 6 is not taken: on
exactly known synthetic planes (tests) its flow is less precise (per-frame error on trusted
pixels 0.07-0.13 at 3, 0.06-0.15 at 4, 0.09-0.16 and one frame 0.41 at 6)."""
MEMORY_FLOW_PRESET = "fast"
"""DIS preset of the memory's flows (one per carried frame, PROPAGATE_FRAMES a frame; the preset's
own pyramid level): "fast" takes 3 ms at 640x360 where "medium" took 12; HoloLens office 0.3473
against 0.3464 (flicker 0.065 both), within the run-to-run spread of the settings around it. A
point the flow carries wrongly does not reproject onto its pixel and is dropped (REPROJECT_TOL_PX)."""
ANGLE_MIN_PX, ANGLE_FULL_PX = 1.0, 3.0
"""Triangulation angle, as px of de-rotated parallax at analysis size, under which a pixel is
not trusted at all / from which it is fully trusted."""


class PairFlow:
    """DIS optical flow of one OpenCV instance for the pairs (created once per run, reused;
    deterministic): the ``preset`` ("ultrafast", "fast", "medium") refined down to pyramid level
    ``finest_scale`` (None: the preset's own) with DIS patches every ``patch_stride`` px (None:
    the preset's own). Called as ``flow(a, b)`` on two gray uint8 frames
    of one size, it returns f_ab (h, w, 2) float32 px (:mod:`rvr_addon.temporal.flow`'s
    conventions)."""

    def __init__(self, preset: str = "medium", finest_scale: int | None = FLOW_FINEST_SCALE,
                 patch_stride: int | None = FLOW_PATCH_STRIDE) -> None:
        if preset not in PRESETS:
            raise ValueError(f"parallax: unknown DIS preset {preset!r}; choose one of {', '.join(PRESETS)}")
        self._dis = cv2.DISOpticalFlow_create(PRESETS[preset])
        if finest_scale is not None:
            if int(finest_scale) < 0:
                raise ValueError(f"parallax: flow_finest_scale must be >= 0 or None, got {finest_scale}")
            self._dis.setFinestScale(int(finest_scale))
        if patch_stride is not None:
            if int(patch_stride) < 1:
                raise ValueError(f"parallax: patch_stride must be >= 1 or None, got {patch_stride}")
            self._dis.setPatchStride(int(patch_stride))

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if a.shape != b.shape:
            raise ValueError(f"PairFlow: frames differ in size, {a.shape} vs {b.shape}")
        return dis_calc(self._dis, a, b)


@dataclass
class _Frame:
    """One frame in the window: analysis gray, its tracks, and once output its map."""

    index: int
    gray: np.ndarray
    full_size: tuple[int, int]  # (W, H) of the input frame
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    pts: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    motion_px: float = 0.0  # median track motion from the previous frame (px)
    q: np.ndarray | None = None  # output inverse depth (clip unit) at analysis size
    conf: np.ndarray | None = None
    epoch: int = -1  # the scale chain the output map belongs to
    tq_ids: np.ndarray | None = None  # once output: the tracks on trusted pixels ...
    tq: np.ndarray | None = None  # ... and their inverse depth there (clip unit)
    cc: np.ndarray | None = None  # once output: the cue's confidence (signal to noise included)


@dataclass
class _Pair:
    """Dense geometry of the pair (a, b): flows, fb error, pose x_b = R x_a + T (|T| = 1)."""

    f_ab: np.ndarray
    f_ba: np.ndarray
    fb_a: np.ndarray
    fb_b: np.ndarray
    R: np.ndarray | None = None
    T: np.ndarray | None = None
    parallax_px: float = 0.0
    inlier_ratio: float = 0.0


def _empty(full_size: tuple[int, int], reason: str, **info) -> CueMap:
    w, h = full_size
    nan = np.full((h, w), np.nan, np.float32)
    return CueMap(NAME, nan, np.zeros((h, w), np.float32), metric=False, shift_free=True,
                  info={"parallax": False, "neighbours": [], "reason": reason, **info})


def analysis_size(width: int, height: int, long_side: int) -> tuple[int, int]:
    """(w, h) of the analysis size: the frame shrunk so its long side is at most ``long_side``
    px (tiny frames are enlarged to DIS's minimum, see :func:`temporal.flow.flow_size`)."""
    return flow_size(width, height, long_side)


def default_K(width: int, height: int, hfov_deg: float = DEFAULT_HFOV_DEG) -> np.ndarray:
    """(3, 3) pinhole intrinsics in px for a ``width`` x ``height`` frame: principal point at
    the centre, focal length :func:`cues.focal_px` (``hfov_deg``, default 66 deg, across the long side)."""
    f = focal_px(max(width, height), hfov_deg)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------------------ geometry


def rays(h: int, w: int, K: np.ndarray) -> np.ndarray:
    """(3, h*w) float32 normalised rays K^-1 (x, y, 1) of every pixel (row-major)."""
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return _normalise(K, xs.ravel(), ys.ravel())


def _normalise(K: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    yn = (y - cy) / fy
    xn = (x - cx - s * yn) / fx
    return np.stack([xn, yn, np.ones_like(xn)]).astype(np.float32)


def triangulate(flow: np.ndarray, K: np.ndarray, R: np.ndarray, T: np.ndarray,
                step: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Depth of every pixel of view a from the flow a->b and the pose ``x_b = R x_a + T``.

    flow: (h, w, 2) px; K: (3, 3) px at that size; step: take every step-th pixel per axis.
    Returns (inverse depth (1/unit of |T|), triangulation angle (rad), epipolar distance of the
    flow's end point (px), in front of both cameras (bool)), each (h', w'). The depth along a's
    ray minimises the algebraic distance of its image in b to the flow's end point
    ``z (x_b x R x_a) + x_b x T = 0`` in least squares.
    """
    fl = flow[::step, ::step]
    h, w = fl.shape[:2]
    ys, xs = np.mgrid[0:flow.shape[0]:step, 0:flow.shape[1]:step].astype(np.float32)
    a = _normalise(K, xs.ravel(), ys.ravel())
    b = _normalise(K, (xs + fl[..., 0]).ravel(), (ys + fl[..., 1]).ravel())
    Ra = R.astype(np.float32) @ a
    tx, ty, tz = (float(v) for v in T)
    bx, by, bz = b[0], b[1], b[2]
    ax, ay, az = Ra[0], Ra[1], Ra[2]
    # c1 = b x Ra, c2 = b x T
    c1x, c1y, c1z = by * az - bz * ay, bz * ax - bx * az, bx * ay - by * ax
    c2x, c2y, c2z = by * tz - bz * ty, bz * tx - bx * tz, bx * ty - by * tx
    den = c1x * c1x + c1y * c1y + c1z * c1z
    num = -(c1x * c2x + c1y * c2y + c1z * c2z)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = den / num  # 1 / z
        z = 1.0 / q
        z2 = z * az + np.float32(tz)
        cosang = (ax * bx + ay * by + az * bz) / np.sqrt((ax * ax + ay * ay + az * az) * (bx * bx + by * by + bz * bz))
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        # epipolar line of a in b (normalised coords): l = T x Ra; distance in px (focal-scaled)
        lx, ly, lz = ty * az - tz * ay, tz * ax - tx * az, tx * ay - ty * ax
        f = np.float32(0.5 * (K[0, 0] + K[1, 1]))
        epi = np.abs(lx * bx + ly * by + lz * bz) / np.sqrt(lx * lx + ly * ly) * f
    front = (z > 0) & (z2 > 0) & np.isfinite(q)
    return (q.reshape(h, w).astype(np.float32), ang.reshape(h, w).astype(np.float32),
            epi.reshape(h, w).astype(np.float32), front.reshape(h, w))


def flow_samples(f_ab: np.ndarray, fb_a: np.ndarray, samples: int = POSE_SAMPLES) -> tuple[np.ndarray, np.ndarray] | None:
    """(N, 2) px correspondences a -> b from dense flow: about ``samples`` on a grid, where the
    forward-backward error ``fb_a`` is under FB_SAMPLE_PX and the end point lies inside (None:
    too few)."""
    h, w = f_ab.shape[:2]
    step = max(int(np.sqrt(h * w / samples)), 1)
    ys, xs = np.mgrid[step // 2:h:step, step // 2:w:step]
    fx, fy, e = f_ab[ys, xs, 0], f_ab[ys, xs, 1], fb_a[ys, xs]
    x2, y2 = xs + fx, ys + fy
    ok = (e < FB_SAMPLE_PX) & (x2 >= 0) & (x2 <= w - 1) & (y2 >= 0) & (y2 <= h - 1)
    if ok.sum() < MIN_TRACKS * 2:
        return None
    return (np.stack([xs[ok], ys[ok]], 1).astype(np.float64),
            np.stack([x2[ok], y2[ok]], 1).astype(np.float64))


def pose_from_flow(f_ab: np.ndarray, fb_a: np.ndarray, K: np.ndarray,
                   samples: int = POSE_SAMPLES) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """Relative pose ``x_b = R x_a + T`` (|T| = 1) from dense flow samples (:func:`flow_samples`):
    essential matrix by RANSAC (threshold E_THRESHOLD_PX), re-estimated on its inliers (LMedS),
    decomposed. Returns (R, T, median de-rotated parallax of the inliers in px, inlier ratio)
    or None (too few samples, degenerate)."""
    pts = flow_samples(f_ab, fb_a, samples)
    return None if pts is None else pose_from_points(*pts, K, refine=True)


def pose_from_points(p1: np.ndarray, p2: np.ndarray, K: np.ndarray, refine: bool = False,
                     threshold_px: float = E_THRESHOLD_PX) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """Relative pose ``x_b = R x_a + T`` (|T| = 1) from (N, 2) px correspondences: essential
    matrix by RANSAC, optionally re-estimated on (at most REFINE_SAMPLES of) its inliers by
    LMedS, decomposed (the solution with most inliers in front of both cameras). Returns (R, T, median de-rotated parallax of the inliers in px,
    inlier ratio) or None."""
    if len(p1) < MIN_TRACKS:
        return None
    try:
        E, mask = cv2.findEssentialMat(p1, p2, K, method=cv2.RANSAC, prob=0.999, threshold=threshold_px)
        if E is None or E.shape != (3, 3):
            return None
        inl = mask.ravel().astype(bool)
        if inl.sum() < MIN_TRACKS:
            return None
        if refine:
            sub = np.flatnonzero(inl)[::max(int(inl.sum()) // REFINE_SAMPLES, 1)]
            E2, _ = cv2.findEssentialMat(p1[sub], p2[sub], K, method=cv2.LMEDS, prob=0.99)
            # LMedS can lock onto a dominant plane (a small median, a large error elsewhere):
            # the re-estimate is kept only if it explains all the RANSAC inliers at least as well
            # (truncated squared Sampson distance, the MSAC score)
            if E2 is not None and E2.shape == (3, 3) and (
                    msac_score(E2, p1[inl], p2[inl], K, threshold_px) <= msac_score(E, p1[inl], p2[inl], K, threshold_px)):
                E = E2
        R1, R2, t = cv2.decomposeEssentialMat(E)
    except cv2.error:
        return None
    # the one of the four decompositions that puts the most inliers in front of both cameras
    # (cv2.recoverPose also drops points beyond 50 baselines: most of a distant scene)
    a = _normalise(K, p1[inl, 0], p1[inl, 1])
    b = _normalise(K, p2[inl, 0], p2[inl, 1])
    best = None
    for R in (R1, R2):
        for T in (t.ravel(), -t.ravel()):
            n = _in_front(a, b, R, T)
            if best is None or n > best[0]:
                best = (n, R, T)
    n, R, T = best
    if n < MIN_TRACKS:
        return None
    T = T / max(np.linalg.norm(T), 1e-12)
    return R, T, float(np.median(derotated_parallax(p1[inl], p2[inl], K, R))), float(inl.mean())


def sampson_px(E: np.ndarray, p1: np.ndarray, p2: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N,) Sampson distance (px, first-order geometric distance to the epipolar constraint of the
    essential matrix E) of (N, 2) px correspondences p1 -> p2 under intrinsics K."""
    a = _normalise(K, p1[:, 0], p1[:, 1]).astype(np.float64)
    b = _normalise(K, p2[:, 0], p2[:, 1]).astype(np.float64)
    Ea, Eb = E @ a, E.T @ b
    num = np.abs(np.sum(b * Ea, 0))
    den = np.sqrt(Ea[0] ** 2 + Ea[1] ** 2 + Eb[0] ** 2 + Eb[1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = num / den * 0.5 * (K[0, 0] + K[1, 1])
    return np.where(np.isfinite(d), d, np.inf)


def msac_score(E: np.ndarray, p1: np.ndarray, p2: np.ndarray, K: np.ndarray, threshold_px: float) -> float:
    """Mean of min(d, threshold)^2 over the correspondences, d their Sampson distance (px^2):
    lower explains them better (a far miss costs no more than the threshold)."""
    d = np.minimum(sampson_px(E, p1, p2, K), threshold_px)
    return float(np.mean(d * d))


def _in_front(a: np.ndarray, b: np.ndarray, R: np.ndarray, T: np.ndarray) -> int:
    """How many ray pairs (3, N) normalised triangulate in front of both cameras."""
    Ra = R.astype(np.float32) @ a
    tx, ty, tz = T.astype(np.float32).ravel()
    bx, by, bz = b[0], b[1], b[2]
    ax, ay, az = Ra[0], Ra[1], Ra[2]
    # c1 = b x Ra, c2 = b x T (written out: np.cross's axis handling costs more than the products)
    c1x, c1y, c1z = by * az - bz * ay, bz * ax - bx * az, bx * ay - by * ax
    c2x, c2y, c2z = by * tz - bz * ty, bz * tx - bx * tz, bx * ty - by * tx
    with np.errstate(divide="ignore", invalid="ignore"):
        z = -(c1x * c2x + c1y * c2y + c1z * c2z) / (c1x * c1x + c1y * c1y + c1z * c1z)
        z2 = z * az + tz
    return int(np.sum((z > 0) & (z2 > 0)))


def rotation_px(R: np.ndarray, K: np.ndarray) -> float:
    """How far (px) the rotation R alone moves the centre of the frame: focal length x angle."""
    return float(K[0, 0] * np.linalg.norm(cv2.Rodrigues(np.asarray(R, np.float64))[0]))


def derotated_parallax(p1: np.ndarray, p2: np.ndarray, K: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(N,) px between where the rotation alone sends each point of view a and where it is
    seen in view b: the parallax the translation makes (0 for a rotating camera)."""
    a = _normalise(K, p1[:, 0], p1[:, 1]).astype(np.float64)
    Ra = R @ a
    u = K[0, 0] * Ra[0] / Ra[2] + K[0, 1] * Ra[1] / Ra[2] + K[0, 2]
    v = K[1, 1] * Ra[1] / Ra[2] + K[1, 2]
    return np.hypot(u - p2[:, 0], v - p2[:, 1])


def homography_parallax(p1: np.ndarray, p2: np.ndarray) -> float:
    """Parallax a pair holds (px): the 90th percentile of the residuals a RANSAC homography
    leaves on the correspondences (a rotating camera or a plane leaves only noise)."""
    if len(p1) < MIN_TRACKS:
        return 0.0
    try:
        H, _ = cv2.findHomography(p1, p2, cv2.RANSAC, 1.0)
    except cv2.error:
        return 0.0
    if H is None:
        return 0.0
    pr = cv2.perspectiveTransform(p1.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    return float(np.percentile(np.hypot(*(pr - p2).T), 90))


def three_view_residual(pa: np.ndarray, pb: np.ndarray, pc: np.ndarray, K: np.ndarray) -> float | None:
    """How badly intrinsics K explain three views of the same (N, 2) px points: the pose of
    (a, c) from their essential matrix, the points triangulated from a and c, then placed in b
    by PnP (RANSAC); the mean reprojection error in b (px, each capped at 3). A wrong focal
    length distorts the two-view reconstruction, which the third view then cannot see
    consistently. None: too few points or a degenerate pose."""
    try:
        E, m = cv2.findEssentialMat(pa, pc, K, cv2.RANSAC, 0.999, 1.0)
        if E is None or E.shape != (3, 3):
            return None
        _, R, T, m2, _ = cv2.recoverPose(E, pa, pc, K, distanceThresh=1e6, mask=m.copy())
        inl = m2.ravel() > 0
        if inl.sum() < MIN_TRACKS:
            return None
        P1 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
        X = cv2.triangulatePoints(P1, K @ np.hstack([R, T]), pa[inl].T, pc[inl].T)
        X = (X[:3] / X[3]).T
        ok = np.isfinite(X).all(1) & (X[:, 2] > 0)
        X, ub = X[ok], pb[inl][ok]
        if len(X) < MIN_TRACKS:
            return None
        found, rv, tv, _ = cv2.solvePnPRansac(X, ub, K, None, reprojectionError=2.0, iterationsCount=100)
        if not found:
            return None
        pr, _ = cv2.projectPoints(X, rv, tv, K, None)
    except cv2.error:
        return None
    return float(np.mean(np.minimum(np.hypot(*(pr.reshape(-1, 2) - ub).T), 3.0)))


def refine_focal(triples: list, K: np.ndarray, run: "_Run") -> float | None:
    """Focal length (px at analysis size) that best explains the tracks of frame ``triples``
    [(a, b, c), ...] (:func:`three_view_residual`), searched on FOCAL_STEPS around K's (the
    guess) in FOCAL_STEP ratios with a parabola through the best three; each triple's curve is
    divided by its minimum and the curves averaged. The minimum's uncertainty comes from a
    bootstrap over the triples, and the answer is the guess and the minimum weighted by their
    inverse variances (a ragged curve, as lens distortion or a rolling shutter leave, barely
    moves the guess). None (keep the guess): fewer than FOCAL_MIN_TRIPLES triples, or under 1 %
    of change."""
    f0 = float(K[0, 0])
    fs = f0 * FOCAL_STEP ** np.arange(FOCAL_STEPS[0], FOCAL_STEPS[1] + 1)
    curves = []
    for a, b, c in triples:
        ids = np.intersect1d(np.intersect1d(a.ids, b.ids, assume_unique=True), c.ids, assume_unique=True)
        if len(ids) < 2 * MIN_TRACKS:
            continue
        pa, pb, pc = (f.pts[np.searchsorted(f.ids, ids)].astype(np.float64) for f in (a, b, c))
        row = []
        for f in fs:
            Kf = K.copy()
            Kf[0, 0] = Kf[1, 1] = f
            row.append(three_view_residual(pa, pb, pc, Kf))
        if any(r is None for r in row) or min(row) <= 0:
            continue
        curves.append(np.array(row) / min(row))
    if len(curves) < FOCAL_MIN_TRIPLES:
        return None
    curves = np.array(curves)
    log_fs = np.log(fs)
    best = _argmin_log(np.mean(curves, 0), log_fs)
    # uncertainty of that minimum: bootstrap over the triples (lens distortion, a rolling shutter
    # or too little rotation leave a flat or ragged curve whose minimum wanders)
    rng = np.random.default_rng(0)
    boot = [_argmin_log(np.mean(curves[rng.integers(0, len(curves), len(curves))], 0), log_fs)
            for _ in range(FOCAL_BOOTSTRAP)]
    var = max(float(np.var(boot)), 0.02 ** 2)
    # shrink toward the guess by the two uncertainties (the guess's: FOCAL_PRIOR_SIGMA)
    w = FOCAL_PRIOR_SIGMA ** 2 / (FOCAL_PRIOR_SIGMA ** 2 + var)
    f = float(np.exp(np.log(f0) + w * (best - np.log(f0))))
    return None if abs(np.log(f / f0)) < 0.01 else f


def _argmin_log(curve: np.ndarray, log_fs: np.ndarray) -> float:
    """log focal length at the minimum of a curve sampled on ``log_fs`` (a parabola through the
    best three samples; the end sample where the minimum is at an end)."""
    g = int(np.argmin(curve))
    if not 0 < g < len(curve) - 1:
        return float(log_fs[g])
    lo, mid, hi = np.log(curve[g - 1:g + 2])
    den = lo - 2 * mid + hi
    d = 0.5 * (lo - hi) / den if den > 0 else 0.0
    return float(log_fs[g] + np.clip(d, -0.5, 0.5) * (log_fs[1] - log_fs[0]))


# ------------------------------------------------------------------------------ helpers


def _soft(x: np.ndarray, tol: np.ndarray | float) -> np.ndarray:
    """1 up to half the tolerance, 0 beyond 1.5 tolerances, linear between."""
    return np.clip(1.5 - x / tol, 0.0, 1.0)


def _median_stack(values: np.ndarray) -> np.ndarray:
    """Median over axis 0 of a small (k, N) stack with NaNs (NaN where all are NaN)."""
    k = values.shape[0]
    if k == 1:
        return values[0]
    if k == 2:
        a, b = values
        return np.where(np.isfinite(a), np.where(np.isfinite(b), 0.5 * (a + b), a), b)
    s = np.sort(values, axis=0)  # NaNs last
    n = np.sum(np.isfinite(values), axis=0)
    lo = np.clip((n - 1) // 2, 0, k - 1)
    hi = np.clip(n // 2, 0, k - 1)
    m = 0.5 * (np.take_along_axis(s, lo[None], 0)[0] + np.take_along_axis(s, hi[None], 0)[0])
    m[n == 0] = np.nan
    return m


def group_median(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median of ``values`` (N,) per distinct key of ``keys`` (N,) (non-empty): (the sorted
    distinct keys, their medians), as ``np.median`` of each group gives them, in one sort."""
    order = np.lexsort((values, keys))
    k, v = keys[order], values[order]
    uniq, start, count = np.unique(k, return_index=True, return_counts=True)
    lo, hi = start + (count - 1) // 2, start + count // 2
    return uniq, 0.5 * (v[lo] + v[hi])


def _median_ratio(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """Median of a / b over ``mask`` where both are finite and positive (None: < 50 pixels)."""
    ok = mask & np.isfinite(a) & np.isfinite(b) & (a > 0) & (b > 0)
    if ok.sum() < 50:
        return None
    return float(np.exp(np.median(np.log(a[ok]) - np.log(b[ok]))))


def upsample(q: np.ndarray, conf: np.ndarray, full_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Inverse depth and confidence from analysis size to ``full_size`` = (W, H): inverse depth
    bilinear over the known pixels (normalised convolution), confidence nearest; NaN and 0
    where either says nothing."""
    if (q.shape[1], q.shape[0]) == tuple(full_size):
        out_q, out_c = q.copy(), conf.copy()
    else:
        known = (conf > 0) & np.isfinite(q)
        num = cv2.resize(np.where(known, q, 0).astype(np.float32), full_size, interpolation=cv2.INTER_LINEAR)
        den = cv2.resize(known.astype(np.float32), full_size, interpolation=cv2.INTER_LINEAR)
        out_c = cv2.resize(conf.astype(np.float32), full_size, interpolation=cv2.INTER_NEAREST)
        with np.errstate(divide="ignore", invalid="ignore"):
            out_q = num / den
        out_q[den < 1e-3] = np.nan
    bad = ~np.isfinite(out_q) | (out_c <= 0)
    out_q[bad] = np.nan
    out_c[bad] = 0.0
    return out_q.astype(np.float32), np.clip(out_c, 0, 1).astype(np.float32)


# ------------------------------------------------------------------------------ the estimator


class ParallaxEstimator:
    """Streaming parallax cue (module docstring).

    analysis_long_side: px of the analysis size's long side; window: W, frames looked at
    behind and ahead; K: (3, 3) intrinsics in px of the full frames (None: :func:`default_K`);
    per_side: neighbours chosen behind and ahead (1-2); target_parallax_px: the median
    de-rotated parallax of the tracks (px at analysis size) a neighbour should reach (the
    nearest that does is taken, else the one with the most); min_parallax_px: the homography
    residual (px) under which a pair counts as rotation only / a plane; preset: the pairs' DIS preset (the
    memory's flows: MEMORY_FLOW_PRESET);
    refine_focal: without K, pick the focal length from the clip's first frames
    (:func:`refine_focal`) instead of keeping the 66 deg guess; flow_finest_scale: the finest
    pyramid level DIS refines its flow to (0: the analysis size itself; None: the preset's own,
    1 for "medium", half the analysis size; see :class:`PairFlow`); share_pairs: behind, prefer
    an earlier frame whose pair with t is computed already (:meth:`_Run._shared_behind`);
    photometric_check: lower the confidence where a plane sweep of t's neighbours contradicts
    the flow's depth (:mod:`.sweep`, step 6b of the module docstring).
    """

    def __init__(self, analysis_long_side: int = 640, window: int = 8, K: np.ndarray | None = None,
                 per_side: int = 1, target_parallax_px: float = 5.0, min_parallax_px: float = 0.3,
                 preset: str = "medium", refine_focal: bool = True,
                 flow_finest_scale: int | None = FLOW_FINEST_SCALE, share_pairs: bool = True,
                 photometric_check: bool = True) -> None:
        if window < 1:
            raise ValueError(f"ParallaxEstimator: window must be >= 1, got {window}")
        self.analysis_long_side = int(analysis_long_side)
        self.window = int(window)
        self.K = None if K is None else np.asarray(K, np.float64)
        self.per_side = int(per_side)
        self.target_parallax_px = float(target_parallax_px)
        self.min_parallax_px = float(min_parallax_px)
        self.preset = preset
        self.refine_focal = bool(refine_focal)
        self.flow_finest_scale = flow_finest_scale
        self.share_pairs = bool(share_pairs)
        self.photometric_check = bool(photometric_check)

    # ---------------------------------------------------------------- public API

    def maps(self, frames: Iterable[np.ndarray]) -> Iterator[CueMap]:
        """One :class:`CueMap` per input frame ((H, W, 3) uint8 RGB), in order; frame t is
        yielded once frame t + window has been read (or the clip ended). The clip's first maps
        are held back until CLIP_SNR_MIN_FRAMES frames have a signal to noise (at most
        GATE_HOLD_FRAMES maps): the clip's gate (:func:`clip_gate`) then applies to them too
        (:func:`start_gate`), so the frames before the clip can be judged do not hand the
        fusion noise the clip's later frames are found to be."""
        run = _Run(self)
        buf: list[_Frame] = []
        held: list[CueMap] = []
        done = 0  # index of the next frame to output
        calibrate = self.K is None and self.refine_focal
        n_cal = max(2 * self.window + 1, CAL_FRAMES)

        def emit(m: CueMap | None) -> list[CueMap]:
            if m is not None:
                if not held and len(run.snrs) >= CLIP_SNR_MIN_FRAMES:
                    return [m]  # the gate is running: output() applied it
                held.append(m)
                if len(run.snrs) < CLIP_SNR_MIN_FRAMES and len(held) < GATE_HOLD_FRAMES:
                    return []
            out = [_gated(x, start_gate(run.snrs)) for x in held]
            held.clear()
            return out

        for i, frame in enumerate(frames):
            buf.append(run.add(i, frame, buf[-1] if buf else None))
            if calibrate:
                if len(buf) < n_cal:
                    continue
                run.refine_focal(buf)
                calibrate = False
            while done + self.window <= buf[-1].index:
                yield from emit(run.output(buf, done - buf[0].index))
                done += 1
                while buf[0].index < done - self.window:
                    run.forget(buf.pop(0).index)
        if calibrate and buf:
            run.refine_focal(buf)
        while buf and done <= buf[-1].index:
            yield from emit(run.output(buf, done - buf[0].index))
            done += 1
        yield from emit(None)

    def camera_translates(self, frames: Iterable[np.ndarray], max_frames: int = 60,
                          exclude: Callable[[np.ndarray], np.ndarray | None] | None = None) -> tuple[bool, str]:
        """Cheap clip-level check from the tracks alone (no dense flow): does the camera move
        with enough baseline for parallax anywhere in the first ``max_frames`` frames?
        ``exclude``: frame -> (H, W) bool mask of pixels whose tracks do not count (the people:
        a talking head in front of a flat backdrop moves every track there is, and that is no
        baseline), or None. Returns (translates, reason)."""
        run = _Run(self)
        buf: list[_Frame] = []
        best, moved, texture = 0.0, 0.0, False
        for i, frame in enumerate(frames):
            if i >= max_frames:
                break
            mask = exclude(frame) if exclude is not None else None
            buf.append(run.add(i, frame, buf[-1] if buf else None, mask))
            buf = buf[-(self.window + 1):]
            texture |= len(buf[-1].ids) >= MIN_TRACKS
            moved = max(moved, buf[-1].motion_px)
            if len(buf) > 1 and run.track_shift(buf[0], buf[-1]) >= STILL_SHIFT_PX:
                best = max(best, run.track_parallax(buf[0], buf[-1]))
            if best >= self.target_parallax_px:
                break
        if not buf:
            return False, "empty clip"
        if len(buf) == 1 and i == 0:
            return False, "one frame: no second view"
        ok, reason = _judge(best, moved, texture, self.min_parallax_px)
        return ok, (f"parallax {best:.1f} px" if ok else reason)


def _judge(parallax: float, moved: float, texture: bool, min_px: float) -> tuple[bool, str]:
    if not texture:
        return False, "no texture to track (flat or dark frames)"
    if parallax >= min_px:
        return True, "parallax"
    if moved < 0.3:
        return False, "still camera"
    return False, "rotation only or a planar scene: no baseline"


class _Run:
    """The state of one pass over a clip (tracks, flows, output maps): never shared."""

    def __init__(self, est: ParallaxEstimator) -> None:
        self.est = est
        self.dis = PairFlow(est.preset, est.flow_finest_scale)
        self.dis_memory = PairFlow(MEMORY_FLOW_PRESET, None, None)  # the memory's flows: the reprojection test checks them
        self.size: tuple[int, int] | None = None
        self.K: np.ndarray | None = None
        self.next_id = 0
        self.pairs: OrderedDict[tuple[int, int], _Pair | None] = OrderedDict()
        self.epoch = 0  # the current scale chain (a new one starts where the scale is reset)
        self.focal_refined = False
        self.unstable = 0  # pairs of the current output frame dropped for too much rotation
        self.ratios: list[float] = []  # parallax / rotation flow of the current frame's pairs
        self.snrs: list[float] = []  # every output frame's signal to noise so far (the clip's gate)

    # ---------------------------------------------------------------- per input frame

    def add(self, i: int, frame: np.ndarray, prev: _Frame | None, exclude: np.ndarray | None = None) -> _Frame:
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"parallax: frame {i} must be (H, W, 3) RGB, got {frame.shape}")
        full = (int(frame.shape[1]), int(frame.shape[0]))
        if self.size is None:
            self.full = full
            self.size = analysis_size(full[0], full[1], self.est.analysis_long_side)
            K = default_K(*full) if self.est.K is None else self.est.K
            self.K = scale_K(K, full, self.size)
        elif full != self.full:
            raise ValueError(f"parallax: frame {i} is {full[0]}x{full[1]} but the clip's first frame is "
                             f"{self.full[0]}x{self.full[1]}; a clip keeps one resolution")
        fr = _Frame(i, to_flow_gray(frame, self.size), full)
        keep = None
        if exclude is not None and exclude.any():
            keep = cv2.resize((~exclude.astype(bool)).astype(np.uint8), self.size, interpolation=cv2.INTER_NEAREST)
        self._track(prev, fr, keep)
        return fr

    def _track(self, prev: _Frame | None, fr: _Frame, keep: np.ndarray | None = None) -> None:
        """Track prev's corners into fr and top up new ones; ``keep`` (analysis size, 1 = usable):
        tracks outside it are dropped and no corner is started there."""
        ids, pts = np.zeros(0, np.int64), np.zeros((0, 2), np.float32)
        if prev is not None and len(prev.ids):
            p0 = prev.pts.reshape(-1, 1, 2)
            lk = dict(winSize=(21, 21), maxLevel=3,
                      criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
            p1, st, _ = cv2.calcOpticalFlowPyrLK(prev.gray, fr.gray, p0, None, **lk)
            pb, st2, _ = cv2.calcOpticalFlowPyrLK(fr.gray, prev.gray, p1, None, **lk)
            h, w = fr.gray.shape
            p1 = p1.reshape(-1, 2)
            good = ((st.ravel() == 1) & (st2.ravel() == 1) & (np.hypot(*(pb.reshape(-1, 2) - prev.pts).T) < 0.7)
                    & (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1))
            if keep is not None:
                xi = np.clip(np.rint(p1[:, 0]), 0, w - 1).astype(int)
                yi = np.clip(np.rint(p1[:, 1]), 0, h - 1).astype(int)
                good &= keep[yi, xi] > 0
            ids, pts = prev.ids[good], p1[good].astype(np.float32)
            if good.any():
                fr.motion_px = float(np.median(np.hypot(*(pts - prev.pts[good]).T)))
        if len(ids) < 0.7 * MAX_CORNERS:
            mask = np.full(fr.gray.shape, 255, np.uint8) if keep is None else (keep > 0).astype(np.uint8) * 255
            for x, y in pts.astype(int):
                cv2.circle(mask, (int(x), int(y)), 7, 0, -1)
            new = cv2.goodFeaturesToTrack(fr.gray, MAX_CORNERS - len(ids), 0.01, 7, mask=mask, blockSize=5)
            if new is not None and len(new):
                new = new.reshape(-1, 2).astype(np.float32)
                ids = np.concatenate([ids, np.arange(self.next_id, self.next_id + len(new))])
                pts = np.concatenate([pts, new])
                self.next_id += len(new)
        fr.ids, fr.pts = ids, pts

    def refine_focal(self, buf: list[_Frame]) -> None:
        """Replace the guessed focal length by :func:`refine_focal`'s on the buffered frames."""
        triples = []
        for o in range(0, len(buf) - 2, 2):  # (a, b, c): c the first with CAL_PARALLAX_PX, b between
            for k in range(o + 2, len(buf)):
                if self.track_parallax(buf[o], buf[k]) >= CAL_PARALLAX_PX:
                    triples.append((buf[o], buf[(o + k) // 2], buf[k]))
                    break
        f = refine_focal(triples, self.K, self)
        if f is not None:
            self.K = self.K.copy()
            self.K[0, 0] = self.K[1, 1] = f
            self.focal_refined = True

    def forget(self, index: int) -> None:
        for key in [k for k in self.pairs if index in k]:
            del self.pairs[key]

    # ---------------------------------------------------------------- pairs

    def track_parallax(self, a: _Frame, b: _Frame) -> float:
        """Homography residual (px) of the tracks a and b share (0: too few)."""
        p1, p2 = self._common(a, b)
        return homography_parallax(p1, p2) if p1 is not None else 0.0

    def track_shift(self, a: _Frame, b: _Frame) -> float:
        """Lower-quartile displacement (px) of the tracks a and b share (0: too few). A still
        camera keeps the background in place even where people move (their residual is no
        baseline); a moving camera moves nearly every track."""
        p1, p2 = self._common(a, b)
        return float(np.percentile(np.hypot(*(p2 - p1).T), 25)) if p1 is not None else 0.0

    def _common(self, a: _Frame, b: _Frame) -> tuple[np.ndarray | None, np.ndarray | None]:
        _, ia, ib = np.intersect1d(a.ids, b.ids, assume_unique=True, return_indices=True)
        if len(ia) < MIN_TRACKS:
            return None, None
        return a.pts[ia].astype(np.float64), b.pts[ib].astype(np.float64)

    def track_score(self, a: _Frame, b: _Frame) -> tuple[float, float]:
        """(homography residual, median de-rotated parallax) in px of the tracks a and b share;
        the second is 0 unless the first shows parallax (no pose from a rotation or a plane)."""
        p1, p2 = self._common(a, b)
        if p1 is None:
            return 0.0, 0.0
        h = homography_parallax(p1, p2)
        if h < self.est.min_parallax_px:
            return h, 0.0
        pose = pose_from_points(p1, p2, self.K, threshold_px=1.0)
        return h, (0.0 if pose is None else pose[2])

    def pair(self, a: _Frame, b: _Frame) -> _Pair | None:
        """Dense geometry of (a, b) (cached; the reverse pair reuses the flows)."""
        key = (a.index, b.index)
        if key in self.pairs:
            return self.pairs[key]
        rev = self.pairs.get((b.index, a.index))
        if rev is not None:
            f_ab, f_ba, fb_a, fb_b = rev.f_ba, rev.f_ab, rev.fb_b, rev.fb_a
        else:
            f_ab = self.dis(a.gray, b.gray)
            f_ba = self.dis(b.gray, a.gray)
            fb_a, fb_b = fb_error(f_ab, f_ba), fb_error(f_ba, f_ab)
        p = _Pair(f_ab, f_ba, fb_a, fb_b)
        if rev is not None and rev.R is not None:
            p.R = rev.R.T
            p.T = -rev.R.T @ rev.T
            p.parallax_px, p.inlier_ratio = rev.parallax_px, rev.inlier_ratio
        else:
            pose = pose_from_flow(f_ab, fb_a, self.K)
            if pose is not None:
                p.R, p.T, p.parallax_px, p.inlier_ratio = pose
        self.pairs[key] = p
        return p

    def _pair_map(self, a: _Frame, p: _Pair, step: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw inverse depth (1/|T|), confidence and angle of pair p in view a."""
        q, ang, epi, front = triangulate(p.f_ab, self.K, p.R, p.T, step)
        fb = p.fb_a[::step, ::step]
        fl = p.f_ab[::step, ::step]
        mag = np.sqrt(fl[..., 0] ** 2 + fl[..., 1] ** 2)
        par_px = ang * np.float32(self.K[0, 0])
        c = (_soft(fb, FB_TOL_PX + FB_TOL_RELATIVE * mag) * _soft(epi, EPI_TOL_PX)
             * np.clip((par_px - ANGLE_MIN_PX) / (ANGLE_FULL_PX - ANGLE_MIN_PX), 0, 1))
        h, w = p.f_ab.shape[:2]
        ys, xs = np.mgrid[0:h:step, 0:w:step]
        x2, y2 = xs + p.f_ab[::step, ::step, 0], ys + p.f_ab[::step, ::step, 1]
        inside = (x2 >= 0) & (x2 <= w - 1) & (y2 >= 0) & (y2 <= h - 1)
        c = np.where(front & inside & (q > 0) & (q < Q_MAX), c, 0).astype(np.float32)
        ok = c > 0.5
        if ok.sum() >= 100:  # a spike far nearer than the bulk of the frame: a flow error
            c = np.where(q <= SPIKE_RATIO * np.percentile(q[ok], 95), c, 0).astype(np.float32)
        q = np.where(c > 0, q, np.nan).astype(np.float32)
        return q, c, ang

    # ---------------------------------------------------------------- scale from the tracks

    def _keep_track_depth(self, t: _Frame) -> None:
        """Remember the output inverse depth of t at its tracks on trusted pixels."""
        h, w = t.q.shape
        xi = np.clip(np.rint(t.pts[:, 0]).astype(int), 0, w - 1)
        yi = np.clip(np.rint(t.pts[:, 1]).astype(int), 0, h - 1)
        q, c = t.q[yi, xi], t.conf[yi, xi]
        ok = np.isfinite(q) & (c > 0.5) & (q > 0)
        t.tq_ids, t.tq = t.ids[ok], q[ok].astype(np.float64)

    def _pnp(self, n: _Frame, t: _Frame) -> tuple | None:
        """Pose of t in the clip's unit from n's tracks with trusted inverse depth (PnP, RANSAC,
        refined): (X (k, 3) n's points, indices of their tracks in t, inlier indices, R, T) with
        ``X_t = R X_n + T``, or None (another chain, or fewer than MIN_SCALE_TRACKS)."""
        if n.tq_ids is None or n.epoch != self.epoch or len(n.tq_ids) < MIN_SCALE_TRACKS:
            return None
        _, ia, ib = np.intersect1d(n.tq_ids, t.ids, assume_unique=True, return_indices=True)
        if len(ia) < MIN_SCALE_TRACKS:
            return None
        _, ja, _ = np.intersect1d(n.ids, n.tq_ids[ia], assume_unique=True, return_indices=True)
        # n.tq_ids is a subset of n.ids in the same order, so ja follows ia's order
        X = (_normalise(self.K, n.pts[ja, 0], n.pts[ja, 1]).astype(np.float64) / n.tq[ia]).T
        uv = t.pts[ib].astype(np.float64)
        try:
            ok, rvec, tvec, inl = cv2.solvePnPRansac(X, uv, self.K, None, iterationsCount=100,
                                                     reprojectionError=PNP_THRESHOLD_PX, confidence=0.99,
                                                     flags=cv2.SOLVEPNP_EPNP)
        except cv2.error:
            return None
        if not ok or inl is None or len(inl) < MIN_SCALE_TRACKS:
            return None
        inl = inl.ravel()
        try:
            rvec, tvec = cv2.solvePnPRefineLM(X[inl], uv[inl], self.K, None, rvec, tvec)
        except cv2.error:
            pass
        return X, ib, inl, cv2.Rodrigues(rvec)[0], tvec.reshape(3)

    def _track_prediction(self, buf: list[_Frame], c: int, poses: dict | None = None
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Inverse depth (clip unit) of t's tracks predicted by every earlier output frame n of
        the chain in the window: n's map makes its tracks 3-D points, PnP (RANSAC) on their
        positions in t gives t's pose in the clip's unit, the points' depth in t follows; per
        track the median over the frames n. Returns (x, y) pixel indices in t and the inverse
        depths, or None (fewer than MIN_SCALE_TRACKS). ``poses``, if given, receives t's pose
        from each such frame n: ``{n index in buf: (R, T)}``."""
        t = buf[c]
        ids_all, q_all = [], []
        for k, n in enumerate(buf[:c]):
            found = self._pnp(n, t)
            if found is None:
                continue
            X, ib, inl, R, T = found
            if poses is not None:
                poses[k] = (R, T)
            z = (X[inl] @ R.T + T.reshape(1, 3))[:, 2]
            good = z > 0
            ids_all.append(t.ids[ib][inl][good])
            q_all.append(1.0 / z[good])
        if not ids_all:
            return None
        uniq, qm = group_median(np.concatenate(ids_all), np.concatenate(q_all))
        if len(uniq) < MIN_SCALE_TRACKS:
            return None
        _, it, _ = np.intersect1d(t.ids, uniq, assume_unique=True, return_indices=True)
        h, w = t.gray.shape
        xi = np.clip(np.rint(t.pts[it, 0]).astype(int), 0, w - 1)
        yi = np.clip(np.rint(t.pts[it, 1]).astype(int), 0, h - 1)
        return xi, yi, qm

    # ---------------------------------------------------------------- per output frame

    def _choose(self, buf: list[_Frame], c: int) -> tuple[list[tuple[int, float]], float]:
        t = buf[c]
        chosen: list[tuple[int, float]] = []
        best = 0.0
        for side in (-1, 1):
            if side < 0 and self.est.share_pairs:
                shared, h_max = self._shared_behind(buf, c)
                best = max(best, h_max)
                if shared:
                    chosen += shared
                    continue
            scored = []
            for k in range(1, self.est.window + 1):
                j = c + side * k
                if not 0 <= j < len(buf):
                    break
                h, par = self.track_score(t, buf[j])
                best = max(best, h)
                if h >= self.est.min_parallax_px and par >= MIN_DENSE_PARALLAX_PX:
                    scored.append((j, par))
                if sum(x[1] >= self.est.target_parallax_px for x in scored) >= self.est.per_side:
                    break
            good = [x for x in scored if x[1] >= self.est.target_parallax_px]
            pick = good[:self.est.per_side] if good else sorted(scored, key=lambda x: -x[1])[:self.est.per_side]
            chosen += pick
        return chosen, best

    def _shared_behind(self, buf: list[_Frame], c: int) -> tuple[list[tuple[int, float]], float]:
        """t's behind neighbours whose pair with t is computed already (an earlier frame chose t as
        its neighbour ahead: the flows both ways and the pose are reused) and whose tracks reach
        the target parallax as seen from t, nearest first: per_side of them, else none (the usual
        scan decides). Also the largest homography residual (px) seen."""
        t = buf[c]
        out: list[tuple[int, float]] = []
        best = 0.0
        for k in range(1, self.est.window + 1):
            j = c - k
            if j < 0:
                break
            p = self.pairs.get((buf[j].index, t.index))
            if p is None or p.R is None or p.parallax_px < MIN_DENSE_PARALLAX_PX:
                continue
            h, par = self.track_score(t, buf[j])
            best = max(best, h)
            if h >= self.est.min_parallax_px and par >= self.est.target_parallax_px:
                out.append((j, par))
                if len(out) >= self.est.per_side:
                    return out, best
        return [], best

    def _add_map(self, maps: list, t: _Frame, buf: list[_Frame], j: int) -> None:
        p = self.pair(t, buf[j])
        if p is None or p.R is None or p.parallax_px < MIN_DENSE_PARALLAX_PX:
            return
        # errors that grow with the rotation (a rolling shutter, a focal length or lens
        # distortion off, the frames' timing) leave false parallax in proportion to the flow the
        # rotation makes: the pair's parallax must dominate it
        lo, hi = ROT_RATIO
        ratio = p.parallax_px / max(rotation_px(p.R, self.K), 1e-6)
        self.ratios.append(round(float(ratio), 3))
        f_r = float(np.clip((ratio - lo) / (hi - lo), 0.0, 1.0))
        if f_r <= 0:
            self.unstable += 1
            return
        q, conf, ang = self._pair_map(t, p)
        conf = conf * np.float32(f_r)
        if (conf > 0.5).sum() >= 100:
            maps.append((j, q, conf, ang, p))

    def _propagate(self, buf: list[_Frame], c: int, poses: dict) -> tuple | None:
        """The earlier output frames' maps carried into t (the scale chain's memory): per frame n
        with t's pose from n (PnP, ``poses``), t's flow into n samples n's inverse depth, the
        3-D point moves by the pose into t and must reproject onto the pixel it came from (a
        point n got wrong, or one that moved, does not). Returns (q, chain confidence, cue
        confidence) at analysis size, fused over the PROPAGATE_FRAMES latest such n, or None."""
        t = buf[c]
        h, w = t.gray.shape
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
        Qs, Cs, CCs = [], [], []
        for k in sorted(poses, reverse=True)[:PROPAGATE_FRAMES]:
            n = buf[k]
            if n.q is None or n.cc is None:
                continue
            R, T = poses[k]
            if (t.index, n.index) in self.pairs or (n.index, t.index) in self.pairs:
                p = self.pair(t, n)  # cached: flows both ways
                f, fb = p.f_ab, p.fb_a
            else:  # one flow; the reprojection test below rejects what it gets wrong
                f, fb = self.dis_memory(t.gray, n.gray), None
            mx, my = xs + f[..., 0], ys + f[..., 1]
            qs = cv2.remap(np.where(n.conf > 0, n.q, np.nan).astype(np.float32), mx, my, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))
            ray = _normalise(self.K, mx.ravel(), my.ravel())
            with np.errstate(divide="ignore", invalid="ignore"):
                Xt = R.astype(np.float32) @ (ray / qs.ravel()[None]) + T.astype(np.float32)[:, None]
                zt = Xt[2]
                u = self.K[0, 0] * Xt[0] / zt + self.K[0, 2]
                v = self.K[1, 1] * Xt[1] / zt + self.K[1, 2]
                err = np.hypot(u - xs.ravel(), v - ys.ravel()).reshape(h, w)
                qt = (1.0 / zt).reshape(h, w)
            ok = np.isfinite(qt) & (qt > 0) & (qt < Q_MAX) & np.isfinite(err)
            g = _soft(np.where(ok, err, 1e9), REPROJECT_TOL_PX) * np.float32(PROPAGATE_DECAY)
            if fb is not None:
                g = g * _soft(fb, FB_TOL_PX + FB_TOL_RELATIVE * np.sqrt(f[..., 0] ** 2 + f[..., 1] ** 2))
            g = np.where(ok, g, 0.0).astype(np.float32)
            for conf, out in ((n.conf, Cs), (n.cc, CCs)):
                out.append(g * cv2.remap(conf.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=0.0))
            Qs.append(np.where(g > 0, qt, np.nan).astype(np.float32))
        if not Qs:
            return None
        Q, C = np.stack(Qs), np.stack(Cs)
        sw = C.sum(0)
        with np.errstate(invalid="ignore", divide="ignore"):
            q = (np.nan_to_num(Q) * C).sum(0) / sw
        q = np.where(sw > 1e-6, q, np.nan).astype(np.float32)
        return q, np.clip(C.max(0), 0, 1).astype(np.float32), np.clip(np.stack(CCs).max(0), 0, 1).astype(np.float32)

    def output(self, buf: list[_Frame], c: int) -> CueMap:
        t = buf[c]
        if len(buf) < 2:
            return _empty(t.full_size, "one frame: no second view")
        poses: dict = {}
        cur, why, best = self._current(buf, c, poses)
        prop = self._propagate(buf, c, poses) if PROPAGATE_FRAMES > 0 else None
        if cur is None and prop is None:
            return _empty(t.full_size, why, track_parallax_px=round(best, 2))
        if cur is None:
            q_chain, c_chain, c_cue = prop
            info = {"parallax": True, "neighbours": [], "reason": "carried from earlier frames (" + why + ")",
                    "scale_reset": False, "propagated": True}
        else:
            q_out, c_out, f_snr, info = cur
            q_chain, c_chain = q_out, c_out
            c_cue = (c_out * np.float32(f_snr)).astype(np.float32)
            if prop is not None and not info["scale_reset"]:
                both = (c_out > 0.5) & (prop[1] > 0.5) & np.isfinite(q_out) & np.isfinite(prop[0])
                if both.sum() >= 100:
                    info["memory_disagreement"] = round(float(np.median(np.abs(np.log(prop[0][both] / q_out[both])))), 4)
                q_chain, c_chain, c_cue = _merge(q_out, c_out, prop[0], prop[1], c_cue, prop[2] * np.float32(0.5 + 0.5 * f_snr))
                info["propagated"] = True
        t.q, t.conf, t.epoch, t.cc = q_chain, c_chain, self.epoch, c_cue
        self._keep_track_depth(t)
        if cur is not None and info.get("snr") is not None:
            self.snrs.append(float(info["snr"]))
        gate = clip_gate(self.snrs)
        info["clip_snr"] = round(float(np.median(self.snrs)), 3) if self.snrs else None
        if gate < 1.0:
            c_cue = (c_cue * np.float32(gate)).astype(np.float32)
            info["clip_gate"] = round(gate, 3)
        q_full, c_full = upsample(q_chain, c_cue, t.full_size)
        return CueMap(NAME, q_full, c_full, metric=False, shift_free=True, info=info)

    def _current(self, buf: list[_Frame], c: int, poses: dict) -> tuple[tuple | None, str, float]:
        """t's own map from its chosen neighbours: ((q, geometric confidence, signal-to-noise
        factor, info) or None, why not, best track parallax px). Fills ``poses`` (t's pose from
        the earlier output frames) on the way."""
        t = buf[c]
        chosen, best = self._choose(buf, c)
        texture = len(t.ids) >= MIN_TRACKS
        moved = max(f.motion_px for f in buf)
        pred = self._track_prediction(buf, c, poses)
        if not chosen:
            ok, why = _judge(best, moved, texture, self.est.min_parallax_px)
            if ok:  # a homography does not explain the tracks, but the de-rotated parallax is tiny
                why = f"parallax under {MIN_DENSE_PARALLAX_PX} px once the rotation is removed: no baseline"
            return None, why, best
        maps = []  # (j, q_raw, conf, angle, pair)
        self.unstable = 0
        self.ratios = []
        for j, _ in chosen:
            self._add_map(maps, t, buf, j)
        if maps and pred is None and not any(buf[j].q is not None and buf[j].epoch == self.epoch for j, *_ in maps):
            # no chosen neighbour carries the clip's unit: anchor on the earliest output frame
            # of the same chain in the window, which also joins the fusion
            prior = [j for j in range(c)
                     if buf[j].q is not None and buf[j].epoch == self.epoch and j not in dict(chosen)]
            if prior:  # the earliest: the longest baseline, mostly
                self._add_map(maps, t, buf, prior[0])
        if not maps:
            why = ("translation too weak against the rotation (rotation-borne errors would dominate)" if self.unstable
                   else "flow or pose failed on every neighbour (no rigid parallax)")
            return None, why, best
        # scale: from the tracks' inverse depth predicted by the earlier output frames, else
        # anchor on a neighbour already output in the clip's unit
        scales: dict[int, float] = {}
        spreads: dict[int, float] = {}  # MAD of log(pair / prediction) at the tracks
        if pred is not None:
            xi, yi, qp = pred
            for j, q, conf, ang, p in maps:
                qr = q[yi, xi]
                ok = np.isfinite(qr) & (conf[yi, xi] > 0.5)
                if ok.sum() >= MIN_SCALE_TRACKS:
                    lr = np.log(qr[ok]) - np.log(qp[ok])
                    scales[j] = float(np.exp(np.median(lr)))
                    spreads[j] = float(np.median(np.abs(lr - np.median(lr))))
        for j, q, conf, ang, p in maps:
            n = buf[j]
            if j in scales or n.q is None or n.epoch != self.epoch:
                continue
            back = self.pair(n, t)
            if back is None or back.R is None:
                continue
            qn, cn, _ = self._pair_map(n, back, step=2)
            r = _median_ratio(qn, n.q[::2, ::2], (cn > 0.25) & (n.conf[::2, ::2] > 0.5))
            if r is not None:
                scales[j] = r
        ref = max(maps, key=lambda m: (m[0] in scales, float((m[2] > 0.5).sum())))
        if ref[0] in scales:
            unit, reset = scales[ref[0]], False
        else:
            med = float(np.nanmedian(ref[1][ref[2] > 0.5]))
            unit, reset = med, True
            self.epoch += 1
        qs, cs = [], []
        views = []  # (gray, R, T in the clip's unit) of the neighbours fused, for the sweep
        for j, q, conf, ang, p in maps:
            if j == ref[0]:
                r = unit
            elif j in scales:
                r = scales[j]
            else:
                r = _median_ratio(q, ref[1], (conf > 0.5) & (ref[2] > 0.5))
                r = None if r is None else r * unit
            if r is None:
                continue
            qs.append(q / np.float32(r))
            cs.append(conf)
            views.append((buf[j].gray, p.R, p.T * r))
        Q, C = np.stack(qs), np.stack(cs)
        disagree = []  # median |log ratio| of every two pairs' maps where both trust
        for a in range(len(qs)):
            for b in range(a + 1, len(qs)):
                both = (C[a] > 0.5) & (C[b] > 0.5)
                if both.sum() >= 100:
                    disagree.append(float(np.median(np.abs(np.log(Q[a][both] / Q[b][both])))))
        if len(qs) == 1:
            q_out, c_out = Q[0], C[0] * np.float32(0.9)
        else:
            h, w = Q.shape[1:]
            m = _median_stack(Q.reshape(len(qs), -1)).reshape(h, w)
            with np.errstate(invalid="ignore"):
                agree = np.exp(-((Q / m[None] - 1.0) / 0.1) ** 2)
            W = np.where(np.isfinite(Q), C * agree, 0).astype(np.float32)
            sw = W.sum(0)
            with np.errstate(divide="ignore", invalid="ignore"):
                q_out = np.where(np.isfinite(Q), Q, 0).__mul__(W).sum(0) / sw
            n_valid = np.isfinite(Q).sum(0)
            # agreeing neighbours add up (probabilistic or); one alone keeps 0.9 of its own
            c_or = 1.0 - np.prod(1.0 - np.clip(W, 0, 1), axis=0)
            c_out = np.where(n_valid >= 2, c_or, 0.9 * W.max(0)).astype(np.float32)
            q_out = np.where(sw > 1e-6, q_out, np.nan).astype(np.float32)
        c_out = np.where(np.isfinite(q_out), c_out, 0).astype(np.float32)
        contradicted = None
        if self.est.photometric_check:
            c_out, contradicted = checked_confidence(t.gray, views, self.K, q_out, c_out)
        # signal to noise: the spread of the frame's log inverse depth against how much two
        # independent measurements of it disagree (pairs, or a pair and the earlier frames'
        # prediction at the tracks); near 1 the map holds no structure the noise does not
        noises = disagree + ([float(np.median(list(spreads.values())))] if spreads else [])
        trusted = c_out > 0.5
        snr, f_snr = None, 1.0
        if noises and trusted.sum() >= 100:
            p10, p90 = np.percentile(np.log(q_out[trusted]), [10, 90])
            signal = max(float(p90 - p10) / 2.56, SNR_SIGNAL_FLOOR)
            snr = signal / max(float(np.median(noises)), 1e-3)
            f_snr = float(np.clip((snr - SNR_RANGE[0]) / (SNR_RANGE[1] - SNR_RANGE[0]), 0, 1))
        # the scale chain keeps the geometric confidence (a noisy frame's depths still carry the
        # clip's unit); the cue's confidence also carries the frame's signal to noise
        ang_all = np.concatenate([a[3][a[2] > 0.5] for a in maps])
        info = {"parallax": True, "neighbours": [int(buf[j].index - t.index) for j, *_ in maps],
                "median_angle_deg": round(float(np.degrees(np.median(ang_all))) if ang_all.size else 0.0, 4),
                "pair_parallax_px": [round(m[4].parallax_px, 2) for m in maps],
                "scale_reset": reset, "reason": "parallax",
                "focal_px": round(float(self.K[0, 0]) * t.full_size[0] / self.size[0], 2),
                "focal_refined": self.focal_refined,
                "pair_disagreement": round(max(disagree), 4) if disagree else None,
                "track_spread": round(max(spreads.values()), 4) if spreads else None,
                "snr": None if snr is None else round(snr, 3), "rotation_ratio": self.ratios,
                "photometric_contradicted": None if contradicted is None else round(contradicted, 4)}
        return (q_out, c_out, f_snr, info), "parallax", best


def clip_gate(snrs: list[float]) -> float:
    """0..1: how far a clip's parallax is trusted at all, from the median signal to noise of its
    frames so far (``snrs``; through SNR_RANGE; 1 until CLIP_SNR_MIN_FRAMES frames have one). A
    frame's own SNR misses errors its pairs share (a rolling shutter under fast rotation, a wrong
    focal length): where most frames of the clip are noise, the few that look clean are not
    trusted either. Gates what the cue hands to the fusion, not the scale chain or the memory."""
    if len(snrs) < CLIP_SNR_MIN_FRAMES:
        return 1.0
    return _median_snr_gate(snrs)


def _median_snr_gate(snrs: list[float]) -> float:
    """0..1: the median of ``snrs`` (non-empty) through SNR_RANGE."""
    med = float(np.median(snrs))
    return float(np.clip((med - SNR_RANGE[0]) / (SNR_RANGE[1] - SNR_RANGE[0]), 0.0, 1.0))


def start_gate(snrs: list[float]) -> float:
    """The gate of the maps held back at a clip's start (:meth:`ParallaxEstimator.maps`):
    :func:`clip_gate` once CLIP_SNR_MIN_FRAMES frames have a signal to noise, else the median of
    those there are through SNR_RANGE, and 1 when none has one (nothing to judge by)."""
    if len(snrs) >= CLIP_SNR_MIN_FRAMES:
        return clip_gate(snrs)
    if not snrs:
        return 1.0
    return _median_snr_gate(snrs)


def _gated(m: CueMap, gate: float) -> CueMap:
    """``m`` with its confidence times ``gate`` (info ``clip_gate``); ``m`` itself when gate >= 1."""
    if gate >= 1.0:
        return m
    info = dict(m.info, clip_gate=round(gate, 3))
    return CueMap(m.name, m.inverse_depth, (m.confidence * np.float32(gate)).astype(np.float32), m.metric,
                  m.shift_free, info)


def _merge(q_a: np.ndarray, c_a: np.ndarray, q_b: np.ndarray, c_b: np.ndarray, k_a: np.ndarray,
           k_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A frame's own inverse depth q_a (confidence c_a) and the one carried from earlier frames q_b
    (c_b) fused: a confidence-weighted mean where they agree (within ~15 %), b's weight falling
    where they disagree. Returns (q, confidence, cue confidence): confidences are the
    probabilistic or of the agreeing weights, the second from the cue confidences k_a, k_b."""
    fa, fb = np.isfinite(q_a) & (c_a > 0), np.isfinite(q_b) & (c_b > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        agree = np.where(fa & fb, np.exp(-((q_b / q_a - 1.0) / 0.15) ** 2), 1.0)
    wa = np.where(fa, c_a, 0.0)
    wb = np.where(fb, c_b * agree, 0.0)
    sw = wa + wb
    with np.errstate(invalid="ignore", divide="ignore"):
        q = (np.nan_to_num(q_a) * wa + np.nan_to_num(q_b) * wb) / sw
    q = np.where(sw > 1e-6, q, np.nan).astype(np.float32)
    known = np.isfinite(q)
    out = []
    for x, y in ((wa, wb), (np.where(fa, k_a, 0.0), np.where(fb, k_b * agree, 0.0))):
        conf = 1.0 - (1.0 - np.clip(x, 0, 1)) * (1.0 - np.clip(y, 0, 1))
        out.append(np.where(known, conf, 0.0).astype(np.float32))
    return q, out[0], out[1]
